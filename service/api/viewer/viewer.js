// The operator's live view (GET /viewer): agents, their sets and their confidence, in the world frame.
//
// Data: the agents come from polling the `list_agents` op on WS /v1/stream (one message for all of
// them); an agent's contours (GET /v1/agents/{id}/frt: the tube of K and C and the slider's time
// slice, which costs a fifth of all the slices at once) are fetched only when its FRT version or
// the slider changes, at most one request per agent and MAX_FETCHES in all at once.
// Drawing: d3.geoPath turns each contour into a Path2D once per version, in world coordinates;
// a frame sets the canvas transform (d3.zoom's pan and zoom on top of the fitted view) and fills the
// cached paths, on requestAnimationFrame, only when something changed; planners' trajectories
// checked in the last seconds (also in list_agents' answer) go on top. uPlot draws the selected
// agent's beta and belief over time. The page's state is window.frtViewer (see `api` below).
// Maps: for the maps the agents name, the page reads each map's extent once (GET /v1/maps/{id})
// and its geometry within the view, padded (GET /v1/maps/{id}/geojson?bbox=...), again only when
// the view leaves the box fetched or zooms in past twice its detail, and draws it under the sets,
// muted. With "uncut set" on, contours are fetched with include_uncut=true and the set before the
// map's cut is outlined, dotted, beside the cut one.

const d3 = window.d3;
const uPlot = window.uPlot;

const POLL_MS = 250; // list_agents period (the fleet is observed at 2-10 Hz)
const MAX_FETCHES = 6; // contour requests in flight (a browser's connections per origin)
const WAIT_READY_MS = 1000; // fetch a version's contours before its exact set is ready after this
const HISTORY = 240; // beta points kept per agent
const FRAME_SAMPLES = 600;
const SLICE_STEP_S = 0.5;
const MAX_SLICES = 12;
const MAP_MAX_BOX_M = 2000; // the server's cap on a map box's side
const MAP_PAD = 0.5; // a map box reaches this share of the view beyond each side
const MAP_RETRY_MS = 5000; // a map whose read failed is asked for again after this

const STYLE = {
  background: "#f7f7f5",
  grid: "#e2e2de",
  classColours: { car: "#1f77b4", cyclist: "#ff7f0e", pedestrian: "#2ca02c" },
  otherColour: "#7f7f7f",
  tubeC: 0.15, // fill opacities, painted in this order
  tubeK: 0.3,
  sliceC: 0.0,
  sliceK: 0.55,
  outline: 0.8,
  clearPath: "#1a9850", // a planner's trajectory clear of every agent's C
  hitPath: "#d73027", // ... and from its first point inside one
  markerPx: 9,
  mapFill: "#dedbd2", // the drivable area, under everything but the grid
  mapLane: "#c4c0b4", // lane outlines, one pixel
  mapCentre: "#cfcbc0", // lane centre lines, dashed
  uncutOutline: 0.7, // the uncut set's C, dotted
};

const params = new URLSearchParams(location.search);
const token = params.get("token") || sessionStorage.getItem("frt-viewer-token");
if (params.has("token")) {
  sessionStorage.setItem("frt-viewer-token", token);
  params.delete("token"); // keep the token out of the address bar (and of shared screenshots)
  history.replaceState(null, "", location.pathname + (params.size ? `?${params}` : ""));
}
const base = location.pathname.replace(/\/viewer\/?$/, "");
const httpBase = `${location.origin}${base}`;
const wsBase = `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}${base}`;
const authHeaders = token ? { Authorization: `Bearer ${token}` } : {};

const canvas = document.getElementById("map");
const ctx = canvas.getContext("2d");
const el = (id) => document.getElementById(id);

const state = {
  agents: new Map(), // id -> agent record (see upsertAgent)
  checks: [], // planners' trajectories checked in the last seconds, newest first
  selected: null,
  horizon: 3.0,
  slices: [],
  options: {
    colour: "class", showTube: true, showSlice: true, showGrid: true, showChecks: true,
    showMap: true, showUncut: false, sliceIndex: 2,
  },
  maps: new Map(), // map id -> map record (see mapRecord)
  view: { cx: 0, cy: 0, s: 4, follow: true }, // fitted view: world centre, pixels per metre
  zoom: d3.zoomIdentity,
  width: 0,
  height: 0,
  dirty: true,
  connected: false,
  error: null,
  stats: {
    polls: 0, pollMs: [], fetches: 0, fetchErrors: 0, inFlight: 0,
    frames: 0, drawMs: [], frameIntervalMs: [], lastFrameAt: null, maxLag: 0, lag: 0,
    worstAgentLag: 0, maxWorstAgentLag: 0, mapFetches: 0, mapFetchErrors: 0,
  },
};

