// The task form: a patrol, go_to or pick posted to /api/tasks as the API's JSON
// (docs/service.md). Target fields take a station or roadmap node name, or "x, y" in the map
// frame; while one has the focus, a click on the map fills in the nearest station or node.
// A 4xx answer names the field: the form marks that input and shows the reason.

const TARGET_FIELDS = new Set(["target", "pickup", "dropoff", "waypoints"]);
const POSE = /^\s*\(?\s*(-?\d+(?:\.\d+)?)\s*[, ]\s*(-?\d+(?:\.\d+)?)\s*\)?\s*$/;

function target(text) {
  const m = POSE.exec(text);
  return m ? [Number(m[1]), Number(m[2])] : text.trim();
}

export class TaskForm {
  constructor(form, post, onSubmitted) {
    this.form = form;
    this.post = post;
    this.onSubmitted = onSubmitted;
    this.site = null;
    this.focused = null;
    this.lastId = "";
    this.result = form.querySelector("#task-result");
    this.kind = form.querySelector("#f-kind");
    this.kind.addEventListener("change", () => this.showKind());
    form.addEventListener("submit", (e) => {
      e.preventDefault();
      this.submit();
    });
    for (const input of form.querySelectorAll("input")) {
      input.addEventListener("input", () => input.classList.remove("invalid"));
      if (!TARGET_FIELDS.has(input.name)) continue;
      input.addEventListener("focus", () => this.setPicking(input));
    }
    // picking lasts until something other than the map or a target field is pressed
    document.addEventListener("mousedown", (e) => {
      if (e.target.id === "map" || (e.target.name && TARGET_FIELDS.has(e.target.name))) return;
      this.setPicking(null);
    });
    this.showKind();
  }

  setSite(site) {
    this.site = site;
    const opt = (v) => Object.assign(document.createElement("option"), { value: v });
    const stations = site.stations.map((s) => s.name);
    const nodes = site.roadmap.nodes.map((n) => n.name);
    this.form.querySelector("#dl-stations").replaceChildren(...stations.map(opt));
    this.form.querySelector("#dl-targets").replaceChildren(...[...stations, ...nodes].map(opt));
    const route = this.form.querySelector("#f-route");
    route.replaceChildren(
      Object.assign(document.createElement("option"), { value: "", textContent: "waypoints below" }),
      ...site.routes.map((r) => Object.assign(document.createElement("option"), { value: r.name, textContent: r.name })),
    );
    if (site.routes.length) route.value = site.routes[0].name;
  }

  /** Fill the robot choice once the robots are known. */
  setRobots(names) {
    const sel = this.form.querySelector("#f-robot");
    if (sel.options.length - 1 === names.length) return;
    const keep = sel.value;
    sel.replaceChildren(
      Object.assign(document.createElement("option"), { value: "", textContent: "any" }),
      ...names.map((n) => Object.assign(document.createElement("option"), { value: n, textContent: n })),
    );
    sel.value = keep;
  }

  showKind() {
    const kind = this.kind.value;
    for (const row of this.form.querySelectorAll(".row.kind")) row.hidden = !row.classList.contains(kind);
  }

  picking() {
    return this.focused !== null;
  }

  setPicking(input) {
    this.focused = input;
    document.body.classList.toggle("picking", input !== null);
    const hint = document.getElementById("pick-hint");
    hint.hidden = input === null;
    if (input) document.getElementById("pick-field").textContent = input.name;
  }

  /** The nearest station (within 1.5 m) or else roadmap node to (x, y), into the focused field. */
  pickAt(x, y) {
    if (!this.focused || !this.site) return;
    let best = null;
    let bestD = Infinity;
    const stationsOnly = this.focused.name === "pickup" || this.focused.name === "dropoff";
    for (const s of this.site.stations) {
      const d = Math.hypot(s.x - x, s.y - y);
      if (d < bestD) [best, bestD] = [s.name, d];
    }
    if (!stationsOnly && bestD > 1.5) {
      for (const n of this.site.roadmap.nodes) {
        const d = Math.hypot(n.x - x, n.y - y);
        if (d < bestD) [best, bestD] = [n.name, d];
      }
    }
    if (best === null) return;
    const input = this.focused;
    if (input.name === "waypoints") {
      input.value = input.value.trim() ? `${input.value.replace(/[,\s]+$/, "")}, ${best}` : best;
      this.form.querySelector("#f-route").value = "";
    } else {
      input.value = best;
    }
    input.classList.remove("invalid");
    input.focus();
  }

  body() {
    const f = this.form.elements;
    const kind = this.kind.value;
    const b = { kind };
    if (kind === "go_to") b.target = target(f.target.value);
    if (kind === "pick") {
      b.pickup = target(f.pickup.value);
      b.dropoff = target(f.dropoff.value);
      if (f.dwell_s.value !== "") b.dwell_s = Number(f.dwell_s.value);
    }
    if (kind === "patrol") {
      if (f.route.value) b.route = f.route.value;
      else b.waypoints = f.waypoints.value.split(/[,;]+/).map((w) => w.trim()).filter(Boolean);
      if (f.laps.value !== "") b.laps = Number(f.laps.value);
    }
    if (f.priority.value !== "" && Number(f.priority.value) !== 0) b.priority = Number(f.priority.value);
    if (f.robot.value) b.robot = f.robot.value;
    if (f.name.value.trim()) b.name = f.name.value.trim();
    return b;
  }

  async submit() {
    for (const i of this.form.querySelectorAll(".invalid")) i.classList.remove("invalid");
    const button = this.form.querySelector("#f-submit");
    button.disabled = true;
    let res;
    try {
      res = await this.post("/api/tasks", this.body());
    } catch (e) {
      this.show("err", `not submitted: ${e.message}`);
      return;
    } finally {
      button.disabled = false;
    }
    if (res.ok) {
      this.lastId = res.data.id;
      this.result.dataset.taskId = res.data.id;
      this.onSubmitted(res.data);
      this.onTask(res.data);
      return;
    }
    const err = res.data || {};
    const field = String(err.field || "");
    const name = field.split(/[.[]/)[0];
    const input = name ? this.form.elements[name] : null;
    if (input && input.classList) input.classList.add("invalid");
    this.show("err", `${field ? field + ": " : ""}${err.error || "HTTP " + res.status}`);
  }

  /** Follow the last submitted task's state in the result line. */
  onTask(task) {
    if (!task || task.id !== this.lastId) return;
    this.result.dataset.state = task.state;
    const who = task.robot ? ` (${task.robot})` : "";
    this.show(task.state === "failed" ? "err" : "ok", `${task.id} ${task.kind}: ${task.state}${who}${task.message ? " - " + task.message : ""}`);
  }

  show(cls, text) {
    this.result.className = `result ${cls}`;
    this.result.textContent = text;
  }
}
