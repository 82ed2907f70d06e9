// Showing a pose: the 4x4 matrix and both quaternion orders, each with a copy button.

/** Quaternion [w, x, y, z] (w >= 0) of the rotation part of a row-major 4x4 (Shepperd's method). */
export function quatWxyz(m) {
  const [r00, r11, r22] = [m[0][0], m[1][1], m[2][2]];
  const trace = r00 + r11 + r22;
  let q;
  if (trace > 0) {
    const s = 2 * Math.sqrt(1 + trace);
    q = [s / 4, (m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s];
  } else if (r00 > r11 && r00 > r22) {
    const s = 2 * Math.sqrt(1 + r00 - r11 - r22);
    q = [(m[2][1] - m[1][2]) / s, s / 4, (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s];
  } else if (r11 > r22) {
    const s = 2 * Math.sqrt(1 + r11 - r00 - r22);
    q = [(m[0][2] - m[2][0]) / s, (m[0][1] + m[1][0]) / s, s / 4, (m[1][2] + m[2][1]) / s];
  } else {
    const s = 2 * Math.sqrt(1 + r22 - r00 - r11);
    q = [(m[1][0] - m[0][1]) / s, (m[0][2] + m[2][0]) / s, (m[1][2] + m[2][1]) / s, s / 4];
  }
  return q[0] < 0 ? q.map((v) => -v) : q;
}

const fmt = (v) => (Math.abs(v) < 5e-7 ? 0 : v).toFixed(6).padStart(11);

/**
 * Fill `element` with the pose: matrix `name` (row-major 4x4), quat_wxyz and quat_xyzw (given,
 * or computed from the matrix), each as text with a button that copies it as JSON.
 */
export function showPose(element, name, matrix, wxyz = quatWxyz(matrix), xyzw = [...wxyz.slice(1), wxyz[0]]) {
  element.replaceChildren(
    block(`${name} (4×4, row-major)`, matrix.map((row) => row.map(fmt).join(' ')).join('\n'), JSON.stringify(matrix)),
    block('quat_wxyz (w, x, y, z)', wxyz.map(fmt).join(' '), JSON.stringify(wxyz)),
    block('quat_xyzw (x, y, z, w: ROS, SciPy)', xyzw.map(fmt).join(' '), JSON.stringify(xyzw)),
  );
}

function block(title, text, copied) {
  const div = document.createElement('div');
  div.className = 'pose-block';
  const head = document.createElement('div');
  head.className = 'pose-head';
  const span = document.createElement('span');
  span.textContent = title;
  const button = document.createElement('button');
  button.textContent = 'copy';
  button.title = 'copy as JSON';
  button.addEventListener('click', () => copy(copied, button));
  head.append(span, button);
  const pre = document.createElement('pre');
  pre.textContent = text;
  div.append(head, pre);
  return div;
}

async function copy(text, button) {
  try {
    await navigator.clipboard.writeText(text);
  } catch {  // no clipboard API (not a secure context): the old way
    const area = Object.assign(document.createElement('textarea'), { value: text });
    document.body.append(area);
    area.select();
    document.execCommand('copy');
    area.remove();
  }
  button.textContent = 'copied';
  setTimeout(() => { button.textContent = 'copy'; }, 1200);
}