// ------------------------------------------------------------------------------ colours

const betaColour = (beta) => d3.interpolatePlasma(0.85 * Math.min(Math.max(beta, 0), 1));

function agentColour(agent) {
  if (state.options.colour === "beta") return betaColour(agent.info.beta);
  return STYLE.classColours[agent.cls] || STYLE.otherColour;
}

function withAlpha(colour, alpha) {
  const c = d3.color(colour);
  c.opacity = alpha;
  return c.formatRgb();
}

// ------------------------------------------------------------------------------ geometry

function toPath(geometry) {
  if (!geometry) return null;
  const path = new Path2D();
  d3.geoPath(null, path)(geometry); // no projection: world metres as they are
  return path;
}

function pathsOf(contours) {
  const pair = (p) => ({ K: toPath(p && p.K), C: toPath(p && p.C) });
  return {
    tube: pair(contours.tube),
    slices: contours.slices.map((s) => ({ t: s.t, ...pair(s) })),
  };
}

// World -> screen: the fitted view, then d3.zoom's transform.
function matrix() {
  const { cx, cy, s } = state.view;
  const k = state.zoom.k;
  const a = k * s;
  const e = state.zoom.x + k * (state.width / 2 - cx * s);
  const f = state.zoom.y + k * (state.height / 2 + cy * s);
  return { a, e, f };
}

function toScreen(x, y) {
  const { a, e, f } = matrix();
  return [e + a * x, f - a * y];
}

function fitView() {
  const list = [...state.agents.values()];
  if (!list.length || !state.width) return;
  const xs = list.map((a) => a.info.state.x);
  const ys = list.map((a) => a.info.state.y);
  const margin = 25; // metres: a 3 s tube of a car at urban speed
  const [x0, x1] = [d3.min(xs) - margin, d3.max(xs) + margin];
  const [y0, y1] = [d3.min(ys) - margin, d3.max(ys) + margin];
  const s = Math.min(state.width / (x1 - x0), state.height / (y1 - y0));
  state.view = { cx: (x0 + x1) / 2, cy: (y0 + y1) / 2, s, follow: true };
  state.zoom = d3.zoomIdentity;
  d3.select(canvas).property("__zoom", d3.zoomIdentity);
  state.dirty = true;
  pumpMaps();
}

// ------------------------------------------------------------------------------ data

function upsertAgent(info, now) {
  let agent = state.agents.get(info.agent_id);
  if (!agent) {
    agent = {
      id: info.agent_id, info, cls: info.agent_class || "car", version: 0, behindSince: now,
      contours: null, paths: null, contoursVersion: 0, contoursSlice: null, contoursAt: 0,
      drawnVersion: 0, uncutPaths: null, contoursUncut: false, assumptions: [],
      conservative: false,
      fetching: false, history: [],
    };
    state.agents.set(info.agent_id, agent);
  }
  agent.info = info;
  agent.cls = info.agent_class || agent.cls;
  if (info.frt_version !== agent.version) {
    // Since when the drawn set has been behind: a new version every poll must not reset it.
    if (agent.version === agent.contoursVersion) agent.behindSince = now;
    agent.version = info.frt_version;
  }
  const last = agent.history[agent.history.length - 1];
  if (!last || info.timestamp > last.t) {
    agent.history.push({ t: info.timestamp, beta: info.beta, pLow: info.belief.beta_low });
    if (agent.history.length > HISTORY) agent.history.shift();
    if (agent.id === state.selected) state.plotDirty = true;
  }
  return agent;
}

function onAgents(result) {
  const now = performance.now();
  const seen = new Set();
  for (const info of result.agents) seen.add(upsertAgent(info, now).id);
  for (const id of [...state.agents.keys()]) {
    if (!seen.has(id)) state.agents.delete(id);
  }
  if (state.selected && !state.agents.has(state.selected)) select(null);
  if (state.view.follow) fitView();
  state.truncated = result.truncated ? result.total : 0;
  state.checks = result.checks || [];
  state.dirty = true;
  pumpFetches();
  pumpMaps();
}

const sliceTime = () => state.slices[state.options.sliceIndex];

function wanted(agent, now) {
  if (agent.fetching) return false;
  if (agent.version === agent.contoursVersion) {
    return agent.contoursSlice !== sliceTime() || (state.options.showUncut && !agent.contoursUncut);
  }
  return agent.info.frt_ready || now - agent.behindSince >= WAIT_READY_MS;
}

