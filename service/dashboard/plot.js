// Minimal SVG plots for the dashboard (no external libraries, no network).
// linePlot(container, {title, xlabel, ylabel, logx, logy, series: [{name, color,
// points: [[x, y], ...], dashed, scatter, ranges: [[x, lo, hi], ...]}], xticks: [[x, label], ...],
// markers: [{x, label, color, dashed}]}) draws axes, ticks (or the given x tick labels),
// lines/points with vertical interval bars, vertical markers, legend.
"use strict";

const SVG_NS = "http://www.w3.org/2000/svg";

function svgEl(tag, attrs, parent) {
  const el = document.createElementNS(SVG_NS, tag);
  for (const [k, v] of Object.entries(attrs || {})) el.setAttribute(k, v);
  if (parent) parent.appendChild(el);
  return el;
}

function niceTicks(lo, hi, log) {
  if (log) {
    const inRange = (t) => t >= lo / 1.0001 && t <= hi * 1.0001;
    for (const mantissas of [[1], [1, 2, 5], [1, 1.5, 2, 3, 5, 7]]) {  // denser when the range is narrow
      const ticks = [];
      for (let e = Math.floor(Math.log10(lo)); e <= Math.ceil(Math.log10(hi)); e++)
        for (const m of mantissas) ticks.push(m * 10 ** e);
      if (ticks.filter(inRange).length >= 3 || mantissas.length === 6) return ticks.filter(inRange);
    }
  }
  const step = 10 ** Math.floor(Math.log10((hi - lo) / 4 || 1));
  const mult = [1, 2, 5, 10].find((m) => (hi - lo) / (step * m) <= 6) || 10;
  const ticks = [];
  for (let t = Math.ceil(lo / (step * mult)) * step * mult; t <= hi + 1e-12; t += step * mult) ticks.push(t);
  return ticks;
}

function fmt(v) {
  if (v === 0) return "0";
  const a = Math.abs(v);
  return a >= 1e4 || a < 1e-2 ? v.toExponential(0) : String(+v.toPrecision(3));
}

function linePlot(container, opts) {
  const W = opts.width || 420, H = opts.height || 280, L = 60, R = 10, T = 24, B = 60;
  const usable = (p) => Number.isFinite(p[0]) && Number.isFinite(p[1]) &&
    (!opts.logx || p[0] > 0) && (!opts.logy || p[1] > 0);
  const series = opts.series.map((s) => ({ ...s, points: s.points.filter(usable) }));
  const all = series.flatMap((s) => [...s.points,
    ...(s.ranges || []).flatMap(([x, lo, hi]) => [[x, lo], [x, hi]]).filter(usable)]);
  const svg = svgEl("svg", { width: W, height: H, class: "plot", role: "img" }, container);
  svgEl("text", { x: W / 2, y: 15, "text-anchor": "middle", "font-weight": "bold" }, svg)
    .textContent = opts.title || "";
  if (!all.length) {
    svgEl("text", { x: W / 2, y: H / 2, "text-anchor": "middle" }, svg).textContent = "no data";
    return svg;
  }
  const ext = (i, log) => {
    let lo = Math.min(...all.map((p) => p[i])), hi = Math.max(...all.map((p) => p[i]));
    if (lo === hi) { lo = log ? lo / 2 : lo - 1; hi = log ? hi * 2 : hi + 1; }
    return [lo, hi];
  };
  const [x0, x1] = ext(0, opts.logx), [y0, y1] = ext(1, opts.logy);
  const tr = (v, lo, hi, log, a, b) => {
    const f = log ? (Math.log(v) - Math.log(lo)) / (Math.log(hi) - Math.log(lo)) : (v - lo) / (hi - lo);
    return a + f * (b - a);
  };
  const X = (v) => tr(v, x0, x1, opts.logx, L, W - R), Y = (v) => tr(v, y0, y1, opts.logy, H - B, T);
  svgEl("rect", { x: L, y: T, width: W - L - R, height: H - T - B, fill: "none", stroke: "#999" }, svg);
  for (const [t, text] of opts.xticks || niceTicks(x0, x1, opts.logx).map((t) => [t, fmt(t)])) {
    svgEl("line", { x1: X(t), x2: X(t), y1: T, y2: H - B, stroke: "#eee" }, svg);
    svgEl("text", { x: X(t), y: H - B + 14, "text-anchor": "middle" }, svg).textContent = text;
  }
  for (const m of opts.markers || []) {
    svgEl("line", { x1: X(m.x), x2: X(m.x), y1: T, y2: H - B, stroke: m.color || "#000", class: "marker",
      "stroke-width": 1.5, "stroke-dasharray": m.dashed ? "4,3" : "none" }, svg);
    svgEl("text", { x: X(m.x) + 3, y: T + 11, fill: m.color || "#000" }, svg).textContent = m.label || "";
  }
  for (const t of niceTicks(y0, y1, opts.logy)) {
    svgEl("line", { x1: L, x2: W - R, y1: Y(t), y2: Y(t), stroke: "#eee" }, svg);
    svgEl("text", { x: L - 4, y: Y(t) + 4, "text-anchor": "end" }, svg).textContent = fmt(t);
  }
  svgEl("text", { x: (L + W - R) / 2, y: H - B + 30, "text-anchor": "middle" }, svg).textContent = opts.xlabel || "";
  svgEl("text", { x: 12, y: (T + H - B) / 2, transform: `rotate(-90 12 ${(T + H - B) / 2})`,
    "text-anchor": "middle" }, svg).textContent = opts.ylabel || "";
  series.forEach((s, i) => {
    const color = s.color || ["#d62728", "#1f77b4", "#8c564b", "#2ca02c", "#9467bd"][i % 5];
    const pts = s.scatter ? s.points : [...s.points].sort((a, b) => a[0] - b[0]);
    if (!s.scatter && pts.length > 1) {
      svgEl("polyline", { points: pts.map((p) => `${X(p[0])},${Y(p[1])}`).join(" "), fill: "none",
        stroke: color, "stroke-width": 1.5, "stroke-dasharray": s.dashed ? "5,3" : "none" }, svg);
    }
    for (const [x, lo, hi] of (s.ranges || []).filter((r) => usable([r[0], r[1]]) && usable([r[0], r[2]])))
      svgEl("line", { x1: X(x), x2: X(x), y1: Y(lo), y2: Y(hi), stroke: color, "stroke-width": 1 }, svg);
    for (const p of pts) svgEl("circle", { cx: X(p[0]), cy: Y(p[1]), r: 3, fill: color }, svg);
    const lx = L + (i % 3) * 120, ly = H - 12 - Math.floor(i / 3) * 14;
    svgEl("rect", { x: lx, y: ly - 8, width: 10, height: 10, fill: color }, svg);
    svgEl("text", { x: lx + 14, y: ly + 1 }, svg).textContent = s.name;
  });
  return svg;
}

window.linePlot = linePlot;
