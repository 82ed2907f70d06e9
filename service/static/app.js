// The page: controls, URL state, and the live anytime run over WS /v1/estimate/stream.
//
// The URL holds the state, so a link reproduces a run:
//   /?example=chair_a&model=chair&budget_ms=50&run=1          (opens the example and runs it)
//   /?tab=align&a=chair_a&b=chair_b&refine=1&run=1            (aligns an example pair)
// Other keys: max_iterations, ensemble (K runs from turned starts, fused), units (the cloud's unit,
// for model auto), up (which way is up in the cloud, x,y,z), play_ms (0: show iterations
// as they arrive). When a run ends, its
// final JSON is written into #result.

import { getJSON, readCloudFile, streamEstimate } from './api.js';
import { runAlign, showPair } from './align.js';
import { describeObjects, runScene } from './scene.js';
import { drawPlot } from './plot.js';
import { showPose } from './pose.js';
import { View, centring, normalization } from './view.js';

const $ = (id) => document.getElementById(id);
const params = new URLSearchParams(location.search);
const view = new View($('view3d'), $('notice'));
const state = { models: [], pairs: [], scenes: [], budgetSet: false, clouds: {}, estimates: [], queue: [], timer: null, stream: null };

function setStatus(text, error = false) {
  $('status').textContent = text;
  $('status').classList.toggle('error', error);
}

/** Write the controls' state into the URL (no reload), so the address can be shared. */
function saveUrl(extra = {}) {
  const tab = document.body.dataset.tab;
  const keep = {
    tab: tab === 'pose' ? null : tab,
    model: $('model').value,
    budget_ms: state.budgetSet ? $('budget').value : null,  // else the tab's own default
    max_iterations: $('max-iterations').value || null,
    up: $('up').value.trim() || null,
    ...(tab === 'pose'
      ? {
          example: state.clouds.main?.example ?? null,
          ensemble: $('ensemble').value || null,
          units: $('units').value || null,
          viewpoint: $('viewpoint').value.trim() || null,
          recheck: $('recheck').value || null,
          verify: $('verify').value || null,
          mirror: $('mirror').value || null,
          centre: $('centre').value || null,
          play_ms: $('play').value === '250' ? null : $('play').value,
        }
      : tab === 'align'
        ? { a: state.clouds.a?.example ?? null, b: state.clouds.b?.example ?? null, refine: $('refine').checked ? null : '0' }
        : { scene: $('example-scene').value || null }),
    ...extra,
  };
  const query = new URLSearchParams(Object.entries(keep).filter(([, v]) => v !== null && v !== ''));
  history.replaceState(null, '', `${location.pathname}?${query}`);
}

// Each tab's budget until the user sets one: a scene's objects share one budget, an alignment's
// two clouds and its choice another (the API's defaults).
const TAB_BUDGET_MS = { pose: 50, align: 100, scene: 500 };

function setTab(tab) {
  document.body.dataset.tab = tab;
  if (!state.budgetSet) $('budget').value = TAB_BUDGET_MS[tab];
  document.querySelectorAll('.tab').forEach((b) => b.classList.toggle('active', b.dataset.tab === tab));
  view.showCanonical(tab === 'pose');  // the alignment is shown in B's frame, not canonical
  if (view.sceneGroup) view.sceneGroup.visible = tab === 'scene';
  $('pose-title').textContent = { pose: 'Pose: T_canonical_from_input', align: 'Alignment: T_b_from_a', scene: '' }[tab];
  $('legend').textContent = {
    pose: 'orange: the cloud, by the pose so far (iteration 0: centred)',
    align: 'blue: B (reference) · orange: A, moved onto B · in B\'s frame, centred on B',
    scene: 'grey: the scene · each object in its colour: its points, its box, its axes (x red, y green up, z blue back)',
  }[tab];
  showClouds();
}

/** What the tab shows before a run: the cloud centred, or the pair as sent. */
function showClouds() {
  const { main, a, b } = state.clouds;
  if (document.body.dataset.tab === 'align') {
    if (a && b) showPair(view, a.points, b.points);
    return;
  }
  if (document.body.dataset.tab === 'scene') {
    view.removeCloud('reference');
    view.removeCloud('main');
    return;
  }
  view.removeCloud('reference');
  if (main) showCloud(main.points);
}

