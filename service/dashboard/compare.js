// The image comparison view of a run (as tev or the FLIP viewer): any two layers (reference,
// a seed's image or error map, the bias and variance maps; of this run or of a second one;
// an EXR the user uploads, with the error maps against it) under an A/B split slider
// (img-comparison-slider, vendored) with a flip button, an exposure for the HDR images,
// false-colour maps with colour bars (maps of one quantity share one range unless
// "separate colour ranges" is ticked), a readout of the true values under the cursor, and
// one zoom and pan shared by every image (wheel: zoom; drag: pan).
import { colourBar, fetchLayer, range, sharedRange, toImageData, valuesAt } from "./pixels.js";

const SIZE = 320;   // CSS pixels of every image view

const esc = (s) => String(s ?? "").replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" })[c]);

// The per-pixel maps a run stored (runs of 2+ seeds): [layer, artifact kind, label].
const MAPS = [["bias", "rel_bias_map", "relative bias map"], ["variance", "rel_variance_map", "relative variance map"]];

// The layers one can look at: [key, label, run id, layer, seed, uploaded image id].
function choices(run, other, uploaded) {
  const of = (r, prefix) => [
    ...r.per_seed.map((s) => [`${r.id}:image:${s.seed}`, `${prefix}image, seed ${s.seed}`, r.id, "image", s.seed]),
    ...r.per_seed.map((s) => [`${r.id}:error:${s.seed}`, `${prefix}error map, seed ${s.seed}`, r.id, "error", s.seed]),
    ...MAPS.filter(([, kind]) => r.artifacts.some((a) => a.kind === kind))
      .map(([layer, , label]) => [`${r.id}:${layer}`, `${prefix}${label}`, r.id, layer, null])];
  const againstUpload = uploaded ? [["upload", "uploaded image", run.id, "uploaded", null, uploaded],
    ...run.per_seed.map((s) => [`upload:error:${s.seed}`, `error map against the uploaded image, seed ${s.seed}`,
      run.id, "error", s.seed, uploaded])] : [];
  return [[`${run.id}:reference`, "reference", run.id, "reference", null], ...of(run, ""),
    ...(other ? of(other, `run ${other.id}: `) : []), ...againstUpload];
}

// Sends a chosen EXR file to POST /api/v1/images with the typed API key (an upload is a
// write: the login cookie does not authorize it); answers the stored image's id, or
// throws the service's message.
async function uploadImage(run, file, key) {
  const r = await fetch(`/api/v1/images?run=${run.id}`, { method: "POST", body: file,
    headers: { "Content-Type": "image/x-exr", "X-API-Key": key } });
  const body = await r.json().catch(() => ({}));
  if (!r.ok) {
    const detail = Array.isArray(body.detail) ? body.detail.map((d) => d.msg).join("; ") : body.detail;
    throw new Error(`${r.status}: ${detail ?? "upload failed"}`);
  }
  return body.id;
}

