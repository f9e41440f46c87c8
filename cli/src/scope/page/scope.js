// feedloop scope page: polls the scope's JSON API and draws min/max envelopes on canvases.
'use strict';

const session = Math.random().toString(36).slice(2) + Date.now().toString(36);
// The launch token `feedloop scope` printed in the page's address (?token=...): sent with every
// API request. Kept for this tab, so a reload of the bare address still works.
const token = new URLSearchParams(location.search).get('token') || sessionStorage.getItem('feedloop-scope-token') || '';
if (token) sessionStorage.setItem('feedloop-scope-token', token);
const sent = () => ({ 'x-scope-session': session, 'x-scope-token': token });
// The Okabe-Ito palette (told apart with the common colour-vision deficiencies), in the order a
// pane's signals take it: a pane's first eight signals never share a colour; beyond that the
// colours repeat dashed.
const PALETTE = ['#0072B2', '#D55E00', '#009E73', '#CC79A7', '#E69F00', '#56B4E9', '#000000', '#F0E442'];
const EVENT_COLORS = { deadline_miss: '#D55E00', plant_overrun: '#E69F00', stall: '#CC79A7',
  swap: '#009E73', rollback: '#B3261E', safety_stop: '#000000' };
// Events closer than this (CSS px) on a plot are drawn as one band with their count.
const EVENT_JOIN_PX = 6;

// What tests and people can inspect from the console.
const scope = window.scope = {
  state: null, frames: 0, views: 0, points: 0, busy: null, panes: [],
  paused: false, lastError: null, lastAnswer: null, savedPath: null,
  // event kinds the page does not draw (unticked in the event legend)
  hiddenKinds: new Set(),
  // per kind, the events in the shown span and the marks (lines, bands) drawn for them
  eventsInView: {}, eventMarks: {},
};

const $ = (id) => document.getElementById(id);

async function api(path, opts = {}) {
  opts.headers = Object.assign(sent(), opts.headers || {});
  const r = await fetch(path, opts);
  const body = await r.json().catch(() => ({ error: 'answer is not JSON (' + r.status + ')' }));
  if (r.status === 409 && body.busy) {
    scope.busy = body.error;
    $('busy').hidden = false;
    $('busy-text').textContent = body.error;
    throw new Error(body.error);
  }
  scope.busy = null;
  $('busy').hidden = true;
  if (!r.ok) throw new Error(body.error || ('HTTP ' + r.status));
  return body;
}

// ---- units -------------------------------------------------------------------------------
function scaleFor(unit, maxAbs) {
  if (unit === 'm') {
    if (maxAbs < 1e-6) return { f: 1e9, label: 'nm' };
    if (maxAbs < 1e-3) return { f: 1e6, label: 'um' };
    if (maxAbs < 1) return { f: 1e3, label: 'mm' };
    return { f: 1, label: 'm' };
  }
  return { f: 1, label: unit || '' };
}

function niceTicks(lo, hi, n) {
  if (!(hi > lo)) { hi = lo + 1; }
  const raw = (hi - lo) / n;
  const mag = Math.pow(10, Math.floor(Math.log10(raw)));
  const step = [1, 2, 5, 10].map((m) => m * mag).find((s) => s >= raw) || raw;
  const ticks = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) ticks.push(v);
  return { ticks, step };
}

function fmtTick(v, step) {
  const d = Math.max(0, -Math.floor(Math.log10(step) + 1e-9));
  return v.toFixed(Math.min(d, 9));
}

// ---- panes -------------------------------------------------------------------------------
function addPane(signals) {
  const div = document.createElement('div');
  div.className = 'pane';
  // the legend sits above the plot, never over its curves
  const legend = document.createElement('div');
  legend.className = 'legend';
  const canvas = document.createElement('canvas');
  const det = document.createElement('details');
  det.className = 'signals';
  det.innerHTML = '<summary>signals</summary>';
  const box = document.createElement('div');
  box.className = 'signals';
  det.appendChild(box);
  div.appendChild(legend);
  div.appendChild(canvas);
  div.appendChild(det);
  $('panes').appendChild(div);
  const pane = { div, legend, canvas, box, signals: signals.slice(), index: scope.panes.length,
    colors: {}, legendKey: null, plot: null };
  scope.panes.push(pane);
  fillPicker(pane);
  return pane;
}

