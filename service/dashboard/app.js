// The nirc-bench dashboard: results overview, per-scene plots and images, history over commits, live jobs.
// Plain JavaScript against the REST API (/api/v1); plots by plot.js (bundled here).
"use strict";

// Raised when the service wants an API key for reads: the view becomes the login form.
class NeedsKey extends Error {}
const api = (path) => fetch(`/api/v1${path}`).then((r) => {
  if (r.status === 401 || r.status === 403) throw new NeedsKey(r.status === 403 ? "that key is invalid or revoked" : "");
  if (!r.ok) throw new Error(`${path}: ${r.status}`);
  return r.json();
});
const view = () => document.getElementById("view");
const esc = (s) => String(s ?? "").replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" })[c]);
const num = (v, d = 3) => (v === null || v === undefined ? "–" : Number(v).toPrecision(d));
const DEVICE_COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#8c564b"];
// The errors of the error-vs-time plots (registry fields), as `nirc-bench pareto` plots them.
const PARETO_FIELDS = ["mrse", "flip"];
let timer = null;
// Results of older estimator or metric versions are hidden unless the header's box is ticked.
const old = () => (document.getElementById("include-old").checked ? "&include_old=true" : "");

function label(run) {
  const p = run.params || {};
  const extra = [p.estimator, p.termination, p.nc ? `Nc ${p.nc}` : null].filter(Boolean).join(" ");
  const stale = run.current ? "" : ` [old: estimator v${run.estimator_version}, metrics v${run.metric_version}]`;
  return `${run.method}${extra ? ` (${extra})` : ""} ${run.spp} spp${stale}`;
}

// A metric cell: a value, "withheld" when the run's quality verdict makes it meaningless, or "–".
const metric = (run, name, value) => (value === null && (run.withheld || []).includes(name) ? "withheld" : num(value));
// The metric registry (GET /api/v1/metrics): columns and plots are built from it, once per page load.
let registry = null;
const metricRegistry = async () => (registry ??= await api("/metrics"));
const better = (m) => `${m.description}${m.unit ? ` [${m.unit}]` : ""}; ${m.direction} is better`;
const unitLabel = (m) => (m.unit ? `${m.label} (${m.unit})` : m.label);
const reasons = (run) => (run.quality.reasons || []).map((r) => `${r.code}: ${r.message}`).join("\n");
const verdictCell = (run) => `<td class="text verdict verdict-${esc(run.verdict ?? "none")}" title="${esc(reasons(run))}">${esc(run.verdict ?? "not judged")}</td>`;

async function overview() {
  const runs = await api(`/results?limit=1000${old()}`);
  const listed = (await metricRegistry()).filter((m) => m.field);
  const latest = new Map();
  for (const run of runs) {  // newest first: keep the first per (scene, method label + versions, device)
    const key = `${run.scene}|${label(run)}|${run.device_key}`;
    if (!latest.has(key)) latest.set(key, run);
  }
  const scenes = [...new Set([...latest.values()].map((r) => r.scene))].sort();
  const heads = listed.map((m) => `<th title="${esc(better(m))}">${esc(unitLabel(m))}</th>${m.ci_field ? "<th>95% CI</th>" : ""}`).join("");
  const cells = (r) => listed.map((m) => {
    const ci = m.ci_field ? (r[m.ci_field] ? `[${num(r[m.ci_field][0])}, ${num(r[m.ci_field][1])}]` : metric(r, m.verdict_name, null)) : null;
    return `<td>${metric(r, m.verdict_name, r[m.field])}</td>${ci === null ? "" : `<td>${ci}</td>`}`;
  }).join("");
  let html = "<h2>Latest results</h2>";
  if (!scenes.length) html += "<p class='muted'>No results yet: submit a job (POST /api/v1/jobs) or run <code>nirc-bench render</code>.</p>";
  for (const scene of scenes) {
    html += `<h3><a href="#/scene/${encodeURIComponent(scene)}">${esc(scene)}</a> <a class="muted" href="#/history/${encodeURIComponent(scene)}">history</a></h3><table><tr>
      <th class="text">method</th><th class="text">device</th><th class="text">verdict</th>${heads}
      <th>ms/frame</th><th>run</th></tr>`;
    for (const r of [...latest.values()].filter((r) => r.scene === scene)) {
      html += `<tr><td class="text">${esc(label(r))}</td><td class="text">${esc(r.device_key)}</td>${verdictCell(r)}
        ${cells(r)}<td>${num(r.seconds_per_frame * 1e3)}</td><td><a href="#/scene/${encodeURIComponent(scene)}/${r.id}">${r.id}</a></td></tr>`;
    }
    html += "</table>";
  }
  view().innerHTML = html;
}

