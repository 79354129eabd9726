// A run's layers as float pixels (GET /api/v1/runs/{id}/pixels/{layer}; an uploaded image
// from GET /api/v1/images/{id}) and their display: radiance tone-mapped with an exposure
// (HDR values kept, so the readout is true), error and variance maps in false colour on a
// log scale, the signed bias map diverging around 0.

// How each layer is shown: radiance, a positive magnitude, or a signed value.
export const DISPLAY = { reference: "radiance", image: "radiance", uploaded: "radiance",
  error: "magnitude", variance: "magnitude", bias: "signed" };

const VIRIDIS = ["#440154", "#472d7b", "#3b528b", "#2c728e", "#21918c", "#28ae80", "#5ec962",
  "#addc30", "#fde725"];
const DIVERGING = ["#2166ac", "#67a9cf", "#d1e5f0", "#f7f7f7", "#fddbc7", "#ef8a62", "#b2182b"];
const NAN_RGB = [255, 0, 255];   // magenta: a non-finite value

const rgbOf = (hex) => [1, 3, 5].map((i) => parseInt(hex.slice(i, i + 2), 16));
const STOPS = { magnitude: VIRIDIS.map(rgbOf), signed: DIVERGING.map(rgbOf) };

// The colour at t in [0, 1] of a colour map, linearly between its stops.
function ramp(stops, t) {
  const f = Math.min(Math.max(t, 0), 1) * (stops.length - 1);
  const i = Math.min(Math.floor(f), stops.length - 2), w = f - i;
  return stops[i].map((c, k) => Math.round(c + w * (stops[i + 1][k] - c)));
}

// A layer's pixels: of run `runId` (its `seed`'s for an image or error map; an error map
// measured against uploaded image `against` instead of the reference), or the uploaded
// image `against` itself (layer "uploaded").
export async function fetchLayer(runId, layer, seed, against) {
  const query = new URLSearchParams();
  if (seed !== undefined && seed !== null) query.set("seed", seed);
  if (against && layer !== "uploaded") query.set("against", against);
  const q = query.toString();
  const path = layer === "uploaded" ? `/api/v1/images/${encodeURIComponent(against)}`
    : `/api/v1/runs/${runId}/pixels/${layer}${q ? `?${q}` : ""}`;
  const r = await fetch(path);
  if (!r.ok) {
    const body = await r.json().catch(() => ({}));
    throw new Error(typeof body.detail === "string" ? body.detail : `${layer}: HTTP ${r.status}`);
  }
  return { runId, layer, seed, against, width: Number(r.headers.get("X-Width")),
    height: Number(r.headers.get("X-Height")), channels: Number(r.headers.get("X-Channels")),
    quantity: r.headers.get("X-Quantity"), display: DISPLAY[layer],
    data: new Float32Array(await r.arrayBuffer()) };
}

// The value a false-colour map shows at pixel p: the mean of its channels.
function scalar(layer, p) {
  let sum = 0;
  for (let c = 0; c < layer.channels; c++) sum += layer.data[p * layer.channels + c];
  return sum / layer.channels;
}

function quantile(sorted, q) {
  return sorted.length ? sorted[Math.min(sorted.length - 1, Math.floor(q * sorted.length))] : NaN;
}

// The colour-bar range of a false-colour layer of its own: its 1st to 99th percentile,
// symmetric around 0 for a signed one. Computed once per layer.
export function range(layer) {
  if (layer.range) return layer.range;
  const n = layer.width * layer.height, values = [];
  for (let p = 0; p < n; p++) {
    const v = scalar(layer, p);
    if (Number.isFinite(v) && (layer.display !== "magnitude" || v > 0)) values.push(layer.display === "signed" ? Math.abs(v) : v);
  }
  values.sort((a, b) => a - b);
  if (layer.display === "signed") {
    const hi = quantile(values, 0.99) || 1;
    layer.range = [-hi, hi];
  } else {
    const lo = quantile(values, 0.01) || 1e-6, hi = quantile(values, 0.99) || 1;
    layer.range = [lo, hi > lo ? hi : lo * 10];
  }
  return layer.range;
}

const srgb = (v) => (v <= 0.0031308 ? 12.92 * v : 1.055 * v ** (1 / 2.4) - 0.055);

// One range for several false-colour layers of one quantity, so that a colour means one
// value in all of them: the lowest low and the highest high of their own ranges.
export function sharedRange(layers) {
  const spans = layers.map(range);
  return [Math.min(...spans.map((s) => s[0])), Math.max(...spans.map((s) => s[1]))];
}

// The layer as 8-bit RGBA: radiance x 2^exposure through the sRGB curve, or false colour
// over `span` ([low, high]; the layer's own range by default).
export function toImageData(layer, exposure, span = null) {
  const n = layer.width * layer.height, out = new ImageData(layer.width, layer.height);
  const gain = 2 ** exposure;
  const [lo, hi] = layer.display === "radiance" ? [0, 1] : span ?? range(layer);
  for (let p = 0; p < n; p++) {
    let rgb;
    if (layer.display === "radiance") {
      rgb = [0, 1, 2].map((c) => layer.data[p * layer.channels + Math.min(c, layer.channels - 1)]);
      rgb = rgb.every(Number.isFinite) ? rgb.map((v) => Math.round(255 * Math.min(1, Math.max(0, srgb(v * gain))))) : NAN_RGB;
    } else {
      const v = scalar(layer, p);
      if (!Number.isFinite(v)) rgb = NAN_RGB;
      else if (layer.display === "signed") rgb = ramp(STOPS.signed, (v - lo) / (hi - lo));
      else rgb = ramp(STOPS.magnitude, v <= 0 ? 0 : (Math.log10(v) - Math.log10(lo)) / (Math.log10(hi) - Math.log10(lo)));
    }
    out.data.set([rgb[0], rgb[1], rgb[2], 255], 4 * p);
  }
  return out;
}

// The layer's values at pixel (x, y), one per channel.
export function valuesAt(layer, x, y) {
  if (x < 0 || y < 0 || x >= layer.width || y >= layer.height) return null;
  const p = y * layer.width + x;
  return Array.from(layer.data.subarray(p * layer.channels, (p + 1) * layer.channels));
}

// A colour bar naming the quantity, with its range `span` (log scale for a magnitude) and
// whether other maps share it.
export function colourBar(layer, span, shared) {
  const bar = document.createElement("div");
  bar.className = "colour-bar";
  const canvas = document.createElement("canvas");
  canvas.width = 256; canvas.height = 12;
  const ctx = canvas.getContext("2d"), img = ctx.createImageData(256, 12);
  const stops = STOPS[layer.display];
  for (let x = 0; x < 256; x++) {
    const rgb = ramp(stops, x / 255);
    for (let y = 0; y < 12; y++) img.data.set([...rgb, 255], 4 * (y * 256 + x));
  }
  ctx.putImageData(img, 0, 0);
  const [lo, hi] = span;
  const fmt = (v) => Number(v).toPrecision(3);
  const scale = layer.display === "magnitude" ? "log scale" : "linear, 0 in the middle";
  const label = document.createElement("div");
  label.className = "colour-bar-label";
  label.textContent = `${fmt(lo)} … ${fmt(hi)}${shared ? " (shared range)" : ""} — ${layer.quantity} (${scale}; magenta: not finite)`;
  bar.append(canvas, label);
  return bar;
}