function fillPicker(pane) {
  const cols = currentColumns();
  pane.box.innerHTML = '';
  for (const c of cols) {
    const l = document.createElement('label');
    const cb = document.createElement('input');
    cb.type = 'checkbox';
    cb.value = c.name;
    cb.checked = pane.signals.includes(c.name);
    cb.onchange = () => {
      pane.signals = cb.checked ? pane.signals.concat([c.name]) : pane.signals.filter((s) => s !== c.name);
    };
    l.appendChild(cb);
    l.appendChild(document.createTextNode(' ' + c.name));
    l.title = c.what + (c.unit ? ' (' + c.unit + ')' : '');
    pane.box.appendChild(l);
  }
}

function currentColumns() {
  const s = scope.state;
  if (!s) return [];
  if ($('source').value === 'capture' && s.capture_view) return s.capture_view.columns;
  return s.columns;
}

function defaultPanes() {
  const s = scope.state;
  const names = new Set(s.columns.map((c) => c.name));
  const pick = (list) => list.filter((n) => names.has(n));
  const a = s.axes;
  const first = a[0] || '';
  const panes = [
    pick([first + '.cmd', first + '.load']),
    pick(a.map((x) => x + '.following_error')),
    pick(a.map((x) => x + '.torque').concat(a.map((x) => x + '.torque_ff'))),
    a.length > 1 ? pick(['contour_error', 'contour_err']) : [],
  ].filter((p) => p.length);
  if (!panes.length && s.columns.length) panes.push([s.columns[0].name]);
  for (const p of panes) addPane(p);
}

// ---- time window -------------------------------------------------------------------------
function windowOf(span) {
  if (!span) return null;
  const [lo, hi] = span;
  const sel = $('span').value;
  const width = sel === 'all' ? Math.max(hi - lo, 1e-6) : parseFloat(sel);
  const live = $('source').value === 'live' && scope.state && scope.state.mode === 'live';
  if (live && !scope.paused) {
    $('offset').value = 1000;
    return [hi - width, hi];
  }
  const frac = $('offset').value / 1000;
  const t1 = Math.min(hi, lo + width + (hi - lo - width) * frac);
  return [t1 - width, t1];
}

// ---- drawing -----------------------------------------------------------------------------
// The colour of each of a pane's signals: its place in the pane, so two never share one.
function paneColors(pane) {
  const out = {};
  pane.signals.forEach((n, i) => { out[n] = { color: PALETTE[i % PALETTE.length], dashed: i >= PALETTE.length }; });
  pane.colors = out;
  return out;
}

function drawLegend(pane, series, label) {
  const key = series.map((s) => s.name).join(',') + '|' + label;
  if (key === pane.legendKey) return;
  pane.legendKey = key;
  pane.legend.innerHTML = '';
  if (!series.length) {
    pane.legend.textContent = '(no signal: pick some below)';
    return;
  }
  for (const s of series) {
    const c = pane.colors[s.name];
    const item = document.createElement('span');
    item.className = 'item';
    item.dataset.signal = s.name;
    const sw = document.createElement('span');
    sw.className = 'swatch';
    sw.style.background = c.dashed ? 'repeating-linear-gradient(90deg,' + c.color + ' 0 4px,transparent 4px 7px)' : c.color;
    item.appendChild(sw);
    item.appendChild(document.createTextNode(s.name + ' (' + label + ')'));
    pane.legend.appendChild(item);
  }
}