function paretoFront(points) {
  const sorted = [...points].sort((a, b) => a[0] - b[0] || a[1] - b[1]);
  const front = [];
  for (const p of sorted) if (!front.length || p[1] < front[front.length - 1][1]) front.push(p);
  return front;
}

async function scenePage(scene, runId) {
  const runs = await api(`/results?scene=${encodeURIComponent(scene)}&limit=1000${old()}`);
  const sweeps = await api(`/sweeps?scene=${encodeURIComponent(scene)}&limit=1${old()}`);
  const v = view();
  v.innerHTML = `<h2>${esc(scene)}</h2><h3>Error vs time (per device; <code>nirc-bench pareto</code> adds speed-ups)</h3><div class="plots" id="pareto"></div>
    <h3>Adaptive equal-bias sweep</h3><div class="plots" id="sweep"></div>
    <h3>Run</h3><p><select id="run"></select></p><p id="verdict"></p>
    <h3>Time per frame</h3><div id="timing"></div>
    <h3>Convergence over frames</h3><div class="plots" id="convergence"></div>
    <h3>Images (click to crop)</h3><div class="images" id="images"></div>`;
  // Error vs time (nirc-bench pareto's view): times compare only on one device, so one plot per
  // device and error (MRSE, FLIP), one series per method (and estimator), the Pareto front dashed.
  const variant = (r) => [r.method, (r.params || {}).estimator].filter(Boolean).join(" ");
  const errors = (await metricRegistry()).filter((m) => PARETO_FIELDS.includes(m.field));
  for (const d of [...new Set(runs.map((r) => r.device_key))]) {
    for (const m of errors) {
      const mine = runs.filter((r) => r.device_key === d && r[m.field] > 0);
      const point = (r) => [r.seconds_per_frame * 1e3, r[m.field]];
      const series = [...new Set(mine.map(variant))].map((name, i) => ({ name, scatter: true,
        color: DEVICE_COLORS[i % 5], points: mine.filter((r) => variant(r) === name).map(point) }));
      series.push({ name: "Pareto front", color: "#000", dashed: true, points: paretoFront(mine.map(point)) });
      linePlot(document.getElementById("pareto"), { title: `${m.label} vs ms per frame (${d})`,
        xlabel: "ms per frame (online training included)", ylabel: unitLabel(m), logx: true, logy: true,
        series, width: 560, height: 320 });
    }
  }

  const sweepEl = document.getElementById("sweep");
  if (!sweeps.length) sweepEl.innerHTML = "<p class='muted'>No sweep of this scene yet (<code>nirc-bench sweep --scene NAME --eps 0.05:1.0</code>).</p>";
  else {
    const rows = sweeps[0].result.rows || [];
    const names = [...new Set(rows.map((r) => r.series))];
    const stale = sweeps[0].current ? "" : ", old versions";
    // One plot per sweep-plotted metric of the registry that this sweep's rows hold.
    const panels = (await metricRegistry()).filter((m) => m.sweep_plot && rows.some((r) => r[m.field] !== undefined))
      .map((m) => [m.field, unitLabel(m), m.log_axis]);
    for (const [key, title, log] of panels) {
      linePlot(sweepEl, { title: `${title} (sweep ${sweeps[0].id}${stale})`, xlabel: "% indirect-radiance bounces", ylabel: title,
        logy: log, series: names.map((n) => ({ name: n, dashed: n.includes("equal time"),
          points: rows.filter((r) => r.series === n).map((r) => [r.ir_bounces_pct, r[key]]) })) });
    }
  }

  const select = document.getElementById("run");
  select.innerHTML = runs.map((r) => `<option value="${r.id}">${r.id}: ${esc(label(r))} — ${esc(r.device_key)} — ${esc(r.verdict ?? "not judged")}</option>`).join("");
  if (runId) select.value = runId;
  select.onchange = () => { location.hash = `#/scene/${encodeURIComponent(scene)}/${select.value}`; };
  if (runs.length) await runDetail(select.value || runs[0].id);
}