// When the server answers fewer contour requests than versions arrive, the agents whose drawn
// sets are oldest go first (the selected one before all), so none of them starves.
function pumpFetches() {
  if (state.stats.inFlight >= MAX_FETCHES) return;
  const now = performance.now();
  const due = [...state.agents.values()].filter((agent) => wanted(agent, now));
  const rank = (agent) => (agent.id === state.selected ? -1 : agent.contoursAt);
  due.sort((a, b) => rank(a) - rank(b));
  for (const agent of due.slice(0, MAX_FETCHES - state.stats.inFlight)) fetchContours(agent);
}

async function fetchContours(agent) {
  agent.fetching = true;
  state.stats.inFlight += 1;
  const t = sliceTime();
  const uncut = state.options.showUncut;
  const query = (t === undefined ? "" : `&slices=${+t.toFixed(3)}`) +
    (uncut ? "&include_uncut=true" : "");
  const url = `${httpBase}/v1/agents/${encodeURIComponent(agent.id)}/frt?include=K,C${query}`;
  try {
    const response = await fetch(url, { headers: authHeaders });
    if (response.ok) {
      const body = await response.json();
      if (body.frt_version >= agent.contoursVersion) {
        agent.contours = body;
        agent.paths = pathsOf(body);
        agent.contoursVersion = body.frt_version;
        agent.contoursSlice = t;
        agent.contoursUncut = uncut;
        agent.uncutPaths = uncut && body.uncut ? pathsOf(body.uncut) : null;
        agent.assumptions = body.assumptions || [];
        agent.contoursAt = performance.now();
        agent.behindSince = agent.contoursAt;
        agent.conservative = body.conservative;
        state.dirty = true;
      }
    } else if (response.status === 404) {
      state.agents.delete(agent.id); // forgotten between the poll and the fetch
    } else {
      state.stats.fetchErrors += 1;
    }
    state.stats.fetches += 1;
  } catch (err) {
    state.stats.fetchErrors += 1;
  } finally {
    agent.fetching = false;
    state.stats.inFlight -= 1;
    pumpFetches();
  }
}

async function loadModel() {
  try {
    const response = await fetch(`${httpBase}/v1/model`, { headers: authHeaders });
    if (response.ok) state.horizon = (await response.json()).horizon_s;
  } catch (err) {
    // the default horizon stands
  }
  const n = Math.min(MAX_SLICES, Math.max(1, Math.round(state.horizon / SLICE_STEP_S)));
  state.slices = d3.range(1, n + 1).map((i) => (i * state.horizon) / n);
  const slider = el("slice");
  slider.max = String(n);
  state.options.sliceIndex = Math.min(state.options.sliceIndex, n - 1);
  slider.value = String(state.options.sliceIndex + 1);
  showSliceLabel();
}

// One socket, one list_agents at a time: the next poll goes out POLL_MS after the last was sent
// (or at once, if its answer took longer), so a slow server is never sent a queue of them.
function connect() {
  const url = `${wsBase}/v1/stream${token ? `?token=${encodeURIComponent(token)}` : ""}`;
  const ws = new WebSocket(url);
  let sentAt = 0;
  let next = 1;
  const poll = () => {
    if (ws.readyState !== WebSocket.OPEN) return;
    sentAt = performance.now();
    ws.send(JSON.stringify({ id: next++, op: "list_agents" }));
  };
  ws.onopen = () => {
    state.connected = true;
    state.error = null;
    poll();
  };
  ws.onmessage = (event) => {
    const answer = JSON.parse(event.data);
    const took = performance.now() - sentAt;
    if (answer.ok) {
      state.stats.polls += 1;
      push(state.stats.pollMs, took, 120);
      onAgents(answer.result);
      measureLag();
    } else {
      state.error = answer.error.detail;
    }
    setTimeout(poll, Math.max(0, POLL_MS - took));
  };
  ws.onclose = () => {
    state.connected = false;
    state.error = state.error || (token ? "stream closed" : "stream closed (token needed? ?token=)");
    state.dirty = true;
    setTimeout(connect, 1000);
  };
}

// Versions known but not drawn: in all, and of the stalest agent.
function measureLag() {
  let lag = 0;
  let worst = 0;
  for (const a of state.agents.values()) {
    const behind = Math.max(0, a.version - a.drawnVersion);
    lag += behind;
    worst = Math.max(worst, behind);
  }
  state.stats.lag = lag;
  state.stats.maxLag = Math.max(state.stats.maxLag, lag);
  state.stats.worstAgentLag = worst;
  state.stats.maxWorstAgentLag = Math.max(state.stats.maxWorstAgentLag, worst);
}

function push(list, value, cap = FRAME_SAMPLES) {
  list.push(value);
  if (list.length > cap) list.shift();
}

// ------------------------------------------------------------------------------ maps

