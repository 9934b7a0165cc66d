// goniod's console (issue #20; daemon/console/README.md). Plain JavaScript, no build step, no
// third-party code: it uses goniod's API (docs/api.md) and nothing else.
//
// Reads are bounded: the event stream (GET /api/v1/events) only says that something changed;
// the page then fetches the status, the queue and the shown run at most once per MIN_FETCH_MS
// each, and falls back to polling every POLL_MS when the stream is down.
'use strict';

const MIN_FETCH_MS = 1000;
const FRAME_MS = 2000;  // the camera view: at most one frame fetched per this
const POLL_MS = 5000;
const TOKEN_KEY = 'gonio.token';  // sessionStorage: gone when the browser session ends
const SVG = 'http://www.w3.org/2000/svg';
const COLOURS = ['#1f5fbf', '#d9480f', '#2b8a3e', '#862e9c', '#c92a2a', '#1098ad', '#5c940d',
                 '#e67700'];

const $ = (id) => document.getElementById(id);

// What the page measures of itself, for the browser test and for anyone curious
// (docs: daemon/console/README.md): per new point, ms from the event to the point drawn.
window.gonioMetrics = { pointShownMs: [], fetches: 0 };

// ---- the API -----------------------------------------------------------------------------------

class ApiError extends Error {
  constructor(status, message) {
    super(message);
    this.status = status;
  }
}

async function request(method, path, body) {
  const headers = {};
  const token = sessionStorage.getItem(TOKEN_KEY);
  if (method !== 'GET' && token) headers.Authorization = 'Bearer ' + token;
  if (body !== undefined) headers['Content-Type'] = 'application/json';
  let res;
  try {
    res = await fetch(path, {
      method, headers, body: body === undefined ? undefined : JSON.stringify(body),
      cache: 'no-store',
    });
  } catch (e) {
    throw new ApiError(0, 'goniod does not answer (' + e.message + ')');
  }
  window.gonioMetrics.fetches++;
  const text = await res.text();
  let json = null;
  try { json = text ? JSON.parse(text) : null; } catch (e) { json = null; }
  if (!res.ok) {
    const msg = json && json.error ? json.error.message : text.slice(0, 200);
    throw new ApiError(res.status, res.status + ': ' + msg);
  }
  return json;
}

function say(text, isError) {
  const m = $('message');
  m.textContent = text;
  m.className = isError ? 'message error' : 'message';
}

// A mutation: its error is shown; a 401 says what the token is.
async function mutate(method, path, body, done) {
  try {
    const r = await request(method, path, body);
    if (done) say(done, false);
    refreshSoon(true);
    return r;
  } catch (e) {
    if (e.status === 401)
      say(e.message + ' - type the token (goniod\'s token file) in the box above', true);
    else
      say(e.message, true);
    return null;
  }
}

// ---- the token ---------------------------------------------------------------------------------

function showTokenState() {
  const has = !!sessionStorage.getItem(TOKEN_KEY);
  $('token-state').textContent = has ? 'changes allowed (this session)' : 'read-only';
  $('token').value = '';
}

// ---- bounded fetching --------------------------------------------------------------------------

const view = {
  status: null,
  jobs: [],
  runs: [],
  run: null,        // the shown run, as GET /api/v1/runs/{id} returns it
  fits: [],
  curveFit: null,   // the id of the fit drawn on the lobe (null: the one BIC prefers)
  curve: null,      // {fit, byIndex: Map(point index -> the fit's value)}
  selected: null,   // the shown run's id
  follow: true,
  pendingPoint: null,  // {run, done, at}: a progress event not drawn yet
};

// Each resource is fetched at most once per minMs; a request in between is deferred.
function throttled(fn, minMs = MIN_FETCH_MS) {
  let last = 0, timer = null, running = false, again = false;
  const run = async () => {
    timer = null;
    if (running) { again = true; return; }
    running = true;
    last = performance.now();
    try { await fn(); } finally {
      running = false;
      if (again) { again = false; schedule(); }
    }
  };
  const schedule = () => {
    if (timer !== null) return;
    const wait = Math.max(0, last + minMs - performance.now());
    timer = setTimeout(run, wait);
  };
  return schedule;
}

const fetchStatus = throttled(async () => {
  try {
    view.status = await request('GET', '/api/v1/status');
    const j = await request('GET', '/api/v1/jobs');
    view.jobs = j.jobs;
    renderStatus();
    if (changed('jobs', j.jobs)) renderJobs();
    const live = view.status.job && view.status.job.run;
    if (view.follow && live && live !== view.selected) select(live);
  } catch (e) {
    $('state').textContent = 'goniod unreachable';
    $('state').dataset.state = 'unreachable';
  }
});

const fetchRuns = throttled(async () => {
  try {
    view.runs = (await request('GET', '/api/v1/runs')).runs;
    if (changed('runs', [view.runs, view.selected])) renderRuns();
  } catch (e) { say(e.message, true); }
});

