// The skinware viewer page. It decodes the binary messages documented in
// docs/viewer.md, keeps the newest responses of every layer, and draws them at
// the display's frame rate into one ImageData. After each draw it
// acknowledges the updates it received, which is what lets the server send
// more: a slow page gets fewer updates, never a backlog.
'use strict';

const KIND_GEOMETRY = 1;
const KIND_UPDATE = 2;
const PROTOCOL_VERSION = 3;
// Indexed by WriterState::code (1 running ... 4 gone), the one numbering;
// 0: connecting, the server has not read the layer yet.
const STATES = ['connecting', 'running', 'paused', 'faulted', 'gone'];
const MODES = ['periodic', 'asap', 'request'];
const FLAG_RESPONSES = 1;
const LAYER_RECORD_BYTES = 32;
// The compact responses (docs/viewer.md): blocks of this many taxels, each
// a head word (minimum, bit width) and the values' bits.
const BLOCK = 256;
// Updates the page lets the server send ahead of its draws.
const INITIAL_CREDIT = 2;
// Full colour at this response above baseline until the server has learnt
// a layer's range (an eighth of 16 bits, as the server's floor).
const DEFAULT_FULL_SCALE = 8191;
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
  // What the updates received would have been with raw 16-bit responses
  // (protocol 2), to compare with updateBytes; and the decoding's cost per update.
  rawUpdateBytes: 0, decodeMs: 0,
  // Per layer, the sequence number of the newest frame received.
  seqs: [],
  // Per layer, the writer states updates reported, each change once, in order.
  statesSeen: [],
  // Overlays in the newest update, and how many updates carried some, and
  // how many times what they showed changed.
  markers: 0, arrows: 0, updatesWithMarkers: 0, updatesWithArrows: 0, overlayChanges: 0,
  // Per layer, where full colour is now (the range typed in for its sensor type, or the auto one), and the auto one.
  fullScales: [], autoScales: [],
  // What the page says of the skin as a whole: 'running', 'stopped' (its layers gone) or 'server gone'.
  skinState: 'connecting',
};

let skin = null;         // decoded geometry
let responses = null;    // Uint16Array, newest response per global sensor
let baseline = null;     // Float32Array, each taxel's resting response
let layerStatus = [];    // per layer: {state, writerRate, readRate, latency, seq, fullScale, resting, highest}
let manualScales = {};   // per sensor type: the full colour typed in, or null (auto)
let overlays = { arrows: [], markers: [] };
let overlayKey = '';     // what the overlays drawn are, to count changes
let layout = null;       // pixel placement of the taxels for the canvas size
let image = null;        // ImageData of the canvas and its Uint32 view
let socket = null;
let dirty = false;
let unacknowledged = 0;
let hovered = -1;

// The colour scale: 256 colours from nothing to full.
const lut = (() => {
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
  drawLegend(lut);
  return lut;
})();

function rgba(r, g, b) {
  // ImageData is RGBA in memory; every browser this page targets is little-endian.
  return (255 << 24 | (b & 255) << 16 | (g & 255) << 8 | (r & 255)) >>> 0;
}

const BACKGROUND = rgba(11, 12, 15);
const GREY_HATCH = [rgba(85, 85, 85), rgba(42, 42, 42)];
const HATCH = { faulted: [rgba(112, 52, 52), rgba(58, 42, 42)], gone: GREY_HATCH, unknown: GREY_HATCH };

function drawLegend(lut) {
  const scale = document.getElementById('scale');
  const legend = scale.getContext('2d');
  const strip = legend.createImageData(256, 1);
  new Uint32Array(strip.data.buffer).set(lut);
  for (let y = 0; y < scale.height; y++) legend.putImageData(strip, 0, y);
}

// Where full colour is for layer l: the range typed in for its sensor
// type, else the one the server learnt from the responses of the layers of
// that type, else the default.
function fullScaleOf(l) {
  const status = layerStatus[l];
  return manualScales[skin.layers[l].sensorType] || (status && status.fullScale) || DEFAULT_FULL_SCALE;
}

