// The side panels and the top bar: control state and buttons, robot health, the selected
// robot, the task table. Each `render*` is cheap to call a few times a second; the task
// table is rebuilt only when a task changed.

import { HEALTHS, STATES, STATE_COLORS, TASK_STATES, OPEN_TASK_STATES } from "./fleet.js";

const $ = (id) => document.getElementById(id);
const MAX_TASK_ROWS = 200;
const MAX_ROBOT_ROWS = 8;

export function el(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") e.className = v;
    else if (k === "text") e.textContent = v;
    else if (k.startsWith("data-")) e.setAttribute(k, v);
    else e[k] = v;
  }
  for (const c of children) if (c != null) e.append(c);
  return e;
}

export function fmtTime(t) {
  if (t == null) return "-";
  const s = Math.floor(t);
  const h = Math.floor(s / 3600);
  const m = Math.floor((s % 3600) / 60);
  const sec = s % 60;
  const pad = (v) => String(v).padStart(2, "0");
  return h ? `${h}:${pad(m)}:${pad(sec)}` : `${pad(m)}:${pad(sec)}`;
}

function clock(iso) {
  if (!iso) return "";
  const d = new Date(iso);
  return Number.isNaN(d.getTime()) ? iso : d.toISOString().slice(11, 19) + " UTC";
}

function batteryColor(b) {
  return b > 0.5 ? "#3fbf6f" : b > 0.2 ? "#f2b33d" : "#ef5350";
}

/** The control badge, the note under the bar and which buttons make sense now. */
export function renderControl(ctl) {
  const state = ctl ? ctl.state : "unknown";
  document.body.dataset.control = state;
  const badge = $("control-badge");
  badge.dataset.state = state;
  badge.textContent = { running: "running", paused: "paused", estop: "e-stop latched" }[state] || state;
  $("btn-pause").disabled = state !== "running";
  $("btn-resume").disabled = state !== "paused";
  $("btn-estop").disabled = state === "estop" || state === "unknown";
  $("btn-release").disabled = state !== "estop";
  const note = $("control-note");
  if (ctl && ctl.action) {
    const what = { pause: "Paused", resume: "Resumed", estop: "E-stop latched", release: "E-stop released" }[ctl.action] || ctl.action;
    const when = ctl.at ? ` at ${clock(ctl.at)}` : "";
    const extra = state === "paused" && ctl.action === "release" ? " - robots stay paused until Resume" : "";
    note.textContent = `${what} by ${ctl.by || "?"}${when} (fleet time ${fmtTime(ctl.t)})${ctl.reason ? ": " + ctl.reason : ""}${extra}`;
    note.hidden = false;
  } else {
    note.hidden = true;
  }
}

/** Health chips and the robots table: dead, stuck and silent robots first, then the
 * emptiest batteries; at most MAX_ROBOT_ROWS rows. */
let lastRobotsKey = "";
export function renderHealth(robots, counts, selected) {
  $("health").replaceChildren(
    ...HEALTHS.map((h) =>
      el("span", { class: `chip ${h}${counts.byHealth[h] ? "" : " zero"}`, "data-health": h, title: healthHelp[h] },
        el("b", { text: String(counts.byHealth[h]) }), h),
    ),
  );
  const order = Array.from({ length: robots.n }, (_, i) => i);
  const severity = [0, 2, 1, 3]; // alive, silent, stuck, dead
  order.sort((a, b) => severity[robots.health[b]] - severity[robots.health[a]] || robots.battery[a] - robots.battery[b]);
  const shown = order.slice(0, MAX_ROBOT_ROWS);
  const key = JSON.stringify([selected, ...shown.map((i) => {
    const r = robots.records[i];
    return [r.name, r.state, r.health, Math.round(r.battery * 100), r.task];
  })]);
  if (key === lastRobotsKey) return;
  lastRobotsKey = key;
  const rows = shown.map((i) => {
    const r = robots.records[i];
    const tr = el("tr", { "data-robot": r.name, "data-state": r.state, "data-health": r.health },
      el("td", { text: r.name }),
      el("td", {}, el("span", { class: "dot", style: `background:${STATE_COLORS[r.state] || STATE_COLORS.other}` }), r.state),
      el("td", { text: r.health, style: `color:${healthColor[r.health]}` }),
      el("td", {}, batteryBar(r.battery), `${Math.round(r.battery * 100)}%`),
      el("td", { text: r.task || "" }));
    if (i === selected) tr.classList.add("selected");
    return tr;
  });
  $("robots").tBodies[0].replaceChildren(...rows);
  $("robots-more").textContent = robots.n > MAX_ROBOT_ROWS ? `${robots.n - MAX_ROBOT_ROWS} more robots: click them on the map` : "";
}

function batteryBar(b) {
  return el("span", { class: "battery" }, el("i", { style: `width:${Math.round(Math.max(0, Math.min(1, b)) * 100)}%;background:${batteryColor(b)}` }));
}

const healthHelp = {
  alive: "reporting its status",
  silent: "no status for more than a second, not yet declared dead",
  stuck: "driving but not moving",
  dead: "its liveliness token is gone or it was silent too long",
};
const healthColor = { alive: "#3fbf6f", silent: "#b0bec5", stuck: "#f2b33d", dead: "#ef5350" };

export function renderLegend(counts) {
  const items = STATES.filter((s) => s !== "other" || counts.byState.other).map((s) =>
    el("span", {}, el("i", { style: `background:${STATE_COLORS[s]}` }), s, el("span", { class: "count", text: String(counts.byState[s]) })),
  );
  items.push(el("span", {}, el("i", { class: "ring", style: "border-color:#ff9f43" }), "stuck"));
  items.push(el("span", {}, el("i", { class: "sq", style: "background:#2e9d57" }), "charger"));
  items.push(el("span", {}, el("i", { class: "sq", style: "background:#8e6bd8;transform:rotate(45deg) scale(0.8)" }), "station"));
  $("legend").replaceChildren(...items);
}