const fetchRun = throttled(async () => {
  if (view.selected === null) return;
  const id = view.selected;
  try {
    const run = await request('GET', '/api/v1/runs/' + id);
    const fits = (await request('GET', '/api/v1/runs/' + id + '/fits')).fits;
    if (id !== view.selected) return;
    view.run = run;
    view.fits = fits;
    await fetchCurve(id);
    if (changed('run', [run, fits, view.curve && view.curve.fit])) renderRun();
  } catch (e) { say(e.message, true); }
});

// The fit drawn on the lobe: the operator's choice, else the one of least BIC. Its
// values at the run's points are fetched once per fit (a fit does not change once stored).
async function fetchCurve(run) {
  // A poor fit can be drawn too: the operator sees where it misses.
  const ok = view.fits.filter((f) => f.summary && f.summary.status && f.summary.status !== 'failed');
  let fit = ok.find((f) => f.id === view.curveFit);
  if (!fit && ok.length) fit = ok.reduce((a, b) => (b.summary.bic < a.summary.bic ? b : a));
  if (!fit) { view.curve = null; return; }
  if (view.curve && view.curve.fit === fit.id && view.curve.run === run) return;
  try {
    const p = await request('GET', '/api/v1/runs/' + run + '/fits/' + fit.id + '/prediction');
    view.curve = { run, fit: fit.id, model: fit.model,
                   byIndex: new Map(p.points.map((q) => [q.index, q.value])) };
  } catch (e) {
    view.curve = null;
    say('the fit cannot be drawn: ' + e.message, true);
  }
}

// Whether what a table or plot shows changed since it was last drawn: a redraw replaces the
// buttons under the operator's pointer, so it happens only when there is something new.
const drawn = {};
function changed(what, data) {
  const key = JSON.stringify(data);
  if (drawn[what] === key) return false;
  drawn[what] = key;
  return true;
}

function refreshSoon(all) {
  fetchStatus();
  if (all) fetchRuns();
  fetchRun();
}

function select(id) {
  view.selected = id;
  view.run = null;
  view.fits = [];
  view.curveFit = null;
  view.curve = null;
  delete drawn.run;
  renderRun();
  drawn.runs = JSON.stringify([view.runs, view.selected]);
  renderRuns();
  fetchRun();
}

// The event stream: a hint to fetch, never the data shown (so a missed event loses nothing).
function listen() {
  if (!window.EventSource) return;
  const es = new EventSource('/api/v1/events');
  es.addEventListener('progress', (ev) => {
    let d = null;
    try { d = JSON.parse(ev.data); } catch (e) { return; }
    if (d && d.run === view.selected && (!view.pendingPoint || d.done > view.pendingPoint.done))
      view.pendingPoint = { run: d.run, done: d.done, at: performance.now() };
    fetchStatus();
    fetchRun();
    fetchFrame();
  });
  // A long fit (a narrow lobe under a large rectangle: minutes) says what it is doing.
  es.addEventListener('fit_progress', (ev) => {
    let d = null;
    try { d = JSON.parse(ev.data); } catch (e) { return; }
    if (d && typeof d.message === 'string' && typeof d.seconds === 'number')
      say('fitting run ' + d.run + ', ' + Math.round(d.seconds) + ' s: ' + d.message, false);
  });
  for (const type of ['state', 'job', 'queue', 'suspend', 'fit', 'log'])
    es.addEventListener(type, () => refreshSoon(type !== 'log'));
  es.onerror = () => { /* EventSource reconnects by itself; the poll covers the gap */ };
}

// ---- rendering ---------------------------------------------------------------------------------

function fmt(x, digits) {
  if (x === null || x === undefined || !isFinite(x)) return '–';
  const a = Math.abs(x);
  if (a !== 0 && (a < 1e-3 || a >= 1e5)) return x.toExponential(digits === undefined ? 2 : digits);
  return x.toFixed(digits === undefined ? 2 : digits);
}

function duration(s) {
  if (!isFinite(s) || s < 0) return '–';
  if (s < 90) return Math.round(s) + ' s';
  if (s < 5400) return Math.round(s / 60) + ' min';
  return (s / 3600).toFixed(1) + ' h';
}

function renderStatus() {
  const s = view.status;
  $('state').textContent = s.state + (s.reason ? ': ' + s.reason : '');
  $('state').dataset.state = s.state;
  const p = s.progress;
  let text = s.job ? 'job ' + s.job.id + ' (' + s.job.name + ')' : 'no job';
  if (s.job && s.job.run) text += ', run ' + s.job.run;
  if (p) text += ': point ' + p.done + ' of ' + p.total + ', ' + duration(p.elapsed_s) +
    ' in, about ' + duration(p.eta_s) + ' to go';
  text += ' · ' + s.queued + ' queued';
  $('progress').textContent = text;
  $('pause').disabled = s.state !== 'running';
  $('resume').disabled = !['paused', 'fault'].includes(s.state);
  $('abort').disabled = !['running', 'paused', 'suspended', 'fault', 'cooling'].includes(s.state);
}

function cell(tr, text) {
  const td = document.createElement('td');
  td.textContent = text;
  tr.appendChild(td);
  return td;
}