// The colour of every response above baseline for one full scale, on a
// square-root scale; a few kept, as the scales change only when a layer's
// range grows or one is typed in.
const colourTables = new Map();
function colourTable(fullScale) {
  let table = colourTables.get(fullScale);
  if (!table) {
    if (colourTables.size >= 8) colourTables.clear();
    table = new Uint32Array(65536);
    const k = 255 * 255 / fullScale;
    for (let v = 0; v < 65536; v++) table[v] = lut[Math.min(255, Math.round(Math.sqrt(v * k)))];
    colourTables.set(fullScale, table);
  }
  return table;
}

// The geometry message, version 3 (docs/viewer.md). A server of another
// version gets the page's message instead of a map.
function decodeGeometry(buffer) {
  const view = new DataView(buffer);
  const version = view.getUint8(1);
  if (version !== PROTOCOL_VERSION) {
    throw new Error(`the server speaks the viewer's protocol ${version}, this page ${PROTOCOL_VERSION}: reload the page (Ctrl-R)`);
  }
  const layerCount = view.getUint16(2, true), sensors = view.getUint32(4, true);
  const bounds = [0, 1, 2, 3].map(i => view.getFloat32(8 + 4 * i, true));
  const placeCount = view.getUint32(24, true), labelCount = view.getUint32(28, true);
  let at = 32;
  const layers = [];
  for (let l = 0; l < layerCount; l++, at += 12) {
    layers.push({ first: view.getUint32(at, true), count: view.getUint32(at + 4, true), nominalRate: view.getFloat32(at + 8, true) });
  }
  const textBytes = view.getUint32(at, true);
  const lines = new TextDecoder().decode(new Uint8Array(buffer, at + 4, textBytes)).split('\n');
  at = (at + 4 + textBytes + 3) & ~3;
  const places = lines.slice(1 + 2 * layerCount, 1 + 2 * layerCount + placeCount);
  const labelTexts = lines.slice(1 + 2 * layerCount + placeCount);
  const labels = [];
  for (let b = 0; b < labelCount; b++, at += 16) {
    labels.push({ text: labelTexts[b], bounds: [0, 4, 8, 12].map(d => view.getFloat32(at + d, true)) });
  }
  const positions = new Float32Array(buffer, at, 2 * sensors); at += 8 * sensors;
  const uid = new Uint32Array(buffer, at, sensors); at += 4 * sensors;
  const module = new Uint32Array(buffer, at, sensors); at += 4 * sensors;
  const patch = new Uint32Array(buffer, at, sensors); at += 4 * sensors;
  const place = new Uint32Array(buffer, at, sensors);
  const layerOf = new Uint16Array(sensors);
  layers.forEach((layer, l) => {
    layer.name = lines[l + 1];
    layer.sensorType = lines[layerCount + l + 1];
    layerOf.fill(l, layer.first, layer.first + layer.count);
  });
  return { name: lines[0], sensors, bounds, layers, labels, places, positions, uid, module, patch, place, layerOf };
}

// Decodes one layer's compact responses (count values, from word `word` of
// `words`) into responses[first ...]; returns the word after them. Per
// block: a head word (bits 0-15 the first value, 16-23 the bit width), then
// the differences from the value before, zigzagged (0, -1, 1, -2 as 0, 1,
// 2, 3), `width` bits each, in 4 lanes (difference i in lane i % 4, at
// position i >> 2), each lane LSB-first in its own words, which are
// interleaved (word k of lane l at 4k + l); a difference may run on into
// its lane's next word, 4 words on. The Uint16Array keeps the sums modulo
// 2^16, as encoded.
function decodeResponses(words, word, first, count) {
  // A local: the hot loop below then does not look the page's binding up.
  const out = responses;
  for (let start = 0; start < count; start += BLOCK) {
    const n = Math.min(BLOCK, count - start), at = first + start;
    if (word >= words.length) throw new Error(`update cut short in the responses of taxel ${at}`);
    const head = words[word++];
    const width = head >>> 16;
    let value = head & 0xffff;
    if (width === 0) {
      out.fill(value, at, at + n);
      continue;
    }
    if (width > 16) throw new Error(`update: block head ${head} has no width of 0 to 16`);
    const end = word + 4 * (((((n + 3) >>> 2) * width) + 31) >>> 5);
    if (end > words.length) throw new Error(`update cut short in the responses of taxel ${at}`);
    const mask = (1 << width) - 1;
    for (let i = 0; i < n; i++) {
      const bit = (i >>> 2) * width, shift = bit & 31;
      const w = word + ((bit >>> 5) << 2) + (i & 3);
      let zigzag = words[w] >>> shift;
      if (shift + width > 32) zigzag |= words[w + 4] << (32 - shift);
      zigzag &= mask;
      value = (value + ((zigzag >>> 1) ^ -(zigzag & 1))) & 0xffff;
      out[at + i] = value;
    }
    word = end;
  }
  return word;
}

