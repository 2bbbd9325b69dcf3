// fwl view: the page. State (run, pulse, colour, tab) lives in the URL; data comes from /api/*.
"use strict";

const state = { run: null, file: null, pulse: null, colour: "height", tab: "explore", box: null };
let summary = null;
const WEBGL = (() => { try { return !!document.createElement("canvas").getContext("webgl"); } catch (e) { return false; } })();
const MAP_LIMIT = WEBGL ? 60000 : 8000;
const SCENE_LIMIT = 25000;
const $ = (id) => document.getElementById(id);
const NS = 1000;  // ps per ns: waveforms are drawn in ns

function fmt(v, digits = 3) {
  if (v === null || v === undefined) return "–";
  if (typeof v !== "number") return String(v);
  if (Number.isInteger(v)) return String(v);
  return Math.abs(v) >= 1e4 || (Math.abs(v) < 1e-3 && v !== 0) ? v.toExponential(digits) : v.toFixed(digits);
}

async function api(path, body) {
  const response = await fetch(path, body === undefined ? {} :
    { method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body) });
  const data = await response.json();
  if (!response.ok) throw new Error(data.error || response.statusText);
  return data;
}

function say(text) { $("message").textContent = text || ""; }

// ---------------------------------------------------------------- URL state

function readUrl() {
  const q = new URLSearchParams(location.search);
  state.run = q.get("run");
  state.colour = q.get("colour") || "height";
  state.tab = q.get("tab") || "explore";
  const box = (q.get("box") || "").split(",").map(Number);
  state.box = box.length === 4 && box.every(isFinite) ? box : null;
  const pulse = q.get("pulse");
  if (pulse && pulse.includes(":")) {
    const at = pulse.lastIndexOf(":");
    state.file = pulse.slice(0, at);
    state.pulse = Number(pulse.slice(at + 1));
  }
}

function writeUrl() {
  const q = new URLSearchParams();
  if (state.run !== null) q.set("run", state.run);
  if (state.pulse !== null) q.set("pulse", `${state.file}:${state.pulse}`);
  q.set("colour", state.colour);
  if (state.box) q.set("box", state.box.map((v) => v.toFixed(2)).join(","));
  q.set("tab", state.tab);
  history.replaceState(null, "", "?" + q.toString());
}

// ---------------------------------------------------------------- catalog: runs and inputs

let polling = null;

async function loadCatalog() {
  const catalog = await api("/api/catalog");
  const runs = $("runs");
  runs.innerHTML = "";
  for (const run of catalog.runs) {
    const li = document.createElement("li");
    li.dataset.run = run.id;
    li.className = "run" + (run.id === state.run ? " active" : "");
    const c = run.counts || {};
    li.innerHTML = `<b></b><small></small>`;
    li.querySelector("b").textContent = run.inputs.join(", ") || run.name;
    li.querySelector("small").textContent =
      `${run.name} · ${c.pulses_read ?? "?"} pulses · ${c.echoes_kept ?? "?"} echoes kept · ${run.optimizer}`;
    li.onclick = () => pickRun(run.id);
    runs.appendChild(li);
  }
  if (!catalog.runs.length) runs.innerHTML = "<li><small>no run yet: decompose an input below</small></li>";
  const inputs = $("inputs");
  inputs.innerHTML = "";
  let running = false;
  for (const input of catalog.inputs) {
    const li = document.createElement("li");
    li.className = "input";
    li.innerHTML = `<b></b><small></small>`;
    li.querySelector("b").textContent = input.name;
    const job = input.job;
    if (job && job.status === "running") {
      running = true;
      li.querySelector("small").textContent = `decomposing: ${job.pulses_done} of ${job.pulses} pulses, ${job.seconds} s`;
      li.insertAdjacentHTML("beforeend", `<div class="progress"><div style="width:${Math.round(100 * job.progress)}%"></div></div>`);
    } else if (input.run) {
      li.querySelector("small").textContent = "has a run: click to show it";
      li.onclick = () => pickRun(input.run);
    } else {
      li.querySelector("small").textContent = job && job.status === "failed" ? `failed: ${job.message}` : "no run yet";
      const button = document.createElement("button");
      button.textContent = "decompose";
      button.onclick = async (event) => {
        event.stopPropagation();
        try { await api("/api/decompose", { input: input.id }); } catch (e) { say(e.message); }
        loadCatalog();
      };
      li.appendChild(button);
    }
    inputs.appendChild(li);
  }
  clearTimeout(polling);
  if (running) polling = setTimeout(loadCatalog, 1500);
  fillTryForm(catalog);
  return catalog;
}