/** The model's entry of GET /v1/models (undefined for 'auto'). */
const modelInfo = (name) => state.models.find((m) => m.name === name);

/** The example pair of a category: the one named after it, else the first of that category. */
const pairOf = (category) => state.pairs.find((p) => p.category && p.name === category)
  ?? state.pairs.find((p) => p.category && p.category === category);

/** The align tab follows its example pair: where the model chosen is of another category, it
 * becomes the loaded model of the pair's category, else 'auto' (a chosen 'auto' stays). */
function followPair() {
  const pair = state.pairs.find((p) => p.a === $('example-a').value && p.b === $('example-b').value);
  const chosen = $('model').value;
  if (!pair?.category || chosen === 'auto' || modelInfo(chosen)?.category === pair.category) return;
  const match = state.models.find((m) => m.name === pair.category)
    ?? state.models.find((m) => m.category === pair.category);
  const offered = [...$('model').options].map((o) => o.value);
  const next = match?.name ?? (offered.includes('auto') ? 'auto' : null);
  if (next) { $('model').value = next; showModel(); }
}

function showModel() {
  const info = modelInfo($('model').value);
  view.setSymmetry(info ? info.symmetry : 'none');
  $('ensemble').options[0].textContent = info ? `the model's: ${info.recommended_ensemble ?? 1}` : "the model's";
  if (!info) {
    $('model-info').textContent = 'auto: the server classifies the cloud, then runs that category\'s model.';
    return;
  }
  const accuracy = info.accuracy[String(info.recommended_iterations)];
  const runs = info.recommended_ensemble ?? 1;
  $('model-info').textContent = `${info.name}: category ${info.category}, symmetry ${info.symmetry}, `
    + `${info.precision}, ${info.points} points, trained with ${info.trained_iterations} iterations; `
    + (accuracy === undefined ? '' : `${(100 * accuracy).toFixed(1)}% correct at ${info.recommended_iterations} iterations (one run); `)
    + (runs > 1 ? `${runs} runs fused by default, as many as the budget holds; ` : '')
    + (info.requires_up ? 'needs the up direction (Up: x,y,z); ' : '')
    + `one step ${info.step_ms.toFixed(2)} ms here.`;
}

function showCloud(points) {
  view.setCloud('main', points, normalization(points).scale);
  view.setPose('main', centring(points));
}

/** Load cloud `slot` ('main', 'a' or 'b') from an example name or a File. */
async function loadCloud(slot, source) {
  const isFile = typeof source !== 'string';
  setStatus(`loading ${isFile ? source.name : source}…`);
  const points = isFile ? await readCloudFile(source) : (await getJSON(`/v1/examples/${encodeURIComponent(source)}`)).points;
  state.clouds[slot] = { points, example: isFile ? null : source, name: isFile ? source.name : source };
  if ((slot === 'main') === (document.body.dataset.tab === 'pose')) showClouds();
  setStatus(`${state.clouds[slot].name}: ${points.length} points`);
  saveUrl();
}

/** A control's value as the request's field: numbers, 'true'/'false', 'x,y,z' as three numbers,
 * text; an empty control leaves the field to the model's default (null). */
function fieldValue(control) {
  const text = control.value.trim();
  if (text === '') return null;
  if (text === 'true' || text === 'false') return text === 'true';
  if (control.type === 'number' || /^\d+$/.test(text)) return Number(text);
  if (text.includes(',')) return text.split(',').map(Number);
  return text;
}

/** The request of the controls that carry a PoseRequest field (data-field), those of the
 * current tab only (``pose-only`` ones not for alignment). */
function collectRequest(poseTab) {
  const body = {};
  for (const control of document.querySelectorAll('[data-field]')) {
    if (!poseTab && control.closest('.pose-only')) continue;
    const value = fieldValue(control);
    if (value !== null) body[control.dataset.field] = value;
  }
  return body;
}

function request() {
  const body = collectRequest(false);
  delete body.up;  // alignment sends each cloud's up (up_a, up_b)
  return body;
}

/** The pose tab's request: every field its controls set; the rest are the model's defaults. */
function poseRequest() {
  return collectRequest(true);
}