// The run's median frame by stage: wall, kernel (Dr.Jit's kernel history) and harness
// (wall - kernel: host work, tracing, launch gaps) milliseconds, launches; the load flag.
function timingTable(run) {
  const wall = run.time_breakdown_ms;
  if (!wall) return "<p class='muted'>No per-stage timing stored with this run.</p>";
  const kernel = run.kernel_breakdown_ms || {};
  const stages = (run.timings || {}).stages || {};
  const load = (run.timings || {}).load;
  const rows = Object.entries(wall).map(([name, ms]) => {
    const k = kernel[name];
    const launches = (stages[name] || {}).launches_median;
    return `<tr><td class="text">${esc(name)}</td><td>${num(ms)}</td><td>${num(k)}</td>
      <td>${k === undefined ? "–" : num(ms - k)}</td><td>${k === undefined || ms <= 0 ? "–" : num(100 * (ms - k) / ms, 2)}</td>
      <td>${launches ?? "–"}</td></tr>`;
  }).join("");
  const share = run.harness_share === null || run.harness_share === undefined ? "–" : `${num(100 * run.harness_share, 2)} %`;
  const quiet = !load ? "not measured" : load.loaded === true ? "LOADED" : load.loaded === false ? "quiet" : "unknown";
  return `<p>${num(run.seconds_per_frame * 1e3)} ms per frame (the median frame's stages), kernel
    ${num((run.kernel_seconds_per_frame ?? NaN) * 1e3)} ms, harness share ${share}; machine while timed: <b>${quiet}</b>
    — ${esc(run.device_key)}</p>
    <table class="timing"><tr><th class="text">stage</th><th>wall ms</th><th>kernel ms</th><th>harness ms</th>
    <th>harness %</th><th>launches</th></tr>${rows}</table>
    ${(run.timing_flags || []).map((f) => `<p class="muted">${esc(f)}</p>`).join("")}`;
}

async function runDetail(runId) {
  const run = await api(`/runs/${runId}`);
  document.getElementById("verdict").innerHTML = `quality verdict: <b class="verdict-${esc(run.verdict ?? "none")}">${esc(run.verdict ?? "not judged")}</b>`
    + (run.quality.reasons || []).map((r) => `<br><span class="muted">${esc(r.code)}: ${esc(r.message)}</span>`).join("");
  document.getElementById("timing").innerHTML = timingTable(run);
  const conv = document.getElementById("convergence");
  const seeds = run.per_seed.filter((s) => s.metrics.convergence);
  linePlot(conv, { title: `run ${run.id}: MRSE over frames`, xlabel: "frame", ylabel: "MRSE", logy: true, width: 560,
    series: seeds.flatMap((s, i) => [
      { name: `seed ${s.seed}`, color: DEVICE_COLORS[i % 5], points: s.metrics.convergence.frame_mrse.map((y, x) => [x, y]) },
      { name: `seed ${s.seed} accumulated`, color: DEVICE_COLORS[i % 5], dashed: true,
        points: s.metrics.convergence.accumulated_mrse.map((y, x) => [x, y]) }]) });
  const art = (kind) => run.artifacts.find((a) => a.kind === kind);
  const images = [["reference", run.reference_id ? `/api/v1/references/${run.reference_id}/preview.png` : null],
    [label(run), art("preview")?.url], ["error map", art("error_map")?.url]];
  const box = document.getElementById("images");
  box.innerHTML = images.map(([name, src]) => `<figure><div class="crop">${src ? `<img src="${src}" alt="${esc(name)}">` : ""}</div>
    <figcaption>${esc(name)}</figcaption></figure>`).join("");
  const imgs = [...box.querySelectorAll("img")];
  const fit = () => imgs.forEach((img) => { img.style.width = "256px"; img.style.transform = "none"; });
  fit();
  box.querySelectorAll(".crop").forEach((crop) => crop.addEventListener("click", (ev) => {
    const rect = crop.getBoundingClientRect();
    const fx = (ev.clientX - rect.left) / rect.width, fy = (ev.clientY - rect.top) / rect.height;
    const zoom = imgs[0] && imgs[0].style.transform.includes("scale") ? 1 : 4;
    if (zoom === 1) return fit();
    imgs.forEach((img) => {
      img.style.transform = `translate(${-(fx * 256 * 4 - 128)}px, ${-(fy * 256 * 4 - 128)}px) scale(4)`;
    });
  }));
}