function applyUpdate(buffer) {
  let decodeMs = 0;
  const view = new DataView(buffer);
  const layerCount = view.getUint16(2, true);
  if (layerCount !== skin.layers.length) throw new Error(`update for ${layerCount} layers, geometry has ${skin.layers.length}`);
  stats.lastUpdateNumber = view.getUint32(4, true);
  stats.mode = MODES[view.getUint8(1)];
  const arrows = view.getUint16(8, true), markers = view.getUint16(10, true);
  let at = 16;
  const included = [];
  for (let l = 0; l < layerCount; l++, at += LAYER_RECORD_BYTES) {
    layerStatus[l] = {
      state: STATES[view.getUint8(at)] || 'unknown', fullScale: view.getUint16(at + 2, true),
      writerRate: view.getFloat32(at + 4, true), readRate: view.getFloat32(at + 8, true),
      latency: view.getFloat32(at + 12, true), seq: view.getUint32(at + 16, true) + view.getUint32(at + 20, true) * 2 ** 32,
      resting: view.getUint16(at + 24, true), highest: view.getUint16(at + 26, true),
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
  setOverlays(next);
  if (next.markers.length) stats.updatesWithMarkers++;
  if (next.arrows.length) stats.updatesWithArrows++;
  stats.rawUpdateBytes += at;
  // The responses are whole 32-bit words from here (the head is a multiple of 4 bytes).
  const words = new Uint32Array(buffer, at, (buffer.byteLength - at) >> 2);
  let word = 0;
  for (const l of included) {
    const { first, count } = skin.layers[l];
    const started = performance.now();
    word = decodeResponses(words, word, first, count);
    decodeMs += performance.now() - started;
    for (let i = first, end = first + count; i < end; i++) {
      const r = responses[i], b = baseline[i];
      baseline[i] = r < b ? r : b + (r - b) * BASELINE_RISE;
    }
    stats.rawUpdateBytes += 2 * count;
  }
  if (word !== words.length) throw new Error(`update: ${4 * (words.length - word)} bytes after the responses`);
  // A moving average of the decoding's cost per update (performance.now() is coarse: averaged over many).
  stats.decodeMs += (decodeMs - stats.decodeMs) * 0.05;
  // For the browser test, which decodes the same bytes with the server's decoder and compares.
  window.skinLastUpdate = buffer;
  // Stopped: some layer's writer is gone and none is there (the others not
  // found yet by a reader that just started: their channels went with the skin).
  const stopped = layerStatus.some(status => status.state === 'gone') &&
    layerStatus.every(status => status.state === 'gone' || status.state === 'connecting');
  showSkinState(stopped ? 'stopped' : 'running');
}

function setOverlays(next) {
  const key = JSON.stringify(next);
  if (key !== overlayKey) stats.overlayChanges++;
  overlayKey = key;
  overlays = next;
  stats.markers = next.markers.length;
  stats.arrows = next.arrows.length;
}

// What the page says of the skin as a whole. A stopped skin (every layer
// gone) or a server gone shows no contacts and no rates: they would be
// those of before.
function showSkinState(state) {
  if (state === stats.skinState) return;
  stats.skinState = state;
  const banner = document.getElementById('banner');
  banner.dataset.state = state;
  banner.hidden = state === 'running';
  if (state === 'stopped') {
    banner.textContent = 'The skin has stopped: its layers\u2019 writers are gone. The page shows it again when it restarts.';
  } else if (state === 'server gone') {
    banner.textContent = 'The viewer\u2019s server is gone (skin view or skin demo stopped): nothing here is live. Retrying every second\u2026';
  }
  if (state !== 'running') setOverlays({ arrows: [], markers: [] });
  dirty = true;
  lastTableUpdate = 0;
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
  // Once per layout, not per draw: a draw writes the taxels' squares only,
  // always the same pixels in the same order, and the overlays go on the
  // canvas, not here: filling the whole canvas every draw was work for nothing.
  layout.pixels.fill(BACKGROUND);
  placeLabels();
  dirty = true;
}

// The map pieces' names (their link, and the regions holding them whole),
// centred over the top of each piece's box: elements over the canvas (not
// drawn in it, so that its pixels stay the heatmap's), placed for the size
// the page shows it at; a label much wider than its piece is left out.
function placeLabels() {
  const box = document.getElementById('labels');
  const shown = canvas.clientWidth / layout.width;
  box.replaceChildren(...skin.labels.map(label => {
    const [x0, , x1, y1] = label.bounds;
    const [left, top] = toCanvas((x0 + x1) / 2, y1);
    const element = document.createElement('div');
    element.className = 'piece-label';
    element.textContent = label.text;
    element.style.left = `${left * shown}px`;
    element.style.top = `${Math.max(0, top - 2) * shown}px`;
    // No room above the piece (the map's top row): inside its top edge.
    if (top * shown < 16) element.classList.add('inside');
    element.dataset.pieceWidth = String((x1 - x0) * layout.scale * shown);
    return element;
  }));
  for (const element of box.children) {
    element.hidden = element.offsetWidth > 1.6 * Number(element.dataset.pieceWidth) + 24;
  }
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
  skin.layers.forEach((layer, l) => {
    const state = (layerStatus[l] || { state: 'connecting' }).state;
    const stripes = HATCH[state];
    const colourOf = colourTable(fullScaleOf(l));
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
  // The contacts' pressures are in the layers' units: the widest scale fills the circles.
  const markerScale = Math.max(...skin.layers.map((_, l) => fullScaleOf(l)), 1);
  for (const [x, y, radius, pressure] of overlays.markers) {
    const [cx, cy] = toCanvas(x, y);
    context.beginPath();
    context.arc(cx, cy, Math.max(4, radius * layout.scale), 0, 2 * Math.PI);
    context.fillStyle = `rgba(255, 255, 255, ${Math.min(0.45, 0.1 + Math.sqrt(Math.max(0, pressure) / markerScale) * 0.35)})`;
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
    row.dataset.state = 'connecting';
    row.innerHTML = '<td></td><td><span class="badge">connecting</span></td><td></td><td></td><td></td><td></td>';
    row.cells[0].textContent = layer.name;
    row.cells[0].title = `sensor type ${layer.sensorType}`;
    row.cells[2].textContent = layer.count.toLocaleString();
    return row;
  }));
  buildRangeTable();
}

// Rates mean something only of a layer being read: a layer connecting,
// gone, or of a skin stopped or out of reach shows none.
function ratesShown(state) {
  return stats.skinState === 'running' && state !== 'connecting' && state !== 'gone' && state !== 'unknown';
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
      const shown = ratesShown(status.state);
      row.cells[3].textContent = shown ? status.writerRate.toFixed(1) : '\u2014';
      row.cells[4].textContent = shown ? status.readRate.toFixed(1) : '\u2014';
      row.cells[5].textContent = shown ? status.latency.toFixed(3) : '\u2014';
    }
  });
  if (full) updateRanges();
}