function runPose() {
  const cloud = state.clouds.main;
  if (!cloud) return setStatus('pick an example or drop a file first', true);
  Object.assign(state, { estimates: [], queue: [], result: null });
  clearTimeout(state.timer);
  state.timer = null;
  $('result').textContent = '';
  $('iteration').textContent = '0';
  $('iterations').textContent = $('max-iterations').value || '…';
  $('stopped-by').textContent = '…';
  document.body.dataset.run = 'running';
  showCloud(cloud.points);
  drawPlot($('plot'), [], 1, 0);
  setButtons(true);
  setStatus(`running ${cloud.name}…`);
  saveUrl({ run: '1' });
  state.stream = streamEstimate({ points: cloud.points, ...poseRequest() }, { onMessage, onClose });
}

function onMessage(message) {
  if (message.type === 'estimate') {
    state.queue.push(message);
    pump();
  } else if (message.type === 'result') {
    const { type, ...result } = message;
    state.result = result;
    $('result').textContent = JSON.stringify(result, null, 2);
    $('iterations').textContent = String(result.iterations);
    $('stopped-by').textContent = result.stopped_by;
    $('timing').textContent = `(${result.iterations} iterations in ${result.elapsed_ms.toFixed(2)} ms, model ${result.model})`;
    const runs = result.ensemble ? `, ${result.ensemble} runs fused` : '';
    const verified = result.verified ? ', fused around the run verify found likeliest' : '';
    const rechecked = result.rechecked === true ? ', doubted and rechecked by more runs'
      : result.rechecked === false ? ', doubted (no time to recheck)' : '';
    const mirror = result.mirror ? ', finished by the mirror symmetry' : '';
    const centre = result.centre ? ', centre corrected' : '';
    setStatus(`done: ${result.iterations} iterations in ${result.elapsed_ms.toFixed(2)} ms${runs}${verified}${rechecked}${mirror}${centre}, stopped by ${result.stopped_by}`);
    pump();
  } else if (message.type === 'error') {
    setStatus(`refused: ${message.detail}`, true);
  } else if (message.category) {  // model 'auto': the classifier's answer comes first
    const p = message.category_probability;
    const size = message.size_used ? `, size ${message.size_m.toFixed(2)} m counted` : '';
    const upright = message.classified_upright ? ', levelled by up' : '';
    const second = message.second_opinion ? `, ${message.classify_looks} looks (one was unsure)` : '';
    setStatus(`classified as ${message.category}${p === undefined ? '' : ` (p = ${p.toFixed(2)})`}${size}${upright}${second}, model ${message.model ?? '?'}`);
    const chosen = modelInfo(message.model ?? message.category);
    if (chosen) view.setSymmetry(chosen.symmetry);
  }
}

function onClose(code) {
  setButtons(false);
  if (!state.result && code !== 1000) setStatus(`${$('status').textContent} (connection closed, code ${code})`, true);
  if (!state.result) document.body.dataset.run = 'failed';
}

/** Show queued iterations one by one: every play_ms (slowed so a person can follow), or at once. */
function pump() {
  if (state.timer) return;
  const playMs = Number($('play').value);
  const next = state.queue.shift();
  if (!next) {
    if (state.result) finish();
    return;
  }
  showIteration(next, playMs);
  if (playMs > 0) {
    state.timer = setTimeout(() => { state.timer = null; pump(); }, playMs);
  } else {
    pump();
  }
}

function showIteration(estimate, playMs) {
  state.estimates.push(estimate);
  $('iteration').textContent = String(estimate.iteration);
  view.setPose('main', estimate.T_canonical_from_input, playMs * 0.8);
  const { scale } = normalization(state.clouds.main.points);
  drawPlot($('plot'), state.estimates, scale, state.result?.iterations ?? Number($('max-iterations').value || 0));
  showPose($('pose'), 'T_canonical_from_input', estimate.T_canonical_from_input, estimate.quat_wxyz, estimate.quat_xyzw);
}

function finish() {
  const r = state.result;
  showPose($('pose'), 'T_canonical_from_input', r.T_canonical_from_input, r.quat_wxyz, r.quat_xyzw);
  if (!state.estimates.length) view.setPose('main', r.T_canonical_from_input);
  document.body.dataset.run = 'done';
}