// Loop events of the shown kinds, where they happened: one thin translucent line for a lone
// event, one shaded band with a count for a run of events closer than EVENT_JOIN_PX; each kind
// has its own strip along the plot's top edge.
function drawEvents(g, events, X, t0, t1, L, T, pw, ph) {
  const byKind = {};
  for (const e of events || []) {
    if (e.t_s < t0 || e.t_s > t1) continue;
    (byKind[e.kind] = byKind[e.kind] || []).push(X(e.t_s));
  }
  const kinds = (scope.state.event_kinds || Object.keys(EVENT_COLORS));
  for (const kind of Object.keys(byKind)) {
    scope.eventsInView[kind] = Math.max(scope.eventsInView[kind] || 0, byKind[kind].length);
    if (scope.hiddenKinds.has(kind)) continue;
    const xs = byKind[kind].sort((a, b) => a - b);
    const col = EVENT_COLORS[kind] || '#000000';
    const strip = T + 1 + Math.max(0, kinds.indexOf(kind)) * 5;
    let i = 0;
    while (i < xs.length) {
      let j = i;
      while (j + 1 < xs.length && xs[j + 1] - xs[j] < EVENT_JOIN_PX) j++;
      const x0 = xs[i], x1 = xs[j], n = j - i + 1;
      g.fillStyle = col; g.strokeStyle = col;
      if (n === 1) {
        g.globalAlpha = 0.45; g.lineWidth = 1;
        g.beginPath(); g.moveTo(Math.round(x0) + 0.5, T); g.lineTo(Math.round(x0) + 0.5, T + ph); g.stroke();
        g.globalAlpha = 0.8; g.fillRect(x0 - 2, strip, 5, 4);
      } else {
        const w = Math.max(2, x1 - x0 + 1);
        g.globalAlpha = 0.12; g.fillRect(x0, T, w, ph);
        g.globalAlpha = 0.8; g.fillRect(x0, strip, w, 4);
        if (w > 26) {
          g.globalAlpha = 1; g.font = '10px system-ui';
          g.fillText(String(n), x0 + 2, strip + 14);
        }
      }
      g.globalAlpha = 1;
      scope.eventMarks[kind] = (scope.eventMarks[kind] || 0) + 1;
      i = j + 1;
    }
  }
}