// The world box the canvas shows: [x0, y0, x1, y1].
function visibleBox() {
  const { a, e, f } = matrix();
  return [(0 - e) / a, (f - state.height) / a, (state.width - e) / a, f / a];
}

function meet(p, q) {
  const box = [
    Math.max(p[0], q[0]), Math.max(p[1], q[1]), Math.min(p[2], q[2]), Math.min(p[3], q[3]),
  ];
  return box[2] > box[0] && box[3] > box[1] ? box : null;
}

// At most `side` metres on a side, around the box's centre.
function capped(box, side) {
  const [cx, cy] = [(box[0] + box[2]) / 2, (box[1] + box[3]) / 2];
  const hw = Math.min(box[2] - box[0], side) / 2;
  const hh = Math.min(box[3] - box[1], side) / 2;
  return [cx - hw, cy - hh, cx + hw, cy + hh];
}

const holds = (outer, inner) =>
  outer[0] <= inner[0] && outer[1] <= inner[1] && outer[2] >= inner[2] && outer[3] >= inner[3];

function mapRecord(id) {
  let record = state.maps.get(id);
  if (!record) {
    record = {
      id, extent: null, box: null, scale: 0, paths: null, features: 0, vertices: 0,
      simplify: null, fetching: false, retryAt: 0, error: null,
    };
    state.maps.set(id, record);
  }
  return record;
}

const namedMaps = () =>
  new Set([...state.agents.values()].map((a) => a.info.map_id).filter((id) => id));

// Reads each named map's extent once, then its geometry around the view when the view has left
// the box last read (or zoomed in past twice its detail): never per frame.
function pumpMaps() {
  if (!state.width || !state.options.showMap) return;
  const now = performance.now();
  const view = visibleBox();
  const scale = matrix().a;
  for (const id of namedMaps()) {
    const record = mapRecord(id);
    if (record.fetching || now < record.retryAt) continue;
    if (!record.extent) {
      fetchMap(record, null, scale);
      continue;
    }
    const seen = meet(view, record.extent);
    if (!seen) continue;
    const needed = capped(seen, 0.8 * MAP_MAX_BOX_M);
    if (record.box && holds(record.box, needed) && scale <= 2 * record.scale) continue;
    const padX = MAP_PAD * (view[2] - view[0]);
    const padY = MAP_PAD * (view[3] - view[1]);
    const padded = [view[0] - padX, view[1] - padY, view[2] + padX, view[3] + padY];
    fetchMap(record, capped(meet(padded, record.extent), MAP_MAX_BOX_M), scale);
  }
}

function mapPaths(features) {
  const path = (kind) => {
    const chosen = features.filter((f) => f.properties.kind === kind);
    if (!chosen.length) return null;
    return toPath({ type: "FeatureCollection", features: chosen });
  };
  return { drivable: path("drivable_area"), lanes: path("lane"), centres: path("centerline") };
}

// box null: the map's summary (its extent); else its geometry within box, simplified to half a
// pixel at the scale it is read for.
async function fetchMap(record, box, scale) {
  record.fetching = true;
  const id = encodeURIComponent(record.id);
  const simplify = Math.min(10, 0.5 / scale);
  const url = box
    ? `${httpBase}/v1/maps/${id}/geojson?bbox=${box.map((v) => +v.toFixed(2)).join(",")}` +
      `&simplify_m=${+simplify.toPrecision(3)}`
    : `${httpBase}/v1/maps/${id}`;
  try {
    const response = await fetch(url, { headers: authHeaders });
    if (!response.ok) throw new Error(`${response.status}`);
    const body = await response.json();
    if (box) {
      Object.assign(record, {
        box, scale, paths: mapPaths(body.features), features: body.features.length,
        vertices: body.vertices, simplify: body.simplify_m, error: null,
      });
      state.stats.mapFetches += 1;
      state.dirty = true;
    } else {
      record.extent = body.extent;
    }
  } catch (err) {
    record.error = String(err.message || err);
    record.retryAt = performance.now() + MAP_RETRY_MS;
    state.stats.mapFetchErrors += 1;
  } finally {
    record.fetching = false;
  }
  if (!box && record.extent) pumpMaps();
}

// ------------------------------------------------------------------------------ drawing

function resize() {
  const rect = canvas.getBoundingClientRect();
  const dpr = window.devicePixelRatio || 1;
  state.width = rect.width;
  state.height = rect.height;
  canvas.width = Math.round(rect.width * dpr);
  canvas.height = Math.round(rect.height * dpr);
  if (state.view.follow) fitView();
  state.dirty = true;
  pumpMaps();
}