function button(td, label, title, onClick) {
  const b = document.createElement('button');
  b.type = 'button';
  b.textContent = label;
  b.title = title;
  b.addEventListener('click', onClick);
  td.appendChild(b);
  return b;
}

function renderJobs() {
  const tbody = $('jobs').querySelector('tbody');
  tbody.replaceChildren();
  const queued = view.jobs.filter((j) => j.state === 'queued');
  for (const j of view.jobs.slice(0, 30)) {
    const tr = document.createElement('tr');
    tr.dataset.job = j.id;
    tr.dataset.state = j.state;
    cell(tr, j.id);
    cell(tr, j.name);
    cell(tr, j.state + (j.message ? ': ' + j.message : ''));
    cell(tr, j.run === null ? '' : j.run);
    const td = cell(tr, '');
    if (j.state === 'queued') {
      const at = queued.indexOf(j);
      if (at > 0)
        button(td, '↑', 'earlier in the queue', () =>
          mutate('POST', '/api/v1/jobs/' + j.id + '/position', { position: at - 1 }));
      if (at < queued.length - 1)
        button(td, '↓', 'later in the queue', () =>
          mutate('POST', '/api/v1/jobs/' + j.id + '/position', { position: at + 1 }));
      button(td, 'cancel', 'take it out of the queue', () =>
        mutate('DELETE', '/api/v1/jobs/' + j.id, undefined, 'job ' + j.id + ' cancelled'));
    }
    tbody.appendChild(tr);
  }
}

function renderRuns() {
  const tbody = $('runs').querySelector('tbody');
  tbody.replaceChildren();
  for (const r of view.runs.slice().reverse().slice(0, 50)) {
    const tr = document.createElement('tr');
    tr.dataset.run = r.id;
    if (r.id === view.selected) tr.className = 'selected';
    cell(tr, r.id);
    cell(tr, r.specimen);
    cell(tr, r.status);
    cell(tr, r.points_done + '/' + r.points_total);
    const td = cell(tr, '');
    button(td, 'open', 'show this run', () => {
      view.follow = false;
      $('follow').checked = false;
      select(r.id);
    });
    const a = document.createElement('a');
    a.href = '/api/v1/runs/' + r.id + '/csv';
    a.download = 'run' + r.id + '.csv';
    a.textContent = ' csv';
    td.appendChild(a);
    tbody.appendChild(tr);
  }
}

function renderRun() {
  const r = view.run;
  if (!r) {
    $('run-title').textContent = view.selected === null ? 'No run selected' : 'Run ' + view.selected;
    $('run-summary').textContent = '';
    for (const id of ['lobe', 'temperature', 'exposure', 'monitor']) $(id).replaceChildren();
    $('fits').querySelector('tbody').replaceChildren();
    $('events').querySelector('tbody').replaceChildren();
    return;
  }
  $('run-title').textContent = 'Run ' + r.id + ': ' + r.specimen;
  let s = r.status + ', ' + r.points_done + ' of ' + r.points_total + ' points';
  if (r.points_skipped) s += ' (' + r.points_skipped + ' skipped)';
  if (r.estimate) s += '; estimated ' + duration(r.estimate.total_s) + ' (' + r.estimate.basis + ')';
  if (r.exposed_s !== null) s += ', exposed ' + duration(r.exposed_s);
  $('run-summary').textContent = s;
  const ms = r.measurements.filter((m) => m.side === 'transmission' || m.side === 'reflection');
  drawLobe($('lobe'), ms, view.curve && view.curve.run === r.id ? view.curve : null);
  drawSeries($('temperature'), ms.map((m) => m.temperature_c), false, 0.5);
  drawSeries($('exposure'), ms.map((m) => m.exposure_s), true);
  drawSeries($('monitor'), ms.map((m) => m.monitor_w), false);
  renderFits();
  renderEvents(r.events);
  $('lobe').dataset.points = ms.length;
  const p = view.pendingPoint;
  if (p && p.run === r.id && ms.length >= p.done) {
    window.gonioMetrics.pointShownMs.push(performance.now() - p.at);
    view.pendingPoint = null;
  }
}

function renderFits() {
  const tbody = $('fits').querySelector('tbody');
  tbody.replaceChildren();
  for (const f of view.fits) {
    const s = f.summary || {};
    const tr = document.createElement('tr');
    tr.dataset.fit = f.id;
    const drawnHere = view.curve && view.curve.fit === f.id;
    if (drawnHere) tr.className = 'selected';
    const td = cell(tr, f.model + ' ');
    if (s.status && s.status !== 'failed' && !drawnHere)
      button(td, 'draw', 'draw this fit on the lobe', () => {
        view.curveFit = f.id;
        delete drawn.run;
        fetchRun();
      });
    cell(tr, s.status || '?');
    cell(tr, s.width ? (s.width_name || 'width') + ' ' + fmt(s.width.value, 4) + ' ± ' +
                          fmt(s.width.sigma, 4) : '–');
    cell(tr, fmt(s.reduced_chi2, 2));
    cell(tr, f.created_at);
    tbody.appendChild(tr);
  }
}

