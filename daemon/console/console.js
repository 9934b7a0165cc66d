// goniod's console (issue #20; daemon/console/README.md). Plain JavaScript, no build step, no
// third-party code: it uses goniod's API (docs/api.md) and nothing else.
//
// Reads are bounded: the event stream (GET /api/v1/events) only says that something changed;
// the page then fetches the status, the queue and the shown run at most once per MIN_FETCH_MS
// each, and falls back to polling every POLL_MS when the stream is down.
'use strict';

const MIN_FETCH_MS = 1000;
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
  selected: null,   // the shown run's id
  follow: true,
  pendingPoint: null,  // {run, done, at}: a progress event not drawn yet
};

// Each resource is fetched at most once per MIN_FETCH_MS; a request in between is deferred.
function throttled(fn) {
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
    const wait = Math.max(0, last + MIN_FETCH_MS - performance.now());
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
    if (changed('run', [run, fits])) renderRun();
  } catch (e) { say(e.message, true); }
});

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
    for (const id of ['lobe', 'temperature', 'exposure']) $(id).replaceChildren();
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
  drawLobe($('lobe'), ms);
  drawSeries($('temperature'), ms.map((m) => m.temperature_c), false);
  drawSeries($('exposure'), ms.map((m) => m.exposure_s), true);
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
    cell(tr, f.model);
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

function drawLobe(svg, ms) {
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
  const incidences = [...new Set(ms.map((m) => m.theta_l_deg))].sort((a, b) => a - b);
  incidences.forEach((inc, k) => {
    const colour = COLOURS[k % COLOURS.length];
    const g = el('g', { 'data-incidence': inc }, svg);
    const pts = ms.filter((m) => m.theta_l_deg === inc).sort((a, b) => a.theta_v_deg - b.theta_v_deg);
    el('polyline', {
      points: pts.map((m) => X(m.theta_v_deg) + ',' + Y(m.value)).join(' '),
      fill: 'none', stroke: colour, 'stroke-width': 1, 'stroke-opacity': 0.5,
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

// One value per point, against the point's order; log scale when asked.
function drawSeries(svg, values, log) {
  svg.replaceChildren();
  const W = 320, H = 160, L = 44, R = 8, T = 8, B = 22;
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
    if (hi - lo < 0.5) { lo -= 0.25; hi += 0.25; }
    Y = (x) => T + (1 - (x - lo) / (hi - lo)) * (H - T - B);
    text(svg, L - 4, Y(lo) + 4, fmt(lo, 1), 'end');
    text(svg, L - 4, Y(hi) + 4, fmt(hi, 1), 'end');
  }
  const X = (i) => L + (v.length < 2 ? 0.5 : i / (v.length - 1)) * (W - L - R);
  const pts = [];
  v.forEach((x, i) => { if (isFinite(x) && (!log || x > 0)) pts.push(X(i) + ',' + Y(x)); });
  el('polyline', { points: pts.join(' '), fill: 'none', stroke: COLOURS[0], 'stroke-width': 1.2 }, svg);
  text(svg, (L + W - R) / 2, H - 6, 'point (in order measured)');
}

// ---- controls ----------------------------------------------------------------------------------

async function readPlan() {
  const f = $('plan-file').files[0];
  if (!f) { say('choose a plan file first', true); return null; }
  if (f.size > 1 << 20) { say(f.name + ': a plan of ' + f.size + ' bytes is too large', true); return null; }
  return { name: f.name, text: await f.text() };
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
  $('follow').addEventListener('change', (ev) => {
    view.follow = ev.target.checked;
    refreshSoon(false);
  });
}

wire();
showTokenState();
listen();
refreshSoon(true);
setInterval(() => refreshSoon(true), POLL_MS);
