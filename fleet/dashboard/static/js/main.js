// The dashboard's entry: load the site, follow /api/ws, draw on every animation frame, and
// wire the buttons, the map's mouse and the task form. `window.fleetDashboard` exposes what
// the browser tests and the bench read (counts, drawn markers, timing figures).

import { Robots, Samples, Tasks } from "./fleet.js";
import { MapView, tintMap } from "./mapview.js";
import { renderControl, renderHealth, renderLegend, renderSelected, renderTasks, fmtTime } from "./panels.js";
import { TaskForm } from "./taskform.js";

const $ = (id) => document.getElementById(id);
const USER = "dashboard";
const PANEL_MS = 250;

const robots = new Robots();
const tasks = new Tasks();
const view = new MapView($("map"), robots);
const wsMs = new Samples(600);
const robotsMs = new Samples(600);
const wsBytes = new Samples(600);
let control = null;
let site = null;
let fleetName = "";
let messages = 0;
let robotMessages = 0;
let rateWindow = [];
let socket = null;
let retryMs = 500;
let taskFilter = "all";
let statsSince = performance.now();
let robotMessagesSince = 0;

// --- the site -----------------------------------------------------------------------------
async function getJson(path) {
  const r = await fetch(path);
  if (!r.ok) throw new Error(`${path}: HTTP ${r.status}`);
  return r.json();
}

async function loadSite() {
  const [map, roadmap, chargers, stations, routes, fleet] = await Promise.all([
    getJson("/api/map"),
    getJson("/api/roadmap"),
    getJson("/api/chargers"),
    getJson("/api/stations"),
    getJson("/api/routes").catch(() => []),
    getJson("/api/fleet").catch(() => null),
  ]);
  if (fleet && !fleet.traffic) $("traffic-state").textContent = "off";
  const image = await new Promise((resolve) => {
    const img = new Image();
    img.onload = () => resolve(tintMap(img));
    img.onerror = () => resolve(null);
    img.src = map.image || "/api/map.png";
  });
  const nodes = new Map(roadmap.nodes.map((n) => [n.name, n]));
  site = { map, roadmap, nodes, chargers, stations, routes, image };
  fleetName = map.name;
  $("fleet-name").textContent = map.name;
  document.title = `${map.name} - fleet dashboard`;
  view.setSite(site);
  form.setSite(site);
}

// --- the WebSocket -------------------------------------------------------------------------
function connect() {
  const proto = location.protocol === "https:" ? "wss" : "ws";
  socket = new WebSocket(`${proto}://${location.host}/api/ws`);
  document.body.dataset.ws = "connecting";
  $("conn").textContent = "connecting";
  socket.onopen = () => {
    retryMs = 500;
    document.body.dataset.ws = "open";
    $("conn").textContent = "live";
  };
  socket.onmessage = (ev) => onMessage(ev.data);
  socket.onclose = () => {
    document.body.dataset.ws = "closed";
    $("conn").textContent = "disconnected: retrying";
    setTimeout(connect, retryMs);
    retryMs = Math.min(retryMs * 2, 5000);
  };
}

function onMessage(text) {
  const t0 = performance.now();
  let m;
  try {
    m = JSON.parse(text);
  } catch {
    return;
  }
  messages += 1;
  if (m.type === "robots") {
    const known = robots.n;
    robots.update(m.robots, m.t, t0);
    if (robots.n !== known) countRobots();
    robotMessages += 1;
    rateWindow.push(t0);
    const dt = performance.now() - t0;
    robotsMs.add(dt);
    wsMs.add(dt);
    wsBytes.add(text.length);
    return;
  }
  if (m.type === "hello") {
    // another fleet behind the same address (a restart with another config): start afresh
    if (fleetName && m.fleet && m.fleet !== fleetName) location.reload();
    tasks.reset(m.tasks || []);
    setControl(m.control);
  } else if (m.type === "task") {
    tasks.put(m.task);
    form.onTask(m.task);
  } else if (m.type === "fleet") {
    setControl(m.control);
  } else if (m.type === "traffic") {
    view.setTraffic(m);
    $("traffic-state").textContent = m.enabled ? `${m.segments.length} reserved` : "off";
  }
  wsMs.add(performance.now() - t0);
}

function setControl(ctl) {
  control = ctl;
  renderControl(ctl);
}

// --- commands ------------------------------------------------------------------------------
// A secured fleet (fleet run --secure DIR) takes its API token for every command: open the
// page as /#token=<contents of DIR/api.token>. The token is kept for this tab only
// (sessionStorage) and taken out of the address bar at once; the fragment never reaches a server.
const TOKEN_KEY = "fleet-api-token";
function takeToken() {
  const fromUrl = new URLSearchParams(location.hash.slice(1)).get("token");
  if (fromUrl) {
    sessionStorage.setItem(TOKEN_KEY, fromUrl.trim());
    history.replaceState(null, "", location.pathname + location.search);
  }
}
takeToken();
window.addEventListener("hashchange", takeToken);

