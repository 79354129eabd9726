// The nirc-bench dashboard: results overview, per-scene charts, a run's page with its image
// comparison, history over commits, jobs, the papers' reproduction reports. Plain JavaScript modules against the REST API
// (/api/v1); charts are Vega-Lite specs the service builds (charts.js), images float pixels
// (compare.js). Every number links to the run it came from (#/run/ID).
import { chart, note } from "./charts.js";
import { comparisonView } from "./compare.js";

// Raised when the service wants an API key for reads: the view becomes the login form.
class NeedsKey extends Error {}
const api = (path) => fetch(`/api/v1${path}`).then((r) => {
  if (r.status === 401 || r.status === 403) throw new NeedsKey(r.status === 403 ? "that key is invalid or revoked" : "");
  if (!r.ok) {
    return r.json().catch(() => ({})).then((body) => {   // the service's message, when it gave one
      const detail = Array.isArray(body.detail) ? body.detail.map((d) => d.msg).join("; ") : body.detail;
      throw new Error(`${path}: ${r.status}${detail ? ` — ${detail}` : ""}`);
    });
  }
  return r.json();
});
const view = () => document.getElementById("view");
const esc = (s) => String(s ?? "").replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" })[c]);
const num = (v, d = 3) => (v === null || v === undefined ? "–" : Number(v).toPrecision(d));
// A share as a whole percentage ("100", never "1.0e+2" as toPrecision(2) writes it).
const percent = (share) => (100 * share).toFixed(0);
const enc = encodeURIComponent;
const runLink = (id, text) => `<a href="#/run/${id}" title="run ${id}">${text}</a>`;
let timer = null;
// Results of older estimator or metric versions are hidden unless the header's box is ticked.
const old = () => (document.getElementById("include-old").checked ? "&include_old=true" : "");

// A run's method configuration (its label), marked when older versions computed it.
const label = (run) => `${run.method_label || run.method}${run.current ? "" : ` [old: estimator v${run.estimator_version}, metrics v${run.metric_version}]`}`;
// What must match for two runs to be compared (as jobs/views/chart_groups.py groups them).
const protocol = (run) => ("sweep" in (run.params || {}) ? "frozen cache" : "online training");
// "1 frame", "4 frames".
const count = (n, noun) => `${n} ${noun}${n === 1 ? "" : "s"}`;
const setting = (run) => `${run.resolution.join("×")}, ${run.spp} spp, ${count(run.frames, "frame")}, ${protocol(run)}`;

// The metric registry (GET /api/v1/metrics): columns are built from it, once per page load.
let registry = null;
const metricRegistry = async () => (registry ??= await api("/metrics"));
const better = (m) => `${m.description}${m.unit ? ` [${m.unit}]` : ""}; ${m.direction} is better`;
const unitLabel = (m) => (m.unit ? `${m.label} (${m.unit})` : m.label);

// A metric cell, linked to its run: "withheld" when the run's verdict makes it meaningless,
// "within noise (value)" for a noise-corrected estimate whose interval holds 0, "below the
// noise floor (value)" for a negative one without an interval; the interval is the API's
// (how it was made in the cell's title; none with fewer than 3 seeds), never recomputed.
function metricText(run, m) {
  const value = run[m.field];
  if (value === null || value === undefined) return (run.withheld || []).includes(m.verdict_name) ? "withheld" : "–";
  return runLink(run.id, (run.within_noise || []).includes(m.field) ? `within noise (${num(value)})`
    : (run.below_noise_floor || []).includes(m.field) ? `below the noise floor (${num(value)})` : num(value));
}
const interval = (ci) => (ci ? `[${num(ci[0])}, ${num(ci[1])}]` : "–");
function metricCells(run, m) {
  const text = metricText(run, m);
  const ci = m.ci_field ? run[m.ci_field] : undefined;
  const ciCell = m.ci_field ? `<td title="${esc(run[`${m.field}_ci_note`])}">${ci ? runLink(run.id, interval(ci)) : "–"}</td>` : "";
  return `<td>${text}</td>${ciCell}`;
}
const metricHeads = (listed) => listed.map((m) => `<th title="${esc(better(m))}">${esc(unitLabel(m))}</th>${m.ci_field ? "<th>95% CI</th>" : ""}`).join("");
const reasons = (run) => (run.quality.reasons || []).map((r) => `${r.code}: ${r.message}`).join("\n");
const verdictCell = (run) => `<td class="text verdict verdict-${esc(run.verdict ?? "none")}" title="${esc(reasons(run))}">${esc(run.verdict ?? "not judged")}</td>`;