function drawPane(pane, view, t0, t1) {
  const c = pane.canvas;
  const dpr = window.devicePixelRatio || 1;
  const W = c.clientWidth, H = c.clientHeight;
  if (c.width !== Math.round(W * dpr)) { c.width = Math.round(W * dpr); c.height = Math.round(H * dpr); }
  const g = c.getContext('2d');
  g.setTransform(dpr, 0, 0, dpr, 0, 0);
  g.setLineDash([]);
  g.textAlign = 'left';
  g.clearRect(0, 0, W, H);
  const L = 70, R = 10, T = 6, B = 30;
  const pw = W - L - R, ph = H - T - B;
  // the plot area, in the canvas' CSS pixels
  pane.plot = { x: L, y: T, w: pw, h: ph };
  const series = view.series.filter((s) => pane.signals.includes(s.name));
  const colors = paneColors(pane);
  let lo = Infinity, hi = -Infinity;
  for (const s of series) for (let i = 0; i < s.lo.length; i++) {
    if (s.lo[i] !== null) { lo = Math.min(lo, s.lo[i]); hi = Math.max(hi, s.hi[i]); }
  }
  const unit = series.length ? series[0].unit : '';
  if (!isFinite(lo)) { lo = -1; hi = 1; }
  if (hi - lo < 1e-15) { const m = Math.abs(lo) * 1e-3 || 1e-9; lo -= m; hi += m; }
  const pad = (hi - lo) * 0.06; lo -= pad; hi += pad;
  const sc = scaleFor(unit, Math.max(Math.abs(lo), Math.abs(hi)));
  const X = (t) => L + (t - t0) / (t1 - t0) * pw;
  const Y = (v) => T + (hi - v) / (hi - lo) * ph;
  drawLegend(pane, series, sc.label);
  // grid and ticks
  g.font = '11px system-ui'; g.strokeStyle = '#e6e8ec'; g.fillStyle = '#4a5566'; g.lineWidth = 1;
  const yt = niceTicks(lo * sc.f, hi * sc.f, 5);
  for (const v of yt.ticks) {
    const y = Y(v / sc.f);
    g.beginPath(); g.moveTo(L, y); g.lineTo(L + pw, y); g.stroke();
    g.textAlign = 'right'; g.fillText(fmtTick(v, yt.step), L - 4, y + 4); g.textAlign = 'left';
  }
  const xt = niceTicks(t0, t1, 8);
  for (const v of xt.ticks) {
    const x = X(v);
    g.beginPath(); g.moveTo(x, T); g.lineTo(x, T + ph); g.stroke();
    g.fillText(fmtTick(v, xt.step), x - 14, T + ph + 13);
  }
  g.fillText('t (s)', L + pw - 24, T + ph + 26);
  g.save(); g.translate(11, T + ph / 2); g.rotate(-Math.PI / 2);
  g.textAlign = 'center'; g.fillText(sc.label, 0, 0); g.restore();
  g.strokeStyle = '#8a94a6'; g.strokeRect(L, T, pw, ph);
  // loop events under the curves, clipped to the plot
  const st = scope.state;
  const events = $('source').value === 'capture' ? (st.capture ? st.capture.events : []) : st.events;
  g.save(); g.beginPath(); g.rect(L, T, pw, ph); g.clip();
  drawEvents(g, events, X, t0, t1, L, T, pw, ph);
  // envelopes: one vertical min-max bar per pixel column, joined to the next
  for (const s of series) {
    const col = colors[s.name];
    g.strokeStyle = col.color; g.lineWidth = 1.2; g.setLineDash(col.dashed ? [6, 3] : []); g.beginPath();
    const n = s.lo.length;
    // Zoomed in beyond one cycle per column, columns without a cycle are normal: the line goes
    // through them. A longer run of empty columns is a gap in the data and stays open.
    const period = st.period_s || 0;
    const perCol = period > 0 ? (t1 - t0) / period / n : 1;
    const normalGap = perCol < 1 ? Math.ceil(1 / perCol) + 1 : 1;
    let started = false, empty = 0;
    for (let i = 0; i < n; i++) {
      if (s.lo[i] === null) { if (++empty > normalGap) started = false; continue; }
      empty = 0;
      const x = L + (i + 0.5) / n * pw;
      const y0 = Y(s.lo[i]), y1 = Y(s.hi[i]);
      if (!started) { g.moveTo(x, y0); started = true; } else { g.lineTo(x, y0); }
      g.lineTo(x, y1);
      scope.points += 1;
    }
    g.stroke();
  }
  g.setLineDash([]);
  // the answers to the page's requests, where they happened
  for (const a of st.answers || []) {
    if (a.t_s < t0 || a.t_s > t1) continue;
    const x = X(a.t_s);
    g.fillStyle = a.outcome === 'accepted' ? '#1b7f3a' : '#b3261e';
    g.beginPath(); g.moveTo(x, T + ph - 2); g.lineTo(x - 5, T + ph - 10); g.lineTo(x + 5, T + ph - 10); g.fill();
    g.font = '11px system-ui';
    g.fillText(a.outcome.replace('_', ' ') + ': ' + a.summary.slice(0, 70), Math.min(x + 6, L + pw - 260), T + ph - 4);
  }
  g.restore();
}

// The event legend above the plots: a tick box per kind (untick to hide it), its colour, and
// how many of its events the shown span holds.
function eventLegend(kinds) {
  const box = $('event-kinds');
  if (box.dataset.kinds === kinds.join(',')) return;
  box.dataset.kinds = kinds.join(',');
  box.innerHTML = '<span class="info">events:</span>';
  for (const k of kinds) {
    const l = document.createElement('label');
    l.dataset.kind = k;
    const cb = document.createElement('input');
    cb.type = 'checkbox';
    cb.value = k;
    cb.checked = !scope.hiddenKinds.has(k);
    cb.onchange = () => { if (cb.checked) scope.hiddenKinds.delete(k); else scope.hiddenKinds.add(k); };
    const sw = document.createElement('span');
    sw.className = 'swatch';
    sw.style.background = EVENT_COLORS[k] || '#000000';
    const n = document.createElement('span');
    n.className = 'count';
    l.appendChild(cb); l.appendChild(sw);
    l.appendChild(document.createTextNode(k.replace('_', ' ') + ' '));
    l.appendChild(n);
    box.appendChild(l);
  }
}

