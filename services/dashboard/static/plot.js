// Small hand-written canvas plots: time series (linePlot) and a rotatable 3-D view of paths and frames (View3D).
// Units are whatever the caller gives (the dashboard: s, N, m); no library, so the page works offline.

const PAD = { left: 48, right: 10, top: 10, bottom: 24 };
const MAX_DRAWN = 2000;   // points drawn per line at most (every k-th, the last always): a frame stays a few ms

function strided(n) {
  // The indices drawn of n points: every k-th and the last.
  const step = Math.max(1, Math.ceil(n / MAX_DRAWN));
  const picked = [];
  for (let k = 0; k < n; k += step) picked.push(k);
  if (n && picked[picked.length - 1] !== n - 1) picked.push(n - 1);
  return picked;
}

function bounds(values, lo = Infinity, hi = -Infinity) {
  for (const v of values) if (v !== null && Number.isFinite(v)) { if (v < lo) lo = v; if (v > hi) hi = v; }
  return [lo, hi];
}

function sized(canvas, height) {
  // Draw at the device's pixel density so lines stay sharp.
  const ratio = window.devicePixelRatio || 1;
  const width = canvas.clientWidth || 600;
  canvas.style.height = `${height}px`;
  if (canvas.width !== Math.round(width * ratio) || canvas.height !== Math.round(height * ratio)) {
    canvas.width = Math.round(width * ratio);
    canvas.height = Math.round(height * ratio);
  }
  const ctx = canvas.getContext("2d");
  ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
  ctx.clearRect(0, 0, width, height);
  return { ctx, width, height };
}

function niceTicks(lo, hi, count) {
  const span = hi - lo || 1;
  const step = 10 ** Math.floor(Math.log10(span / count));
  const best = [1, 2, 5, 10].map((m) => m * step).find((s) => span / s <= count) || step * 10;
  const ticks = [];
  for (let v = Math.ceil(lo / best) * best; v <= hi + 1e-12; v += best) ticks.push(+v.toPrecision(10));
  return ticks;
}

// series: [{x: [...], y: [... | null], color, label, dash}], bands: [{x0, x1, color, y0?, y1?}] behind the lines
// (y0, y1: the band's bottom and top as fractions of the plot's height; the full height without them).
export function linePlot(canvas, series, { height = 220, xLabel = "", yLabel = "", bands = [] } = {}) {
  const { ctx, width } = sized(canvas, height);
  let [x0, x1] = [Infinity, -Infinity], [y0, y1] = [0, -Infinity];
  for (const s of series) { [x0, x1] = bounds(s.x, x0, x1); [y0, y1] = bounds(s.y, y0, y1); }
  if (!Number.isFinite(x0)) { x0 = 0; x1 = 1; }
  if (!Number.isFinite(y1)) y1 = 1;
  if (x1 === x0) x1 = x0 + 1;
  if (y1 === y0) y1 = y0 + 1;
  const margin = (y1 - y0) * 0.05; y0 -= margin; y1 += margin;
  const w = width - PAD.left - PAD.right, h = height - PAD.top - PAD.bottom;
  const X = (v) => PAD.left + ((v - x0) / (x1 - x0)) * w;
  const Y = (v) => PAD.top + (1 - (v - y0) / (y1 - y0)) * h;
  for (const b of bands) {
    const [low, high] = [b.y0 ?? 0, b.y1 ?? 1];
    ctx.fillStyle = b.color;
    ctx.fillRect(X(Math.max(b.x0, x0)), PAD.top + (1 - high) * h, X(Math.min(b.x1, x1)) - X(Math.max(b.x0, x0)), (high - low) * h);
  }
  ctx.strokeStyle = "#d8dbe2"; ctx.fillStyle = "#667"; ctx.font = "11px system-ui"; ctx.lineWidth = 1;
  for (const v of niceTicks(y0, y1, 5)) {
    ctx.beginPath(); ctx.moveTo(PAD.left, Y(v)); ctx.lineTo(width - PAD.right, Y(v)); ctx.stroke();
    ctx.fillText(String(v), 4, Y(v) + 4);
  }
  const labelLeft = width - PAD.right - 40;   // where the x axis' label starts: no tick label runs into it
  for (const v of niceTicks(x0, x1, 8)) if (X(v) + 8 < labelLeft) ctx.fillText(String(v), X(v) - 8, height - 8);
  ctx.fillText(xLabel, labelLeft, height - 8);
  ctx.fillText(yLabel, PAD.left + 4, PAD.top + 10);
  for (const s of series) {
    ctx.strokeStyle = s.color; ctx.lineWidth = s.width || 1.5; ctx.setLineDash(s.dash || []);
    ctx.beginPath();
    let pen = false;
    for (const k of strided(s.x.length)) {
      const v = s.y[k];
      if (v === null || !Number.isFinite(v)) { pen = false; continue; }
      if (pen) ctx.lineTo(X(s.x[k]), Y(v)); else ctx.moveTo(X(s.x[k]), Y(v));
      pen = true;
    }
    ctx.stroke();
  }
  ctx.setLineDash([]);
}

