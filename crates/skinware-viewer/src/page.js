// The skinware viewer page. It decodes the binary messages documented in
// docs/viewer.md, keeps the newest responses of every layer, and draws them at
// the display's frame rate into one ImageData. After each draw it
// acknowledges the updates it received, which is what lets the server send
// more: a slow page gets fewer updates, never a backlog.
'use strict';

const KIND_GEOMETRY = 1;
const KIND_UPDATE = 2;
const PROTOCOL_VERSION = 1;
// Indexed by WriterState::code (1 running ... 4 gone), the one numbering.
const STATES = [undefined, 'running', 'paused', 'faulted', 'gone'];
const MODES = ['periodic', 'asap', 'request'];
const FLAG_RESPONSES = 1;
// Updates the page lets the server send ahead of its draws.
const INITIAL_CREDIT = 2;
// Full colour at this response above baseline.
const SCALE_MAX = 20000;
// How fast the baseline follows a rising response (per update); it follows a
// falling one at once, so a pressed taxel keeps its colour for seconds.
const BASELINE_RISE = 0.002;

const canvas = document.getElementById('map');
const context = canvas.getContext('2d', { alpha: false });
const tooltip = document.getElementById('tooltip');
const layerRows = document.querySelector('#layers tbody');

// Statistics the browser test reads; all counters only grow.
const stats = window.skinStats = {
  updates: 0, draws: 0, updateBytes: 0, lastUpdateBytes: 0, geometryBytes: 0,
  lastUpdateNumber: -1, mode: null, fps: 0, updatesPerSecond: 0, animationFrames: 0, renderMs: 0,
  // Per layer, the sequence number of the newest frame received.
  seqs: [],
  // Per layer, the writer states updates reported, each change once, in order.
  statesSeen: [],
  // Overlays in the newest update, and how many updates carried some.
  markers: 0, arrows: 0, updatesWithMarkers: 0, updatesWithArrows: 0,
};

let skin = null;         // decoded geometry
let responses = null;    // Uint16Array, newest response per global sensor
let baseline = null;     // Float32Array, each taxel's resting response
let layerStatus = [];    // per layer: {state, writerRate, readRate, latency, seq}
let overlays = { arrows: [], markers: [] };
let layout = null;       // pixel placement of the taxels for the canvas size
let image = null;        // ImageData of the canvas and its Uint32 view
let socket = null;
let dirty = false;
let unacknowledged = 0;
let hovered = -1;

// Colour of a response above baseline, for every possible u16 difference.
const colourOf = (() => {
  const stops = [[0, 30, 34, 56], [0.15, 40, 30, 110], [0.35, 30, 110, 200], [0.55, 40, 200, 170],
    [0.75, 240, 220, 60], [1, 255, 70, 40]];
  const lut = new Uint32Array(256);
  for (let i = 0; i < 256; i++) {
    const t = i / 255;
    let k = 1;
    while (stops[k][0] < t) k++;
    const [t0, r0, g0, b0] = stops[k - 1], [t1, r1, g1, b1] = stops[k];
    const f = (t - t0) / (t1 - t0);
    lut[i] = rgba(r0 + f * (r1 - r0), g0 + f * (g1 - g0), b0 + f * (b1 - b0));
  }
  const table = new Uint32Array(65536);
  for (let v = 0; v < 65536; v++) table[v] = lut[Math.min(255, Math.round(255 * Math.sqrt(v / SCALE_MAX)))];
  drawLegend(lut);
  return table;
})();

function rgba(r, g, b) {
  // ImageData is RGBA in memory; every browser this page targets is little-endian.
  return (255 << 24 | (b & 255) << 16 | (g & 255) << 8 | (r & 255)) >>> 0;
}

const BACKGROUND = rgba(11, 12, 15);
const HATCH = { faulted: [rgba(112, 52, 52), rgba(58, 42, 42)], gone: [rgba(85, 85, 85), rgba(42, 42, 42)] };