function eventCounts() {
  for (const l of $('event-kinds').querySelectorAll('label')) {
    const n = scope.eventsInView[l.dataset.kind] || 0;
    l.querySelector('.count').textContent = n ? '(' + n + ' in view)' : '';
  }
}

// The binary view (see the server's `view_bin`): a JSON head, then f32 minima and maxima per
// series relative to the series' offset; NaN where a column holds no cycle.
async function viewBin(path) {
  const r = await fetch(path, { headers: sent() });
  if (!r.ok) { await api(path); throw new Error('HTTP ' + r.status); }
  const buf = await r.arrayBuffer();
  const n = new DataView(buf).getUint32(0, true);
  const head = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, n)));
  const data = new Float32Array(buf, 4 + n);
  const cols = head.cols;
  head.series.forEach((s, k) => {
    const lo = new Array(cols), hi = new Array(cols);
    for (let i = 0; i < cols; i++) {
      const a = data[2 * k * cols + i], b = data[(2 * k + 1) * cols + i];
      lo[i] = isNaN(a) ? null : a + s.offset;
      hi[i] = isNaN(b) ? null : b + s.offset;
    }
    s.lo = lo; s.hi = hi;
  });
  scope.busy = null; $('busy').hidden = true;
  return head;
}

let inflight = false;
async function frame() {
  requestAnimationFrame(frame);
  const st = scope.state;
  if (inflight || !st || scope.busy) return;
  const src = $('source').value === 'capture' && st.capture_view ? 'capture' : 'live';
  const span = src === 'capture' ? st.capture_view.span_s : st.span_s;
  const w = windowOf(span);
  if (!w) return;
  const sigs = [...new Set(scope.panes.flatMap((p) => p.signals))];
  const cols = Math.max(50, Math.min(4096, Math.round(($('panes').clientWidth - 80) * (window.devicePixelRatio || 1))));
  inflight = true;
  try {
    const v = await viewBin('/api/view?fmt=bin&src=' + src + '&t0=' + w[0] + '&t1=' + w[1] + '&cols=' + cols +
      '&sig=' + encodeURIComponent(sigs.join(',')));
    scope.views += 1;
    scope.eventsInView = {}; scope.eventMarks = {};
    for (const p of scope.panes) drawPane(p, v, w[0], w[1]);
    eventCounts();
    scope.frames += 1;
    $('time-info').textContent = w[0].toFixed(4) + ' .. ' + w[1].toFixed(4) + ' s';
  } catch (e) {
    scope.lastError = String(e);
  } finally {
    inflight = false;
  }
}

// ---- sidebar -----------------------------------------------------------------------------
function fmtUs(v) { return v === null || v === undefined ? 'n/a' : (v < 10 ? v.toFixed(2) : v.toFixed(1)) + ' us'; }