// A rotatable orthographic 3-D view: lines [{points: [[x,y,z]...], color}], triads [{origin, axes: [x, y, z]}].
export class View3D {
  constructor(canvas, { height = 320 } = {}) {
    this.canvas = canvas; this.height = height; this.yaw = -0.6; this.pitch = 0.5;
    this.lines = []; this.triads = []; this.triadLength = 0.02;
    canvas.classList.add("view3d");
    let drag = null;
    canvas.addEventListener("pointerdown", (e) => { drag = [e.clientX, e.clientY]; canvas.setPointerCapture(e.pointerId); });
    canvas.addEventListener("pointerup", () => { drag = null; });
    canvas.addEventListener("pointermove", (e) => {
      if (!drag) return;
      this.yaw += (e.clientX - drag[0]) * 0.01;
      this.pitch = Math.max(-1.5, Math.min(1.5, this.pitch + (e.clientY - drag[1]) * 0.01));
      drag = [e.clientX, e.clientY];
      this.draw();
    });
  }

  set(lines, triads = []) { this.lines = lines; this.triads = triads; this.draw(); }

  draw() {
    const { ctx, width, height } = sized(this.canvas, this.height);
    const all = this.lines.flatMap((l) => strided(l.points.length).map((k) => l.points[k]))
      .concat(this.triads.map((t) => t.origin));
    if (!all.length) return;
    const lo = [0, 1, 2].map((i) => bounds(all.map((p) => p[i]))[0]);
    const hi = [0, 1, 2].map((i) => bounds(all.map((p) => p[i]))[1]);
    const centre = lo.map((v, i) => (v + hi[i]) / 2);
    const span = Math.max(...hi.map((v, i) => v - lo[i]), 1e-3);
    const scale = (0.8 * Math.min(width, height)) / span;
    const cy = Math.cos(this.yaw), sy = Math.sin(this.yaw), cp = Math.cos(this.pitch), sp = Math.sin(this.pitch);
    const project = (p) => {
      const x = p[0] - centre[0], y = p[1] - centre[1], z = p[2] - centre[2];
      const u = cy * x - sy * y;                   // about world z (yaw), then tilt (pitch): z stays up on screen
      const v = sy * x + cy * y;
      return [width / 2 + scale * u, height / 2 - scale * (cp * z - sp * v)];
    };
    const segment = (a, b, color, width_ = 1.5) => {
      const [p, q] = [project(a), project(b)];
      ctx.strokeStyle = color; ctx.lineWidth = width_;
      ctx.beginPath(); ctx.moveTo(p[0], p[1]); ctx.lineTo(q[0], q[1]); ctx.stroke();
    };
    for (const line of this.lines) {
      ctx.strokeStyle = line.color; ctx.lineWidth = line.width || 1.5; ctx.beginPath();
      strided(line.points.length).forEach((k, j) => {
        const [x, y] = project(line.points[k]);
        if (j) ctx.lineTo(x, y); else ctx.moveTo(x, y);
      });
      ctx.stroke();
    }
    const length = Math.max(span * 0.06, 1e-3);
    for (const t of this.triads) {
      ["#d32f2f", "#2e7d32", "#1565c0"].forEach((color, j) => {
        segment(t.origin, t.origin.map((v, i) => v + t.axes[j][i] * length), color);
      });
    }
    const axis = [[1, 0, 0], [0, 1, 0], [0, 0, 1]];   // the world axes' directions, bottom left
    const o = [30, height - 30];
    ["x", "y", "z"].forEach((name, j) => {
      const p = project(centre.map((c, i) => c + axis[j][i] * (25 / scale)));
      const q = project(centre);
      ctx.strokeStyle = ["#d32f2f", "#2e7d32", "#1565c0"][j]; ctx.beginPath();
      ctx.moveTo(o[0], o[1]); ctx.lineTo(o[0] + p[0] - q[0], o[1] + p[1] - q[1]); ctx.stroke();
      ctx.fillStyle = ctx.strokeStyle; ctx.fillText(name, o[0] + p[0] - q[0], o[1] + p[1] - q[1]);
    });
  }
}