// The colour range of each sensor type (its layers share it): a number
// typed in (full colour at that response above baseline), or empty for the
// range the server learnt from the responses of its layers. Kept per skin
// and sensor type in the browser's storage.
function rangeKey(sensorType) {
  return `skinware-view:${skin.name}:${sensorType}:full-scale`;
}

function sensorTypes() {
  return [...new Set(skin.layers.map(layer => layer.sensorType))];
}

function buildRangeTable() {
  const rows = document.querySelector('#ranges tbody');
  manualScales = {};
  for (const type of sensorTypes()) {
    const stored = Number(localStorage.getItem(rangeKey(type)));
    manualScales[type] = stored >= 1 && stored <= 65535 ? stored : null;
  }
  rows.replaceChildren(...sensorTypes().map(type => {
    const row = document.createElement('tr');
    row.dataset.sensorType = type;
    row.innerHTML = '<td></td><td><input type="number" min="1" max="65535" step="1" placeholder="auto"></td>' +
      '<td><button type="button">auto</button></td><td class="learnt"></td>';
    const layers = skin.layers.filter(layer => layer.sensorType === type).map(layer => layer.name);
    row.cells[0].textContent = type;
    row.cells[0].title = `layers ${layers.join(', ')}`;
    const input = row.querySelector('input');
    input.value = manualScales[type] ? String(manualScales[type]) : '';
    input.addEventListener('change', () => setManualScale(type, input.value));
    row.querySelector('button').addEventListener('click', () => { input.value = ''; setManualScale(type, ''); });
    return row;
  }));
}