function fillTryForm(catalog) {
  const form = $("try-form");
  for (const [name, values] of [["preset", catalog.presets], ["optimizer", catalog.optimizers]]) {
    const select = form.elements[name];
    if (select.options.length > 1) continue;
    for (const v of values) select.add(new Option(v, v));
  }
}

async function pickRun(id) {
  if (id !== state.run) { state.file = null; state.pulse = null; state.box = null; }
  state.run = id;
  for (const li of document.querySelectorAll("#runs li")) li.classList.toggle("active", li.dataset.run === id);
  writeUrl();
  say("");
  summary = await api(`/api/summary?run=${encodeURIComponent(id)}`);
  const files = $("pulse-file");
  files.innerHTML = "";
  for (const f of summary.files) files.add(new Option(f, f));
  drawSummary();
  loadPulseList();
  await loadEchoes();
  if (state.pulse === null && summary.first_pulse) { state.file = summary.first_pulse[0]; state.pulse = summary.first_pulse[1]; }
  if (state.pulse !== null) await showPulse(state.file, state.pulse);
}

// ---------------------------------------------------------------- overview: map and 3D

function colourTitle() {
  return { height: "z (m)", amplitude: "amplitude (counts)", width: "FWHM (ps)", fit_error: "fit error",
    reflectance: "reflectance", range: "range (m)" }[state.colour];
}

function echoTraces(data, three) {
  const traces = [];
  for (const kept of [true, false]) {
    const idx = [];
    data.kept.forEach((k, i) => { if (k === kept) idx.push(i); });
    const pick = (a) => idx.map((i) => a[i]);
    const trace = {
      name: kept ? "kept echoes" : "spurious echoes", meta: kept ? "kept" : "spurious",
      x: pick(data.x), y: pick(data.y),
      customdata: idx.map((i) => [data.files[data.file[i]], data.pulse_id[i]]),
      hovertemplate: "pulse %{customdata[1]}<br>%{marker.color:.3g}<extra>%{fullData.name}</extra>",
      mode: "markers",
      marker: {
        color: pick(data.value), colorscale: "Viridis", size: three ? 2 : (kept ? 4 : 6),
        cmin: data.cmin, cmax: data.cmax,
        symbol: kept ? "circle" : (three ? "diamond-open" : "x"),
        showscale: kept, colorbar: kept ? { title: { text: colourTitle() }, thickness: 12 } : undefined,
        opacity: kept ? 0.9 : 0.8,
      },
    };
    if (three) { trace.type = "scatter3d"; trace.z = pick(data.z); } else trace.type = WEBGL ? "scattergl" : "scatter";
    traces.push(trace);
  }
  return traces;
}

function finiteRange(values) {
  let lo = Infinity, hi = -Infinity;
  for (const v of values) if (v !== null && isFinite(v)) { if (v < lo) lo = v; if (v > hi) hi = v; }
  return lo <= hi ? [lo, hi] : [0, 1];
}