function renderEvents(events) {
  const tbody = $('events').querySelector('tbody');
  tbody.replaceChildren();
  for (const e of events.slice().reverse().slice(0, 200)) {
    const tr = document.createElement('tr');
    tr.dataset.kind = e.kind;
    cell(tr, e.at);
    cell(tr, e.kind);
    cell(tr, e.detail);
    tbody.appendChild(tr);
  }
}

// ---- plots (SVG) -------------------------------------------------------------------------------

function el(name, attrs, parent) {
  const e = document.createElementNS(SVG, name);
  for (const k in attrs) e.setAttribute(k, attrs[k]);
  if (parent) parent.appendChild(e);
  return e;
}

function text(parent, x, y, s, anchor) {
  const t = el('text', { x, y, 'text-anchor': anchor || 'middle' }, parent);
  t.textContent = s;
  return t;
}

// Decades of a positive range, widened to whole decades.
function logRange(values) {
  const pos = values.filter((v) => v > 0 && isFinite(v));
  if (pos.length === 0) return [0, 1];
  let lo = Math.floor(Math.log10(Math.min(...pos)));
  let hi = Math.ceil(Math.log10(Math.max(...pos)));
  if (hi <= lo) hi = lo + 1;
  return [lo, hi];
}

// `curve` (optional): a stored fit's values at the points, drawn dashed through them.
function drawLobe(svg, ms, curve) {
  svg.replaceChildren();
  const W = 640, H = 360, L = 56, R = 96, T = 12, B = 34;
  el('rect', { x: L, y: T, width: W - L - R, height: H - T - B, fill: 'none', class: 'axis' }, svg);
  if (ms.length === 0) { text(svg, W / 2, H / 2, 'no points yet'); return; }
  const xs = ms.map((m) => m.theta_v_deg);
  let x0 = Math.min(...xs), x1 = Math.max(...xs);
  const pad = Math.max(0.5, 0.03 * (x1 - x0));  // points at the ends stay clear of the frame
  x0 -= pad;
  x1 += pad;
  const [d0, d1] = logRange(ms.map((m) => m.value).concat(ms.map((m) => m.value - m.sigma)));
  const X = (x) => L + (x - x0) / (x1 - x0) * (W - L - R);
  const Y = (v) => {
    const l = Math.log10(Math.max(v, Math.pow(10, d0)));
    return T + (1 - (l - d0) / (d1 - d0)) * (H - T - B);
  };
  for (let d = d0; d <= d1; ++d) {
    el('line', { x1: L, x2: W - R, y1: Y(Math.pow(10, d)), y2: Y(Math.pow(10, d)), class: 'grid' }, svg);
    text(svg, L - 4, Y(Math.pow(10, d)) + 4, '1e' + d, 'end');
  }
  const step = niceStep((x1 - x0) / 6);
  for (let x = Math.ceil(x0 / step) * step; x <= x1 + 1e-9; x += step) {
    el('line', { x1: X(x), x2: X(x), y1: H - B, y2: H - B + 4, class: 'axis' }, svg);
    text(svg, X(x), H - B + 16, Math.round(x * 10) / 10);
  }
  text(svg, (L + W - R) / 2, H - 4, 'θv (deg)');
  if (curve) text(svg, W - R + 10, H - B, '- - ' + curve.model, 'start');
  const incidences = [...new Set(ms.map((m) => m.theta_l_deg))].sort((a, b) => a - b);
  incidences.forEach((inc, k) => {
    const colour = COLOURS[k % COLOURS.length];
    const g = el('g', { 'data-incidence': inc }, svg);
    const pts = ms.filter((m) => m.theta_l_deg === inc).sort((a, b) => a.theta_v_deg - b.theta_v_deg);
    el('polyline', {
      points: pts.map((m) => X(m.theta_v_deg) + ',' + Y(m.value)).join(' '),
      fill: 'none', stroke: colour, 'stroke-width': 1, 'stroke-opacity': 0.5,
    }, g);
    const fitted = curve ? pts.filter((m) => curve.byIndex.has(m.index)) : [];
    if (fitted.length > 1)
      el('polyline', {
        points: fitted.map((m) => X(m.theta_v_deg) + ',' + Y(curve.byIndex.get(m.index))).join(' '),
        fill: 'none', stroke: colour, 'stroke-width': 1.5, 'stroke-dasharray': '5 3',
        class: 'fit',
      }, g);
    for (const m of pts) {
      el('line', { x1: X(m.theta_v_deg), x2: X(m.theta_v_deg), y1: Y(m.value - m.sigma),
                   y2: Y(m.value + m.sigma), stroke: colour, class: 'bar' }, g);
      const c = el('circle', { cx: X(m.theta_v_deg), cy: Y(m.value), r: 2.5, fill: colour,
                               class: 'point' }, g);
      const t = el('title', {}, c);
      t.textContent = 'point ' + m.index + ': θl ' + m.theta_l_deg + ', θv ' +
        fmt(m.theta_v_deg, 2) + ': ' + fmt(m.value, 4) + ' ± ' + fmt(m.sigma, 4) +
        (m.flags ? ' (flags ' + m.flags + ')' : '');
    }
    el('rect', { x: W - R + 10, y: T + 6 + 16 * k, width: 10, height: 10, fill: colour }, svg);
    text(svg, W - R + 26, T + 15 + 16 * k, 'θl ' + inc + '°', 'start');
  });
}