async function post(path, body) {
  const headers = { "Content-Type": "application/json", "X-Fleet-User": USER };
  const token = sessionStorage.getItem(TOKEN_KEY);
  if (token) headers.Authorization = `Bearer ${token}`;
  const r = await fetch(path, { method: "POST", headers, body: JSON.stringify(body ?? {}) });
  let data = null;
  try {
    data = await r.json();
  } catch {
    data = null;
  }
  if (r.status === 401) {
    const why = data ? data.error : "HTTP 401";
    data = { error: `${why} — open this page as ${location.origin}/#token=<DIR/api.token>` };
  }
  return { ok: r.ok, status: r.status, data };
}

for (const b of document.querySelectorAll("#topbar .controls button")) {
  b.addEventListener("click", async () => {
    const action = b.dataset.action;
    const res = await post(`/api/fleet/${action}`, { by: USER });
    if (res.ok) setControl(res.data);
    else alertNote(`${action} refused: ${res.data ? res.data.error : "HTTP " + res.status}`);
  });
}

function alertNote(text) {
  const note = $("control-note");
  note.textContent = text;
  note.hidden = false;
}

async function cancelTask(id) {
  const res = await post(`/api/tasks/${encodeURIComponent(id)}/cancel`, {});
  if (res.ok) tasks.put(res.data);
  else alertNote(`cancel ${id} refused: ${res.data ? res.data.error : "HTTP " + res.status}`);
}

const form = new TaskForm($("task-form"), post, (task) => tasks.put(task));

// --- the map's mouse -----------------------------------------------------------------------
const canvas = $("map");
let drag = null;
canvas.addEventListener("wheel", (e) => {
  e.preventDefault();
  const r = canvas.getBoundingClientRect();
  view.zoomAt(e.clientX - r.left, e.clientY - r.top, Math.pow(1.0015, -e.deltaY));
}, { passive: false });
canvas.addEventListener("mousedown", (e) => {
  drag = { x: e.clientX, y: e.clientY, moved: 0 };
  canvas.classList.add("dragging");
});
window.addEventListener("mouseup", (e) => {
  canvas.classList.remove("dragging");
  if (drag && drag.moved < 4 && e.target === canvas) click(e);
  drag = null;
});
canvas.addEventListener("mousemove", (e) => {
  const r = canvas.getBoundingClientRect();
  const px = e.clientX - r.left;
  const py = e.clientY - r.top;
  if (drag) {
    const dx = e.clientX - drag.x;
    const dy = e.clientY - drag.y;
    drag.moved += Math.abs(dx) + Math.abs(dy);
    drag.x = e.clientX;
    drag.y = e.clientY;
    if (drag.moved >= 4) view.pan(dx, dy);
  }
  const i = view.robotAt(px, py);
  if (i !== view.hover) {
    view.hover = i;
    view.dirty = true;
  }
  tooltip(i, px, py);
});
canvas.addEventListener("mouseleave", () => {
  view.hover = -1;
  view.dirty = true;
  $("tooltip").hidden = true;
});
canvas.addEventListener("dblclick", () => {
  view.userView = false;
  view.fit();
});
$("btn-fit").addEventListener("click", () => {
  view.userView = false;
  view.fit();
});
$("opt-names").addEventListener("change", (e) => {
  view.showNames = e.target.checked;
  view.dirty = true;
});
$("opt-nodes").addEventListener("change", (e) => {
  view.showNodes = e.target.checked;
  view.bgDirty = true;
});
$("sel-close").addEventListener("click", () => select(-1));
// rows are rebuilt as robots and tasks change: listen on the tables, not the rows
$("robots").tBodies[0].addEventListener("mousedown", (e) => {
  const tr = e.target.closest("tr[data-robot]");
  if (tr) select(robots.index.get(tr.dataset.robot) ?? -1);
});
$("tasks").tBodies[0].addEventListener("click", (e) => {
  const b = e.target.closest("button[data-cancel]");
  if (b) cancelTask(b.dataset.cancel);
});
for (const radio of document.querySelectorAll('input[name="task-filter"]')) {
  radio.addEventListener("change", (e) => {
    taskFilter = e.target.value;
    tasks.dirty = true;
  });
}