// A run's ms/frame, marked L (the flags as its tooltip) where it was timed on a loaded machine.
function loadedTime(r) {
  const time = runLink(r.id, num(r.seconds_per_frame * 1e3));
  const flags = r.timing_flags || [];
  return flags.length ? `${time} <b class="loaded" title="${esc(flags.join("; "))}">L</b>` : time;
}

function resultsTable(runs, listed) {
  return `<table class="results"><tr><th class="text">method</th><th class="text">setting</th><th class="text">device</th>
    <th class="text">verdict</th>${metricHeads(listed)}<th>ms/frame</th><th>run</th></tr>${runs.map((r) => `<tr>
    <td class="text">${esc(label(r))}</td><td class="text">${esc(setting(r))}</td><td class="text">${esc(r.device_key)}</td>${verdictCell(r)}
    ${listed.map((m) => metricCells(r, m)).join("")}<td>${loadedTime(r)}</td><td>${runLink(r.id, r.id)}</td></tr>`).join("")}</table>`;
}

async function overview() {
  const runs = await api(`/results?limit=1000${old()}`);
  const listed = (await metricRegistry()).filter((m) => m.field);
  const latest = new Map();
  for (const run of runs) {  // newest first: the latest per scene, configuration, setting and device
    const key = `${run.scene}|${label(run)}|${setting(run)}|${run.device_key}`;
    if (!latest.has(key)) latest.set(key, run);
  }
  const scenes = [...new Set([...latest.values()].map((r) => r.scene))].sort();
  let html = "<h2>Latest results</h2><p class='muted'>The latest run of each method configuration per setting and device; rows of different settings or devices are not comparable. Every number opens its run.</p>";
  if (!scenes.length) html += "<p class='muted'>No results yet: submit a job (POST /api/v1/jobs) or run <code>nirc-bench render</code>.</p>";
  for (const scene of scenes) {
    const mine = [...latest.values()].filter((r) => r.scene === scene)
      .sort((a, b) => setting(a).localeCompare(setting(b)) || a.device_key.localeCompare(b.device_key));
    html += `<h3><a href="#/scene/${enc(scene)}">${esc(scene)}</a> <a class="muted" href="#/history/${enc(scene)}">history</a></h3>${resultsTable(mine, listed)}`;
  }
  view().innerHTML = html;
}