function niceStep(raw) {
  const p = Math.pow(10, Math.floor(Math.log10(raw)));
  for (const m of [1, 2, 5, 10]) if (m * p >= raw) return m * p;
  return 10 * p;
}

// One value per point, against the point's order; log scale when asked, else a linear axis at
// least minSpan tall.
function drawSeries(svg, values, log, minSpan = 0) {
  svg.replaceChildren();
  const W = 320, H = 160, L = 58, R = 8, T = 8, B = 22;  // L: room for 0.001218
  el('rect', { x: L, y: T, width: W - L - R, height: H - T - B, fill: 'none', class: 'axis' }, svg);
  const v = values.map((x) => (x === null || x === undefined ? NaN : x));
  const ok = v.filter((x) => isFinite(x) && (!log || x > 0));
  if (ok.length === 0) { text(svg, W / 2, H / 2, 'no data'); return; }
  let lo, hi, Y;
  if (log) {
    [lo, hi] = logRange(ok);
    Y = (x) => T + (1 - (Math.log10(x) - lo) / (hi - lo)) * (H - T - B);
    for (let d = lo; d <= hi; ++d) text(svg, L - 4, Y(Math.pow(10, d)) + 4, '1e' + d, 'end');
  } else {
    lo = Math.min(...ok); hi = Math.max(...ok);
    // At least minSpan, or a percent of the values (a monitor's watts), around what was seen.
    const span = Math.max(minSpan, 0.02 * Math.abs((lo + hi) / 2), hi - lo, 1e-12);
    const mid = (lo + hi) / 2;
    lo = mid - span / 2; hi = mid + span / 2;
    Y = (x) => T + (1 - (x - lo) / (hi - lo)) * (H - T - B);
    const digits = Math.max(1, Math.ceil(-Math.log10(span)) + 1);
    text(svg, L - 4, Y(lo) + 4, fmt(lo, digits), 'end');
    text(svg, L - 4, Y(hi) + 4, fmt(hi, digits), 'end');
  }
  const X = (i) => L + (v.length < 2 ? 0.5 : i / (v.length - 1)) * (W - L - R);
  const pts = [];
  v.forEach((x, i) => { if (isFinite(x) && (!log || x > 0)) pts.push(X(i) + ',' + Y(x)); });
  el('polyline', { points: pts.join(' '), fill: 'none', stroke: COLOURS[0], 'stroke-width': 1.2 }, svg);
  text(svg, (L + W - R) / 2, H - 6, 'point (in order measured)');
}

// ---- controls ----------------------------------------------------------------------------------

// The plan as shown in the text box (loaded from the chosen file or the instrument's plans,
// perhaps edited since), named after where it came from.
let planName = null;
async function readPlan() {
  if (!$('plan-text').value.trim()) {
    if (!$('plan-file').files[0]) { say('choose a plan, or type one', true); return null; }
    if (!(await loadPlanFile())) return null;
  }
  const text = $('plan-text').value;
  if (text.length > 1 << 20) { say('a plan of ' + text.length + ' characters is too large', true); return null; }
  return { name: planName || 'console.toml', text };
}

async function loadPlanFile() {
  const f = $('plan-file').files[0];
  if (!f) return false;
  if (f.size > 1 << 20) { say(f.name + ': a plan of ' + f.size + ' bytes is too large', true); return false; }
  $('plan-text').value = await f.text();
  planName = f.name;
  $('plan-catalogue').value = '';
  return true;
}

// The instrument's plans (goniod --plans): offered when goniod has them; an invalid one is listed
// with its error and cannot be chosen.
async function loadCatalogue() {
  let r;
  try { r = await request('GET', '/api/v1/plans'); } catch (e) { return; }
  const sel = $('plan-catalogue');
  sel.hidden = !r.configured || r.plans.length === 0;
  for (const p of r.plans) {
    const o = document.createElement('option');
    o.value = p.name;
    o.textContent = p.name + (p.description ? ' - ' + p.description : '');
    if (!p.valid) { o.disabled = true; o.title = p.error; o.textContent += ' (invalid)'; }
    sel.appendChild(o);
  }
}

async function loadCataloguePlan() {
  const name = $('plan-catalogue').value;
  if (!name) return;
  try {
    const p = await request('GET', '/api/v1/plans/' + encodeURIComponent(name));
    $('plan-text').value = p.text;
    planName = p.name;
    $('plan-file').value = '';
  } catch (e) { say(e.message, true); }
}

