// The service's HTTP and WebSocket API, as the page uses it.

/** GET a JSON resource; throws an Error with the service's `detail` on a 4xx/5xx. */
export async function getJSON(path) {
  return reply(await fetch(path));
}

/** POST a JSON body (or raw bytes with `raw: true`); returns the parsed JSON reply. */
export async function postJSON(path, body, { raw = false } = {}) {
  const init = raw
    ? { method: 'POST', body, headers: { 'content-type': 'application/octet-stream' } }
    : { method: 'POST', body: JSON.stringify(body), headers: { 'content-type': 'application/json' } };
  return reply(await fetch(path, init));
}

async function reply(response) {
  const text = await response.text();
  let body = null;
  try { body = JSON.parse(text); } catch { /* not JSON: reported below */ }
  if (!response.ok) {
    throw new Error(body?.detail ?? `${response.status} ${response.statusText}`);
  }
  return body;
}

/** A dropped file -> its points [[x, y, z], ...], read on the server by itnet.cloud_io. */
export async function readCloudFile(file) {
  const path = `/v1/clouds/read?filename=${encodeURIComponent(file.name)}`;
  const body = await postJSON(path, await file.arrayBuffer(), { raw: true });
  return body.points;
}

/**
 * Run one estimate over WS /v1/estimate/stream (protocol: docs/service.md).
 * Calls onMessage(m) for every message: {type: "estimate" | "result" | "error" | ...}; onClose(code)
 * once the socket closes. Returns {cancel()}, which asks the server to stop before its next step.
 */
export function streamEstimate(request, { onMessage, onClose }) {
  const scheme = location.protocol === 'https:' ? 'wss' : 'ws';
  const socket = new WebSocket(`${scheme}://${location.host}/v1/estimate/stream`);
  socket.onopen = () => socket.send(JSON.stringify(request));
  socket.onmessage = (event) => onMessage(JSON.parse(event.data));
  socket.onerror = () => {};  // the close event that follows says what happened
  socket.onclose = (event) => onClose(event.code);
  return {
    cancel() {
      if (socket.readyState === WebSocket.OPEN) socket.send(JSON.stringify({ type: 'cancel' }));
    },
  };
}