let echoRequests = 0;
async function loadEchoes() {
  if (!state.run) return;
  const mine = ++echoRequests;
  const kept = $("kept-only").checked ? 1 : 0;
  const box = state.box ? `&box=${state.box.join(",")}` : "";
  const base = `/api/echoes?run=${encodeURIComponent(state.run)}&colour=${state.colour}&kept=${kept}`;
  const [map, scene] = await Promise.all([api(`${base}${box}&limit=${MAP_LIMIT}`), api(`${base}${box}&limit=${SCENE_LIMIT}`)]);
  const returns = $("show-returns").checked
    ? await api(`/api/returns?run=${encodeURIComponent(state.run)}${box}&limit=${MAP_LIMIT}`) : null;
  if (mine !== echoRequests) return;  // the view moved on meanwhile
  for (const data of [map, scene]) [data.cmin, data.cmax] = finiteRange(data.value);
  $("map-count").textContent = `${map.x.length} of ${map.total} echoes in view`;
  $("scene-count").textContent = `${scene.x.length} of ${scene.total}`;
  const mapTraces = echoTraces(map, false);
  const sceneTraces = echoTraces(scene, true);
  if (returns) {  // drawn last, over the echoes
    mapTraces.push({ type: WEBGL ? "scattergl" : "scatter", mode: "markers", name: "system returns", meta: "returns",
      x: returns.x, y: returns.y, hoverinfo: "skip", marker: { color: "rgba(230,80,40,0.45)", size: 6, symbol: "circle-open" } });
    sceneTraces.push({ type: "scatter3d", mode: "markers", name: "system returns", meta: "returns", hoverinfo: "skip",
      x: returns.x, y: returns.y, z: returns.z, marker: { color: "rgba(230,80,40,0.35)", size: 1.5 } });
  }
  const legend = { orientation: "h", x: 0, y: -0.2, yanchor: "top" };
  const mapLayout = { margin: { l: 60, r: 10, t: 10, b: 70 }, legend, uirevision: state.run,
    xaxis: { title: { text: "x (m)" } }, yaxis: { title: { text: "y (m)" }, scaleanchor: "x" } };
  if (state.box) { mapLayout.xaxis.range = [state.box[0], state.box[1]]; mapLayout.yaxis.range = [state.box[2], state.box[3]]; }
  await Plotly.react("map", mapTraces, mapLayout, { responsive: true, displaylogo: false });
  await Plotly.react("scene", sceneTraces, { margin: { l: 0, r: 0, t: 0, b: 30 }, legend, uirevision: state.run,
    scene: { aspectmode: "data", xaxis: { title: { text: "x" } }, yaxis: { title: { text: "y" } }, zaxis: { title: { text: "z" } } } },
    { responsive: true, displaylogo: false });
  bindPlotEvents();
}

let bound = false;
function bindPlotEvents() {
  if (bound) return;
  bound = true;
  const onClick = (event) => {
    const p = event.points && event.points[0];
    if (p && p.customdata) showPulse(p.customdata[0], p.customdata[1]);
  };
  $("map").on("plotly_click", onClick);
  $("scene").on("plotly_click", onClick);
  let timer = null;
  $("map").on("plotly_relayout", (e) => {
    // a zoom or pan: ask again for the echoes in the new box, denser as it shrinks
    if (e["xaxis.autorange"]) state.box = null;
    else if (e["xaxis.range[0]"] !== undefined && e["yaxis.range[0]"] !== undefined)
      state.box = [e["xaxis.range[0]"], e["xaxis.range[1]"], e["yaxis.range[0]"], e["yaxis.range[1]"]];
    else return;
    clearTimeout(timer);
    writeUrl();
    timer = setTimeout(loadEchoes, 250);
  });
}

// ---------------------------------------------------------------- pulse list

async function loadPulseList() {
  if (!state.run) return;
  const data = await api(`/api/pulses?run=${encodeURIComponent(state.run)}&order=${$("pulse-order").value}&limit=40`);
  const list = $("pulses");
  list.innerHTML = "";
  for (const p of data.pulses) {
    const li = document.createElement("li");
    li.className = "pulse";
    li.dataset.file = p.source_file;
    li.dataset.pulse = p.pulse_id;
    li.innerHTML = "<b></b><small></small>";
    li.querySelector("b").textContent = `${p.pulse_id}`;
    li.querySelector("small").textContent =
      `${p.source_file} · ${p.n_echoes} echoes (${p.n_echoes_kept} kept) · R² ${fmt(p.r2, 3)}`;
    li.onclick = () => showPulse(p.source_file, p.pulse_id);
    list.appendChild(li);
  }
}

// ---------------------------------------------------------------- pulse view