// A schedule and its plans: the files chosen, and for a plan it names that was not chosen, the
// instrument's plan of that name (the API's error names one found nowhere).
async function readSchedule() {
  const f = $('schedule-file').files[0];
  if (!f) { say('choose a schedule file first', true); return null; }
  const files = [f, ...$('schedule-plans').files];
  const big = files.find((x) => x.size > 1 << 20);
  if (big) { say(big.name + ': ' + big.size + ' bytes is too large', true); return null; }
  const text = await f.text();
  const plans = {};
  for (const p of $('schedule-plans').files) plans[p.name] = await p.text();
  for (const m of text.matchAll(/^\s*plan\s*=\s*"([^"]+)"/gm)) {
    if (plans[m[1]] !== undefined || $('plan-catalogue').hidden) continue;
    try {
      plans[m[1]] = (await request('GET', '/api/v1/plans/' + encodeURIComponent(m[1]))).text;
    } catch (e) { /* the schedule's check names the plan that is missing */ }
  }
  return { name: f.name, schedule: text, plans };
}

function showSchedule(r, queued) {
  const lines = r.jobs.map((j) => {
    if (queued) return 'job ' + j.id + ': ' + j.name;
    let s = j.plan + ' (line ' + j.line + ') × ' + j.repeat + ': ' + j.points + ' points' +
      (j.skipped ? ' (' + j.skipped + ' skipped)' : '') + ', about ' + duration(j.estimate_s) +
      ' each (' + j.estimate_basis + ')';
    if (j.cooler_setpoint_c !== null) s += '; cools to ' + j.cooler_setpoint_c + ' °C first';
    if (j.fit && j.fit.length) s += '; fits ' + j.fit.join(', ');
    return s;
  });
  $('schedule-result').textContent = lines.join('\n') + '\nabout ' + duration(r.estimate_s) +
    ' in all';
}

// ---- the camera view ---------------------------------------------------------------------------

const cam = {
  info: null,       // GET /api/v1/frame: what the shown frame is
  pixels: null,     // its Uint16Array, width x height
  image: null,      // its ImageData at the current contrast
  drag: null,       // {x0, y0, x1, y1}: frame pixels, while dragging and after
  chosen: null,     // the rectangle placed (frame pixels) and its coverage
};

const fetchFrame = throttled(async () => {
  if (document.hidden) return;
  let info;
  try {
    info = await request('GET', '/api/v1/frame');
  } catch (e) {
    if (e.status !== 404) $('frame-info').textContent = e.message;
    return;
  }
  if (cam.info && info.seq === cam.info.seq) { cam.info = info; return; }
  const res = await fetch('/api/v1/frame/pixels', { cache: 'no-store' });
  window.gonioMetrics.fetches++;
  if (!res.ok) return;
  const buf = await res.arrayBuffer();
  const w = Number(res.headers.get('X-Frame-Width')), h = Number(res.headers.get('X-Frame-Height'));
  if (buf.byteLength !== w * h * 2) return;  // a newer frame came between the two requests
  const seq = Number(res.headers.get('X-Frame-Seq'));
  const dv = new DataView(buf);
  const px = new Uint16Array(w * h);
  for (let i = 0; i < px.length; ++i) px[i] = dv.getUint16(2 * i, true);
  if (seq !== info.seq) {  // the pixels are newer than the description: describe them
    try { info = await request('GET', '/api/v1/frame'); } catch (e) { return; }
    if (info.seq !== seq) return;
  }
  cam.info = info;
  cam.pixels = px;
  showFrameInfo();
  renderFrame();
}, FRAME_MS);

function showFrameInfo() {
  const f = cam.info;
  let s = (f.source === 'snap' ? 'snap' : 'run ' + f.run + ', point ' + f.point) + ' at ' +
    f.at.replace('T', ' ').replace('Z', ' UTC') + ': ' + fmt(f.exposure_s, 4) + ' s, ' +
    f.frame_width + ' × ' + f.frame_height;
  if (f.scale > 1) s += ' shown 1:' + f.scale;
  s += ', values ' + f.min + '–' + f.max + ' ADU';
  if (f.saturated_pixels) s += ', ' + f.saturated_pixels + ' saturated';
  $('frame-info').textContent = s;
  $('frame').dataset.seq = f.seq;
  $('frame').dataset.saturated = f.saturated_pixels;
}

// Contrast: black at the frame's least value, white at a fraction of its greatest (the slider,
// 1 down to 1e-3), linear or log (the lobe spans four decades); saturated pixels red.
function renderFrame() {
  const f = cam.info, px = cam.pixels;
  if (!f || !px) return;
  const canvas = $('frame');
  if (canvas.width !== f.width || canvas.height !== f.height) {
    canvas.width = f.width;
    canvas.height = f.height;
  }
  const ctx = canvas.getContext('2d');
  const img = ctx.createImageData(f.width, f.height);
  const lo = f.min;
  const white = Math.max(1, (f.max - lo) * Math.pow(10, -3 * (1 - $('frame-white').value / 100)));
  const log = $('frame-log').checked;
  const norm = log ? 1 / Math.log1p(white) : 1 / white;
  const d = img.data;
  for (let i = 0; i < px.length; ++i) {
    const j = 4 * i;
    if (px[i] === f.saturated_mark) {
      d[j] = 255; d[j + 1] = 0; d[j + 2] = 0; d[j + 3] = 255;
      continue;
    }
    const x = Math.max(0, px[i] - lo);
    const g = Math.round(255 * Math.min(1, (log ? Math.log1p(x) : x) * norm));
    d[j] = d[j + 1] = d[j + 2] = g;
    d[j + 3] = 255;
  }
  ctx.putImageData(img, 0, 0);
  const box = (r, colour) => {
    ctx.strokeStyle = colour;
    ctx.lineWidth = Math.max(1, f.width / 256);
    ctx.strokeRect(r.x / f.scale, r.y / f.scale, r.width / f.scale, r.height / f.scale);
  };
  if (f.rectangle) box(f.rectangle, '#2fd15a');
  const r = dragRect();
  if (r) box(r, '#ffd43b');
}