function drawLegend(lut) {
  const scale = document.getElementById('scale');
  const legend = scale.getContext('2d');
  const strip = legend.createImageData(256, 1);
  new Uint32Array(strip.data.buffer).set(lut);
  for (let y = 0; y < scale.height; y++) legend.putImageData(strip, 0, y);
  document.getElementById('scale-max').textContent = SCALE_MAX.toLocaleString();
}

function decodeGeometry(buffer) {
  const view = new DataView(buffer);
  if (view.getUint8(1) !== PROTOCOL_VERSION) throw new Error(`protocol version ${view.getUint8(1)}, page speaks ${PROTOCOL_VERSION}`);
  const layerCount = view.getUint16(2, true), sensors = view.getUint32(4, true);
  const bounds = [0, 1, 2, 3].map(i => view.getFloat32(8 + 4 * i, true));
  let at = 24;
  const layers = [];
  for (let l = 0; l < layerCount; l++, at += 12) {
    layers.push({ first: view.getUint32(at, true), count: view.getUint32(at + 4, true), nominalRate: view.getFloat32(at + 8, true) });
  }
  const textBytes = view.getUint32(at, true);
  const names = new TextDecoder().decode(new Uint8Array(buffer, at + 4, textBytes)).split('\n');
  at = (at + 4 + textBytes + 3) & ~3;
  const positions = new Float32Array(buffer, at, 2 * sensors); at += 8 * sensors;
  const uid = new Uint32Array(buffer, at, sensors); at += 4 * sensors;
  const module = new Uint32Array(buffer, at, sensors); at += 4 * sensors;
  const patch = new Uint32Array(buffer, at, sensors);
  const layerOf = new Uint16Array(sensors);
  layers.forEach((layer, l) => { layer.name = names[l + 1]; layerOf.fill(l, layer.first, layer.first + layer.count); });
  return { name: names[0], sensors, bounds, layers, positions, uid, module, patch, layerOf };
}

function applyUpdate(buffer) {
  const view = new DataView(buffer);
  const layerCount = view.getUint16(2, true);
  if (layerCount !== skin.layers.length) throw new Error(`update for ${layerCount} layers, geometry has ${skin.layers.length}`);
  stats.lastUpdateNumber = view.getUint32(4, true);
  stats.mode = MODES[view.getUint8(1)];
  const arrows = view.getUint16(8, true), markers = view.getUint16(10, true);
  let at = 16;
  const included = [];
  for (let l = 0; l < layerCount; l++, at += 24) {
    layerStatus[l] = {
      state: STATES[view.getUint8(at)] || 'gone', writerRate: view.getFloat32(at + 4, true),
      readRate: view.getFloat32(at + 8, true), latency: view.getFloat32(at + 12, true),
      seq: view.getUint32(at + 16, true) + view.getUint32(at + 20, true) * 2 ** 32,
    };
    if (view.getUint8(at + 1) & FLAG_RESPONSES) included.push(l);
  }
  stats.seqs = layerStatus.map(status => status.seq);
  layerStatus.forEach((status, l) => {
    const seen = stats.statesSeen[l] || (stats.statesSeen[l] = []);
    if (seen[seen.length - 1] !== status.state) seen.push(status.state);
  });
  const next = { arrows: [], markers: [] };
  for (let i = 0; i < arrows; i++, at += 16) {
    next.arrows.push([0, 4, 8, 12].map(d => view.getFloat32(at + d, true)));
  }
  for (let i = 0; i < markers; i++, at += 16) {
    next.markers.push([0, 4, 8, 12].map(d => view.getFloat32(at + d, true)));
  }
  overlays = next;
  stats.markers = next.markers.length;
  stats.arrows = next.arrows.length;
  if (next.markers.length) stats.updatesWithMarkers++;
  if (next.arrows.length) stats.updatesWithArrows++;
  for (const l of included) {
    const { first, count } = skin.layers[l];
    const fresh = new Uint16Array(buffer, at, count);
    responses.set(fresh, first);
    for (let i = first, end = first + count; i < end; i++) {
      const r = responses[i], b = baseline[i];
      baseline[i] = r < b ? r : b + (r - b) * BASELINE_RISE;
    }
    at += 2 * count;
  }
}