// The maps the agents name, under the sets: the road filled, lanes outlined, centre lines dashed.
function drawMaps(dpr) {
  const { a, e, f } = matrix();
  const px = 1 / a;
  ctx.setTransform(dpr * a, 0, 0, -dpr * a, dpr * e, dpr * f);
  let drawn = 0;
  for (const id of namedMaps()) {
    const paths = (state.maps.get(id) || {}).paths;
    if (!paths) continue;
    if (paths.drivable) {
      ctx.fillStyle = STYLE.mapFill;
      ctx.fill(paths.drivable, "evenodd");
    }
    ctx.lineWidth = px;
    if (paths.lanes) {
      ctx.setLineDash([]);
      ctx.strokeStyle = STYLE.mapLane;
      ctx.stroke(paths.lanes);
    }
    if (paths.centres) {
      ctx.setLineDash([4 * px, 4 * px]);
      ctx.strokeStyle = STYLE.mapCentre;
      ctx.stroke(paths.centres);
    }
    drawn += 1;
  }
  ctx.setLineDash([]);
  state.mapsDrawn = drawn;
}

function drawGrid(dpr) {
  const { a, e, f } = matrix();
  const x0 = (0 - e) / a;
  const x1 = (state.width - e) / a;
  const y0 = (f - state.height) / a;
  const y1 = f / a;
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.strokeStyle = STYLE.grid;
  ctx.lineWidth = 1;
  ctx.beginPath();
  for (const x of d3.ticks(x0, x1, 10)) {
    const [sx] = toScreen(x, 0);
    ctx.moveTo(Math.round(sx) + 0.5, 0);
    ctx.lineTo(Math.round(sx) + 0.5, state.height);
  }
  for (const y of d3.ticks(y0, y1, 8)) {
    const [, sy] = toScreen(0, y);
    ctx.moveTo(0, Math.round(sy) + 0.5);
    ctx.lineTo(state.width, Math.round(sy) + 0.5);
  }
  ctx.stroke();
  const step = d3.tickStep(x0, x1, 10);
  ctx.fillStyle = "#888";
  ctx.fillText(`grid ${step} m`, state.width - 70, state.height - 8);
}

function drawSets(agent, dpr) {
  const paths = agent.paths;
  if (!paths) return;
  const { a, e, f } = matrix();
  ctx.setTransform(dpr * a, 0, 0, -dpr * a, dpr * e, dpr * f);
  const colour = agentColour(agent);
  const px = 1 / a; // one screen pixel in metres
  const fill = (path, alpha) => {
    if (path && alpha > 0) {
      ctx.fillStyle = withAlpha(colour, alpha);
      ctx.fill(path, "evenodd");
    }
  };
  const stroke = (path, width, dash, alpha = STYLE.outline) => {
    if (!path) return;
    ctx.setLineDash(dash.map((d) => d * px));
    ctx.lineWidth = width * px;
    ctx.strokeStyle = withAlpha(colour, alpha);
    ctx.stroke(path);
  };
  const dashes = agent.conservative ? [6, 4] : [];
  const uncut = state.options.showUncut ? agent.uncutPaths : null;
  const atSlice = (list) => list.find((s) => Math.abs(s.t - sliceTime()) < 1e-6);
  if (state.options.showTube) {
    fill(paths.tube.C, STYLE.tubeC);
    fill(paths.tube.K, STYLE.tubeK);
    stroke(paths.tube.C, agent.id === state.selected ? 2 : 1, dashes);
    if (uncut) stroke(uncut.tube.C, 1.5, [2, 3], STYLE.uncutOutline);
  }
  const slice = atSlice(paths.slices);
  if (state.options.showSlice && slice) {
    fill(slice.C, STYLE.sliceC);
    fill(slice.K, STYLE.sliceK);
    stroke(slice.C, 1, dashes);
    const whole = uncut && atSlice(uncut.slices);
    if (whole) stroke(whole.C, 1.5, [2, 3], STYLE.uncutOutline);
  }
  ctx.setLineDash([]);
}

// A checked trajectory: green while clear of every agent's C, red from its first collision on;
// dashed where an answer was conservative; fading with age.
function drawCheck(check, dpr) {
  const points = check.trajectory.map(([, x, y]) => toScreen(x, y));
  if (!points.length) return;
  const hits = Object.values(check.agents)
    .map((a) => a.first_collision_index)
    .filter((i) => i !== null && i !== undefined);
  const n = check.trajectory.length;
  const first = hits.length ? Math.min(...hits) : n;
  const alpha = Math.max(0.25, 1 - check.age_s / 2);
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.lineWidth = 2.5;
  ctx.setLineDash(check.conservative ? [5, 3] : []);
  const part = (from, to, colour) => { // points from..to, both included
    if (to <= from) return;
    ctx.beginPath();
    ctx.moveTo(...points[from]);
    for (let i = from + 1; i <= to; i++) ctx.lineTo(...points[i]);
    ctx.strokeStyle = withAlpha(colour, alpha);
    ctx.stroke();
  };
  part(0, Math.min(first, n - 1), STYLE.clearPath);
  if (first < n) part(first, n - 1, STYLE.hitPath);
  ctx.setLineDash([]);
  for (const [i, [sx, sy]] of points.entries()) {
    if (i === 0 || i === first) {
      ctx.beginPath();
      ctx.arc(sx, sy, 3.5, 0, 2 * Math.PI);
      ctx.fillStyle = withAlpha(i >= first ? STYLE.hitPath : STYLE.clearPath, alpha);
      ctx.fill();
    }
  }
}