// The rectangle being dragged or placed, frame pixels, inside the frame.
function dragRect() {
  const d = cam.drag, f = cam.info;
  if (!d || !f) return null;
  const clamp = (v, hi) => Math.max(0, Math.min(hi, v));
  const x0 = clamp(Math.min(d.x0, d.x1), f.frame_width - 1);
  const y0 = clamp(Math.min(d.y0, d.y1), f.frame_height - 1);
  const x1 = clamp(Math.max(d.x0, d.x1), f.frame_width - 1);
  const y1 = clamp(Math.max(d.y0, d.y1), f.frame_height - 1);
  return { x: x0, y: y0, width: x1 - x0 + 1, height: y1 - y0 + 1 };
}

function framePixel(ev) {
  const f = cam.info, b = $('frame').getBoundingClientRect();
  return {
    x: Math.floor((ev.clientX - b.left) / b.width * f.width * f.scale),
    y: Math.floor((ev.clientY - b.top) / b.height * f.height * f.scale),
  };
}

function rectangleToml(r) {
  return '[rectangle]\nx = ' + r.x + '\ny = ' + r.y + '\nwidth = ' + r.width + '\nheight = ' +
    r.height + '\n';
}

// What the placed rectangle takes in, from goniod's bench geometry (GET /api/v1/rectangle).
async function describeRectangle(r) {
  const toml = rectangleToml(r);
  cam.chosen = { rect: r, toml };
  $('rect-toml').textContent = toml;
  $('rect-toml').hidden = false;
  $('rect-to-plan').disabled = false;
  const sample = /^\s*sample\s*=\s*"([^"]*)"/m.exec($('plan-text').value);
  let q = '?x=' + r.x + '&y=' + r.y + '&width=' + r.width + '&height=' + r.height;
  if (sample) q += '&specimen=' + encodeURIComponent(sample[1]);
  let s = r.width + ' × ' + r.height + ' px';
  try {
    const c = await request('GET', '/api/v1/rectangle' + q);
    s += ' = ' + fmt(c.width_mm, 2) + ' × ' + fmt(c.height_mm, 2) + ' mm at the sample' +
      ' (' + fmt(c.thickness_mm, 1) + ' mm plate); view directions spread ' +
      fmt(c.view_spread_deg.rms, 3) + '° rms (max ' + fmt(c.view_spread_deg.max, 3) +
      '°), light ' + fmt(c.light_spread_deg.rms, 3) + '° rms, at normal incidence';
  } catch (e) {
    s += ' (' + e.message + ')';
  }
  if (cam.chosen.rect === r) $('rect-info').textContent = s;
}