async function scenePage(scene) {
  const [charts, sweeps, runs] = await Promise.all([api(`/charts/scene?scene=${enc(scene)}${old()}`),
    api(`/sweeps?scene=${enc(scene)}&limit=1${old()}`), api(`/results?scene=${enc(scene)}&limit=1000${old()}`)]);
  const v = view();
  v.innerHTML = `<h2>${esc(scene)}</h2><p><a href="#/history/${enc(scene)}">history over commits</a></p>
    <h3>Error vs time</h3><p class="muted">One group per resolution, frames, protocol, device and versions: only comparable runs share a chart. In it each method configuration is one curve over its equal-time knob (spp, N_c, eps: points on a curve, not groups), one hue per method with shades and dashes for its configurations, and the group's Pareto front in black. Hover a point for the run's parameters; click it to open the run; wheel to zoom, drag to pan.</p>
    <div id="pareto"></div><h3 id="sweep-title">Sweeps</h3><div class="plots" id="sweep"></div>
    <h3>Runs</h3><div id="runs"></div>`;
  const pareto = document.getElementById("pareto");
  if (!charts.groups.length) note(pareto, "No runs of this scene yet.");
  for (const group of charts.groups) {
    const section = document.createElement("section");
    section.className = "group";
    section.innerHTML = `<h4>${esc(group.title)}</h4><div class="plots"></div>`;
    pareto.appendChild(section);
    for (const spec of group.charts) await chart(section.querySelector(".plots"), spec);
    for (const animated of group.animations) {
      section.insertAdjacentHTML("beforeend", `<h5>Animated: error per frame</h5><div class="plots animation"></div>`);
      await animatedView(section.querySelector(".plots.animation:last-of-type"), animated);
    }
  }
  const sweepEl = document.getElementById("sweep");
  if (!sweeps.length) note(sweepEl, "No sweep of this scene yet (nirc-bench sweep --scene NAME --eps 0.05:1.0).");
  else {
    const answer = await api(`/charts/sweeps/${sweeps[0].id}`);
    document.getElementById("sweep-title").textContent = `${answer.title} (the latest, sweep ${sweeps[0].id})`;
    for (const spec of answer.charts) await chart(sweepEl, spec);
  }
  document.getElementById("runs").innerHTML = resultsTable(runs, (await metricRegistry()).filter((m) => m.field));
}