function drawHistogram(lat) {
  const c = $('histogram'), g = c.getContext('2d');
  const W = c.width, H = c.height, L = 36, B = 28, T = 14;
  g.clearRect(0, 0, W, H);
  g.font = '10px system-ui'; g.fillStyle = '#1d2430';
  g.fillText('round trip (us, log scale) - cycles (log)', L, 10);
  const bins = lat.bins.filter((b) => b[2] > 0);
  if (!bins.length) { g.fillText('no cycles yet', L, H / 2); return; }
  const x0 = Math.log10(bins[0][0]), x1 = Math.log10(bins[bins.length - 1][1]);
  const ymax = Math.log10(Math.max(...bins.map((b) => b[2])) + 1);
  const X = (v) => L + (Math.log10(v) - x0) / Math.max(x1 - x0, 1e-9) * (W - L - 6);
  g.strokeStyle = '#8a94a6'; g.strokeRect(L, T, W - L - 6, H - T - B);
  for (const b of bins) {
    const h = Math.log10(b[2] + 1) / ymax * (H - T - B);
    g.fillStyle = '#1f5fbf';
    g.fillRect(X(b[0]), H - B - h, Math.max(1, X(b[1]) - X(b[0]) - 1), h);
  }
  g.fillStyle = '#4a5566';
  for (let e = Math.ceil(x0); e <= x1; e++) {
    const v = Math.pow(10, e), x = X(v);
    g.fillRect(x, H - B, 1, 4);
    g.fillText(v >= 1 ? String(v) : v.toFixed(1), x - 6, H - B + 14);
  }
  g.fillText('cycles: ' + lat.count, L, H - 2);
}

function fmtCount(v) { return v === null || v === undefined ? '-' : Number(v).toLocaleString('en-US'); }
function fmtSecs(v) { return (v < 10 ? v.toFixed(1) : v.toFixed(0)) + ' s'; }
function esc(t) { return String(t).replace(/&/g, '&amp;').replace(/</g, '&lt;'); }

// The counters, each from one source: since start, the loop's own status (the figures its
// summary reports); in the last N s, the cycles the scope holds.
function counterTable(st) {
  const s = st.status, w = st.window;
  const since = s ? 'since start' : null;
  const win = w ? 'in the last ' + fmtSecs(w.seconds) : null;
  const rows = [
    ['deadline_misses', 'deadline misses (cycles)', s && s.deadline_misses, 'deadline_miss'],
    ['plant_overruns', 'plant overruns (cycles)', s && s.plant_overruns, 'plant_overrun'],
    ['stall', 'stall cycles', null, 'stall'],
    ['swaps', 'swaps', s && s.swaps, 'swap'],
    ['rollback', 'swaps rolled back', null, 'rollback'],
    ['safety_stop', 'safe stops begun', null, 'safety_stop'],
    ['rejected_requests', 'refused requests', s && s.rejected_requests, null],
    ['nonfinite_faults', 'non-finite torques caught', s && s.nonfinite_faults, null],
  ];
  const cell = (label, v) => label === null || v === null || v === undefined
    ? '<td class="num">-</td>'
    : '<td class="num" data-window="' + label + '" data-value="' + v + '">' + fmtCount(v) + '</td>';
  let h = '<tr><th></th><th class="num">' + (since || 'since start') + '</th><th class="num">' +
    (win || 'recent') + '</th></tr>';
  for (const [key, name, total, kind] of rows) {
    h += '<tr data-counter="' + key + '"><td>' + name + '</td>' + cell(since, total) +
      cell(win, kind && w ? w.counts[kind] : null) + '</tr>';
  }
  $('counters').innerHTML = h;
  $('counters-note').textContent = (s ? 'since start: the loop\'s own count over its cycles before cycle ' +
    fmtCount(s.cycle) + ' (t = ' + s.t_s.toFixed(1) + ' s), as the run\'s summary counts them'
    : 'since start: no status from the loop yet') +
    (w ? '; in the last ' + fmtSecs(w.seconds) + ': the ' + fmtCount(w.cycles) + ' cycles before it that the scope holds' : '') + '.';
}

// The status line under the stages: the same figures as the counters' "since start" column.
function statusLine(s) {
  const item = (key, name) => name + ' <span data-counter="' + key + '" data-window="since start" data-value="' +
    s[key] + '">' + fmtCount(s[key]) + '</span>';
  return 'since start, as of cycle ' + fmtCount(s.cycle) + ': ' + [
    item('deadline_misses', 'deadline misses'), item('plant_overruns', 'plant overruns'),
    item('swaps', 'swaps'), item('rejected_requests', 'refused requests'),
  ].join(', ');
}

