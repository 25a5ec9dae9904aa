// Small hand-written canvas plots: time series (linePlot) and strips of labelled spans on the same time axis
// (stripPlot: phases, contact, segments). Units are whatever the caller gives and labels (the dashboard: s, N); the
// 3-D scene is scene3d.js.

const PAD = { left: 56, right: 10, top: 10, bottom: 24 };
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
// (y0, y1: the band's bottom and top as fractions of the plot's height; the full height without them); areas:
// [{x: [...], low: [...], high: [...], color}] shaded between low and high in data units, behind the lines; xRange:
// [x0, x1] shared with the plots beside it (default: the series' own); zero: a line at y = 0.
export function linePlot(canvas, series, { height = 220, xLabel = "", yLabel = "", bands = [], areas = [], xRange = null, zero = false } = {}) {
  const { ctx, width } = sized(canvas, height);
  let [x0, x1] = [Infinity, -Infinity], [y0, y1] = [0, -Infinity];
  for (const s of series) { [x0, x1] = bounds(s.x, x0, x1); [y0, y1] = bounds(s.y, y0, y1); }
  for (const a of areas) { [x0, x1] = bounds(a.x, x0, x1); [y0, y1] = bounds(a.low, y0, y1); [y0, y1] = bounds(a.high, y0, y1); }
  if (xRange) [x0, x1] = xRange;
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
  for (const a of areas) {
    // The upper edge left to right, the lower edge back: one closed polygon.
    const picked = strided(a.x.length);
    ctx.fillStyle = a.color;
    ctx.beginPath();
    picked.forEach((k, j) => (j ? ctx.lineTo(X(a.x[k]), Y(a.high[k])) : ctx.moveTo(X(a.x[k]), Y(a.high[k]))));
    for (const k of [...picked].reverse()) ctx.lineTo(X(a.x[k]), Y(a.low[k]));
    ctx.closePath();
    ctx.fill();
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
  if (zero && y0 < 0 && y1 > 0) {
    ctx.strokeStyle = "#556"; ctx.beginPath(); ctx.moveTo(PAD.left, Y(0)); ctx.lineTo(width - PAD.right, Y(0)); ctx.stroke();
  }
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

// rows: [{label, spans: [{x0, x1, color, text?}]}], one strip each, on the time axis [x0, x1] (s) of the plots
// beside it; a span's text is written in it where it fits. The bottom row carries the time ticks and xLabel.
export function stripPlot(canvas, rows, { xRange, xLabel = "", rowHeight = 18 } = {}) {
  const height = rows.length * rowHeight + 22;
  const { ctx, width } = sized(canvas, height);
  const [x0, x1] = xRange[1] > xRange[0] ? xRange : [xRange[0], xRange[0] + 1];
  const w = width - PAD.left - PAD.right;
  const X = (v) => PAD.left + ((Math.min(Math.max(v, x0), x1) - x0) / (x1 - x0)) * w;
  ctx.font = "11px system-ui"; ctx.textBaseline = "middle";
  rows.forEach((row, r) => {
    const top = r * rowHeight + 2;
    ctx.fillStyle = "#f0f1f4"; ctx.fillRect(PAD.left, top, w, rowHeight - 3);
    ctx.fillStyle = "#667"; ctx.fillText(row.label, 4, top + rowHeight / 2 - 1);
    for (const span of row.spans) {
      const [a, b] = [X(span.x0), X(span.x1)];
      ctx.fillStyle = span.color; ctx.fillRect(a, top, Math.max(b - a, 1), rowHeight - 3);
      if (span.text && ctx.measureText(span.text).width + 6 < b - a) {
        ctx.fillStyle = "#1d2330"; ctx.fillText(span.text, a + 3, top + rowHeight / 2 - 1);
      }
    }
  });
  ctx.fillStyle = "#667"; ctx.textBaseline = "alphabetic";
  const labelLeft = width - PAD.right - 40;
  for (const v of niceTicks(x0, x1, 8)) if (X(v) + 8 < labelLeft) ctx.fillText(String(v), X(v) - 8, height - 6);
  ctx.fillText(xLabel, labelLeft, height - 6);
}
