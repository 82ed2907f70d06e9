// A small plot of the anytime run, one column per iteration: the update's rotation (degrees,
// bars) and translation (in cloud radii, line) on top, the elapsed time (ms, line) below.

const ROTATION = '#e8743b';
const TRANSLATION = '#3b82c4';
const ELAPSED = '#555';

/** Draw `estimates` (the stream's messages) on `canvas`; `scale` converts input units to radii. */
export function drawPlot(canvas, estimates, scale, iterations) {
  const ctx = canvas.getContext('2d');
  const { width, height } = canvas;
  ctx.clearRect(0, 0, width, height);
  ctx.font = '11px sans-serif';
  const n = Math.max(iterations || 0, estimates.length, 1);
  const left = 34;
  const right = width - 34;
  const x = (i) => left + ((i - 0.5) / n) * (right - left);
  const top = { y0: 18, y1: height * 0.55 };
  const bottom = { y0: height * 0.55 + 22, y1: height - 16 };

  const rotations = estimates.map((e) => e.update_rotation_deg);
  const shifts = estimates.map((e) => e.update_translation / scale);
  const maxRotation = niceMax(Math.max(1, ...rotations));
  const maxShift = niceMax(Math.max(0.01, ...shifts));
  frame(ctx, left, right, top, `update: rotation (°, bars, max ${maxRotation}) · translation (radii, line, max ${maxShift})`);
  const barWidth = Math.max(2, ((right - left) / n) * 0.6);
  ctx.fillStyle = ROTATION;
  estimates.forEach((e, k) => {
    const h = (rotations[k] / maxRotation) * (top.y1 - top.y0);
    ctx.fillRect(x(e.iteration) - barWidth / 2, top.y1 - h, barWidth, h);
  });
  line(ctx, estimates.map((e, k) => [x(e.iteration), top.y1 - (shifts[k] / maxShift) * (top.y1 - top.y0)]), TRANSLATION);

  const elapsed = estimates.map((e) => e.elapsed_ms);
  const maxElapsed = niceMax(Math.max(0.1, ...elapsed));
  frame(ctx, left, right, bottom, `elapsed since the request (ms, max ${maxElapsed})`);
  line(ctx, estimates.map((e, k) => [x(e.iteration), bottom.y1 - (elapsed[k] / maxElapsed) * (bottom.y1 - bottom.y0)]), ELAPSED);

  ctx.fillStyle = '#333';
  ctx.textAlign = 'center';
  const every = Math.ceil(n / 10);
  for (let i = 1; i <= n; i += every) ctx.fillText(String(i), x(i), height - 3);
}

function frame(ctx, left, right, band, title) {
  ctx.strokeStyle = '#bbb';
  ctx.beginPath();
  ctx.moveTo(left, band.y0);
  ctx.lineTo(left, band.y1);
  ctx.lineTo(right, band.y1);
  ctx.stroke();
  ctx.fillStyle = '#333';
  ctx.textAlign = 'left';
  ctx.fillText(title, left, band.y0 - 6);
}

function line(ctx, points, color) {
  ctx.strokeStyle = color;
  ctx.fillStyle = color;
  ctx.lineWidth = 1.5;
  ctx.beginPath();
  points.forEach(([px, py], k) => (k ? ctx.lineTo(px, py) : ctx.moveTo(px, py)));
  ctx.stroke();
  for (const [px, py] of points) ctx.fillRect(px - 2, py - 2, 4, 4);
  ctx.lineWidth = 1;
}

/** 1, 2 or 5 times a power of ten, at least `value`. */
function niceMax(value) {
  const power = 10 ** Math.floor(Math.log10(value));
  const step = [1, 2, 5, 10].find((m) => m * power >= value);
  return Number((step * power).toPrecision(2));
}