// An animated run's (or a scene's animated runs') error per frame (GET /api/v1/charts,
// jobs/views/animation_chart.py) and, below it, the frames each run took to recover after
// each change with the bootstrap interval.
async function animatedView(container, view) {
  if (view.chart) await chart(container, view.chart);
  else note(container, view.note);
  if (!view.recoveries.length) return;
  const rows = view.recoveries.map((r) => `<tr><td class="text">${runLink(r.run, esc(r.series))}</td>
    <td>${r.change_frame}</td><td class="text">${esc(r.label)}</td>
    ${r.note ? `<td colspan="3" class="text muted">${esc(r.note)}</td>`
      : `<td>${r.frames}${r.within_window ? " (in the steady window)" : ""}</td><td>${interval(r.low === null ? null : [r.low, r.high])}</td><td>${num(r.steady_error)}</td>`}</tr>`).join("");
  container.insertAdjacentHTML("beforeend", `<table class="recovery"><caption>frames to recover after each change (95 % bootstrap interval over seeds)</caption>
    <tr><th class="text">run</th><th>change at frame</th><th class="text">what changed</th><th>frames to recover</th><th>95% interval</th><th>steady MRSE</th></tr>${rows}</table>`);
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
      <td>${k === undefined ? "–" : num(ms - k)}</td><td>${k === undefined || ms <= 0 ? "–" : percent((ms - k) / ms)}</td>
      <td>${launches ?? "–"}</td></tr>`;
  }).join("");
  const share = run.harness_share === null || run.harness_share === undefined ? "–" : `${percent(run.harness_share)} %`;
  const quiet = !load ? "not measured" : load.loaded === true ? "LOADED" : load.loaded === false ? "quiet" : "unknown";
  return `<p>${num(run.seconds_per_frame * 1e3)} ms per frame (the median frame's stages), kernel
    ${num((run.kernel_seconds_per_frame ?? NaN) * 1e3)} ms, harness share ${share}; machine while timed: <b>${quiet}</b>
    — ${esc(run.device_key)}</p>
    <table class="timing"><tr><th class="text">stage</th><th>wall ms</th><th>kernel ms</th><th>harness ms</th>
    <th>harness %</th><th>launches</th></tr>${rows}</table>
    ${(run.timing_flags || []).map((f) => `<p class="muted">${esc(f)}</p>`).join("")}`;
}

// Two runs side by side (GET /api/v1/compare, as `nirc-bench runs compare` shows it): what
// differs, each run's speed, efficiency 1/(MRSE x time) with its interval, load flags and
// verdicts; then every listed metric of both runs with its own interval, and the change
// with its Welch interval and whether it excludes 0.
function comparisonTables(cmp) {
  const cols = (cells) => cells.map((c) => `<td>${c}</td>`).join("");
  const row = (name, cells) => `<tr><td class="text">${esc(name)}</td>${cols(cells)}</tr>`;
  const byId = new Map(cmp.runs.map((r) => [r.id, r]));
  const fields = new Map((registry || []).map((m) => [m.name, m]));
  const st = cmp.standings;
  const head = `<table class="comparison" id="comparison-runs"><tr><th class="text">setting</th>${cmp.runs.map((r) => `<th>${runLink(r.id, `run ${r.id}`)}</th>`).join("")}</tr>
    ${row("what ran", cmp.runs.map((r) => esc(label(r))))}
    ${Object.entries(cmp.differences).map(([name, values]) => row(name, values.map((v) => esc(typeof v === "object" && v !== null ? JSON.stringify(v) : v ?? "–")))).join("")
      || row("(settings)", cmp.runs.map(() => "the same"))}
    ${row("ms / frame", st.map((s) => num(s.ms_per_frame)))}
    ${row("efficiency [1/s] (95% CI)", st.map((s) => (s.efficiency === null ? "–" : `${num(s.efficiency)} ${s.efficiency_ci95 ? interval(s.efficiency_ci95) : ""}`)))}
    ${row("timing", st.map((s) => (s.timing_flags.length ? `<b>${esc(s.timing_flags.join("; "))}</b>` : "not loaded")))}
    ${row("quality verdict", st.map((s) => esc(s.verdict ?? "–")))}
    ${row("rBias²", st.map((s) => esc(`${s.bias_verdict ?? "–"} (${s.rbias2_basis ?? "–"})`)))}</table>`;
  const deltas = cmp.deltas.map((d) => `<table class="comparison delta"><caption>run ${d.run} against run ${d.baseline}</caption>
    <tr><th class="text">metric</th><th>run ${d.baseline}</th><th>run ${d.run}</th><th>change</th><th>ratio</th>
    <th>95% interval of the change</th><th>differs</th><th class="text">note</th></tr>
    ${d.metrics.map((m) => {
      const reg = fields.get(m.metric);
      const value = (id) => { const r = byId.get(id); return reg?.field ? `${metricText(r, reg)} ${reg.ci_field && r[reg.ci_field] ? interval(r[reg.ci_field]) : ""}` : "–"; };
      return `<tr data-metric="${esc(m.metric)}"><td class="text">${esc(m.label)} (${esc(m.direction)} better)</td><td>${value(d.baseline)}</td><td>${value(d.run)}</td>
        <td>${num(m.delta)}</td><td>${num(m.ratio)}</td><td>${interval(m.delta_ci95)}</td>
        <td>${m.differs === null ? "–" : m.differs ? "yes" : "no"}</td><td class="text muted">${esc(m.interval_note)}</td></tr>`;
    }).join("")}</table>`).join("");
  return `${head}${deltas}${cmp.animation.map(animationComparison).join("")}<p class="muted" id="comparison-note">note: ${esc(cmp.note)}</p>`;
}

// Two animated runs (the compare answer's `animation`, jobs/views/animation_comparison.py):
// per change both runs' frames to recover with their bootstrap intervals and whether they
// differ (disjoint intervals), per segment both steady errors, both flickers; the error per
// frame of both is drawn below (#compare-animation). Else why they are not comparable.
function animationComparison(d) {
  if (!d.comparable) return `<p class="status-failed animation-comparison">${esc(d.note)}</p>`;
  const heads = `<th>run ${d.baseline}</th><th>run ${d.run}</th>`;
  const differs = (x) => (x === null ? "–" : x ? "<b>differ</b>" : "no");
  const spread = (r) => (r.low === null ? "" : ` ${interval([r.low, r.high])}`);
  const recovery = (r) => (r.frames === null ? `<span class="muted">${esc(r.note)}</span>` : `${r.frames}${spread(r)}`);
  const flicker = (f) => (f.mean === null ? `<span class="muted">${esc(f.note)}</span>` : `${num(f.mean)}${spread(f)}`);
  return `<section class="animation-comparison"><h4>Animated: run ${d.run} against run ${d.baseline}</h4>
    <table class="comparison recovery-comparison"><caption>frames to recover after each change (95 % bootstrap interval over seeds)</caption>
    <tr><th>change at frame</th><th class="text">what changed</th>${heads}<th>differ</th></tr>
    ${d.changes.map((c) => `<tr><td>${c.change_frame}</td><td class="text">${esc(c.label)}</td>
      <td>${recovery(c.baseline)}</td><td>${recovery(c.run)}</td><td>${differs(c.differs)}</td></tr>`).join("")}</table>
    <table class="comparison steady-comparison"><caption>steady MRSE per segment</caption>
    <tr><th>frames</th>${heads}</tr>
    ${d.segments.map((s) => `<tr><td>${s.first}–${s.last}</td><td>${num(s.baseline)}</td><td>${num(s.run)}</td></tr>`).join("")}</table>
    ${d.flicker ? `<table class="comparison flicker-comparison"><caption>flicker (seed mean, 95 % Student t interval)</caption>
    <tr>${heads}<th>differ</th></tr><tr><td>${flicker(d.flicker.baseline)}</td><td>${flicker(d.flicker.run)}</td><td>${differs(d.flicker.differs)}</td></tr></table>`
      : "<p class='muted'>no flicker stored with these runs</p>"}
    <p class="muted">${esc(d.note)}</p><div class="plots animation" id="compare-animation"></div></section>`;
}

async function runPage(runId, otherId) {
  const [run, other, charts] = await Promise.all([api(`/runs/${runId}`), otherId ? api(`/runs/${otherId}`) : null, api(`/charts/runs/${runId}`)]);
  const listed = (await metricRegistry()).filter((m) => m.field);
  const compared = other ? await api(`/compare?runs=${run.id},${other.id}`).then(comparisonTables, (err) => {
    if (err instanceof NeedsKey) throw err;
    return `<p class="status-failed">${esc(err.message)}</p>`;
  }) : "";
  const params = Object.entries(run.params || {}).map(([k, v]) => `${k}=${typeof v === "object" ? JSON.stringify(v) : v}`).join(", ");
  view().innerHTML = `<h2>Run ${run.id}: ${esc(label(run))}</h2>
    <p><a href="#/scene/${enc(run.scene)}">${esc(run.scene)}</a> — ${esc(setting(run))}, ${count(run.seeds, "seed")}, eps ${esc((run.metrics || {}).eps ?? "–")} — ${esc(run.device_key)}
    — commit <code>${esc(run.git_commit ?? "unknown")}</code> — ${esc(run.created_at)}</p>
    <p class="muted">parameters (resolved): ${esc(params || "defaults")}</p>
    ${(run.scene_overrides || []).length ? `<p class="muted">scene file settings not used: ${run.scene_overrides.map(esc).join("; ")}</p>` : ""}
    <p>quality verdict: <b class="verdict-${esc(run.verdict ?? "none")}">${esc(run.verdict ?? "not judged")}</b>
    ${(run.quality.reasons || []).map((r) => `<br><span class="muted">${esc(r.code)}: ${esc(r.message)}</span>`).join("")}</p>
    ${resultsTable([run], listed)}
    ${other ? `<h3>Compared with run ${other.id}</h3>${compared}` : ""}
    <h3>Image comparison</h3>
    <form id="other-run" class="compare-controls">side by side with run <input id="other-id" type="number" min="1" value="${esc(otherId ?? "")}" size="6"> <button type="submit">show</button></form>
    <div id="compare"></div>
    <h3>Time per frame</h3><div id="timing">${timingTable(run)}</div>
    <h3>Convergence over frames</h3><div class="plots" id="convergence"></div>
    ${charts.animation ? `<h3>Animated scene: error per frame and recovery</h3><div class="plots animation" id="animation"></div>` : ""}`;
  document.getElementById("other-run").onsubmit = (ev) => {
    ev.preventDefault();
    const id = document.getElementById("other-id").value;
    location.hash = id ? `#/run/${run.id}/${enc(id)}` : `#/run/${run.id}`;
  };
  const conv = document.getElementById("convergence");
  if (charts.convergence) await chart(conv, charts.convergence);
  else note(conv, charts.note);
  if (charts.animation) await animatedView(document.getElementById("animation"), charts.animation);
  const compareAnimation = document.getElementById("compare-animation");
  if (compareAnimation) {
    const both = await api(`/charts/compare/${run.id}/${other.id}`);
    if (both.animation) await chart(compareAnimation, both.animation);
    else note(compareAnimation, both.note);
  }
  await comparisonView(document.getElementById("compare"), run, other);
}