function drawMarker(agent, dpr) {
  const { x, y, heading } = agent.info.state;
  const [sx, sy] = toScreen(x, y);
  const r = STYLE.markerPx;
  ctx.setTransform(dpr, 0, 0, dpr, dpr * sx, dpr * sy);
  ctx.rotate(-heading); // screen y points down: a counter-clockwise world heading turns this way
  ctx.beginPath();
  ctx.moveTo(r, 0);
  ctx.lineTo(-0.7 * r, 0.6 * r);
  ctx.lineTo(-0.4 * r, 0);
  ctx.lineTo(-0.7 * r, -0.6 * r);
  ctx.closePath();
  ctx.fillStyle = agentColour(agent);
  ctx.fill();
  ctx.lineWidth = 1;
  ctx.strokeStyle = "#222";
  ctx.stroke();
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  if (agent.id === state.selected) {
    ctx.beginPath();
    ctx.arc(sx, sy, r + 5, 0, 2 * Math.PI);
    ctx.lineWidth = 2;
    ctx.strokeStyle = "#000";
    ctx.stroke();
  }
  if (agent.conservative) {
    ctx.fillStyle = "#b35900";
    ctx.fillText("≈", sx + r + 3, sy - r);
  }
}

function draw() {
  const start = performance.now();
  const dpr = window.devicePixelRatio || 1;
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.fillStyle = STYLE.background;
  ctx.fillRect(0, 0, state.width, state.height);
  ctx.font = "12px system-ui, sans-serif";
  if (state.options.showMap) drawMaps(dpr);
  if (state.options.showGrid) drawGrid(dpr);
  const agents = [...state.agents.values()];
  for (const agent of agents) drawSets(agent, dpr);
  if (state.options.showChecks) {
    for (const check of [...state.checks].reverse()) drawCheck(check, dpr); // newest on top
  }
  for (const agent of agents) {
    drawMarker(agent, dpr);
    agent.drawnVersion = agent.contoursVersion;
  }
  ctx.setTransform(1, 0, 0, 1, 0, 0);
  state.stats.frames += 1;
  push(state.stats.drawMs, performance.now() - start);
}

function frame(now) {
  if (state.stats.lastFrameAt !== null && state.dirty) {
    push(state.stats.frameIntervalMs, now - state.stats.lastFrameAt);
  }
  if (state.dirty) {
    state.dirty = false;
    draw();
    state.stats.lastFrameAt = now;
    showPanel();
  }
  requestAnimationFrame(frame);
}

// ------------------------------------------------------------------------------ panel

let plot = null;

function makePlot() {
  const opts = {
    width: 300,
    height: 150,
    scales: { x: { time: false }, y: { range: [0, 1] } },
    series: [
      { label: "t [s]" },
      { label: "β", stroke: "#c0392b", width: 2 },
      { label: "P(β_low)", stroke: "#2c7fb8", width: 1.5, dash: [5, 3] },
    ],
    axes: [{ size: 30 }, { size: 35 }],
    cursor: { drag: { x: false, y: false } },
    legend: { live: false },
  };
  plot = new uPlot(opts, [[], [], []], el("beta-plot"));
}

function updatePlot() {
  const agent = state.agents.get(state.selected);
  const h = agent ? agent.history : [];
  plot.setData([h.map((p) => p.t), h.map((p) => p.beta), h.map((p) => p.pLow)]);
  state.plotDirty = false;
}

const fmt = (v, digits = 3) => (Number.isFinite(v) ? v.toFixed(digits) : String(v));