// Where each taxel goes on the canvas, its square size, and which taxel each
// pixel belongs to (for hovering).
function computeLayout() {
  let width = Math.max(300, Math.floor(canvas.parentElement.clientWidth));
  const [minX, minY, maxX, maxY] = skin.bounds;
  const margin = 12;
  const spanX = Math.max(maxX - minX, 1e-6), spanY = Math.max(maxY - minY, 1e-6);
  let height = Math.max(200, Math.min(Math.round(window.innerHeight * 0.85), Math.round(width * spanY / spanX) + 2 * margin));
  const scale = Math.min((width - 2 * margin) / spanX, (height - 2 * margin) / spanY);
  // Shrink the canvas around the map, so that the page does not scale it down.
  width = Math.ceil(spanX * scale) + 2 * margin;
  height = Math.ceil(spanY * scale) + 2 * margin;
  canvas.width = width; canvas.height = height;
  canvas.style.maxWidth = `${width}px`;
  const n = skin.sensors, x = new Int32Array(n), y = new Int32Array(n);
  for (let i = 0; i < n; i++) {
    x[i] = Math.round(margin + (skin.positions[2 * i] - minX) * scale);
    y[i] = Math.round(height - margin - (skin.positions[2 * i + 1] - minY) * scale);
  }
  const size = Math.max(1, Math.min(8, Math.floor(0.8 * typicalSpacing() * scale)));
  const half = size >> 1;
  const offset = new Int32Array(n), hatch = new Uint8Array(n), pick = new Int32Array(width * height).fill(-1);
  for (let i = 0; i < n; i++) {
    const left = Math.min(Math.max(x[i] - half, 0), width - size), top = Math.min(Math.max(y[i] - half, 0), height - size);
    offset[i] = top * width + left;
    hatch[i] = ((left + top) >> 3) & 1;
    for (let py = Math.max(0, top - 1); py < Math.min(height, top + size + 1); py++) {
      pick.fill(i, py * width + Math.max(0, left - 1), py * width + Math.min(width, left + size + 1));
    }
  }
  image = context.createImageData(width, height);
  layout = { width, height, scale, minX, minY, margin, size, offset, hatch, pick, pixels: new Uint32Array(image.data.buffer) };
  dirty = true;
}

// The usual distance between neighbouring taxels, metres, from a sample.
function typicalSpacing() {
  const n = skin.sensors, p = skin.positions, nearest = [];
  const step = Math.max(1, Math.floor(n / 200));
  for (let s = 0; s < n; s += step) {
    let best = Infinity;
    for (let j = 0; j < n; j++) {
      if (j === s) continue;
      const dx = p[2 * j] - p[2 * s], dy = p[2 * j + 1] - p[2 * s + 1], d = dx * dx + dy * dy;
      if (d > 0 && d < best) best = d;
    }
    if (best < Infinity) nearest.push(Math.sqrt(best));
  }
  nearest.sort((a, b) => a - b);
  return nearest.length ? nearest[nearest.length >> 1] : 0.01;
}

function render() {
  const { width, size, offset, hatch, pixels } = layout;
  pixels.fill(BACKGROUND);
  skin.layers.forEach((layer, l) => {
    const state = (layerStatus[l] || { state: 'gone' }).state;
    const stripes = HATCH[state];
    for (let i = layer.first, end = layer.first + layer.count; i < end; i++) {
      let colour;
      if (stripes) {
        colour = stripes[hatch[i]];
      } else {
        const above = responses[i] - baseline[i];
        colour = colourOf[above <= 0 ? 0 : above >= 65535 ? 65535 : above | 0];
      }
      for (let row = 0, at = offset[i]; row < size; row++, at += width) {
        for (let column = 0; column < size; column++) pixels[at + column] = colour;
      }
    }
  });
  context.putImageData(image, 0, 0);
  drawOverlays();
}