// History over commits (GET /api/v1/charts/history): per listed metric, one chart per
// setting (scene, resolution, frames, protocol, device), one line per run label and spp;
// the detected steps listed below.
async function historyPage(scene, method) {
  const runs = await api(`/results?limit=1000${old()}`);
  const scenes = [...new Set([...(await api("/scenes")).map((s) => s.name), ...runs.map((r) => r.scene)])];
  const methods = (await api("/methods")).methods.map((m) => m.name);
  scene = scene || runs[0]?.scene || scenes[0];
  method = method || runs.find((r) => r.scene === scene)?.method || methods[0];
  const options = (names, chosen) => names.map((n) => `<option${n === chosen ? " selected" : ""}>${esc(n)}</option>`).join("");
  view().innerHTML = `<h2>History over commits</h2>
    <p><select id="history-scene">${options(scenes, scene)}</select> <select id="history-method">${options(methods, method)}</select></p>
    <p class="muted">Median over the seeds of each commit's runs, with its interval; one chart per setting (scene, resolution, frames, protocol, device), one line per run label and spp, never pooled.
    Red: a detected step (Welch t-test between consecutive commits, Holm-adjusted); grey dashed: a version change, never compared across.</p>
    <div id="history"></div><h3>Detected steps</h3><div id="steps"></div>`;
  const go = () => { location.hash = `#/history/${enc(document.getElementById("history-scene").value)}/${enc(document.getElementById("history-method").value)}`; };
  document.getElementById("history-scene").onchange = go;
  document.getElementById("history-method").onchange = go;
  const answer = await api(`/charts/history?scene=${enc(scene)}&method=${enc(method)}`);
  const box = document.getElementById("history");
  const steps = [];
  for (const m of answer.metrics) {
    const section = document.createElement("section");
    section.innerHTML = `<h4>${esc(m.label)}</h4><div class="plots"></div>`;
    box.appendChild(section);
    if (!m.charts.length) note(section, m.below_noise_floor
      ? `Every median of ${m.label} of ${method} on ${scene} (${m.below_noise_floor}) is at or below 0, below the noise floor: none can be drawn on its log axis.`
      : `No value of ${m.label} in a run of ${method} on ${scene} with a clean commit.`);
    for (const c of m.charts) await chart(section.querySelector(".plots"), c.spec);
    for (const p of m.steps) steps.push([m, p]);
  }
  document.getElementById("steps").innerHTML = steps.length
    ? `<table><tr><th class="text">metric</th><th class="text">commit</th><th class="text">setting</th><th>change of the median</th><th>p (Holm)</th><th>runs</th></tr>${
      steps.map(([m, p]) => `<tr class="step"><td class="text">${esc(m.label)}</td><td class="text"><code>${esc(p.commit.slice(0, 12))}</code></td>
        <td class="text">${esc(`${p.config}: ${p.setting}`)}</td><td>${num(p.change)}</td><td>${num(p.p_holm, 2)}</td>
        <td>${p.runs.map((id) => runLink(id, id)).join(", ")}</td></tr>`).join("")}</table>`
    : "<p class='muted'>No step detected.</p>";
}