export async function comparisonView(container, run, other, uploaded = null) {
  const options = choices(run, other, uploaded);
  const byKey = new Map(options.map((o) => [o[0], o]));
  const select = (id, chosen) => `<select id="${id}">${options.map(([key, label]) =>
    `<option value="${esc(key)}"${key === chosen ? " selected" : ""}>${esc(label)}</option>`).join("")}</select>`;
  const firstSeed = run.per_seed[0]?.seed ?? 0;
  container.innerHTML = `<div class="compare-controls">
      A ${select("layer-a", `${run.id}:reference`)} B ${select("layer-b", `${run.id}:image:${firstSeed}`)}
      <button type="button" id="flip" title="swap A and B">flip A/B</button>
      <label>exposure <input type="range" id="exposure" min="-8" max="8" step="0.5" value="0"> <output id="exposure-value">0 EV</output></label>
      <button type="button" id="reset-view">reset zoom</button>
      <label title="each error, bias or variance map on its own range instead of one range per quantity"><input type="checkbox" id="separate-ranges"> separate colour ranges</label></div>
    <form id="upload-form" class="compare-controls">compare with an EXR of this run's size (as a reference):
      <input type="file" id="upload-file" accept=".exr,image/x-exr" required>
      API key <input type="password" id="upload-key" autocomplete="current-password" required maxlength="200" size="24">
      <button type="submit">upload</button> <span id="upload-status" class="muted">${uploaded ? `uploaded image ${esc(uploaded.slice(0, 12))}…` : ""}</span></form>
    <div class="compare-main"><figure><img-comparison-slider id="ab" handle="true" tabindex="0">
      <canvas slot="first" id="canvas-a" width="${SIZE}" height="${SIZE}"></canvas>
      <canvas slot="second" id="canvas-b" width="${SIZE}" height="${SIZE}"></canvas></img-comparison-slider>
      <figcaption id="ab-caption"></figcaption></figure>
      <div><h4>Value under the cursor</h4><table id="readout" class="readout"><tr><td class="muted">move over an image</td></tr></table></div></div>
    <div class="compare-grid" id="compare-grid"></div>`;
  const shown = [];          // {canvas, key, bar}: what each canvas draws
  const layers = new Map();  // key -> fetched layer (or its error)
  const bitmaps = new Map(); // key + exposure -> canvas with the layer's 8-bit pixels
  const view = { s: SIZE, ox: 0, oy: 0 };   // screen = offset + (pixel / width) * s
  const exposure = () => Number(container.querySelector("#exposure").value);

  async function layer(key) {
    if (!layers.has(key)) {
      const [, , runId, name, seed, against] = byKey.get(key);
      const pending = fetchLayer(runId, name, seed, against).catch((err) => ({ error: err.message }));
      layers.set(key, pending);
      pending.then((data) => { pending.loaded = data; });
    }
    return layers.get(key);
  }
  // A false-colour layer's range: its own, or (by default) the one it shares with every
  // loaded layer of its quantity on the page (this run's, the second run's, against the
  // upload), so that equal colours are equal values.
  const separate = () => container.querySelector("#separate-ranges").checked;
  const peers = (data) => [...new Set(shown.map((e) => e.key))].map((key) => layers.get(key)?.loaded)
    .filter((d) => d && !d.error && d.layer === data.layer);
  const span = (data) => (data.display === "radiance" ? [0, 1] : separate() ? range(data) : sharedRange(peers(data)));
  function bitmap(key, data) {
    const id = `${key}@${data.display === "radiance" ? exposure() : span(data).join(",")}`;
    if (!bitmaps.has(id)) {
      const c = document.createElement("canvas");
      c.width = data.width; c.height = data.height;
      c.getContext("2d").putImageData(toImageData(data, exposure(), span(data)), 0, 0);
      bitmaps.set(id, c);
    }
    return bitmaps.get(id);
  }
  async function draw(entry) {
    const data = await layer(entry.key);
    const ctx = entry.canvas.getContext("2d");
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.fillStyle = "#222";
    ctx.fillRect(0, 0, SIZE, SIZE);
    if (data.error) {
      ctx.fillStyle = "#ddd";
      ctx.fillText(data.error.slice(0, 60), 6, 16);
      return;
    }
    ctx.imageSmoothingEnabled = false;
    const k = view.s / data.width;
    ctx.setTransform(k, 0, 0, k, view.ox, view.oy);
    ctx.drawImage(bitmap(entry.key, data), 0, 0);
    entry.canvas.dataset.range = data.display === "radiance" ? "" : span(data).join(",");
    if (entry.bar && data.display !== "radiance") entry.bar.replaceChildren(colourBar(data, span(data), !separate() && peers(data).length > 1));
  }
  // Every shown layer is loaded before any is drawn: a shared range needs all of them.
  const redraw = async () => {
    await Promise.all(shown.map((e) => layer(e.key)));
    return Promise.all(shown.map(draw));
  };

  // ---- the grid: every layer of the run (and of the second run) side by side ----
  const grid = container.querySelector("#compare-grid");
  const gridKeys = [`${run.id}:reference`, `${run.id}:image:${firstSeed}`, `${run.id}:error:${firstSeed}`,
    `${run.id}:bias`, `${run.id}:variance`,
    ...(other ? [`${other.id}:image:${other.per_seed[0]?.seed ?? 0}`, `${other.id}:error:${other.per_seed[0]?.seed ?? 0}`] : []),
    "upload", `upload:error:${firstSeed}`]
    .filter((key) => byKey.has(key));
  for (const key of gridKeys) {
    const figure = document.createElement("figure");
    figure.innerHTML = `<canvas width="${SIZE}" height="${SIZE}" data-layer="${esc(key)}"></canvas><figcaption>${esc(byKey.get(key)[1])}</figcaption><div class="bar"></div>`;
    grid.appendChild(figure);
    shown.push({ canvas: figure.querySelector("canvas"), key, bar: figure.querySelector(".bar") });
  }
  const a = { canvas: container.querySelector("#canvas-a"), key: "" };
  const b = { canvas: container.querySelector("#canvas-b"), key: "" };
  shown.push(a, b);
  const chooseAB = () => {
    a.key = container.querySelector("#layer-a").value;
    b.key = container.querySelector("#layer-b").value;
    container.querySelector("#ab-caption").textContent = `left: A = ${byKey.get(a.key)[1]}; right: B = ${byKey.get(b.key)[1]}`;
    return redraw();   // A or B may change a shared range
  };
  container.querySelector("#layer-a").onchange = chooseAB;
  container.querySelector("#layer-b").onchange = chooseAB;
  container.querySelector("#flip").onclick = () => {
    const sa = container.querySelector("#layer-a"), sb = container.querySelector("#layer-b");
    [sa.value, sb.value] = [sb.value, sa.value];
    return chooseAB();
  };
  container.querySelector("#exposure").oninput = () => {
    container.querySelector("#exposure-value").textContent = `${exposure()} EV`;
    redraw();
  };
  container.querySelector("#reset-view").onclick = () => { Object.assign(view, { s: SIZE, ox: 0, oy: 0 }); redraw(); };
  container.querySelector("#separate-ranges").onchange = redraw;
  container.querySelector("#upload-form").onsubmit = async (ev) => {
    ev.preventDefault();
    const status = container.querySelector("#upload-status");
    status.textContent = "uploading…";
    try {
      const id = await uploadImage(run, container.querySelector("#upload-file").files[0],
        container.querySelector("#upload-key").value.trim());
      container.dataset.ready = "false";
      await comparisonView(container, run, other, id);
    } catch (err) {
      status.textContent = err.message;
      status.className = "status-failed";
    }
  };

  // ---- synchronized zoom and pan: one transform for every canvas ----
  const local = (canvas, ev) => {
    const r = canvas.getBoundingClientRect();
    return [(ev.clientX - r.left) * (SIZE / r.width), (ev.clientY - r.top) * (SIZE / r.height)];
  };
  let drag = null;
  for (const entry of shown) {
    const c = entry.canvas;
    c.addEventListener("wheel", (ev) => {
      ev.preventDefault();
      const [mx, my] = local(c, ev), f = ev.deltaY < 0 ? 1.25 : 0.8;
      view.ox = mx - (mx - view.ox) * f; view.oy = my - (my - view.oy) * f; view.s *= f;
      redraw();
    }, { passive: false });
    c.addEventListener("pointerdown", (ev) => { drag = [ev.clientX, ev.clientY]; ev.stopPropagation(); });
    c.addEventListener("pointermove", (ev) => {
      if (drag && ev.buttons) {
        view.ox += ev.clientX - drag[0]; view.oy += ev.clientY - drag[1];
        drag = [ev.clientX, ev.clientY];
        redraw();
      }
      readout(entry, ...local(c, ev));
    });
  }
  window.addEventListener("pointerup", () => { drag = null; });

  // ---- readout: the true values of every shown layer at the pixel under the cursor ----
  async function readout(entry, mx, my) {
    const data = await layer(entry.key);
    if (data.error) return;
    const x = Math.floor(((mx - view.ox) / view.s) * data.width), y = Math.floor(((my - view.oy) / view.s) * data.width);
    const rows = [];
    for (const key of new Set(shown.map((e) => e.key))) {
      const d = await layer(key);
      const values = d.error ? null : valuesAt(d, Math.floor((x / data.width) * d.width), Math.floor((y / data.width) * d.width));
      rows.push(`<tr><td class="text">${esc(byKey.get(key)[1])}</td><td>${values ? values.map((v) => v.toPrecision(4)).join(", ") : "–"}</td></tr>`);
    }
    container.querySelector("#readout").innerHTML = `<tr><th class="text">pixel</th><th>(${x}, ${y})</th></tr>${rows.join("")}`;
  }

  if (uploaded) {   // A/B: the uploaded image against the first seed's
    container.querySelector("#layer-a").value = "upload";
    container.querySelector("#layer-b").value = `${run.id}:image:${firstSeed}`;
  }
  await chooseAB();
  container.dataset.ready = "true";
}