function showPanel() {
  if (state.plotDirty) updatePlot();
  const agent = state.agents.get(state.selected);
  const s = state.stats;
  const draws = [...s.drawMs].sort((x, y) => x - y);
  const p50 = draws.length ? draws[Math.floor(draws.length / 2)] : NaN;
  el("status").textContent = state.connected
    ? `live · ${state.agents.size} agents${state.truncated ? ` (of ${state.truncated})` : ""}`
    : `disconnected${state.error ? `: ${state.error}` : ""}`;
  el("stats").textContent =
    `polls ${s.polls} · contour fetches ${s.fetches} (errors ${s.fetchErrors}) · ` +
    `versions behind ${s.lag} · frame draw p50 ${fmt(p50, 2)} ms`;
  if (!agent) return;
  const info = agent.info;
  el("sel-title").textContent = agent.id;
  const facts = {
    class: agent.cls,
    "x, y [m]": `${fmt(info.state.x, 2)}, ${fmt(info.state.y, 2)}`,
    "heading, speed": `${fmt(info.state.heading, 3)} rad, ${fmt(info.state.speed, 2)} m/s`,
    time: `${fmt(info.timestamp, 2)} s`,
    β: fmt(info.beta),
    "P(β_low), P(β_high)": `${fmt(info.belief.beta_low)}, ${fmt(info.belief.beta_high)}`,
    "FRT version": `${info.frt_version} (drawn ${agent.drawnVersion})`,
    "exact set": info.frt_ready ? "ready" : "computing",
    "drawn set": agent.conservative ? "conservative (contains the exact one)" : "exact",
    map: info.map_id || "none",
    "cut by": agent.assumptions.length ? agent.assumptions.join(", ") : "nothing",
  };
  el("sel-facts").replaceChildren(
    ...Object.entries(facts).flatMap(([k, v]) => {
      const dt = document.createElement("dt");
      const dd = document.createElement("dd");
      dt.textContent = k;
      dd.textContent = v;
      if (k === "drawn set" && agent.conservative) dd.className = "conservative";
      return [dt, dd];
    }),
  );
  const b = info.control_bounds;
  const row = (name, dim, unit) => {
    const tr = document.createElement("tr");
    const cells = [`${name} [${unit}]`, b[`${dim}_min_start`], b[`${dim}_max_start`],
      b[`${dim}_min_end`], b[`${dim}_max_end`]];
    for (const [i, v] of cells.entries()) {
      const td = document.createElement(i ? "td" : "th");
      td.textContent = i ? fmt(v, 3) : v;
      tr.append(td);
    }
    return tr;
  };
  const head = document.createElement("tr");
  for (const text of ["control bounds", "min start", "max start", "min end", "max end"]) {
    const th = document.createElement("th");
    th.textContent = text;
    head.append(th);
  }
  el("bounds").replaceChildren(head, row("steering", "u1", "rad/s"), row("accel.", "u2", "m/s²"));
}

function showLegend() {
  const parts = state.options.colour === "class"
    ? Object.entries(STYLE.classColours).map(([k, c]) => [k, c])
    : [0.03, 0.25, 0.5, 0.75, 1].map((b) => [`β ${b}`, betaColour(b)]);
  el("legend").replaceChildren(
    ...parts.flatMap(([label, colour]) => {
      const sw = document.createElement("span");
      sw.className = "swatch";
      sw.style.background = colour;
      return [sw, document.createTextNode(label)];
    }),
    document.createTextNode(
      " · light: C = K ⊕ R_col, mid: K, dark: slice K, dashed/≈: conservative" +
      " · planner paths: green clear, red in C · grey: the map's road and lanes" +
      " · dotted: C before the map's cut",
    ),
  );
}

function showSliceLabel() {
  const t = state.slices[state.options.sliceIndex];
  el("slice-out").textContent = t === undefined ? "" : `t = ${fmt(t, 2)} s`;
}

function select(id) {
  state.selected = id;
  document.querySelector("#selected .hint").hidden = Boolean(id);
  state.plotDirty = true;
  state.dirty = true;
  if (!id) {
    el("sel-title").textContent = "no agent selected";
    el("sel-facts").replaceChildren();
    el("bounds").replaceChildren();
  }
}

function pick(event) {
  const [mx, my] = d3.pointer(event, canvas);
  let best = null;
  let bestD = 20; // pixels
  for (const agent of state.agents.values()) {
    const [sx, sy] = toScreen(agent.info.state.x, agent.info.state.y);
    const d = Math.hypot(sx - mx, sy - my);
    if (d < bestD) [best, bestD] = [agent.id, d];
  }
  if (best) select(best);
}

// ------------------------------------------------------------------------------ set-up

function setOptions(options) {
  Object.assign(state.options, options);
  el("colour").value = state.options.colour;
  el("show-tube").checked = state.options.showTube;
  el("show-slice").checked = state.options.showSlice;
  el("show-checks").checked = state.options.showChecks;
  el("show-map").checked = state.options.showMap;
  el("show-uncut").checked = state.options.showUncut;
  el("slice").value = String(state.options.sliceIndex + 1);
  showSliceLabel();
  showLegend();
  state.dirty = true;
  pumpFetches(); // a new slice time: every agent's slice is fetched again
  pumpMaps();
}

