// The alignment tab: POST /v1/align, then cloud A moved onto cloud B in the view.

import { postJSON } from './api.js';
import { normalization } from './view.js';
import { showPose } from './pose.js';

const MOVE_MS = 1500;

/** Geodesic angle (degrees) between the rotations of two row-major 4x4 matrices. */
function angleDeg(p, q) {
  let trace = 0;
  for (let i = 0; i < 3; i++) for (let k = 0; k < 3; k++) trace += p[k][i] * q[k][i];
  return (Math.acos(Math.min(1, Math.max(-1, (trace - 1) / 2))) * 180) / Math.PI;
}

/**
 * Align A onto B through the service and show it: B (blue) and A (orange) as sent, both in B's
 * display frame (B's centroid at the origin, B's RMS radius as the unit), then A moving by
 * T_b_from_a. `truth`: the example pair's true T_b_from_a, if known. Returns the reply.
 */
export async function runAlign({ view, a, b, request, truth, elements }) {
  const toDisplay = showPair(view, a, b);
  const reply = await postJSON('/v1/align', { points_a: a, points_b: b, ...request });
  view.setPose('main', multiply(toDisplay, reply.T_b_from_a), MOVE_MS);
  showPose(elements.pose, 'T_b_from_a', reply.T_b_from_a);
  const parts = [
    `rotation ${reply.rotation_deg.toFixed(1)}°, ${(100 * reply.probability).toFixed(0)}% likely right`,
    `hypothesis ${reply.hypothesis}${reply.considered ? ` (rivals judged of ${reply.considered})` : ''}, ${reply.refined ? 'refined by ICP' : 'no ICP'}`,
    reply.runner_up ? `runner-up ${reply.runner_up.hypothesis} ${(100 * reply.runner_up.probability).toFixed(0)}%` : 'no runner-up',
    `${reply.iterations} IT-Net iterations, ${reply.elapsed_ms.toFixed(1)} ms on the server`,
  ];
  if (reply.up_a) parts.push('both poses held upright by each scan\'s up direction');
  if (truth) parts.push(`error against the example's truth: ${angleDeg(reply.T_b_from_a, truth).toFixed(2)}°`);
  elements.summary.textContent = parts.join(' · ');
  return reply;
}

/** Show B and A as sent, in B's display frame; returns that frame's row-major 4x4. */
export function showPair(view, a, b) {
  const { centre, scale } = normalization(b);
  const toDisplay = [[1, 0, 0, -centre[0]], [0, 1, 0, -centre[1]], [0, 0, 1, -centre[2]], [0, 0, 0, 1]];
  view.setCloud('reference', b, scale);
  view.setCloud('main', a, scale);
  view.setPose('reference', toDisplay);
  view.setPose('main', toDisplay);
  return toDisplay;
}

/** Row-major 4x4 product p · q. */
export function multiply(p, q) {
  return p.map((row) => q[0].map((_, j) => row.reduce((sum, v, k) => sum + v * q[k][j], 0)));
}