/** The selected robot's details (hidden when none is selected). */
export function renderSelected(robots, i) {
  const panel = $("robot-panel");
  if (i < 0) {
    panel.hidden = true;
    return;
  }
  const r = robots.records[i];
  panel.hidden = false;
  panel.dataset.robot = r.name;
  $("sel-name").textContent = r.name;
  const pose = r.pose ? `${r.pose.x.toFixed(2)}, ${r.pose.y.toFixed(2)}  ${((r.pose.theta * 180) / Math.PI).toFixed(0)}\u00b0` : "-";
  const bat = el("span", {}, batteryBar(r.battery), `${(r.battery * 100).toFixed(0)} %${r.charging ? " charging" : ""}`);
  const rows = [
    ["state", el("span", {}, el("i", { class: "dot", style: `background:${STATE_COLORS[r.state] || STATE_COLORS.other}` }), r.state)],
    ["health", r.health],
    ["battery", bat],
    ["pose (map)", pose],
    ["task", r.task || "-"],
    ["leaf", r.leaf || "-"],
    ["laps", String(r.laps)],
    ["distance", `${r.distance_m.toFixed(1)} m`],
    ["status at", fmtTime(r.t)],
  ];
  $("sel-details").replaceChildren(...rows.flatMap(([k, v]) => [el("dt", { text: k }), el("dd", {}, v)]));
}

function what(t) {
  const s = t.spec || {};
  if (t.kind === "go_to") return `\u2192 ${fmtTarget(s.target)}`;
  if (t.kind === "pick") return `${fmtTarget(s.pickup)} \u2192 ${fmtTarget(s.dropoff)}`;
  if (t.kind === "patrol") return s.route ? s.route : (s.waypoints || []).map(fmtTarget).join(" ");
  if (t.kind === "inspection") return `${(s.waypoints || []).length} stops`;
  return t.name || "";
}

function fmtTarget(v) {
  if (v == null) return "?";
  if (typeof v === "string") return v;
  if (Array.isArray(v)) return `(${v.map((c) => Number(c).toFixed(1)).join(", ")})`;
  if (typeof v === "object" && "target" in v) return fmtTarget(v.target);
  if (typeof v === "object") return `(${Number(v.x).toFixed(1)}, ${Number(v.y).toFixed(1)})`;
  return String(v);
}

function progress(t) {
  if (t.kind === "patrol") {
    const laps = t.spec && t.spec.laps;
    return laps ? `${t.laps}/${laps} laps` : `${t.laps} laps`;
  }
  if (t.steps_total) return `${t.steps_done}/${t.steps_total}`;
  return "";
}

const taskRows = new Map(); // task id -> its <tr>, kept while shown so clicks never hit a stale row
let lastOrder = "";

/** Set a row's cells from the task, touching only what changed. */
function fillTaskRow(tr, t) {
  if (!tr.cells.length) {
    for (let k = 0; k < 6; k++) tr.append(document.createElement("td"));
    tr.cells[0].className = "id";
    tr.cells[0].textContent = t.id;
    tr.cells[1].append(el("span", { class: "kindtag", text: t.kind }), what(t));
    tr.cells[1].title = `${t.kind} ${what(t)}`;
    tr.cells[2].append(el("span", {}));
    tr.dataset.taskId = t.id;
  }
  const set = (node, prop, v) => {
    if (node[prop] !== v) node[prop] = v;
  };
  if (tr.dataset.state !== t.state) tr.dataset.state = t.state;
  set(tr, "title", t.message || t.name || "");
  const badge = tr.cells[2].firstChild;
  set(badge, "className", `badge state ${t.state}`);
  set(badge, "textContent", t.state);
  set(tr.cells[3], "textContent", t.robot || "");
  set(tr.cells[4], "textContent", progress(t));
  const open = OPEN_TASK_STATES.has(t.state);
  const button = tr.cells[5].firstChild;
  if (open && !button) tr.cells[5].append(el("button", { title: `cancel ${t.id}`, text: "\u00d7", "data-cancel": t.id }));
  if (!open && button) button.remove();
}

/** The task counts and table (newest first, at most MAX_TASK_ROWS rows). */
export function renderTasks(tasks, filter) {
  const counts = tasks.counts();
  $("task-counts").replaceChildren(
    ...TASK_STATES.map((s) => el("span", { class: `chip${counts[s] ? "" : " zero"}`, "data-state": s },
      el("b", { text: String(counts[s]) }), s)),
  );
  const list = tasks.list(filter);
  const shown = list.slice(0, MAX_TASK_ROWS);
  tasks.dirty = false;
  const keep = new Set();
  const rows = shown.map((t) => {
    let tr = taskRows.get(t.id);
    if (!tr) {
      tr = document.createElement("tr");
      taskRows.set(t.id, tr);
      if (tasks.fresh.has(t.id)) tr.classList.add("fresh");
    }
    fillTaskRow(tr, t);
    keep.add(t.id);
    return tr;
  });
  for (const id of taskRows.keys()) if (!keep.has(id)) taskRows.delete(id);
  tasks.fresh.clear();
  const order = shown.map((t) => t.id).join(",");
  if (order !== lastOrder) {
    lastOrder = order;
    $("tasks").tBodies[0].replaceChildren(...rows);
  }
  $("tasks-more").textContent = list.length > MAX_TASK_ROWS ? `${list.length - MAX_TASK_ROWS} older tasks not shown` : "";
}