// History over commits (GET /api/v1/ci/history): one plot per listed metric of the registry,
// one line per setting (median over the seeds of a commit's runs, with its interval);
// detected steps are red lines, version changes (never compared) grey dashed ones.
async function historyPage(scene, method) {
  const runs = await api(`/results?limit=1000${old()}`);
  const scenes = [...new Set([...(await api("/scenes")).map((s) => s.name), ...runs.map((r) => r.scene)])];
  const methods = (await api("/methods")).methods.map((m) => m.name);
  scene = scene || runs[0]?.scene || scenes[0];
  method = method || runs.find((r) => r.scene === scene)?.method || methods[0];
  const options = (names, chosen) => names.map((n) => `<option${n === chosen ? " selected" : ""}>${esc(n)}</option>`).join("");
  view().innerHTML = `<h2>History over commits</h2>
    <p><select id="history-scene">${options(scenes, scene)}</select> <select id="history-method">${options(methods, method)}</select></p>
    <p class="muted">Median over the seeds of each commit's runs, with an interval for it. Red: a detected step
    (Welch t-test between consecutive commits, Holm-adjusted); grey dashed: a version change, never compared across.</p>
    <div class="plots" id="history"></div><h3>Detected steps</h3><div id="steps"></div>`;
  const go = () => { location.hash = `#/history/${encodeURIComponent(document.getElementById("history-scene").value)}/${encodeURIComponent(document.getElementById("history-method").value)}`; };
  document.getElementById("history-scene").onchange = go;
  document.getElementById("history-method").onchange = go;
  const steps = [];
  for (const m of (await metricRegistry()).filter((m) => m.field)) {
    const h = await api(`/ci/history?metric=${encodeURIComponent(m.name)}&scene=${encodeURIComponent(scene)}&method=${encodeURIComponent(method)}`);
    const points = h.series.flatMap((s) => s.points).sort((a, b) => (a.time < b.time ? -1 : a.time > b.time ? 1 : 0));
    const commits = [...new Set(points.map((p) => p.commit))];
    const x = new Map(commits.map((c, i) => [c, i]));
    const every = Math.ceil(commits.length / 8);
    const setting = (s) => `${s.resolution.join("×")}, ${s.spp} spp, ${s.frames} frames`;
    const series = h.series.map((s) => ({ name: setting(s),
      points: s.points.filter((p) => p.median !== null).map((p) => [x.get(p.commit), p.median]),
      ranges: s.points.filter((p) => p.ci).map((p) => [x.get(p.commit), p.ci[0], p.ci[1]]) }));
    const markers = h.series.flatMap((s) => s.points.flatMap((p) => (p.step
      ? [{ x: x.get(p.commit) - 0.5, label: "step", color: "#d62728" }]
      : p.break_before ? [{ x: x.get(p.commit) - 0.5, label: "version", color: "#888", dashed: true }] : [])));
    linePlot(document.getElementById("history"), { title: `${unitLabel(m)} over commits (${m.direction} is better)`,
      xlabel: "commit, oldest to newest", ylabel: unitLabel(m), logy: m.log_axis, series, markers, width: 560, height: 320,
      xticks: commits.map((c, i) => [i, c.slice(0, 7)]).filter((_, i) => i % every === 0) });
    for (const s of h.series) for (const p of s.points.filter((p) => p.step)) steps.push([m, s, p, setting(s)]);
  }
  document.getElementById("steps").innerHTML = steps.length
    ? `<table><tr><th class="text">metric</th><th class="text">commit</th><th class="text">setting</th><th>change of the median</th><th>p (Holm)</th><th>runs</th></tr>${
      steps.map(([m, , p, name]) => `<tr class="step"><td class="text">${esc(unitLabel(m))}</td><td class="text"><code>${esc(p.commit.slice(0, 12))}</code></td>
        <td class="text">${esc(name)}</td><td>${num(p.change)}</td><td>${num(p.p_holm, 2)}</td><td>${p.runs.join(", ")}</td></tr>`).join("")}</table>`
    : "<p class='muted'>No step detected.</p>";
}