// Replaces the plan's [rectangle] table (to the next table) with the placed one, or appends it.
function rectangleIntoPlan() {
  if (!cam.chosen) return;
  const box = $('plan-text');
  const table = /^\[rectangle\][^\n]*\n?(?:(?!\s*\[)[^\n]*(?:\n|$))*/m;
  const plan = box.value;
  box.value = table.test(plan) ? plan.replace(table, cam.chosen.toml)
    : plan.replace(/\n*$/, '\n\n') + cam.chosen.toml;
  say('the plan\'s [rectangle] is now the one placed; a dry run checks it', false);
}

function wireCamera() {
  const canvas = $('frame');
  canvas.addEventListener('pointerdown', (ev) => {
    if (!cam.info) return;
    const p = framePixel(ev);
    cam.drag = { x0: p.x, y0: p.y, x1: p.x, y1: p.y, active: true };
    canvas.setPointerCapture(ev.pointerId);
    renderFrame();
  });
  // The drag's far corner follows the pointer; on release the rectangle is described.
  const follow = (ev, last) => {
    if (!cam.drag || !cam.drag.active) return;
    const p = framePixel(ev);
    cam.drag.x1 = p.x;
    cam.drag.y1 = p.y;
    cam.drag.active = !last;
    renderFrame();
    if (last) describeRectangle(dragRect());
  };
  canvas.addEventListener('pointermove', (ev) => follow(ev, false));
  canvas.addEventListener('pointerup', (ev) => follow(ev, true));
  $('frame-white').addEventListener('input', renderFrame);
  $('frame-log').addEventListener('change', renderFrame);
  $('rect-to-plan').addEventListener('click', rectangleIntoPlan);
  $('snap').addEventListener('click', async () => {
    const t = Number($('snap-exposure').value);
    $('snap').disabled = true;
    const r = await mutate('POST', '/api/v1/camera/snap', { exposure_s: t }, 'snapped at ' + t + ' s');
    $('snap').disabled = false;
    if (r) fetchFrame();
  });
}

function wire() {
  $('token-form').addEventListener('submit', (ev) => {
    ev.preventDefault();
    const t = $('token').value.trim();
    if (t) sessionStorage.setItem(TOKEN_KEY, t);
    showTokenState();
  });
  $('token-forget').addEventListener('click', () => {
    sessionStorage.removeItem(TOKEN_KEY);
    showTokenState();
  });
  $('pause').addEventListener('click', () =>
    mutate('POST', '/api/v1/pause', {}, 'pause asked: after the current point is stored'));
  $('resume').addEventListener('click', () => mutate('POST', '/api/v1/resume', {}, 'resumed'));
  $('abort').addEventListener('click', () => {
    const s = view.status;
    $('abort-question').textContent = 'Abort ' + (s && s.job && s.job.run ? 'run ' + s.job.run
      : 'the current job') + '? Its stored points are kept; it cannot be resumed.';
    $('abort-confirm').hidden = false;
  });
  $('abort-no').addEventListener('click', () => { $('abort-confirm').hidden = true; });
  $('abort-yes').addEventListener('click', async () => {
    $('abort-confirm').hidden = true;
    await mutate('POST', '/api/v1/abort', {}, 'abort asked: the current point finishes first');
  });
  $('dry-run').addEventListener('click', async () => {
    const plan = await readPlan();
    if (!plan) return;
    // A one-entry schedule is the API's dry run of a plan (docs/api.md).
    const schedule = '[[job]]\nplan = ' + JSON.stringify(plan.name) + '\nrepeat = ' +
      Number($('plan-repeat').value || 1) + '\n';
    const r = await mutate('POST', '/api/v1/schedules',
      { name: 'console', schedule, plans: { [plan.name]: plan.text }, dry_run: true });
    if (!r) return;
    const j = r.jobs[0];
    $('dry-run-result').textContent = plan.name + ': ' + j.points + ' points' +
      (j.skipped ? ' (' + j.skipped + ' skipped)' : '') + ', about ' + duration(r.estimate_s) +
      ' (' + j.estimate_basis + ')';
    say('dry run: nothing was queued', false);
  });
  $('submit-form').addEventListener('submit', async (ev) => {
    ev.preventDefault();
    const plan = await readPlan();
    if (!plan) return;
    const repeat = Number($('plan-repeat').value || 1);
    const r = await mutate('POST', '/api/v1/jobs', { name: plan.name, plan: plan.text, repeat });
    if (r) say(plan.name + ' queued' + (r.id ? ' as job ' + r.id : ' ' + repeat + ' times'), false);
  });
  $('plan-file').addEventListener('change', loadPlanFile);
  $('plan-catalogue').addEventListener('change', loadCataloguePlan);
  $('schedule-dry-run').addEventListener('click', async () => {
    const s = await readSchedule();
    if (!s) return;
    const r = await mutate('POST', '/api/v1/schedules', { name: s.name, schedule: s.schedule,
                                                         plans: s.plans, dry_run: true });
    if (!r) return;
    showSchedule(r, false);
    say('schedule dry run: nothing was queued', false);
  });
  $('schedule-form').addEventListener('submit', async (ev) => {
    ev.preventDefault();
    const s = await readSchedule();
    if (!s) return;
    const r = await mutate('POST', '/api/v1/schedules',
      { name: s.name, schedule: s.schedule, plans: s.plans });
    if (!r) return;
    showSchedule(r, true);
    say(s.name + ': ' + r.jobs.length + ' job(s) queued', false);
  });
  $('plan-download').addEventListener('click', () => {
    const a = document.createElement('a');
    a.href = URL.createObjectURL(new Blob([$('plan-text').value], { type: 'text/plain' }));
    a.download = planName || 'plan.toml';
    a.click();
    setTimeout(() => URL.revokeObjectURL(a.href), 1000);
  });
  wireCamera();
  $('fit').addEventListener('click', async () => {
    const id = view.selected;
    if (id === null) { say('open a run first', true); return; }
    $('fit').disabled = true;
    say('fitting run ' + id + '…', false);
    const r = await mutate('POST', '/api/v1/runs/' + id + '/fit', { models: ['beckmann', 'ggx'] },
      'run ' + id + ' fitted (Beckmann and GGX); the dashed line is the fit BIC prefers');
    $('fit').disabled = false;
    if (r) { delete drawn.run; fetchRun(); }
  });
  $('follow').addEventListener('change', (ev) => {
    view.follow = ev.target.checked;
    refreshSoon(false);
  });
}

wire();
showTokenState();
listen();
refreshSoon(true);
fetchFrame();
loadCatalogue();
setInterval(() => { refreshSoon(true); fetchFrame(); }, POLL_MS);