const time = (t) => (t ? new Date(t).toISOString().replace("T", " ").slice(0, 19) : "–");
function duration(job) {
  if (!job.started_at) return "–";
  const s = ((job.finished_at ? new Date(job.finished_at) : new Date()) - new Date(job.started_at)) / 1000;
  return s < 120 ? `${s.toFixed(1)} s` : `${(s / 60).toFixed(1)} min`;
}
function specText(spec) {
  const res = Array.isArray(spec.resolution) ? spec.resolution.join("×") : spec.resolution && `${spec.resolution}×${spec.resolution}`;
  return [res, spec.spp && `${spec.spp} spp`, spec.frames && count(spec.frames, "frame"),
    spec.seeds && count(spec.seeds, "seed"), spec.eps && `eps ${spec.eps}`].filter(Boolean).join(", ");
}

async function jobsPage() {
  const jobs = await api("/jobs?limit=100");
  const rows = jobs.map((j) => {
    const spec = j.spec || {};
    const p = j.progress && j.progress.total ? `${esc(j.progress.stage)} ${j.progress.done}/${j.progress.total}` : "";
    const result = j.run_id ? runLink(j.run_id, `run ${j.run_id}`)
      : j.sweep_id ? `<a href="#/scene/${enc(spec.scene ?? "")}">sweep ${j.sweep_id}</a>`
      : j.kind === "reproduce" && j.status === "succeeded" ? `<a href="#/paper/${enc(spec.paper)}">${esc(spec.paper)} ${esc(spec.figure)}</a>` : "";
    const kind = j.kind === "stage" ? `stage of ${j.parent_id}: ${esc(spec.name)}` : esc(j.kind);
    const scene = spec.scene ? `<a href="#/scene/${enc(spec.scene)}">${esc(spec.scene)}</a>` : "–";
    return `<tr><td>${j.id}</td><td class="text">${kind}</td><td class="text">${scene}</td><td class="text">${esc(spec.method ?? (spec.methods || []).join(", "))}</td>
      <td class="text">${esc(specText(spec))}</td><td class="text">${time(j.created_at)}</td><td class="text">${time(j.started_at)}</td>
      <td class="text">${time(j.finished_at)}</td><td>${duration(j)}</td><td class="text status-${esc(j.status)}">${esc(j.status)}</td>
      <td class="text">${p}</td><td>${j.attempts}/${j.max_attempts}</td><td class="text">${esc(j.worker)}</td>
      <td class="text">${esc(j.error)}</td><td>${result}</td></tr>`;
  }).join("");
  view().innerHTML = `<h2>Jobs</h2><table class="jobs"><tr><th>id</th><th class="text">kind</th><th class="text">scene</th><th class="text">method</th>
    <th class="text">spec</th><th class="text">submitted (UTC)</th><th class="text">started</th><th class="text">ended</th><th>duration</th>
    <th class="text">state</th><th class="text">progress</th><th>attempts</th><th class="text">worker</th><th class="text">error</th><th>result</th></tr>${rows}</table>
    <p class='muted'>refreshes every 2 s</p>`;
}