async function jobsPage() {
  const jobs = await api("/jobs?limit=100");
  let html = `<h2>Jobs</h2><table><tr><th>id</th><th class="text">kind</th><th class="text">status</th>
    <th class="text">progress</th><th>attempts</th><th class="text">worker</th><th class="text">error</th><th>result</th></tr>`;
  for (const j of jobs) {
    const p = j.progress && j.progress.total ? `${esc(j.progress.stage)} ${j.progress.done}/${j.progress.total}` : "";
    const result = j.run_id ? `run ${j.run_id}` : j.sweep_id ? `sweep ${j.sweep_id}` : "";
    const kind = j.kind === "stage" ? `stage of ${j.parent_id}: ${esc(j.spec.name)}` : j.kind;
    html += `<tr><td>${j.id}</td><td class="text">${kind}</td><td class="text status-${j.status}">${j.status}</td>
      <td class="text">${p}</td><td>${j.attempts}/${j.max_attempts}</td><td class="text">${esc(j.worker)}</td>
      <td class="text">${esc(j.error)}</td><td>${result}</td></tr>`;
  }
  view().innerHTML = html + "</table><p class='muted'>refreshes every 2 s</p>";
}

// The key goes to the service once; it answers with an HttpOnly cookie (unreadable here)
// that the browser sends with every read from then on.
function loginForm(message) {
  view().innerHTML = `<form id="login"><h2>API key</h2>
    <p class="muted">This service's results are not public. Enter an API key (<code>nirc-bench apikey create</code>);
    this browser keeps it in a cookie that page scripts cannot read.</p>
    <input type="password" id="api-key" name="api-key" autocomplete="current-password" required maxlength="200" size="60">
    <button type="submit">log in</button>
    <p class="status-failed" id="login-error">${esc(message)}</p></form>`;
  document.getElementById("login").addEventListener("submit", async (event) => {
    event.preventDefault();
    const r = await fetch("/api/v1/auth/login", {
      method: "POST", headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ api_key: document.getElementById("api-key").value.trim() }),
    });
    if (r.ok) route();
    else document.getElementById("login-error").textContent = r.status === 403 ? "that key is invalid or revoked" : `login failed: ${r.status}`;
  });
}

async function route() {
  clearTimeout(timer);
  const parts = location.hash.replace(/^#\/?/, "").split("/").map(decodeURIComponent);
  try {
    if (parts[0] === "jobs") { await jobsPage(); timer = setTimeout(route, 2000); }
    else if (parts[0] === "scene" && parts[1]) await scenePage(parts[1], parts[2]);
    else if (parts[0] === "history") await historyPage(parts[1], parts[2]);
    else await overview();
  } catch (err) {
    if (err instanceof NeedsKey) loginForm(err.message);
    else view().innerHTML = `<p class="status-failed">${esc(err.message)}</p>`;
  }
}

document.getElementById("logout").addEventListener("click", async (event) => {
  event.preventDefault();
  await fetch("/api/v1/auth/logout", { method: "POST" });
  route();
});
window.addEventListener("hashchange", route);
document.getElementById("include-old").addEventListener("change", route);
route();