function updateSidebar(st) {
  const live = st.mode === 'live';
  $('title').textContent = 'feedloop scope - ' + (live ? 'loop ' + st.instance : 'recording') +
    (st.read_only ? ' (read-only)' : '');
  // a recording has no trigger, swaps, latency or counters: those controls go
  for (const e of document.querySelectorAll('.live-only')) e.hidden = !live;
  $('swap-panel').hidden = !live || !!st.read_only;
  $('source').options[0].textContent = live ? 'loop (live)' : 'recording';
  eventLegend(st.event_kinds || []);
  $('banner').textContent = st.connection + (st.period_s ? ' | period ' + (st.period_s * 1e6).toFixed(0) + ' us' : '') +
    (st.runs > 1 ? ' | run ' + st.runs + ' (the loop restarted)' : '');
  if (!live) return updateCapture(st);
  const lat = st.latency;
  $('latency').textContent = 'since the scope began watching this run, ' + fmtCount(lat.count) + ' round trips: p50 ' +
    fmtUs(lat.p50_us) + ', p99 ' + fmtUs(lat.p99_us) + ', p99.9 ' + fmtUs(lat.p999_us) + ', max ' + fmtUs(lat.max_us) +
    '; cycles without a command ' + fmtCount(lat.missed_cycles);
  drawHistogram(lat);
  counterTable(st);
  $('feed').innerHTML = [
    ['cycles missing from plant / scheduler records', fmtCount(st.lost.plant_cycles) + ' / ' + fmtCount(st.lost.scheduler_cycles)],
    ['blocks the scope fell behind on (dropped, oldest first)', fmtCount(st.lost.scope_blocks)],
    ['dropped by the loop recorders', fmtCount(st.lost.recorder_dropped)],
  ].map(([k, v]) => '<tr><td>' + k + ', since the scope began watching</td><td class="num">' + v + '</td></tr>').join('');
  if (st.status) {
    // one row per stage, one column per axis: as many columns as axes, so it fits the sidebar
    const stages = ['position', 'feedforward', 'compensator', 'velocity'];
    const axes = st.status.axes;
    let h = '<tr><th>stage</th>' + axes.map((a) => '<th>' + esc(a.axis) + '</th>').join('') + '</tr>';
    for (const s of stages) {
      h += '<tr><td>' + s + '</td>' + axes.map((a) => '<td>' + esc(a.stages[s] || '-') + '</td>').join('') + '</tr>';
    }
    h += '<tr><td>torque</td>' + axes.map((a) => '<td>' + (a.torque === null ? '-' : a.torque.toFixed(3) + ' N m') + '</td>').join('') + '</tr>';
    $('status').innerHTML = h;
    $('status-line').innerHTML = statusLine(st.status);
  } else {
    $('status').innerHTML = '<tr><td>no status from the loop yet</td></tr>';
    $('status-line').textContent = '';
  }
  updateCapture(st);
}

function updateCapture(st) {
  $('trig-status').textContent = st.trigger ? 'armed: ' + st.trigger.describe : 'not armed';
  $('cap-status').textContent = st.capture ? 'captured: ' + st.capture.describe + ', ' + st.capture.cycles +
    ' cycles from ' + st.capture.first_t_s.toFixed(4) + ' s' : (st.capture_view ? 'a trace is open as the capture view' : 'no capture yet');
  $('answers').innerHTML = (st.answers || []).slice().reverse().map((a) =>
    '<li class="' + a.outcome + '">t = ' + a.t_s.toFixed(4) + ' s: ' + a.summary.replace(/</g, '&lt;') + '</li>').join('');
  const axSel = $('sw-axis');
  if (axSel.options.length !== st.axes.length) axSel.innerHTML = st.axes.map((a) => '<option>' + a + '</option>').join('');
  const ev = $('trig-event');
  if (!ev.options.length) ev.innerHTML = st.event_kinds.map((k) => '<option>' + k + '</option>').join('');
  const sig = $('trig-signal');
  if (sig.options.length !== st.columns.length) sig.innerHTML = st.columns.map((c) => '<option>' + c.name + '</option>').join('');
  const tl = $('trace-list');
  if (st.traces.length > 1 && tl.options.length !== st.traces.length) {
    $('trace-list-row').hidden = false;
    tl.innerHTML = st.traces.map((t, i) => '<option value="' + i + '">' + t + '</option>').join('');
  }
}

