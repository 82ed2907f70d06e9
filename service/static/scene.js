// The scene tab: POST /v1/scene with a depth image or a scene cloud, then the scene drawn with
// each object's points coloured, its box and, where it has a pose, its canonical axes.
//
// Display: the camera's frame (x right, y down, z ahead) turned half a turn about its z axis, so
// the floor is below and the view's camera (in front, on -z) looks into the scene as the depth
// camera did; centred on the scene's points and scaled by their RMS radius, as the other tabs
// scale a cloud.

import * as THREE from 'three';
import { normalization } from './view.js';

const PALETTE = [0xe8743b, 0x3b82c4, 0x2ca02c, 0x9467bd, 0xd62728, 0x8c564b, 0x17becf, 0xbcbd22];
const BACKGROUND = 0xb8b8b8;
const SHOWN_POINTS = 30000;
const KINDS = { png: 'image/png', npy: 'application/x-npy' };

/** A scene file -> the fetch body and content type: PNG and .npy as they are; any other cloud
 * file read on the server by itnet.cloud_io (POST /v1/clouds/read) and sent as float32 N x 3. */
async function sceneBody(file) {
  const suffix = file.name.split('.').pop().toLowerCase();
  if (KINDS[suffix]) return { body: await file.arrayBuffer(), kind: KINDS[suffix] };
  const read = await fetch(`/v1/clouds/read?filename=${encodeURIComponent(file.name)}`, {
    method: 'POST', body: await file.arrayBuffer(), headers: { 'content-type': 'application/octet-stream' },
  });
  const parsed = await read.json();
  if (!read.ok) throw new Error(parsed.detail ?? `${read.status}`);
  return { body: new Float32Array(parsed.points.flat()).buffer, kind: 'application/octet-stream' };
}

/**
 * Find the objects of `file` through the service and draw them in `view`. `intrinsics`: the
 * text 'fx,fy,cx,cy' (depth images), `depthScale`: depth units per metre or '' (the default),
 * `up`: which way is up in the camera's frame, the text 'x,y,z', or '' (the floor searched about
 * -y); `room`: 'true' (a room's fused cloud), 'false' (a camera's view) or '' (decided by the
 * service). Returns the reply.
 */
export async function runScene({ view, file, intrinsics, depthScale, up = '', room = '', budgetMs }) {
  const query = new URLSearchParams({ budget_ms: String(budgetMs), indices: 'false', points: String(SHOWN_POINTS) });
  const camera = intrinsics.split(',').map((v) => v.trim()).filter((v) => v !== '');
  if (camera.length === 4) ['fx', 'fy', 'cx', 'cy'].forEach((k, i) => query.set(k, camera[i]));
  if (depthScale) query.set('depth_scale', depthScale);
  if (up.trim()) query.set('up', up.trim());
  if (room) query.set('room', room);
  const { body, kind } = await sceneBody(file);
  const response = await fetch(`/v1/scene?${query}`, { method: 'POST', body, headers: { 'content-type': kind } });
  const reply = await response.json();
  if (!response.ok) throw new Error(reply.detail ?? `${response.status}`);
  drawScene(view, reply);
  return reply;
}

/** The objects as a list: category, probability (and whether unsure), points, pose or why none. */
export function describeObjects(list, reply) {
  list.replaceChildren(...reply.objects.map((o, k) => {
    const item = document.createElement('li');
    item.style.color = `#${PALETTE[k % PALETTE.length].toString(16).padStart(6, '0')}`;
    const pose = o.T_canonical_from_input
      ? `posed in ${o.iterations} iterations (${o.model})`
      : `no pose (${o.no_pose})`;
    const centre = o.box.center.map((v) => v.toFixed(2)).join(', ');
    const name = o.category ?? `unknown (${o.unknown}; ${o.candidates[0]?.category ?? '?'}`
      + ` ${(100 * o.category_probability).toFixed(0)}%)`;
    const named = o.category === null ? '' : ` ${(100 * o.category_probability).toFixed(0)}%`
      + (o.unsure ? ' (unsure)' : '');
    item.textContent = `${name}${named}, `
      + `${o.points} points, box centre [${centre}] m, ${pose}`;
    return item;
  }));
}

/** Replace the drawn scene (points, boxes, axes) by `reply`'s. */
export function drawScene(view, reply) {
  if (!view.scene) return;  // no WebGL
  if (view.sceneGroup) view.scene.remove(view.sceneGroup);
  const points = reply.scene_points ?? [];
  const { centre, scale } = normalization(points.length ? points : [[0, 0, 0]]);
  const group = new THREE.Group();
  group.rotation.z = Math.PI;  // camera frame (x right, y down) -> y up, seen from -z
  group.scale.setScalar(1 / scale);
  const inner = new THREE.Group();
  inner.position.set(-centre[0], -centre[1], -centre[2]);
  group.add(inner);
  inner.add(cloud(points, reply.scene_point_objects ?? []));
  reply.objects.forEach((o, k) => {
    const color = PALETTE[k % PALETTE.length];
    inner.add(box(o.box, color));
    if (o.T_canonical_from_input) inner.add(axes(o.T_canonical_from_input, o.box));
  });
  view.scene.add(group);
  view.sceneGroup = group;
}

function cloud(points, owners) {
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute('position', new THREE.Float32BufferAttribute(points.flat(), 3));
  const colors = [];
  const c = new THREE.Color();
  owners.forEach((k) => { c.setHex(k < 0 ? BACKGROUND : PALETTE[k % PALETTE.length]); colors.push(c.r, c.g, c.b); });
  geometry.setAttribute('color', new THREE.Float32BufferAttribute(colors, 3));
  return new THREE.Points(geometry, new THREE.PointsMaterial({ size: 2, sizeAttenuation: false, vertexColors: true }));
}

/** The box's 12 edges: `center`, `size` along the columns of `R_camera_from_box`. */
function box({ center, size, R_camera_from_box: r }, color) {
  const corner = (sx, sy, sz) => [0, 1, 2].map((i) => center[i]
    + r[i][0] * sx * size[0] / 2 + r[i][1] * sy * size[1] / 2 + r[i][2] * sz * size[2] / 2);
  const signs = [-1, 1];
  const edges = [];
  for (const a of signs) for (const b of signs) {
    edges.push(corner(-1, a, b), corner(1, a, b), corner(a, -1, b), corner(a, 1, b), corner(a, b, -1), corner(a, b, 1));
  }
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute('position', new THREE.Float32BufferAttribute(edges.flat(), 3));
  return new THREE.LineSegments(geometry, new THREE.LineBasicMaterial({ color }));
}

/** The object's canonical axes (x red, y green: up, z blue: back) at its box's centre: the rows
 * of T_canonical_from_input's rotation, in the camera frame. */
function axes(pose, { center, size }) {
  const group = new THREE.Group();
  const length = 0.6 * Math.max(...size);
  [[0, 0xd62728], [1, 0x2ca02c], [2, 0x1f77b4]].forEach(([row, color]) => {
    const dir = new THREE.Vector3(pose[row][0], pose[row][1], pose[row][2]).normalize();
    group.add(new THREE.ArrowHelper(dir, new THREE.Vector3(...center), length, color, 0.15 * length, 0.08 * length));
  });
  return group;
}
