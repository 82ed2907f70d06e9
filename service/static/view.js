// The 3D view: clouds, the canonical axes with their labels, the category's symmetry.
//
// Display units: a cloud is drawn scaled by 1 / s, s its RMS radius about its centroid (the
// service's own normalisation), so every cloud and the axes share one size whatever the unit.
// A cloud's pose is a 4x4 row-major matrix that maps its points as sent into the shown frame.

import * as THREE from 'three';
import { OrbitControls } from 'three/addons/OrbitControls.js';

const COLORS = { main: 0xe8743b, reference: 0x3b82c4 };

/** Centroid [x, y, z] and RMS radius of points [[x, y, z], ...] (as itnet.preprocess does). */
export function normalization(points) {
  const c = [0, 0, 0];
  for (const p of points) { c[0] += p[0]; c[1] += p[1]; c[2] += p[2]; }
  c.forEach((_, i) => { c[i] /= points.length; });
  let sum = 0;
  for (const p of points) sum += (p[0] - c[0]) ** 2 + (p[1] - c[1]) ** 2 + (p[2] - c[2]) ** 2;
  return { centre: c, scale: Math.sqrt(sum / points.length) || 1 };
}

/** The row-major 4x4 that moves a cloud's centroid to the origin (the engine's iteration 0). */
export function centring(points) {
  const { centre } = normalization(points);
  return [[1, 0, 0, -centre[0]], [0, 1, 0, -centre[1]], [0, 0, 1, -centre[2]], [0, 0, 0, 1]];
}

export class View {
  /** `canvas`: where to draw. Without WebGL the view says so and its methods do nothing. */
  constructor(canvas, notice) {
    this.clouds = {};
    this.scale = 1;
    this.tweens = [];
    try {
      this.renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
    } catch (err) {
      notice.textContent = `3D view unavailable here (${err.message}); the numbers still update.`;
      notice.hidden = false;
      return;
    }
    this.renderer.setPixelRatio(window.devicePixelRatio);
    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(0xfbfbfa);
    this.camera = new THREE.PerspectiveCamera(40, 1, 0.01, 100);
    this.camera.position.set(3.2, 2.4, -4.2);  // in front (-z), above, to the side
    this.controls = new OrbitControls(this.camera, canvas);
    this.controls.enableDamping = true;
    this.frame = new THREE.Group();
    this.scene.add(this.frame);
    this.drawAxes();
    this.symmetry = new THREE.Group();
    this.scene.add(this.symmetry);
    const loop = (now) => {
      this.resize();
      this.stepTweens(now);
      this.controls.update();
      this.renderer.render(this.scene, this.camera);
      requestAnimationFrame(loop);
    };
    requestAnimationFrame(loop);
  }

  resize() {
    const canvas = this.renderer.domElement;
    const { clientWidth: w, clientHeight: h } = canvas;
    if (canvas.width !== Math.floor(w * window.devicePixelRatio) || canvas.height !== Math.floor(h * window.devicePixelRatio)) {
      this.renderer.setSize(w, h, false);
      this.camera.aspect = w / Math.max(h, 1);
      this.camera.updateProjectionMatrix();
    }
  }

  drawAxes() {
    const axes = [
      [[1.4, 0, 0], 0xd62728, '+x'],
      [[0, 1.4, 0], 0x2ca02c, '+y up'],
      [[0, 0, 1.4], 0x1f77b4, '+z back'],
    ];
    for (const [tip, color, text] of axes) {
      const dir = new THREE.Vector3(...tip).normalize();
      this.frame.add(new THREE.ArrowHelper(dir, new THREE.Vector3(), 1.4, color, 0.1, 0.05));
      this.frame.add(label(text, new THREE.Vector3(...tip).multiplyScalar(1.12), color));
    }
    const grid = new THREE.GridHelper(3, 6, 0xcccccc, 0xe6e6e6);
    grid.position.y = -1.2;
    this.frame.add(grid);
  }

  /** Show or hide the canonical axes and the symmetry (hidden where the view is not canonical). */
  showCanonical(visible) {
    if (!this.scene) return;
    this.frame.visible = visible;
    this.symmetry.visible = visible;
  }