async function pollState() {
  try {
    const st = await api('/api/state');
    const names = (x) => x.columns.map((c) => c.name).join(',');
    const fresh = !scope.state;
    const first = fresh || names(scope.state) !== names(st);
    scope.state = st;
    if (first) {
      // a recording is shown whole at first
      if (fresh && st.mode !== 'live') $('span').value = 'all';
      for (const p of scope.panes) p.div.remove();
      scope.panes = [];
      defaultPanes();
    }
    updateSidebar(st);
  } catch (e) {
    scope.lastError = String(e);
    if (!scope.busy) $('banner').textContent = 'scope not reachable: ' + e;
  }
  setTimeout(pollState, 250);
}

async function post(path, body, extra) {
  return api(path, { method: 'POST', body: typeof body === 'string' ? body : JSON.stringify(body), headers: extra || {} });
}

function wire() {
  $('takeover').onclick = () => post('/api/takeover', {}).catch(() => {});
  $('pause').onclick = () => { scope.paused = !scope.paused; $('pause').textContent = scope.paused ? 'Follow' : 'Pause'; };
  $('add-pane').onclick = () => addPane([]);
  $('source').onchange = () => { for (const p of scope.panes) fillPicker(p); };
  $('trig-kind').onchange = () => {
    const lvl = $('trig-kind').value === 'level';
    $('trig-level-row').hidden = !lvl; $('trig-event').hidden = lvl;
  };
  $('trig-arm').onclick = async () => {
    const kind = $('trig-kind').value;
    const body = { kind, pre_s: parseFloat($('trig-pre').value), post_s: parseFloat($('trig-post').value) };
    if (kind === 'event') body.event = $('trig-event').value;
    else Object.assign(body, { signal: $('trig-signal').value, edge: $('trig-edge').value, level: parseFloat($('trig-level').value) });
    try { const r = await post('/api/trigger', body); $('trig-status').textContent = 'armed: ' + r.armed; }
    catch (e) { $('trig-status').textContent = 'refused: ' + e.message; }
  };
  $('trig-cancel').onclick = () => post('/api/trigger/cancel', {}).catch(() => {});
  $('cap-save').onclick = async () => {
    try { const r = await post('/api/capture/save', {}); scope.savedPath = r.path; $('cap-saved').textContent = 'saved to ' + r.path; }
    catch (e) { $('cap-saved').textContent = 'not saved: ' + e.message; }
  };
  $('cap-open').onchange = async () => {
    const f = $('cap-open').files[0];
    if (!f) return;
    try {
      const r = await post('/api/open', await f.text(), { 'x-trace-name': f.name });
      $('cap-saved').textContent = 'opened ' + r.opened + ' (' + r.rows + ' rows)';
      $('source').value = 'capture';
      $('span').value = 'all';
    } catch (e) { $('cap-status').textContent = 'cannot open: ' + e.message; }
  };
  $('trace-open').onclick = () => post('/api/trace?i=' + $('trace-list').value, {}).catch((e) => { $('banner').textContent = String(e); });
  $('sw-send').onclick = async () => {
    const body = { axis: $('sw-axis').value, stage: $('sw-stage').value, plugin: $('sw-plugin').value,
      params: $('sw-params').value, force: $('sw-force').checked };
    try { scope.lastAnswer = await post('/api/swap', body); }
    catch (e) { scope.lastAnswer = { outcome: 'error', summary: e.message }; }
    const li = document.createElement('li');
    li.className = scope.lastAnswer.outcome;
    li.textContent = scope.lastAnswer.summary;
    $('answers').prepend(li);
  };
}

wire();
pollState();
requestAnimationFrame(frame);