async function runAlignTab() {
  const [a, b] = [state.clouds.a, state.clouds.b];
  if (!a || !b) return setStatus('pick clouds A and B first', true);
  $('result').textContent = '';
  document.body.dataset.run = 'running';
  setButtons(true);
  setStatus(`aligning ${a.name} onto ${b.name}…`);
  saveUrl({ run: '1' });
  const pair = state.pairs.find((p) => p.a === a.example && p.b === b.example);
  const body = { ...request(), refine: $('refine').checked ? null : false };
  // Which way is up: for a model that needs it, an example pair's scans say it for each (a
  // level-sensing camera's); otherwise the Up field's, for both clouds, when given.
  const up = $('up').value.trim() ? $('up').value.trim().split(',').map(Number) : null;
  if (modelInfo($('model').value)?.requires_up && pair?.up_a) Object.assign(body, { up_a: pair.up_a, up_b: pair.up_b });
  else if (up) Object.assign(body, { up_a: up, up_b: up });
  try {
    const reply = await runAlign({ view, a: a.points, b: b.points, request: body, truth: pair?.T_b_from_a,
      elements: { pose: $('pose'), summary: $('align-summary') } });
    $('result').textContent = JSON.stringify(reply, null, 2);
    setStatus(`aligned in ${reply.elapsed_ms.toFixed(1)} ms`);
    document.body.dataset.run = 'done';
  } catch (err) {
    setStatus(`refused: ${err.message}`, true);
    document.body.dataset.run = 'failed';
  }
  setButtons(false);
}

/** The chosen example scene's depth image, fetched as a file, or null where there is none. */
async function exampleSceneFile() {
  const name = $('example-scene').value;
  if (!name) return null;
  const response = await fetch(`/v1/examples/scenes/${encodeURIComponent(name)}`);
  if (!response.ok) throw new Error(`example scene ${name}: ${response.status}`);
  return new File([await response.blob()], `${name}.png`, { type: 'image/png' });
}

/** Choosing an example scene drops any chosen file and types its camera's intrinsics. */
function chooseExampleScene() {
  const example = state.scenes.find((s) => s.name === $('example-scene').value);
  if (!example) return;
  state.sceneFile = null;
  $('file-scene').value = '';
  const { fx, fy, cx, cy } = example.intrinsics;
  $('intrinsics').value = [fx, fy, cx, cy].join(',');
}

async function runSceneTab() {
  setButtons(true);
  try {
    const file = state.sceneFile ?? $('file-scene').files[0] ?? await exampleSceneFile();
    if (!file) {
      setStatus('drop or choose a depth image or a scene cloud first', true);
      document.body.dataset.run = 'failed';
      return setButtons(false);
    }
    setStatus(`finding the objects of ${file.name}…`);
    const reply = await runScene({ view, file, intrinsics: $('intrinsics').value,
      depthScale: $('depth-scale').value, up: $('scene-up').value, room: $('scene-room').value,
      budgetMs: Number($('budget').value) });
    describeObjects($('scene-objects'), reply);
    $('scene-summary').textContent = `${reply.objects.length} object(s) in ${reply.elapsed_ms.toFixed(0)} ms `
      + `(segmenting ${reply.segment_ms.toFixed(0)} ms, ${reply.points} points)`;
    $('result').textContent = JSON.stringify({ ...reply, scene_points: undefined, scene_point_objects: undefined }, null, 1);
    setStatus(`${file.name}: ${reply.objects.length} object(s)`);
    document.body.dataset.run = 'done';
  } catch (err) {
    setStatus(err.message, true);
    document.body.dataset.run = 'failed';
  }
  setButtons(false);
}

function setButtons(running) {
  $('run').disabled = running;
  $('cancel').disabled = !running || document.body.dataset.tab !== 'pose';
}

function options(select, names, chosen) {
  select.replaceChildren(...names.map((name) => new Option(name, name, false, name === chosen)));
}

function wireDrop(zone, input, slot) {
  const load = (file) => file && loadCloud(slot, file).catch((err) => setStatus(err.message, true));
  input.addEventListener('change', () => load(input.files[0]));
  zone.addEventListener('dragover', (e) => { e.preventDefault(); zone.classList.add('over'); });
  zone.addEventListener('dragleave', () => zone.classList.remove('over'));
  zone.addEventListener('drop', (e) => { e.preventDefault(); zone.classList.remove('over'); load(e.dataTransfer.files[0]); });
}