  /** The category's symmetry: front arrows (toward -z) for every equivalent turn about +y. */
  setSymmetry(name) {
    if (!this.scene) return;
    this.symmetry.clear();
    const turns = { none: 1, yaw180: 2, yaw90: 4 }[name];
    if (turns === undefined) {  // 'yaw': any turn about up, a ring
      const ring = new THREE.EllipseCurve(0, 0, 1.1, 1.1).getPoints(64);
      const geometry = new THREE.BufferGeometry().setFromPoints(ring.map((p) => new THREE.Vector3(p.x, -1.2, p.y)));
      this.symmetry.add(new THREE.LineLoop(geometry, new THREE.LineBasicMaterial({ color: 0x9467bd })));
      this.symmetry.add(label('any turn about +y', new THREE.Vector3(0, -1.05, -1.25), 0x9467bd));
      return;
    }
    for (let k = 0; k < turns; k++) {
      const angle = (2 * Math.PI * k) / turns;
      const dir = new THREE.Vector3(-Math.sin(angle), 0, -Math.cos(angle));
      const origin = new THREE.Vector3(0, -1.2, 0);
      const color = k === 0 ? 0x9467bd : 0xc5b0d5;
      this.symmetry.add(new THREE.ArrowHelper(dir, origin, 1.3, color, 0.12, 0.07));
      const text = k === 0 ? 'front (-z)' : `front, turned ${Math.round((360 * k) / turns)}°`;
      this.symmetry.add(label(text, dir.clone().multiplyScalar(1.55).add(origin), color));
    }
  }

  /** Show `points` as cloud `key` ('main' or 'reference'); `scale` sets the display unit. */
  setCloud(key, points, scale) {
    this.scale = scale;
    if (!this.scene) return;
    this.removeCloud(key);
    const positions = new Float32Array(points.length * 3);
    points.forEach((p, i) => positions.set(p, 3 * i));
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute('position', new THREE.BufferAttribute(positions, 3));
    const material = new THREE.PointsMaterial({ color: COLORS[key], size: 0.035 });
    const cloud = new THREE.Points(geometry, material);
    cloud.matrixAutoUpdate = false;
    this.clouds[key] = cloud;
    this.scene.add(cloud);
  }

  removeCloud(key) {
    if (this.clouds[key]) {
      this.scene.remove(this.clouds[key]);
      this.clouds[key].geometry.dispose();
      delete this.clouds[key];
    }
  }

  /** Place cloud `key` by `pose` (row-major 4x4, input -> shown frame), over `ms` milliseconds. */
  setPose(key, pose, ms = 0) {
    const cloud = this.clouds[key];
    if (!cloud) return;
    const target = new THREE.Matrix4().set(...pose.flat()).premultiply(
      new THREE.Matrix4().makeScale(1 / this.scale, 1 / this.scale, 1 / this.scale));
    this.tweens = this.tweens.filter((t) => t.cloud !== cloud);
    if (ms <= 0) {
      cloud.matrix.copy(target);
      return;
    }
    this.tweens.push({ cloud, from: decompose(cloud.matrix), to: decompose(target), start: performance.now(), ms });
  }

  stepTweens(now) {
    this.tweens = this.tweens.filter((t) => {
      const f = Math.min(1, (now - t.start) / t.ms);
      const ease = f * f * (3 - 2 * f);
      const position = t.from.position.clone().lerp(t.to.position, ease);
      const rotation = t.from.rotation.clone().slerp(t.to.rotation, ease);
      t.cloud.matrix.compose(position, rotation, t.to.scale);
      return f < 1;
    });
  }
}

function decompose(matrix) {
  const parts = { position: new THREE.Vector3(), rotation: new THREE.Quaternion(), scale: new THREE.Vector3() };
  matrix.decompose(parts.position, parts.rotation, parts.scale);
  return parts;
}

/** A text label that always faces the camera. */
function label(text, position, color) {
  const canvas = document.createElement('canvas');
  canvas.width = 256;
  canvas.height = 64;
  const context = canvas.getContext('2d');
  context.font = '28px sans-serif';
  context.fillStyle = `#${color.toString(16).padStart(6, '0')}`;
  context.textAlign = 'center';
  context.textBaseline = 'middle';
  context.fillText(text, 128, 32);
  const sprite = new THREE.Sprite(new THREE.SpriteMaterial({ map: new THREE.CanvasTexture(canvas), depthTest: false }));
  sprite.position.copy(position);
  sprite.scale.set(0.8, 0.2, 1);
  return sprite;
}