async function papersPage() {
  const papers = await api("/reports");
  view().innerHTML = `<h2>Papers</h2><p class="muted">Each paper's figures and tables as reproduced on this service
    (<code>nirc-bench reproduce … --server</code>, POST /api/v1/reproductions), beside its claims.</p>
    <ul class="papers">${papers.map((p) => `<li><a href="#/paper/${enc(p.paper)}">${esc(p.title)}</a> [${esc(p.reference)}]</li>`).join("")}</ul>`;
}

// One figure of a report: its claims with the catalogue's verdicts, and where it was reproduced here
// its verdicts, table, its PNG beside the charts, and provenance (with what it took).
function figureSection(f) {
  const claims = (f.claims || []).map((c) => `<li>${esc(c.where)}: “${esc(c.quote)}” → <b>${esc(c.verdict)}</b></li>`).join("");
  let html = `<h3>${esc(f.figure)}: ${esc(f.title)}</h3>`;
  html += claims ? `<p>The paper's claims (catalogue verdicts):</p><ul class="claims">${claims}</ul>` : "";
  const s = f.stored;
  if (!s) return `${html}<p class="muted">Not reproduced on this service yet${f.command ? `: <code>${esc(f.command)} --server URL</code>` : f.needs ? ` (needs ${esc(f.needs)})` : ""}.</p>`;
  const r = s.reproduction;
  const verdicts = r.verdicts.map((v) => `<li>${esc(v.claim)}: <b class="verdict-${esc(v.verdict.replace(/ /g, "-"))}">${esc(v.verdict)}</b> (${esc(v.reason)})</li>`).join("");
  const keys = Object.keys(r.quantities);
  const rows = r.points.map((p) => `<tr><td class="text">${esc(p.scene)}</td><td class="text">${esc(p.series)}</td><td>${p.x === null ? "–" : num(p.x)}</td>${keys.map((k) => {
    const e = p.values[k];
    return `<td>${e && e.value !== null ? `${num(e.value)}${e.ci95 ? ` ${interval(e.ci95)}` : ""}` : "–"}</td><td>${k in p.paper ? num(p.paper[k]) : "–"}</td>`;
  }).join("")}</tr>`).join("");
  const prov = s.provenance;
  html += `<p>Reproduced by job ${s.job_id}, mode <code>${esc(r.mode)}</code> (${esc(Object.entries(r.settings).map(([k, v]) => `${k} ${v}`).join(", "))}).</p>`;
  html += verdicts ? `<p>Our verdicts:</p><ul class="verdicts">${verdicts}</ul>` : "";
  html += `<div class="plots"><img class="figure-png" src="${esc(s.figure_url)}" alt="${esc(f.figure)} as drawn by nirc-bench reproduce"></div><table class="results reproduction"><tr><th class="text">scene</th><th class="text">series</th><th>${esc(r.x_label)}</th>${keys.map((k) => `<th>${esc(r.quantities[k])} [95% CI]</th><th>paper</th>`).join("")}</tr>${rows}</table>`;
  const took = prov.time ? `, took wall ${prov.time.wall_s.toFixed(1)} s, CPU ${prov.time.cpu_s.toFixed(1)} s (load ${prov.time.load_start[0].toFixed(2)} → ${prov.time.load_end[0].toFixed(2)})` : "";
  html += `<p class="muted">Provenance: commit ${esc(prov.git_commit)}, finished ${esc(prov.finished_at)}${took}; ${esc(Object.entries(prov.libraries || {}).map(([k, v]) => `${k} ${v}`).join(", "))}.</p>`;
  return html;
}