function toCanvas(x, y) {
  return [layout.margin + (x - layout.minX) * layout.scale, layout.height - layout.margin - (y - layout.minY) * layout.scale];
}

function drawOverlays() {
  context.lineWidth = 2;
  for (const [x, y, radius, pressure] of overlays.markers) {
    const [cx, cy] = toCanvas(x, y);
    context.beginPath();
    context.arc(cx, cy, Math.max(4, radius * layout.scale), 0, 2 * Math.PI);
    context.fillStyle = `rgba(255, 255, 255, ${Math.min(0.45, 0.1 + Math.sqrt(Math.max(0, pressure) / SCALE_MAX) * 0.35)})`;
    context.fill();
    context.strokeStyle = '#ffffff';
    context.stroke();
  }
  context.strokeStyle = '#7fffd4';
  context.fillStyle = '#7fffd4';
  for (const [fx, fy, tx, ty] of overlays.arrows) {
    const [x0, y0] = toCanvas(fx, fy), [x1, y1] = toCanvas(tx, ty);
    const angle = Math.atan2(y1 - y0, x1 - x0);
    context.beginPath(); context.moveTo(x0, y0); context.lineTo(x1, y1); context.stroke();
    context.beginPath(); context.moveTo(x1, y1);
    context.lineTo(x1 - 10 * Math.cos(angle - 0.4), y1 - 10 * Math.sin(angle - 0.4));
    context.lineTo(x1 - 10 * Math.cos(angle + 0.4), y1 - 10 * Math.sin(angle + 0.4));
    context.closePath(); context.fill();
  }
}

function buildLayerTable() {
  layerRows.replaceChildren(...skin.layers.map(layer => {
    const row = document.createElement('tr');
    row.dataset.layer = layer.name;
    row.dataset.state = 'gone';
    row.innerHTML = '<td></td><td><span class="badge">gone</span></td><td></td><td></td><td></td><td></td>';
    row.cells[0].textContent = layer.name;
    row.cells[2].textContent = layer.count.toLocaleString();
    return row;
  }));
}

let lastTableUpdate = 0;
function updateLayerTable(now) {
  const full = now - lastTableUpdate > 250;
  if (full) lastTableUpdate = now;
  skin.layers.forEach((layer, l) => {
    const status = layerStatus[l];
    const row = layerRows.rows[l];
    if (!status || !row) return;
    if (row.dataset.state !== status.state) {
      row.dataset.state = status.state;
      row.querySelector('.badge').textContent = status.state;
    }
    if (full) {
      row.cells[3].textContent = status.writerRate.toFixed(1);
      row.cells[4].textContent = status.readRate.toFixed(1);
      row.cells[5].textContent = status.latency.toFixed(3);
    }
  });
}

// Draw times of the last second, for the page's own frame-rate display.
const drawTimes = [], updateTimes = [];
function countWithin(times, now) {
  while (times.length && times[0] < now - 1000) times.shift();
  return times.length;
}

function frame(now) {
  requestAnimationFrame(frame);
  if (!skin || !layout) return;
  updateLayerTable(now);
  stats.animationFrames++;
  if (dirty) {
    const started = performance.now();
    render();
    // A moving average of the drawing cost, for the docs and the test's report.
    stats.renderMs += (performance.now() - started - stats.renderMs) * 0.05;
    dirty = false;
    stats.draws++;
    drawTimes.push(now);
    if (hovered >= 0) showTooltip();
    if (unacknowledged > 0 && socket && socket.readyState === WebSocket.OPEN) {
      socket.send(JSON.stringify({ ack: unacknowledged }));
      unacknowledged = 0;
    }
  }
  stats.fps = countWithin(drawTimes, now);
  stats.updatesPerSecond = countWithin(updateTimes, now);
  if (stats.draws % 15 === 0) {
    const perUpdate = stats.updates ? stats.updateBytes / stats.updates / 1024 : 0;
    document.getElementById('fps').textContent =
      `${stats.fps} fps · ${stats.updatesPerSecond} updates/s · ${perUpdate.toFixed(1)} KiB/update`;
  }
}