function click(e) {
  const r = canvas.getBoundingClientRect();
  const px = e.clientX - r.left;
  const py = e.clientY - r.top;
  if (form.picking()) {
    const [x, y] = view.toWorld(px, py);
    form.pickAt(x, y);
    return;
  }
  select(view.robotAt(px, py));
}

function select(i) {
  view.selected = i;
  view.dirty = true;
  renderSelected(robots, i);
  renderHealth(robots, robots.counts(), i);
}

function tooltip(i, px, py) {
  const tip = $("tooltip");
  if (i < 0) {
    tip.hidden = true;
    return;
  }
  const r = robots.records[i];
  tip.textContent = `${r.name}  ${r.state}\nbattery ${(r.battery * 100).toFixed(0)} %  ${r.health}\n${r.task ? "task " + r.task : "no task"}`;
  tip.style.left = `${px + 14}px`;
  tip.style.top = `${py + 14}px`;
  tip.hidden = false;
}

// --- the loops -----------------------------------------------------------------------------
let markers = -1;
let lastRaf = 0;
const rafGap = new Samples(600);
function frame(now) {
  if (lastRaf > 0) rafGap.add(now - lastRaf);
  lastRaf = now;
  if (view.frame(now)) {
    canvas.dataset.frames = String(view.frames);
    if (view.drawn !== markers) {
      markers = view.drawn;
      canvas.dataset.markers = String(markers);
    }
  }
  requestAnimationFrame(frame);
}

let namesDefaulted = false;
/** The robot count in the top bar (`data-count`), as soon as a new robot appears. */
function countRobots() {
  const count = $("robot-count");
  if (count.dataset.count === String(robots.n)) return;
  count.dataset.count = String(robots.n);
  count.textContent = String(robots.n);
  form.setRobots(robots.names);
  if (!namesDefaulted && robots.n > 0) {
    namesDefaulted = true;
    view.showNames = robots.n <= 200;
    $("opt-names").checked = view.showNames;
  }
}

function panels() {
  const now = performance.now();
  rateWindow = rateWindow.filter((t) => now - t < 2000);
  $("ws-rate").textContent = rateWindow.length > 1 ? `${(rateWindow.length / 2).toFixed(1)} Hz` : "-";
  $("fleet-time").textContent = fmtTime(robots.t);
  const counts = robots.counts();
  renderHealth(robots, counts, view.selected);
  renderLegend(counts);
  if (view.selected >= 0) renderSelected(robots, view.selected);
  if (tasks.dirty) renderTasks(tasks, taskFilter);
}

new ResizeObserver(() => view.resize()).observe($("map-pane"));
view.resize();
renderControl(null);
window.fleetDashboard = {
  /** Robots known, robots drawn in the last frame, frames drawn. */
  counts: () => ({ robots: robots.n, markers: view.drawn, frames: view.frames, tasks: tasks.byId.size }),
  /** Every marker of the last frame: name, where it was drawn (map frame m) and on screen (CSS px). */
  markers: () =>
    Array.from({ length: view.drawn }, (_, j) => ({
      name: robots.names[view.order[j]],
      x: view.wx[j],
      y: view.wy[j],
      px: view.sx[j],
      py: view.sy[j],
      state: robots.records[view.order[j]].state,
    })),
  /** Timing figures (ms) of message handling and drawing, and the update rate. */
  stats: () => ({
    fleet: fleetName,
    robots: robots.n,
    messages,
    robotMessages,
    ws_ms: wsMs.summary(),
    robots_msg_ms: robotsMs.summary(),
    robots_msg_bytes: wsBytes.summary(),
    frame_ms: view.frameMs.summary(),
    frame_gap_ms: view.frameGap.summary(),
    raf_gap_ms: rafGap.summary(),
    update_period_ms: robots.period,
    since_ms: performance.now() - statsSince,
    robot_messages_since: robotMessages - robotMessagesSince,
  }),
  /** Forget the timing figures so far (the bench calls it after the page warmed up). */
  resetStats: () => {
    for (const sm of [wsMs, robotsMs, wsBytes, view.frameMs, view.frameGap, rafGap]) sm.reset();
    statsSince = performance.now();
    robotMessagesSince = robotMessages;
  },
  /** Measure frames with their rasterization (the bench): read a pixel back after each. */
  setFlush: (on) => {
    view.flush = Boolean(on);
  },
  /** Where a map point (m) is on the canvas (CSS px from its top-left corner). */
  toScreen: (x, y) => [view.ox + x * view.scale, view.oy - y * view.scale],
  control: () => control,
  select: (name) => select(robots.index.get(name) ?? -1),
};
requestAnimationFrame(frame);
setInterval(panels, PANEL_MS);
loadSite().catch((e) => alertNote(`cannot load the site: ${e.message}`));
connect();