async function paperPage(paper) {
  const report = await api(`/reports/${enc(paper)}`);
  view().innerHTML = `<h2>${esc(report.title)} [${esc(report.reference)}]</h2><p><a href="#/papers">all papers</a></p>
    ${report.figures.map((f) => `<section class="figure" data-figure="${esc(f.figure)}">${figureSection(f)}</section>`).join("")}`;
  for (const f of report.figures) {
    const plots = document.querySelector(`section.figure[data-figure="${CSS.escape(f.figure)}"] .plots`);
    for (const spec of f.charts) await chart(plots, spec);
  }
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
    else if (parts[0] === "scene" && parts[1]) await (parts[2] ? runPage(parts[2]) : scenePage(parts[1]));
    else if (parts[0] === "run" && parts[1]) await runPage(parts[1], parts[2]);
    else if (parts[0] === "history") await historyPage(parts[1], parts[2]);
    else if (parts[0] === "papers") await papersPage();
    else if (parts[0] === "paper" && parts[1]) await paperPage(parts[1]);
    else await overview();
  } catch (err) {
    if (err instanceof NeedsKey) loginForm(err.message);
    else view().innerHTML = `<p class="status-failed">${esc(err.message)}</p>`;
  }
  document.body.dataset.ready = location.hash || "#/";
}

document.getElementById("logout").addEventListener("click", async (event) => {
  event.preventDefault();
  await fetch("/api/v1/auth/logout", { method: "POST" });
  route();
});
window.addEventListener("hashchange", route);
document.getElementById("include-old").addEventListener("change", route);
route();