function showTooltip() {
  const i = hovered;
  const l = skin.layerOf[i];
  const above = Math.round(responses[i] - baseline[i]);
  tooltip.textContent = `uid ${skin.uid[i]}  module ${skin.module[i]}  patch ${skin.patch[i]}\n` +
    `layer ${skin.layers[l].name} (${(layerStatus[l] || { state: 'gone' }).state})\n` +
    `response ${responses[i]}  (${above >= 0 ? '+' : ''}${above} above baseline)`;
}

canvas.addEventListener('mousemove', event => {
  if (!layout) return;
  const x = Math.floor(event.offsetX * canvas.width / canvas.clientWidth);
  const y = Math.floor(event.offsetY * canvas.height / canvas.clientHeight);
  hovered = x >= 0 && y >= 0 && x < layout.width && y < layout.height ? layout.pick[y * layout.width + x] : -1;
  tooltip.hidden = hovered < 0;
  if (hovered >= 0) {
    showTooltip();
    tooltip.style.left = `${event.offsetX + 14}px`;
    tooltip.style.top = `${event.offsetY + 14}px`;
  }
});
canvas.addEventListener('mouseleave', () => { hovered = -1; tooltip.hidden = true; });
window.addEventListener('resize', () => { if (skin) computeLayout(); });

function sendMode() {
  const mode = document.querySelector('input[name="mode"]:checked').value;
  document.getElementById('request').disabled = mode !== 'request';
  if (!socket || socket.readyState !== WebSocket.OPEN) return;
  const message = { mode };
  if (mode === 'periodic') message.rate_hz = Number(document.getElementById('rate').value) || 30;
  socket.send(JSON.stringify(message));
}
document.getElementById('mode').addEventListener('change', sendMode);
document.getElementById('mode').addEventListener('submit', event => event.preventDefault());
document.getElementById('request').addEventListener('click', () => {
  if (socket && socket.readyState === WebSocket.OPEN) socket.send(JSON.stringify({ request: true }));
});

function showError(text) {
  const error = document.getElementById('error');
  error.hidden = !text;
  error.textContent = text || '';
}

function connect() {
  const connection = document.getElementById('connection');
  socket = new WebSocket(`${location.protocol === 'https:' ? 'wss' : 'ws'}://${location.host}/ws`);
  socket.binaryType = 'arraybuffer';
  socket.onopen = () => { connection.dataset.state = 'open'; connection.textContent = 'connected'; };
  socket.onmessage = event => {
    if (typeof event.data === 'string') {
      showError(JSON.parse(event.data).error);
      return;
    }
    const kind = new DataView(event.data).getUint8(0);
    if (kind === KIND_GEOMETRY) {
      skin = decodeGeometry(event.data);
      responses = new Uint16Array(skin.sensors);
      baseline = new Float32Array(skin.sensors).fill(Infinity);
      layerStatus = [];
      stats.geometryBytes = event.data.byteLength;
      document.getElementById('skin-name').textContent = `${skin.name} · ${skin.sensors.toLocaleString()} sensors`;
      showError(null);
      buildLayerTable();
      computeLayout();
      sendMode();
      socket.send(JSON.stringify({ ack: INITIAL_CREDIT }));
    } else if (kind === KIND_UPDATE && skin) {
      applyUpdate(event.data);
      stats.updates++;
      stats.updateBytes += event.data.byteLength;
      stats.lastUpdateBytes = event.data.byteLength;
      updateTimes.push(performance.now());
      unacknowledged++;
      dirty = true;
    }
  };
  socket.onclose = () => {
    connection.dataset.state = 'closed';
    connection.textContent = 'disconnected; retrying';
    // Nothing is known about the layers until the server is back.
    layerStatus = layerStatus.map(status => ({ ...status, state: 'gone' }));
    dirty = true;
    setTimeout(connect, 1000);
  };
}

connect();
requestAnimationFrame(frame);