async function main() {
  const [models, examples] = await Promise.all([getJSON('/v1/models'), getJSON('/v1/examples')]);
  state.models = models.models;
  state.pairs = examples.pairs;
  const names = state.models.map((m) => m.name);
  if (models.auto) names.push('auto');  // the classifier, when the server has one
  options($('model'), names, params.get('model') ?? models.default_model);
  const clouds = examples.examples.map((e) => e.name);
  options($('example'), clouds, params.get('example') ?? clouds[0]);
  // The align tab opens on the pair of the chosen model's category where there is one.
  const first = pairOf(modelInfo($('model').value)?.category) ?? examples.pairs[0];
  options($('example-a'), clouds, params.get('a') ?? first?.a ?? clouds[0]);
  options($('example-b'), clouds, params.get('b') ?? first?.b ?? clouds[1]);
  state.scenes = examples.scenes ?? [];
  options($('example-scene'), state.scenes.map((s) => s.name), params.get('scene') ?? state.scenes[0]?.name);
  chooseExampleScene();
  if (params.has('budget_ms')) { $('budget').value = params.get('budget_ms'); state.budgetSet = true; }
  $('budget').addEventListener('change', () => { state.budgetSet = true; });
  if (params.has('max_iterations')) $('max-iterations').value = params.get('max_iterations');
  if (['1', '4', '6', '8'].includes(params.get('ensemble'))) $('ensemble').value = params.get('ensemble');
  if (['m', 'cm', 'mm', 'in', 'ft'].includes(params.get('units'))) $('units').value = params.get('units');
  if (params.get('up')) $('up').value = params.get('up');
  if (params.get('viewpoint')) $('viewpoint').value = params.get('viewpoint');
  for (const id of ['recheck', 'verify', 'mirror', 'centre']) {
    if (['true', 'false'].includes(params.get(id))) $(id).value = params.get(id);
  }
  if (params.has('play_ms')) $('play').value = params.get('play_ms') === '0' ? '0' : '250';
  if (params.get('refine') === '0') $('refine').checked = false;
  setTab(['align', 'scene'].includes(params.get('tab')) ? params.get('tab') : 'pose');
  showModel();
  if (document.body.dataset.tab === 'align' && !params.has('model')) followPair();

  document.querySelectorAll('.tab').forEach((b) => b.addEventListener('click', () => {
    setTab(b.dataset.tab);
    if (b.dataset.tab === 'align') followPair();
    saveUrl();
  }));
  $('model').addEventListener('change', () => { showModel(); saveUrl(); });
  for (const id of ['budget', 'max-iterations', 'ensemble', 'units', 'up', 'viewpoint', 'recheck', 'verify', 'mirror', 'centre', 'play', 'refine']) $(id).addEventListener('change', () => saveUrl());
  const pick = (slot, id) => $(id).addEventListener('change', () => loadCloud(slot, $(id).value).catch((err) => setStatus(err.message, true)));
  pick('main', 'example'); pick('a', 'example-a'); pick('b', 'example-b');
  for (const id of ['example-a', 'example-b']) $(id).addEventListener('change', () => { followPair(); saveUrl(); });
  wireDrop($('drop'), $('file'), 'main'); wireDrop($('drop-a'), $('file-a'), 'a'); wireDrop($('drop-b'), $('file-b'), 'b');
  $('run').addEventListener('click', () => ({ pose: runPose, align: runAlignTab, scene: runSceneTab })[document.body.dataset.tab]());
  const sceneZone = $('drop-scene');
  $('example-scene').addEventListener('change', () => { chooseExampleScene(); saveUrl(); });
  const takeScene = (file) => { if (file) { state.sceneFile = file; setStatus(`${file.name}: press Run`); } };
  $('file-scene').addEventListener('change', () => takeScene($('file-scene').files[0]));
  sceneZone.addEventListener('dragover', (e) => { e.preventDefault(); sceneZone.classList.add('over'); });
  sceneZone.addEventListener('dragleave', () => sceneZone.classList.remove('over'));
  sceneZone.addEventListener('drop', (e) => { e.preventDefault(); sceneZone.classList.remove('over'); takeScene(e.dataTransfer.files[0]); });
  $('cancel').addEventListener('click', () => state.stream?.cancel());

  await Promise.all([loadCloud('main', $('example').value), loadCloud('a', $('example-a').value), loadCloud('b', $('example-b').value)]);
  document.body.dataset.ready = 'true';
  if (params.get('run') === '1') $('run').click();
}

main().catch((err) => setStatus(`could not start: ${err.message}`, true));
