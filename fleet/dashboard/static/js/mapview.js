// The map on a <canvas>: a cached background (the map image, roadmap, chargers, stations)
// and, each animation frame, the reserved segments and every robot drawn in batches by
// colour (one path per colour, so 1000 robots cost a few dozen canvas calls, not thousands).
// World frame: `map`, meters, y up; the view maps it to CSS pixels (scale px/m, y down).

import { STATES, STATE_COLORS, Samples } from "./fleet.js";

const ROBOT_RADIUS_M = 0.3;
const MAP_DARK = [38, 47, 58];
const MAP_LIGHT = [236, 240, 244];

export function robotHue(name) {
  let h = 0;
  for (let i = 0; i < name.length; i++) h = (h * 31 + name.charCodeAt(i)) >>> 0;
  return (h * 137.508) % 360;
}

const MAX_LABELS = 400;

/** Screen rectangles of the labels drawn so far (a grid of 64 px cells): a label that
 * would overlap one is left out. */
class Labels {
  constructor() {
    this.cells = new Map();
    this.count = 0;
  }
  take(x, y, w, h) {
    const c0 = Math.floor(x / 64);
    const c1 = Math.floor((x + w) / 64);
    const r0 = Math.floor(y / 64);
    const r1 = Math.floor((y + h) / 64);
    for (let cx = c0; cx <= c1; cx++) {
      for (let cy = r0; cy <= r1; cy++) {
        for (const b of this.cells.get(cx * 100003 + cy) || []) {
          if (x < b[0] + b[2] && b[0] < x + w && y < b[1] + b[3] && b[1] < y + h) return false;
        }
      }
    }
    const box = [x, y, w, h];
    for (let cx = c0; cx <= c1; cx++) {
      for (let cy = r0; cy <= r1; cy++) {
        const k = cx * 100003 + cy;
        if (!this.cells.has(k)) this.cells.set(k, []);
        this.cells.get(k).push(box);
      }
    }
    this.count += 1;
    return true;
  }
}