el("slice").addEventListener("input", (e) => setOptions({ sliceIndex: +e.target.value - 1 }));
el("colour").addEventListener("change", (e) => setOptions({ colour: e.target.value }));
el("show-tube").addEventListener("change", (e) => setOptions({ showTube: e.target.checked }));
el("show-slice").addEventListener("change", (e) => setOptions({ showSlice: e.target.checked }));
el("show-checks").addEventListener("change", (e) => setOptions({ showChecks: e.target.checked }));
el("show-map").addEventListener("change", (e) => setOptions({ showMap: e.target.checked }));
el("show-uncut").addEventListener("change", (e) => setOptions({ showUncut: e.target.checked }));
el("fit").addEventListener("click", fitView);
canvas.addEventListener("click", pick);
d3.select(canvas).call(
  d3.zoom().scaleExtent([0.05, 200]).on("zoom", (event) => {
    state.zoom = event.transform;
    if (event.sourceEvent) state.view.follow = false; // the user took over
    state.dirty = true;
    pumpMaps();
  }),
);
new ResizeObserver(resize).observe(canvas);

const percentile = (values, q) => {
  const sorted = [...values].sort((x, y) => x - y);
  return sorted.length ? sorted[Math.min(sorted.length - 1, Math.floor(q * sorted.length))] : null;
};

// The page's state for tests and for the console: plain JSON from snapshot(), a few setters.
const api = {
  style: STYLE,
  snapshot() {
    const agents = {};
    for (const a of state.agents.values()) {
      agents[a.id] = {
        version: a.version, contoursVersion: a.contoursVersion, drawnVersion: a.drawnVersion,
        contoursSlice: a.contoursSlice ?? null,
        conservative: a.conservative, cls: a.cls, colour: d3.color(agentColour(a)).formatHex(),
        state: a.info.state, beta: a.info.beta, history: a.history.length,
        timestamp: a.info.timestamp, mapId: a.info.map_id ?? null,
        assumptions: a.assumptions, uncut: Boolean(a.uncutPaths),
      };
    }
    const s = state.stats;
    const maps = {};
    for (const m of state.maps.values()) {
      maps[m.id] = {
        extent: m.extent, box: m.box, features: m.features, vertices: m.vertices,
        simplify: m.simplify, drawable: Boolean(m.paths), fetching: m.fetching, error: m.error,
      };
    }
    return {
      maps, mapsDrawn: state.mapsDrawn || 0,
      connected: state.connected, error: state.error, agents, selected: state.selected,
      checks: state.checks.map((c) => ({
        points: c.trajectory.length, collision: c.collision, conservative: c.conservative,
        age_s: c.age_s,
      })),
      slices: state.slices, options: { ...state.options }, view: { ...state.view },
      zoom: { k: state.zoom.k, x: state.zoom.x, y: state.zoom.y },
      size: [state.width, state.height],
      plot: plot ? { points: plot.data[0].length, beta: plot.data[1].slice(-1)[0] ?? null } : null,
      stats: {
        polls: s.polls, fetches: s.fetches, fetchErrors: s.fetchErrors, frames: s.frames,
        lag: s.lag, maxLag: s.maxLag, worstAgentLag: s.worstAgentLag,
        maxWorstAgentLag: s.maxWorstAgentLag,
        drawMsP50: percentile(s.drawMs, 0.5), drawMsP95: percentile(s.drawMs, 0.95),
        drawMsMax: s.drawMs.length ? Math.max(...s.drawMs) : null,
        frameIntervalMsP50: percentile(s.frameIntervalMs, 0.5),
        frameIntervalMsP95: percentile(s.frameIntervalMs, 0.95),
        pollMsP50: percentile(s.pollMs, 0.5), drawSamples: s.drawMs.length,
        mapFetches: s.mapFetches, mapFetchErrors: s.mapFetchErrors,
      },
    };
  },
  resetStats() {
    Object.assign(state.stats, {
      drawMs: [], frameIntervalMs: [], pollMs: [], maxLag: 0, maxWorstAgentLag: 0,
    });
  },
  setView(cx, cy, s) {
    state.view = { cx, cy, s, follow: false };
    state.zoom = d3.zoomIdentity;
    d3.select(canvas).property("__zoom", d3.zoomIdentity);
    state.dirty = true;
    pumpMaps();
  },
  fit: fitView,
  toScreen,
  select,
  setOptions,
};
window.frtViewer = api;

makePlot();
showLegend();
requestAnimationFrame(frame);
loadModel().then(connect);
