// The fleet as the page knows it: robots in typed arrays (so drawing 1000 of them allocates
// nothing per frame), tasks by id, the control state, reserved roadmap segments, and the
// page's own timing figures (message handling and frame time, read by the bench and tests).

export const STATES = ["idle", "patrol", "picking", "task", "charging", "recovery", "paused", "estop", "dead", "other"];
export const STATE_COLORS = {
  idle: "#9aa5b1",
  patrol: "#4aa3ff",
  picking: "#b388ff",
  task: "#26c6da",
  charging: "#3fbf6f",
  recovery: "#ff9f43",
  paused: "#f2b33d",
  estop: "#ef5350",
  dead: "#4b535c",
  other: "#e0e0e0",
};
export const HEALTHS = ["alive", "silent", "stuck", "dead"];
export const TASK_STATES = ["queued", "assigned", "active", "completed", "failed", "canceled"];
export const OPEN_TASK_STATES = new Set(["queued", "assigned", "active"]);

const STATE_INDEX = new Map(STATES.map((s, i) => [s, i]));
const HEALTH_INDEX = new Map(HEALTHS.map((s, i) => [s, i]));

/** A ring of the latest `n` samples with percentiles. */
export class Samples {
  constructor(n = 600) {
    this.buf = new Float64Array(n);
    this.n = 0;
    this.i = 0;
    this.total = 0;
  }
  reset() {
    this.n = 0;
    this.i = 0;
    this.total = 0;
  }
  add(v) {
    this.buf[this.i] = v;
    this.i = (this.i + 1) % this.buf.length;
    this.n = Math.min(this.n + 1, this.buf.length);
    this.total += 1;
  }
  summary() {
    const a = Array.from(this.buf.subarray(0, this.n)).sort((x, y) => x - y);
    const q = (p) => (a.length ? a[Math.min(a.length - 1, Math.floor(p * a.length))] : null);
    const mean = a.length ? a.reduce((s, v) => s + v, 0) / a.length : null;
    return { count: this.total, n: a.length, mean, p50: q(0.5), p99: q(0.99), max: a.length ? a[a.length - 1] : null };
  }
}

/** Every robot's latest two states (for interpolation between updates), by index. */
export class Robots {
  constructor() {
    this.names = [];
    this.index = new Map();
    this.records = [];
    this.cap = 0;
    this.n = 0;
    this.grow(64);
    this.period = 100; // ms between updates, measured
    this.lastRecv = 0;
    this.t = null; // fleet time of the latest update (s)
    this.version = 0;
  }

  grow(cap) {
    const f = (old) => {
      const a = new Float32Array(cap);
      if (old) a.set(old);
      return a;
    };
    const u = (old) => {
      const a = new Uint8Array(cap);
      if (old) a.set(old);
      return a;
    };
    this.x0 = f(this.x0); this.y0 = f(this.y0); this.th0 = f(this.th0);
    this.x1 = f(this.x1); this.y1 = f(this.y1); this.th1 = f(this.th1);
    this.battery = f(this.battery);
    this.state = u(this.state);
    this.health = u(this.health);
    this.hasPose = u(this.hasPose);
    this.charging = u(this.charging);
    this.cap = cap;
  }

  /** Apply one `robots` message (a list of robot objects); `now`: performance.now(). */
  update(list, t, now) {
    if (this.lastRecv > 0) {
      const dt = now - this.lastRecv;
      if (dt > 5 && dt < 2000) this.period = this.period * 0.8 + dt * 0.2;
    }
    this.lastRecv = now;
    this.t = t;
    for (let k = 0; k < list.length; k++) {
      const r = list[k];
      let i = this.index.get(r.name);
      if (i === undefined) {
        i = this.n++;
        if (i >= this.cap) this.grow(this.cap * 2);
        this.index.set(r.name, i);
        this.names.push(r.name);
        this.records.push(r);
        this.hasPose[i] = 0;
      }
      this.records[i] = r;
      const p = r.pose;
      if (p) {
        if (this.hasPose[i]) {
          this.x0[i] = this.x1[i]; this.y0[i] = this.y1[i]; this.th0[i] = this.th1[i];
        } else {
          this.x0[i] = p.x; this.y0[i] = p.y; this.th0[i] = p.theta;
        }
        this.x1[i] = p.x; this.y1[i] = p.y; this.th1[i] = p.theta;
        this.hasPose[i] = 1;
      } else {
        this.hasPose[i] = 0;
      }
      this.battery[i] = r.battery;
      this.charging[i] = r.charging ? 1 : 0;
      const s = STATE_INDEX.get(r.state);
      this.state[i] = s === undefined ? STATE_INDEX.get("other") : s;
      this.health[i] = HEALTH_INDEX.get(r.health) ?? 0;
    }
    this.version += 1;
  }

  /** How far (0..1) drawing is between the previous and the latest update at `now`. */
  alpha(now) {
    const a = (now - this.lastRecv) / Math.max(this.period, 1);
    return a < 0 ? 0 : a > 1 ? 1 : a;
  }

  /** Counts by state name and by health name. */
  counts() {
    const byState = Object.fromEntries(STATES.map((s) => [s, 0]));
    const byHealth = Object.fromEntries(HEALTHS.map((s) => [s, 0]));
    for (let i = 0; i < this.n; i++) {
      byState[STATES[this.state[i]]] += 1;
      byHealth[HEALTHS[this.health[i]]] += 1;
    }
    return { byState, byHealth };
  }
}

/** The number in a task id such as `t-0042` (ids grow with time), else 0. */
export function idNumber(id) {
  const m = /(\d+)$/.exec(id);
  return m ? Number(m[1]) : 0;
}

/** Tasks by id, newest first when listed; `dirty` until the table is redrawn. */
export class Tasks {
  constructor() {
    this.byId = new Map();
    this.dirty = true;
    this.fresh = new Set();
  }
  reset(list) {
    this.byId.clear();
    for (const t of list) this.byId.set(t.id, t);
    this.dirty = true;
  }
  put(task) {
    if (!task) return;
    if (!this.byId.has(task.id)) this.fresh.add(task.id);
    this.byId.set(task.id, task);
    this.dirty = true;
  }
  list(filter) {
    const out = [];
    for (const t of this.byId.values()) {
      const open = OPEN_TASK_STATES.has(t.state);
      if (filter === "open" && !open) continue;
      if (filter === "done" && open) continue;
      out.push(t);
    }
    out.sort((a, b) => idNumber(b.id) - idNumber(a.id) || (a.id < b.id ? 1 : -1));
    return out;
  }
  counts() {
    const c = Object.fromEntries(TASK_STATES.map((s) => [s, 0]));
    for (const t of this.byId.values()) c[t.state] = (c[t.state] || 0) + 1;
    return c;
  }
}