export class MapView {
  constructor(canvas, robots) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d", { alpha: false });
    this.robots = robots;
    this.site = null; // {map, image, roadmap, chargers, stations}
    this.traffic = { enabled: false, segments: [], nodes: [] };
    this.bg = document.createElement("canvas");
    this.bgDirty = true;
    this.dirty = true;
    this.dpr = window.devicePixelRatio || 1;
    this.w = 0;
    this.h = 0;
    this.scale = 20;
    this.ox = 0;
    this.oy = 0;
    this.userView = false;
    this.showNames = false;
    this.showNodes = false;
    this.flush = false;
    this.selected = -1;
    this.hover = -1;
    this.frameMs = new Samples(600);
    this.frameGap = new Samples(600);
    this.frames = 0;
    this.lastFrame = 0;
    this.drawn = 0;
    this.drawnVersion = -1;
    this.sx = new Float32Array(0);
    this.sy = new Float32Array(0);
    this.wx = new Float32Array(0);
    this.wy = new Float32Array(0);
  }

  setSite(site) {
    this.site = site;
    this.bgDirty = true;
    if (!this.userView) this.fit();
  }

  setTraffic(traffic) {
    this.traffic = traffic;
    this.dirty = true;
  }

  resize() {
    const r = this.canvas.getBoundingClientRect();
    this.dpr = window.devicePixelRatio || 1;
    this.w = Math.max(1, r.width);
    this.h = Math.max(1, r.height);
    this.canvas.width = Math.round(this.w * this.dpr);
    this.canvas.height = Math.round(this.h * this.dpr);
    this.bg.width = this.canvas.width;
    this.bg.height = this.canvas.height;
    if (!this.userView) this.fit();
    this.bgDirty = true;
  }

  /** Show the whole map with a margin. */
  fit() {
    if (!this.site) return;
    const [xmin, xmax, ymin, ymax] = this.site.map.extent;
    const pad = 24;
    const s = Math.min((this.w - 2 * pad) / (xmax - xmin), (this.h - 2 * pad) / (ymax - ymin));
    this.scale = Math.max(s, 0.01);
    this.ox = (this.w - (xmax - xmin) * this.scale) / 2 - xmin * this.scale;
    this.oy = (this.h + (ymax - ymin) * this.scale) / 2 + ymin * this.scale;
    this.bgDirty = true;
  }

  zoomAt(px, py, factor) {
    const s = Math.min(Math.max(this.scale * factor, 0.05), 2000);
    const k = s / this.scale;
    this.ox = px - (px - this.ox) * k;
    this.oy = py - (py - this.oy) * k;
    this.scale = s;
    this.userView = true;
    this.bgDirty = true;
  }

  pan(dx, dy) {
    this.ox += dx;
    this.oy += dy;
    this.userView = true;
    this.bgDirty = true;
  }

  toWorld(px, py) {
    return [(px - this.ox) / this.scale, (this.oy - py) / this.scale];
  }

  /** The robot index under CSS pixel (px, py), or -1. */
  robotAt(px, py) {
    const r = this.robotPx() + 4;
    let best = -1;
    let bestD = r * r;
    for (let i = 0; i < this.drawn; i++) {
      const d = (this.sx[i] - px) ** 2 + (this.sy[i] - py) ** 2;
      if (d <= bestD) {
        bestD = d;
        best = this.order[i];
      }
    }
    return best;
  }

  robotPx() {
    return Math.max(4, ROBOT_RADIUS_M * this.scale);
  }

  // --- background -------------------------------------------------------------------
  drawBackground() {
    const c = this.bg.getContext("2d");
    c.setTransform(this.dpr, 0, 0, this.dpr, 0, 0);
    c.fillStyle = "#0b0f14";
    c.fillRect(0, 0, this.w, this.h);
    const site = this.site;
    if (!site) return;
    const m = site.map;
    const s = this.scale;
    if (site.image) {
      const [x0, , , y1] = m.extent;
      c.imageSmoothingEnabled = s / (1 / m.resolution) < 1;
      c.drawImage(site.image, this.ox + x0 * s, this.oy - y1 * s, m.width * m.resolution * s, m.height * m.resolution * s);
    }
    const P = (x, y) => [this.ox + x * s, this.oy - y * s];
    // roadmap
    const nodes = site.nodes;
    c.lineWidth = Math.max(1, Math.min(3, 0.06 * s));
    c.strokeStyle = "rgba(70, 110, 150, 0.55)";
    c.beginPath();
    for (const [a, b] of site.roadmap.edges) {
      const pa = nodes.get(a);
      const pb = nodes.get(b);
      if (!pa || !pb) continue;
      const [ax, ay] = P(pa.x, pa.y);
      const [bx, by] = P(pb.x, pb.y);
      c.moveTo(ax, ay);
      c.lineTo(bx, by);
    }
    c.stroke();
    const nr = Math.max(1.5, Math.min(4, 0.09 * s));
    c.fillStyle = "rgba(60, 100, 140, 0.85)";
    c.beginPath();
    for (const n of site.roadmap.nodes) {
      const [x, y] = P(n.x, n.y);
      c.moveTo(x + nr, y);
      c.arc(x, y, nr, 0, 2 * Math.PI);
    }
    c.fill();
    // stations: diamonds; chargers: green squares with a bolt
    const st = Math.max(3, Math.min(7, 0.18 * s));
    c.fillStyle = "#8e6bd8";
    c.beginPath();
    for (const p of site.stations) {
      const [x, y] = P(p.x, p.y);
      c.moveTo(x, y - st);
      c.lineTo(x + st, y);
      c.lineTo(x, y + st);
      c.lineTo(x - st, y);
      c.closePath();
    }
    c.fill();
    const ch = Math.max(5, Math.min(12, 0.35 * s));
    for (const p of site.chargers) {
      const [x, y] = P(p.x, p.y);
      c.fillStyle = "#2e9d57";
      c.fillRect(x - ch, y - ch, 2 * ch, 2 * ch);
      c.fillStyle = "#ffffff";
      c.beginPath();
      c.moveTo(x + 0.15 * ch, y - 0.8 * ch);
      c.lineTo(x - 0.45 * ch, y + 0.1 * ch);
      c.lineTo(x - 0.05 * ch, y + 0.1 * ch);
      c.lineTo(x - 0.15 * ch, y + 0.8 * ch);
      c.lineTo(x + 0.45 * ch, y - 0.1 * ch);
      c.lineTo(x + 0.05 * ch, y - 0.1 * ch);
      c.closePath();
      c.fill();
    }
    // labels where they fit
    c.textBaseline = "middle";
    if (s >= 18) {
      c.font = "11px DejaVu Sans, sans-serif";
      c.fillStyle = "#1e5631";
      for (const p of site.chargers) {
        const [x, y] = P(p.x, p.y);
        c.textAlign = "left";
        c.fillText(p.name, x + ch + 3, y);
      }
    }
    if (this.showNodes && s >= 12) {
      c.font = "10px DejaVu Sans, sans-serif";
      c.fillStyle = "#3a5f85";
      c.textAlign = "left";
      for (const n of site.roadmap.nodes) {
        const [x, y] = P(n.x, n.y);
        c.fillText(n.name, x + nr + 2, y - nr - 4);
      }
    }
  }

  // --- one frame ---------------------------------------------------------------------
  /** Draw if anything changed; returns whether it drew. */
  frame(now) {
    const robots = this.robots;
    const moving = robots.alpha(now) < 1;
    if (!this.dirty && !this.bgDirty && !moving && this.drawnVersion === robots.version) return false;
    const t0 = performance.now();
    if (this.bgDirty) {
      this.drawBackground();
      this.bgDirty = false;
    }
    const c = this.ctx;
    c.setTransform(1, 0, 0, 1, 0, 0);
    c.drawImage(this.bg, 0, 0);
    c.setTransform(this.dpr, 0, 0, this.dpr, 0, 0);
    this.drawTraffic(c);
    this.drawRobots(c, robots.alpha(now));
    // reading a pixel back makes the browser rasterize now, so the frame time includes it
    if (this.flush) c.getImageData(0, 0, 1, 1);
    this.dirty = false;
    this.drawnVersion = robots.version;
    const dt = performance.now() - t0;
    this.frameMs.add(dt);
    if (this.lastFrame > 0) this.frameGap.add(t0 - this.lastFrame);
    this.lastFrame = t0;
    this.frames += 1;
    return true;
  }

  drawTraffic(c) {
    const tr = this.traffic;
    if (!tr || !tr.enabled) return;
    const s = this.scale;
    const byRobot = new Map();
    for (const seg of tr.segments) {
      let list = byRobot.get(seg.robot);
      if (!list) byRobot.set(seg.robot, (list = { segs: [], nodes: [] }));
      list.segs.push(seg);
    }
    for (const n of tr.nodes) {
      let list = byRobot.get(n.robot);
      if (!list) byRobot.set(n.robot, (list = { segs: [], nodes: [] }));
      list.nodes.push(n);
    }
    c.lineCap = "round";
    c.lineWidth = Math.max(3, 0.45 * s);
    const nr = Math.max(3, 0.35 * s);
    for (const [robot, { segs, nodes }] of byRobot) {
      const col = `hsla(${robotHue(robot)}, 75%, 55%, 0.45)`;
      c.strokeStyle = col;
      c.beginPath();
      for (const seg of segs) {
        c.moveTo(this.ox + seg.a[0] * s, this.oy - seg.a[1] * s);
        c.lineTo(this.ox + seg.b[0] * s, this.oy - seg.b[1] * s);
      }
      c.stroke();
      c.fillStyle = col;
      c.beginPath();
      for (const n of nodes) {
        const x = this.ox + n.x * s;
        const y = this.oy - n.y * s;
        c.moveTo(x + nr, y);
        c.arc(x, y, nr, 0, 2 * Math.PI);
      }
      c.fill();
    }
    c.lineCap = "butt";
  }

  // long: one batched pass per layer (bodies by colour, headings, rings, batteries, labels)
  drawRobots(c, a) {
    const R = this.robots;
    const n = R.n;
    if (this.sx.length < n) {
      this.sx = new Float32Array(R.cap);
      this.sy = new Float32Array(R.cap);
      this.wx = new Float32Array(R.cap);
      this.wy = new Float32Array(R.cap);
      this.sth = new Float32Array(R.cap);
      this.order = new Int32Array(R.cap);
    }
    const s = this.scale;
    const r = this.robotPx();
    let m = 0;
    for (let i = 0; i < n; i++) {
      if (!R.hasPose[i]) continue;
      const x = R.x0[i] + (R.x1[i] - R.x0[i]) * a;
      const y = R.y0[i] + (R.y1[i] - R.y0[i]) * a;
      let d = R.th1[i] - R.th0[i];
      if (d > Math.PI) d -= 2 * Math.PI;
      else if (d < -Math.PI) d += 2 * Math.PI;
      this.wx[m] = x;
      this.wy[m] = y;
      this.sx[m] = this.ox + x * s;
      this.sy[m] = this.oy - y * s;
      this.sth[m] = R.th0[i] + d * a;
      this.order[m] = i;
      m++;
    }
    this.drawn = m;
    // bodies, one path per state colour
    c.lineWidth = 1;
    c.strokeStyle = "rgba(10, 14, 20, 0.85)";
    for (let k = 0; k < STATES.length; k++) {
      let any = false;
      c.beginPath();
      for (let j = 0; j < m; j++) {
        if (R.state[this.order[j]] !== k) continue;
        c.moveTo(this.sx[j] + r, this.sy[j]);
        c.arc(this.sx[j], this.sy[j], r, 0, 2 * Math.PI);
        any = true;
      }
      if (!any) continue;
      c.fillStyle = STATE_COLORS[STATES[k]];
      c.fill();
      if (r >= 3) c.stroke();
    }
    // headings: a white nose from the centre to the rim
    if (r >= 3.5) {
      c.strokeStyle = "#ffffff";
      c.lineWidth = Math.max(1.2, r * 0.28);
      c.lineCap = "round";
      c.beginPath();
      for (let j = 0; j < m; j++) {
        const th = this.sth[j];
        c.moveTo(this.sx[j] + Math.cos(th) * r * 0.15, this.sy[j] - Math.sin(th) * r * 0.15);
        c.lineTo(this.sx[j] + Math.cos(th) * r * 0.95, this.sy[j] - Math.sin(th) * r * 0.95);
      }
      c.stroke();
      c.lineCap = "butt";
    }
    // health rings: stuck (orange), silent (grey, dashed), dead (red cross)
    this.rings(c, m, 2, "#ff9f43", r + 3, []);
    this.rings(c, m, 1, "#b0bec5", r + 3, [3, 3]);
    this.crosses(c, m, 3, r);
    // batteries under the robot
    if (r >= 5) this.batteries(c, m, r);
    // selection and hover
    for (const [idx, col] of [
      [this.hover, "rgba(255,255,255,0.6)"],
      [this.selected, "#ffffff"],
    ]) {
      const j = idx >= 0 ? this.order.indexOf(idx) : -1;
      if (j < 0 || j >= m) continue;
      c.strokeStyle = col;
      c.lineWidth = 2;
      c.beginPath();
      c.arc(this.sx[j], this.sy[j], r + 6, 0, 2 * Math.PI);
      c.stroke();
    }
    // names
    if (this.showNames && r >= 4) {
      c.font = `${Math.round(Math.min(13, Math.max(10, r * 0.9)))}px DejaVu Sans, sans-serif`;
      c.textAlign = "center";
      c.textBaseline = "bottom";
      c.lineWidth = 3;
      c.strokeStyle = "rgba(236, 240, 244, 0.9)";
      c.fillStyle = "#16202b";
      const placed = new Labels();
      const lh = Math.round(Math.min(13, Math.max(10, r * 0.9)));
      for (let j = 0; j < m && placed.count < MAX_LABELS; j++) {
        const name = R.names[this.order[j]];
        const w = c.measureText(name).width;
        const x = this.sx[j];
        const y = this.sy[j] - r - 3;
        if (x < -w || x > this.w + w || y < 0 || y > this.h + lh) continue;
        if (!placed.take(x - w / 2 - 1, y - lh, w + 2, lh)) continue;
        c.strokeText(name, x, y);
        c.fillText(name, x, y);
      }
    } else if (this.selected >= 0) {
      const j = this.order.indexOf(this.selected);
      if (j >= 0 && j < m) {
        c.font = "12px DejaVu Sans, sans-serif";
        c.textAlign = "center";
        c.textBaseline = "bottom";
        c.fillStyle = "#16202b";
        c.fillText(R.names[this.selected], this.sx[j], this.sy[j] - r - 8);
      }
    }
  }

  rings(c, m, health, color, radius, dash) {
    const R = this.robots;
    let any = false;
    c.beginPath();
    for (let j = 0; j < m; j++) {
      if (R.health[this.order[j]] !== health) continue;
      c.moveTo(this.sx[j] + radius, this.sy[j]);
      c.arc(this.sx[j], this.sy[j], radius, 0, 2 * Math.PI);
      any = true;
    }
    if (!any) return;
    c.setLineDash(dash);
    c.strokeStyle = color;
    c.lineWidth = 2;
    c.stroke();
    c.setLineDash([]);
  }

  crosses(c, m, health, r) {
    const R = this.robots;
    const k = r * 0.6;
    let any = false;
    c.beginPath();
    for (let j = 0; j < m; j++) {
      if (R.health[this.order[j]] !== health) continue;
      const x = this.sx[j];
      const y = this.sy[j];
      c.moveTo(x - k, y - k);
      c.lineTo(x + k, y + k);
      c.moveTo(x + k, y - k);
      c.lineTo(x - k, y + k);
      any = true;
    }
    if (!any) return;
    c.strokeStyle = "#ef5350";
    c.lineWidth = 2;
    c.stroke();
  }

  batteries(c, m, r) {
    const R = this.robots;
    const w = 2 * r;
    const h = Math.max(2.5, r * 0.28);
    c.fillStyle = "rgba(20, 26, 34, 0.8)";
    c.beginPath();
    for (let j = 0; j < m; j++) c.rect(this.sx[j] - r - 1, this.sy[j] + r + 2, w + 2, h + 2);
    c.fill();
    const buckets = [
      [0.5, 2, "#3fbf6f"],
      [0.2, 0.5, "#f2b33d"],
      [-1, 0.2, "#ef5350"],
    ];
    for (const [lo, hi, col] of buckets) {
      c.beginPath();
      for (let j = 0; j < m; j++) {
        const b = R.battery[this.order[j]];
        if (b <= lo || b > hi) continue;
        c.rect(this.sx[j] - r, this.sy[j] + r + 3, w * Math.max(0, Math.min(1, b)), h);
      }
      c.fillStyle = col;
      c.fill();
    }
  }
}

/** The map image recoloured for the page (free light, occupied dark), as a canvas. */
export function tintMap(img) {
  const cv = document.createElement("canvas");
  cv.width = img.naturalWidth;
  cv.height = img.naturalHeight;
  const c = cv.getContext("2d");
  c.drawImage(img, 0, 0);
  const data = c.getImageData(0, 0, cv.width, cv.height);
  const d = data.data;
  const lut = new Uint8ClampedArray(256 * 3);
  for (let v = 0; v < 256; v++) {
    const f = v / 255;
    for (let k = 0; k < 3; k++) lut[v * 3 + k] = MAP_DARK[k] + (MAP_LIGHT[k] - MAP_DARK[k]) * f;
  }
  for (let i = 0; i < d.length; i += 4) {
    const v = d[i];
    d[i] = lut[v * 3];
    d[i + 1] = lut[v * 3 + 1];
    d[i + 2] = lut[v * 3 + 2];
    d[i + 3] = 255;
  }
  c.putImageData(data, 0, 0);
  return cv;
}