const ECHO_COLOURS = ["#1f77b4", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#bcbd22", "#7f7f7f"];

function waveformTraces(fit, withRaw = true) {
  const ns = (a) => a.map((t) => t / NS);
  const traces = [];
  if (withRaw) traces.push({ type: "scatter", mode: "markers", name: "raw samples", meta: "raw", x: ns(fit.time_ps), y: fit.raw,
    marker: { color: "#888", size: 4 } });
  traces.push({ type: "scatter", mode: "lines", name: "denoised", meta: "denoised", x: ns(fit.time_ps), y: fit.denoised,
    line: { color: "#f0a030", width: 1.5 } });
  fit.echoes.forEach((e, k) => traces.push({
    type: "scatter", mode: "lines", meta: "component", x: ns(fit.fine_time_ps), y: e.curve,
    name: `echo ${k} ${e.kept ? "kept" : "spurious: " + e.reject_reason}`,
    line: { color: e.kept ? ECHO_COLOURS[k % ECHO_COLOURS.length] : "#d62728", width: 1.5, dash: e.kept ? "dash" : "dot" },
  }));
  traces.push({ type: "scatter", mode: "lines", name: "model", meta: "model", x: ns(fit.fine_time_ps), y: fit.model,
    line: { color: "#111", width: 2 } });
  if (fit.response) traces.push({ type: "scatter", mode: "lines", name: `system response (${fit.response.source})`,
    meta: "response", x: ns(fit.response.time_ps), y: fit.response.counts, visible: "legendonly",
    line: { color: "#666", width: 1, dash: "dot" } });
  return traces;
}

function returnShapes(returns) {
  return returns.map((r) => ({ type: "line", xref: "x", yref: "paper", x0: r.time_ps / NS, x1: r.time_ps / NS, y0: 0, y1: 1,
    line: { color: "rgba(230,80,40,0.8)", width: 1.5, dash: "dashdot" } }));
}

function returnAnnotations(returns) {
  return returns.map((r) => ({ x: r.time_ps / NS, y: 1, xref: "x", yref: "paper", text: `return ${r.return_number}`,
    showarrow: false, yanchor: "bottom", font: { size: 10, color: "#c05020" } }));
}

function signalRange(fit, returns) {
  // open on where the echoes and returns are (a double click shows the whole waveform)
  const times = fit.echoes.filter((e) => e.kept).map((e) => e.time_ps).concat(returns.map((r) => r.time_ps));
  if (!times.length || !fit.time_ps.length) return undefined;
  const end = fit.time_ps[fit.time_ps.length - 1];
  const pad = Math.max(3 * (fit.config.system_pulse_fwhm_ps || 4000), 0.05 * end);
  return [Math.max(0, Math.min(...times) - pad) / NS, Math.min(end, Math.max(...times) + pad) / NS];
}

function waveformLayout(returns, fit) {
  return { margin: { l: 50, r: 10, t: 18, b: 40 },
    xaxis: { title: { text: "time (ns from the first sample)" }, range: signalRange(fit, returns) },
    yaxis: { title: { text: "counts" } },
    shapes: returnShapes(returns), annotations: returnAnnotations(returns), legend: { font: { size: 10 } } };
}

function metricsTable(fit, extra = []) {
  const rows = [["fit error (Eq. 9)", fit.fit_error], ["fit error vs raw", fit.fit_error_raw], ["RMSE", fit.rmse], ["R²", fit.r2],
    ["background", fit.background], ["noise σ", fit.noise_sigma], ["initial echoes", fit.n_echoes_initial],
    ["model evaluations", fit.model_evaluations], ...extra];
  return "<table>" + rows.map(([k, v]) => `<tr><td>${k}</td><td>${fmt(v)}</td></tr>`).join("") + "</table>";
}

// the run's rows carry radiometry (fwcore.radiometry); a refit's echoes do not, and show "–"
function echoTable(rows) {
  const relative = rows.some((e) => e.radiometry === "relative") ? " (relative)" : "";
  const head = "<tr><th>#</th><th>kept / reason</th><th>amplitude</th><th>time (ns)</th><th title=\"Chauve's sigma, in ps^(α²/2): its unit depends on α\">σ (Chauve)</th><th>α</th><th>FWHM (ps)</th><th>energy</th>" +
    `<th>range (m)</th><th>incidence (°)</th><th>reflectance${relative}</th></tr>`;
  return head + rows.map((e) => `<tr class="echo-row ${e.kept ? "kept" : "spurious"}"><td>${e.echo_index}</td>` +
    `<td>${e.kept ? "kept" : e.reject_reason}</td><td>${fmt(e.amplitude, 2)}</td><td>${fmt(e.time_ps / NS, 3)}</td>` +
    `<td>${fmt(e.sigma_chauve, 3)}</td><td>${fmt(e.alpha, 3)}</td><td>${fmt(e.fwhm_ps, 1)}</td><td>${fmt(e.energy, 1)}</td>` +
    `<td class="radiometry">${fmt(e.range_m, 3)}</td><td>${fmt(e.incidence_deg, 1)}</td><td>${fmt(e.reflectance, 3)}</td></tr>`).join("");
}

async function showPulse(file, pulse) {
  state.file = file; state.pulse = Number(pulse);
  writeUrl();
  $("pulse-id").value = state.pulse;
  $("pulse-file").value = file;
  for (const li of document.querySelectorAll("#pulses li")) li.classList.toggle("active", li.dataset.pulse === String(state.pulse) && li.dataset.file === file);
  $("pulse-title").textContent = `Pulse ${pulse} of ${file}: reading and decomposing…`;
  let data;
  try {
    data = await api(`/api/pulse?run=${encodeURIComponent(state.run)}&file=${encodeURIComponent(file)}&pulse=${pulse}`);
  } catch (e) { $("pulse-title").textContent = `Pulse ${pulse}: ${e.message}`; return; }
  if (data.pulse_id !== state.pulse || data.file !== state.file) return;  // a later click won
  const fit = data.fit;
  $("pulse-title").textContent = `Pulse ${data.pulse_id} of ${data.file}: ${data.echo_rows.length} echoes ` +
    `(${data.echo_rows.filter((e) => e.kept).length} kept), ${data.system_returns.length} system returns, ` +
    `${fit.config.optimizer} / ${fit.config.model}`;
  const plot = $("waveform");
  await Plotly.react(plot, waveformTraces(fit), waveformLayout(data.system_returns, fit), { responsive: true, displaylogo: false });
  plot.dataset.pulse = data.pulse_id;
  plot.dataset.file = data.file;
  plot.dataset.components = fit.echoes.length;
  $("pulse-metrics").innerHTML = metricsTable(fit, [["system pulse FWHM (ps)", fit.config.system_pulse_fwhm_ps]]) +
    (data.reproduced ? `<div class="ok">the refit reproduces the run's echoes</div>`
      : `<div class="bad">today's engine gives ${fit.echoes.length} echoes here; the run's table (below) holds ${data.echo_rows.length}</div>`);
  $("pulse-echoes").innerHTML = echoTable(data.echo_rows);
  $("pulse-returns").innerHTML = "<b>system returns</b> " + (data.system_returns.map((r) =>
    `#${r.return_number} at ${fmt(r.time_ps / NS, 3)} ns (intensity ${r.intensity})`).join(", ") || "none");
  if (state.tab === "try") runTry();
}

// ---------------------------------------------------------------- try

function tryBody() {
  const form = $("try-form");
  const changes = {};
  for (const name of ["optimizer", "model"]) if (form.elements[name].value) changes[name] = form.elements[name].value;
  for (const name of ["noise_threshold", "min_snr", "min_amplitude_ratio", "max_echoes", "generations"]) {
    const v = form.elements[name].value.trim();
    if (v !== "") changes[name] = Number(v);
  }
  if (form.elements.prune_echoes.checked) changes.prune_echoes = true;
  return { run: state.run, file: state.file, pulse: state.pulse, preset: form.elements.preset.value, changes };
}

let tries = 0;
async function runTry() {
  if (state.pulse === null) { $("try-status").textContent = "pick a pulse first"; return; }
  $("try-status").textContent = `refitting pulse ${state.pulse}…`;
  const mine = ++tries;
  let data;
  try { data = await api("/api/try", tryBody()); } catch (e) { if (mine === tries) $("try-status").textContent = e.message; return; }
  if (mine !== tries) return;  // a later refit was asked for: its answer is the one to show
  $("try-status").textContent = `pulse ${data.pulse_id}: changed ${Object.keys(data.changed).map((k) => `${k}=${data.changed[k]}`).join(", ") || "nothing"}`;
  for (const [side, fit] of [["a", data.a], ["b", data.b]]) {
    const kept = fit.echoes.filter((e) => e.kept).length;
    $(`try-${side}-title`).textContent = `${side === "a" ? "the run's" : "yours"}: ${fit.config.optimizer} / ${fit.config.model}, ` +
      `${fit.echoes.length} echoes (${kept} kept), R² ${fmt(fit.r2, 4)}`;
    await Plotly.react(`try-${side}`, waveformTraces(fit), waveformLayout(data.system_returns, data.a), { responsive: true, displaylogo: false });
    $(`try-${side}-metrics`).innerHTML = metricsTable(fit) + `<table>${echoTable(fit.echoes)}</table>`;
  }
}

// ---------------------------------------------------------------- summary

function keyValueRows(pairs) {
  return pairs.map(([k, v]) => `<tr><td>${k}</td><td>${fmt(v)}</td></tr>`).join("");
}

function histogram(div, series, title, xtitle) {
  const traces = series.map(([name, h, colour]) => ({
    type: "bar", name, x: h.edges.slice(0, -1).map((e, i) => (e + h.edges[i + 1]) / 2), y: h.counts,
    width: h.edges.length > 1 ? h.edges[1] - h.edges[0] : 1, marker: { color: colour }, opacity: 0.75 }));
  Plotly.react(div, traces, { title: { text: title, font: { size: 12 } }, barmode: "overlay", margin: { l: 45, r: 10, t: 30, b: 40 },
    xaxis: { title: { text: xtitle } }, yaxis: { title: { text: "count" } }, legend: { orientation: "h", y: -0.25 } },
    { responsive: true, displaylogo: false });
}

function drawSummary() {
  const s = summary, c = s.counts;
  $("counts").innerHTML = keyValueRows([["inputs", s.inputs.join(", ")], ["status", s.status], ["pulses read", c.pulses_read],
    ["decomposed", c.pulses_decomposed], ["rejected", c.pulses_rejected], ["files rejected", c.files_rejected],
    ["echoes kept", c.echoes_kept], ["echoes spurious", c.echoes_spurious], ["seconds", s.seconds]]) +
    `<tr><td colspan="2" class="${s.read_adds_up ? "ok" : "bad"}">read ${s.read_adds_up ? "=" : "≠"} decomposed + rejected</td></tr>`;
  $("config").innerHTML = keyValueRows(Object.entries(s.config));
  $("rejected-total").textContent = `(${s.rejected.total})`;
  $("rejected-reasons").innerHTML = "<tr><th>stage</th><th>reason</th><th>pulses</th></tr>" +
    s.rejected.reasons.map((r) => `<tr><td>${r.stage}</td><td>${r.reason}</td><td>${r.count}</td></tr>`).join("");
  $("rejected-rows").innerHTML = "<tr><th>file</th><th>pulse</th><th>stage</th><th>reason</th></tr>" +
    s.rejected.rows.map((r) => `<tr><td>${r.source_file}</td><td>${r.pulse_id}</td><td>${r.stage}</td><td>${r.reason}</td></tr>`).join("");
  const d = s.distributions;
  if (d.echoes_per_pulse) histogram("hist-echoes", [["all", d.echoes_per_pulse, "#7f9fc0"], ["kept", d.kept_echoes_per_pulse, "#2a7a2a"]],
    "echoes per pulse", "echoes");
  if (d.fit_error) histogram("hist-fit", [["pulses", d.fit_error, "#9467bd"]], "fit error per pulse", "fit error (Eq. 9)");
  if (d.amplitude_kept) histogram("hist-amplitude", [["kept", d.amplitude_kept, "#2a7a2a"], ["spurious", d.amplitude_spurious, "#d62728"]],
    "echo amplitude", "amplitude (counts)");
}

// ---------------------------------------------------------------- wiring

function showTab(tab) {
  state.tab = tab;
  for (const b of document.querySelectorAll("#tabs button")) b.classList.toggle("active", b.dataset.tab === tab);
  for (const s of document.querySelectorAll(".tab")) s.hidden = s.id !== `tab-${tab}`;
  writeUrl();
  window.dispatchEvent(new Event("resize"));  // plots drawn while hidden take their size now
  if (tab === "try" && state.pulse !== null) runTry();
}

async function start() {
  readUrl();
  $("colour").value = state.colour;
  for (const b of document.querySelectorAll("#tabs button")) b.onclick = () => showTab(b.dataset.tab);
  $("colour").onchange = () => { state.colour = $("colour").value; writeUrl(); loadEchoes(); };
  $("kept-only").onchange = loadEchoes;
  $("show-returns").onchange = loadEchoes;
  $("pulse-order").onchange = loadPulseList;
  $("pulse-form").onsubmit = (e) => { e.preventDefault(); showPulse($("pulse-file").value, Number($("pulse-id").value)); };
  $("try-form").onsubmit = (e) => { e.preventDefault(); runTry(); };
  showTab(state.tab);
  try {
    const catalog = await loadCatalog();
    const run = state.run && catalog.runs.some((r) => r.id === state.run) ? state.run : (catalog.runs[0] || {}).id;
    if (run !== undefined) await pickRun(run);
    document.body.dataset.ready = "1";
  } catch (e) { say(e.message); }
}

start();