function setManualScale(type, text) {
  const value = Math.round(Number(text));
  manualScales[type] = text !== '' && value >= 1 && value <= 65535 ? value : null;
  if (manualScales[type]) localStorage.setItem(rangeKey(type), String(manualScales[type]));
  else localStorage.removeItem(rangeKey(type));
  updateRanges();
  dirty = true;
}

function updateRanges() {
  for (const row of document.querySelector('#ranges tbody').rows) {
    const type = row.dataset.sensorType;
    const l = skin.layers.findIndex(layer => layer.sensorType === type);
    const status = layerStatus[l];
    row.dataset.mode = manualScales[type] ? 'manual' : 'auto';
    row.querySelector('.learnt').textContent = status && status.fullScale
      ? `auto ${status.fullScale.toLocaleString()} (resting ${status.resting.toLocaleString()}, highest ${status.highest.toLocaleString()})`
      : 'auto: no frame yet';
  }
  skin.layers.forEach((_, l) => {
    stats.fullScales[l] = fullScaleOf(l);
    stats.autoScales[l] = layerStatus[l] ? layerStatus[l].fullScale : 0;
  });
  updateLegend();
}

// The legend's end: the full scale, if every layer has the same one.
function updateLegend() {
  const scales = skin.layers.map((_, l) => fullScaleOf(l));
  const same = scales.every(scale => scale === scales[0]);
  document.getElementById('scale-max').textContent =
    !scales.length ? '' : same ? scales[0].toLocaleString() : 'each sensor type\u2019s full scale (below)';
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
  const place = skin.places[skin.place[i]];
  tooltip.textContent = `uid ${skin.uid[i]}  module ${skin.module[i]}  patch ${skin.patch[i]}\n` +
    (place ? `${place}\n` : '') +
    `layer ${skin.layers[l].name}, ${skin.layers[l].sensorType} (${(layerStatus[l] || { state: 'connecting' }).state})\n` +
    `response ${responses[i]}  (${above >= 0 ? '+' : ''}${above} above baseline; full colour at ${fullScaleOf(l).toLocaleString()})`;
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

// Whether the server answered the last connection with an error (which the page shows) instead of a map.
let refused = false;

function connect() {
  const connection = document.getElementById('connection');
  refused = false;
  // The version in the query: a server of another version answers with a message, not bytes this page cannot read.
  socket = new WebSocket(`${location.protocol === 'https:' ? 'wss' : 'ws'}://${location.host}/ws?protocol=${PROTOCOL_VERSION}`);
  socket.binaryType = 'arraybuffer';
  socket.onopen = () => { connection.dataset.state = 'open'; connection.textContent = 'connected'; };
  socket.onmessage = event => {
    if (typeof event.data === 'string') {
      // The server refused: no geometry published, or a page of another version.
      refused = true;
      showError(JSON.parse(event.data).error);
      return;
    }
    const kind = new DataView(event.data).getUint8(0);
    if (kind === KIND_GEOMETRY) {
      try {
        skin = decodeGeometry(event.data);
      } catch (error) {
        showError(error.message);
        socket.close();
        return;
      }
      responses = new Uint16Array(skin.sensors);
      baseline = new Float32Array(skin.sensors).fill(Infinity);
      layerStatus = [];
      stats.skinState = null;
      showSkinState('running');
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
    layerStatus = layerStatus.map(status => ({ ...status, state: 'unknown' }));
    if (skin && !refused) showSkinState('server gone');
    dirty = true;
    setTimeout(connect, 1000);
  };
}

connect();
requestAnimationFrame(frame);
