// fwl view: the page. State (run, pulse, colour, tab) lives in the URL; data comes from /api/*.
// Every value from a file, a configuration or a reason reaches the page as text (textContent, via el() and
// fillTable()), never as markup: a file may be named <img src=x onerror=...>.las.
"use strict";

const state = { run: null, file: null, pulse: null, colour: "height", tab: "explore", box: null, layer: null };
let summary = null;
let picked = null;  // the shown pulse's echoes in the map's frame, marked on the map
const WEBGL = (() => { try { return !!document.createElement("canvas").getContext("webgl"); } catch (e) { return false; } })();
const MAP_LIMIT = WEBGL ? 60000 : 8000;
const SCENE_LIMIT = 25000;
const $ = (id) => document.getElementById(id);
const NS = 1000;  // ps per ns: waveforms are drawn in ns
// this page's own id: a later refit from it cancels its refit still waiting on the server
const PAGE = Array.from({ length: 16 }, () => "abcdefghijklmnopqrstuvwxyz0123456789"[Math.floor(Math.random() * 36)]).join("");
const TOKEN = (() => {  // a viewer open to the network gives its token once, in the URL it prints
  const q = new URLSearchParams(location.search);
  const given = q.get("token");
  if (given) { sessionStorage.setItem("fwl-token", given); }
  return given || sessionStorage.getItem("fwl-token") || "";
})();
const SUPERSCRIPT = { "-": "⁻", 0: "⁰", 1: "¹", 2: "²", 3: "³", 4: "⁴", 5: "⁵", 6: "⁶", 7: "⁷", 8: "⁸", 9: "⁹" };

function fmt(v, digits = 3, unit = "") {
  if (v === null || v === undefined || (typeof v === "number" && !isFinite(v))) return "–";
  if (typeof v !== "number") return String(v);
  let text;
  if (Math.abs(v) >= 1e7 || (Math.abs(v) < 1e-3 && v !== 0)) {  // a power of ten a person reads, not 1.2e+4
    const [m, e] = v.toExponential(2).split("e");
    text = `${m}×10${String(Number(e)).split("").map((c) => SUPERSCRIPT[c]).join("")}`;
  } else if (Number.isInteger(v)) text = String(v);
  else text = v.toFixed(Math.abs(v) >= 1000 ? Math.min(digits, 1) : digits);
  return unit ? `${text} ${unit}` : text;
}

// an element with text (never markup) and attributes
function el(tag, text, attrs = {}) {
  const node = document.createElement(tag);
  if (text !== undefined && text !== null) node.textContent = String(text);
  for (const [k, v] of Object.entries(attrs)) if (v !== undefined && v !== null) node.setAttribute(k, v);
  return node;
}

// a table from a header and rows of cells: a cell is a value (shown as text) or {text, class, title}
function fillTable(table, head, rows, rowClass = () => null) {
  table.replaceChildren();
  if (head) table.appendChild(rowOf("th", head));
  rows.forEach((r, i) => { const tr = rowOf("td", r); const c = rowClass(i); if (c) tr.className = c; table.appendChild(tr); });
  return table;
}

function rowOf(tag, cells) {
  const tr = document.createElement("tr");
  for (const c of cells) {
    const cell = c !== null && typeof c === "object" ? c : { text: c };
    tr.appendChild(el(tag, cell.text, { class: cell.class, title: cell.title, colspan: cell.colspan }));
  }
  return tr;
}

async function api(path, body) {
  const headers = TOKEN ? { "X-Fwl-Token": TOKEN } : {};
  const response = await fetch(path, body === undefined ? { headers } :
    { method: "POST", headers: { ...headers, "Content-Type": "application/json" }, body: JSON.stringify(body) });
  let data;
  try { data = await response.json(); } catch (e) { data = {}; }
  if (!response.ok) { const err = new Error(data.error || response.statusText); err.status = response.status; throw err; }
  return data;
}

function say(text) { $("message").textContent = text || ""; }

// ---------------------------------------------------------------- URL state

// a pulse id stays its digits end to end: GEDI's shot numbers and LVIS's pulse ids lie beyond 2^53, where a
// JavaScript number is no longer exact (19640119700108618 would become ...616); BigInt checks it without rounding
const PULSE_ID = /^-?[0-9]{1,20}$/;
const INT64 = [-(2n ** 63n), 2n ** 63n - 1n];

// the id's canonical digits ("007" -> "7"), as the server answers them; null when it is no 64-bit whole number
function pulseText(text) {
  const digits = String(text ?? "").trim();
  if (!PULSE_ID.test(digits)) return null;
  const value = BigInt(digits);
  return value < INT64[0] || value > INT64[1] ? null : value.toString();
}

function readUrl() {
  const q = new URLSearchParams(location.search);
  state.run = q.get("run");
  state.colour = q.get("colour") || "height";
  state.tab = q.get("tab") || "explore";
  state.layer = q.get("layer");  // a grid's map under the echoes: JSON [grid, map, band]
  const box = (q.get("box") || "").split(",").map(Number);
  state.box = box.length === 4 && box.every(isFinite) ? box : null;
  const pulse = q.get("pulse");
  if (pulse && pulse.includes(":")) {
    const at = pulse.lastIndexOf(":");
    const id = pulse.slice(at + 1);
    if (pulseText(id) !== null) { state.file = pulse.slice(0, at); state.pulse = pulseText(id); }
    else $("pulse-error").textContent = `the URL's pulse ${JSON.stringify(id)} is no pulse id (a whole number)`;
  }
}

function writeUrl() {
  const q = new URLSearchParams();
  if (state.run !== null) q.set("run", state.run);
  if (state.pulse !== null) q.set("pulse", `${state.file}:${state.pulse}`);
  q.set("colour", state.colour);
  if (state.box) q.set("box", state.box.map((v) => v.toFixed(2)).join(","));
  if (state.layer) q.set("layer", state.layer);
  q.set("tab", state.tab);
  history.replaceState(null, "", "?" + q.toString());  // the token stays out of the URL once read
}

// ---------------------------------------------------------------- catalog: runs and inputs

let polling = null;

function listItem(title, detail, className) {
  const li = el("li", null, { class: className });
  li.append(el("b", title), el("small", detail));
  return li;
}

async function loadCatalog() {
  const catalog = await api("/api/catalog");
  const runs = $("runs");
  runs.replaceChildren();
  for (const run of catalog.runs) {
    const c = run.counts || {};
    const li = listItem(run.inputs.join(", ") || run.name,
      `${run.name} · ${c.pulses_read ?? "?"} pulses · ${c.echoes_kept ?? "?"} echoes kept · ${run.optimizer}`,
      "run" + (run.id === state.run ? " active" : ""));
    li.dataset.run = run.id;
    li.onclick = () => pickRun(run.id).catch((e) => say(e.message));
    runs.appendChild(li);
  }
  if (!catalog.runs.length) runs.appendChild(el("li")).appendChild(el("small", "no run yet: decompose an input below"));
  const inputs = $("inputs");
  inputs.replaceChildren();
  let running = false;
  for (const input of catalog.inputs) {
    const job = input.job;
    const li = listItem(input.name, "", "input");
    const small = li.querySelector("small");
    if (job && job.status === "running") {
      running = true;
      small.textContent = `decomposing: ${job.pulses_done} of ${job.pulses} pulses, ${job.seconds} s`;
      const bar = li.appendChild(el("div", null, { class: "progress" })).appendChild(el("div"));
      bar.style.width = `${Math.round(100 * job.progress)}%`;
    } else if (input.run) {
      small.textContent = "has a run: click to show it";
      li.onclick = () => pickRun(input.run).catch((e) => say(e.message));
    } else {
      small.textContent = job && job.status === "failed" ? `failed: ${job.message}` : "no run yet";
      const button = li.appendChild(el("button", "decompose"));
      button.onclick = async (event) => {
        event.stopPropagation();
        try { await api("/api/decompose", { input: input.id }); } catch (e) { small.textContent = e.message; return; }
        loadCatalog().catch((e) => say(e.message));
      };
    }
    inputs.appendChild(li);
  }
  for (const item of catalog.unavailable || []) {  // listed with the reason; the rest of the page works
    inputs.appendChild(listItem(item.name, `unavailable: ${item.reason}`, "input unavailable"));
  }
  clearTimeout(polling);
  if (running) polling = setTimeout(() => loadCatalog().catch((e) => say(e.message)), 1500);
  fillTryForm(catalog);
  return catalog;
}

function fillTryForm(catalog) {
  const form = $("try-form");
  for (const [name, values] of [["preset", catalog.presets], ["optimizer", catalog.optimizers], ["model", catalog.models]]) {
    const select = form.elements[name];
    if (select.options.length > 1) continue;
    for (const v of values) select.add(new Option(v, v));
  }
}

async function pickRun(id) {
  if (id !== state.run) { state.file = null; state.pulse = null; state.box = null; state.layer = null; picked = null; }
  state.run = id;
  for (const li of document.querySelectorAll("#runs li")) li.classList.toggle("active", li.dataset.run === id);
  writeUrl();
  say("");
  summary = await api(`/api/summary?run=${encodeURIComponent(id)}`);
  const files = $("pulse-file");
  files.replaceChildren();
  for (const f of summary.files) files.add(new Option(f, f));
  offerColours();
  drawSummary();
  loadPulseList().catch((e) => say(e.message));
  loadGrids().catch((e) => { $("grid-note").textContent = e.message; });
  await loadEchoes();
  if (state.pulse === null && summary.first_pulse) { state.file = summary.first_pulse[0]; state.pulse = summary.first_pulse[1]; }
  if (state.pulse !== null) await showPulse(state.file, state.pulse);
}

// colour modes the run has a column for; the others greyed, with the reason as their tooltip
function offerColours() {
  const colours = summary.colours || {};
  for (const option of $("colour").options) {
    const why = colours[option.value];
    option.disabled = !!why;
    option.title = why || "";
    option.textContent = option.dataset.label + (why ? " ✗" : "");  // the reason: its tooltip and the note
  }
  $("colour-note").textContent = colours[state.colour] ? `${state.colour}: ${colours[state.colour]}` : "";
}

// ---------------------------------------------------------------- overview: map and 3D

const COLOUR_TITLES = { height: "height", amplitude: "amplitude (DN)", width: "FWHM (ns)", fit_error: "fit error",
  reflectance: "reflectance", range: "range (m)" };

function colourTitle(data) {
  if (state.colour === "height") return (data.frame && data.frame.labels[2]) || "z (m)";
  return COLOUR_TITLES[state.colour];
}

function echoTraces(data, three) {
  const traces = [];
  const lo = data.cmin, hi = data.cmax;
  for (const kept of [true, false]) {
    const idx = [];
    data.kept.forEach((k, i) => { if (k === kept) idx.push(i); });
    const pick = (a) => idx.map((i) => a[i]);
    // beyond the 2nd-98th percentile: a triangle pointing the way the value lies
    const outlier = (v) => v === null ? "none" : v > hi ? "above" : v < lo ? "below" : "";
    const shape = { above: three ? "diamond" : "triangle-up", below: three ? "square" : "triangle-down",
      none: three ? "circle-open" : "circle-open", "": "circle" };
    const trace = {
      name: kept ? "kept echoes" : "spurious echoes", meta: kept ? "kept" : "spurious",
      x: pick(data.x), y: pick(data.y),
      customdata: idx.map((i) => [data.files[data.file[i]], data.pulse_id[i]]),
      hovertemplate: `pulse %{customdata[1]}<br>%{marker.color:.4g} ${data.unit || ""}<extra>%{fullData.name}</extra>`,
      mode: "markers",
      marker: {
        color: pick(data.value).map((v) => v === null ? (lo ?? 0) : v), colorscale: "Viridis",
        size: three ? 2 : (kept ? 4 : 6), cmin: lo ?? 0, cmax: hi ?? 1,
        symbol: kept ? pick(data.value).map((v) => shape[outlier(v)]) : (three ? "diamond-open" : "x"),
        showscale: kept && lo !== null,
        colorbar: kept ? { title: { text: `${colourTitle(data)}<br>2nd–98th pct`, side: "right" }, thickness: 12,
          len: 0.8 } : undefined,
        opacity: kept ? 0.9 : 0.8,
      },
    };
    if (three) { trace.type = "scatter3d"; trace.z = pick(data.z); trace.marker.symbol = "circle"; }
    else trace.type = WEBGL ? "scattergl" : "scatter";
    traces.push(trace);
  }
  return traces;
}

function pickedTrace(three) {
  if (!picked) return [];
  const t = { mode: "markers", name: `pulse ${state.pulse}`, meta: "picked", hoverinfo: "skip",
    x: picked.x, y: picked.y, marker: { color: "#e02020", size: 16, symbol: "circle-open", line: { width: 3 } } };
  if (three) { t.type = "scatter3d"; t.z = picked.z; t.marker = { color: "#e02020", size: 5, symbol: "diamond" }; }
  else t.type = WEBGL ? "scattergl" : "scatter";  // one kind of trace: an SVG layer over WebGL takes the clicks
  return [t];
}

function span(values) {
  let lo = Infinity, hi = -Infinity;
  for (const v of values) { if (v < lo) lo = v; if (v > hi) hi = v; }
  return [lo, hi];
}

// tick labels with as many decimals as the view's span needs (whole metres over a field, centimetres over a
// tree): never "41, 41, 41"
function tickFormat([lo, hi]) {
  const width = hi - lo;
  if (!(width > 0) || !isFinite(width)) return ",.0f";
  return `,.${Math.min(6, Math.max(0, Math.ceil(1 - Math.log10(width))))}f`;
}

// the 3D view in true proportions (metres on every axis), unless the run is far wider than tall (a GEDI track
// kilometres long and 40 m high would be a flat sheet): then heights stretched until they span a quarter of the
// width, and the title says by how much
function sceneAspect(scene) {
  const [x, y, z] = [span(scene.x), span(scene.y), span(scene.z)].map(([lo, hi]) => hi - lo);
  const wide = Math.max(x, y);
  if (!(z > 0) || !(wide > 0) || z >= wide / 8) return { layout: { aspectmode: "data" }, exaggeration: 1 };
  return { layout: { aspectmode: "manual", aspectratio: { x: x / wide, y: y / wide, z: 0.25 } },
    exaggeration: wide / 4 / z };
}

// a 3D axis has no room for where its origin is: the map says it
function short(title) { return { text: title.text.replace(" from the run's centre", "") }; }

function axisTitles(frame) {
  const labels = (frame && frame.labels) || ["x", "y", "z"];
  return labels.map((l) => ({ text: l }));
}

let echoRequests = 0;
let lastEchoes = null;
async function loadEchoes() {
  if (!state.run) return;
  const mine = ++echoRequests;
  const kept = $("kept-only").checked ? 1 : 0;
  const box = state.box ? `&box=${state.box.join(",")}` : "";
  const base = `/api/echoes?run=${encodeURIComponent(state.run)}&colour=${encodeURIComponent(state.colour)}&kept=${kept}`;
  let map, scene, returns;
  try {
    [map, scene] = await Promise.all([api(`${base}${box}&limit=${MAP_LIMIT}`), api(`${base}${box}&limit=${SCENE_LIMIT}`)]);
    returns = $("show-returns").checked
      ? await api(`/api/returns?run=${encodeURIComponent(state.run)}${box}&limit=${MAP_LIMIT}`) : null;
  } catch (e) { $("colour-note").textContent = e.message; return; }
  if (mine !== echoRequests) return;  // the view moved on meanwhile
  lastEchoes = { map, scene, returns };
  $("colour-note").textContent = map.unavailable ? `${state.colour}: ${map.unavailable}` :
    (map.below + map.above ? `${map.below} below and ${map.above} above the 2nd–98th percentile (triangles)` : "");
  $("map-count").textContent = `${map.x.length} of ${map.total} echoes in view`;
  await drawOverview();
}

async function drawOverview() {
  if (!lastEchoes) return;
  const { map, scene, returns } = lastEchoes;
  const mapTraces = echoTraces(map, false);
  const sceneTraces = echoTraces(scene, true);
  if (returns) {  // drawn last, over the echoes
    mapTraces.push({ type: WEBGL ? "scattergl" : "scatter", mode: "markers", name: "system returns", meta: "returns",
      x: returns.x, y: returns.y, hoverinfo: "skip", marker: { color: "rgba(230,80,40,0.45)", size: 6, symbol: "circle-open" } });
    sceneTraces.push({ type: "scatter3d", mode: "markers", name: "system returns", meta: "returns", hoverinfo: "skip",
      x: returns.x, y: returns.y, z: returns.z, marker: { color: "rgba(230,80,40,0.35)", size: 1.5 } });
  }
  if (lastLayer) mapTraces.unshift(gridTrace(lastLayer));  // first: drawn under the echoes
  // each trace keyed by what it is, not its place: Plotly keeps a colour bar by the trace's uid, and a grid put
  // first took over the echoes' bar (its ticks left over it, the grid's own bar drawn off the page)
  for (const t of [...mapTraces, ...sceneTraces]) t.uid = t.meta;
  mapTraces.push(...pickedTrace(false));
  sceneTraces.push(...pickedTrace(true));
  const [tx, ty, tz] = axisTitles(map.frame);
  const legend = { orientation: "h", x: 0, y: -0.22, yanchor: "top", font: { size: 10 } };
  const [bx, by] = state.box ? [[state.box[0], state.box[1]], [state.box[2], state.box[3]]] : [span(map.x), span(map.y)];
  // with a grid's colour bar across the top, fixed margins that hold both bars: left to grow, Plotly's margins
  // chased the two bars until the map was a strip 60 px high with the grid out of sight
  const margin = lastLayer ? { l: 70, r: 100, t: 58, b: 100, autoexpand: false } : { l: 70, r: 10, t: 10, b: 80 };
  const mapLayout = { margin, legend: lastLayer ? { ...legend, y: -0.3 } : legend, uirevision: state.run,
    xaxis: { title: tx, tickformat: tickFormat(bx) }, yaxis: { title: ty, scaleanchor: "x", tickformat: tickFormat(by) } };
  if (state.box) { mapLayout.xaxis.range = [state.box[0], state.box[1]]; mapLayout.yaxis.range = [state.box[2], state.box[3]]; }
  // where a local frame's origin is, and the CRS it is made of, beside the panel's title (not under its toolbar)
  $("map-origin").textContent = map.frame && map.frame.centre ? `origin ${map.frame.centre}, ${map.frame.crs}` : "";
  await Plotly.react("map", mapTraces, mapLayout, { responsive: true, displaylogo: false });
  const aspect = sceneAspect(scene);
  $("scene-count").textContent = `${scene.x.length} of ${scene.total}` +
    (aspect.exaggeration > 1 ? ` · heights ×${fmt(aspect.exaggeration, 1)}` : "");
  await Plotly.react("scene", sceneTraces, { margin: { l: 0, r: 0, t: 0, b: 30 }, legend, uirevision: state.run,
    // the camera a little further out than Plotly's (1.25 each way): the axis titles stay inside the panel
    scene: { ...aspect.layout, camera: { eye: { x: 1.55, y: 1.55, z: 1.0 } }, xaxis: { title: short(tx) }, yaxis: { title: short(ty) },
      zaxis: { title: short(tz), nticks: 5 } } },  // a few height ticks: stretched or not, they crowd
    { responsive: true, displaylogo: false });
  bindPlotEvents();
}

// ---------------------------------------------------------------- grids: fwl grid's maps under the echoes

let lastLayer = null;  // the shown layer's cells, as /api/grid gives them
let layerRequests = 0;
let layerCoarse = false;  // the whole grid came in blocks: a zoom asks again for the cells of its box

async function loadGrids() {
  const select = $("grid-layer");
  select.replaceChildren(new Option("none", ""));
  lastLayer = null;
  layerCoarse = false;
  $("grid-note").textContent = "";
  const run = state.run;
  const data = await api(`/api/grids?run=${encodeURIComponent(run)}`);
  if (run !== state.run) return;
  for (const grid of data.grids) {
    const group = el("optgroup", null, { label: `${grid.name}: ${grid.cell || `${fmt(grid.cell_m)} m`} cells` });
    for (const layer of grid.layers) {
      const option = new Option(layer.label, JSON.stringify([grid.id, layer.map, layer.band]));
      if (grid.unavailable) { option.disabled = true; option.title = grid.unavailable; }
      group.appendChild(option);
    }
    select.appendChild(group);
  }
  if (!data.grids.length) {
    select.disabled = true;
    select.title = "this run has no grid: fwl grid RUN_DIR --cell 2 writes one into the run's grid/ folder";
  } else select.disabled = false;
  const unavailable = data.grids.find((g) => g.unavailable);
  if (unavailable) $("grid-note").textContent = unavailable.unavailable;
  try { state.layer = state.layer && JSON.stringify(JSON.parse(state.layer)); } catch (e) { state.layer = null; }
  const wanted = [...select.options].find((o) => o.value === state.layer && !o.disabled);
  select.value = wanted ? state.layer : "";
  if (state.layer && !wanted) { state.layer = null; writeUrl(); }
  if (wanted) await loadLayer();
}

async function loadLayer() {
  const mine = ++layerRequests;
  if (!state.layer) { lastLayer = null; $("grid-note").textContent = ""; return drawOverview(); }
  const [grid, map, band] = JSON.parse(state.layer);
  const box = layerCoarse && state.box ? `&box=${state.box.join(",")}` : "";
  $("grid-note").textContent = "reading the grid…";
  let layer;
  try {
    layer = await api(`/api/grid?run=${encodeURIComponent(state.run)}&grid=${encodeURIComponent(grid)}` +
      `&map=${encodeURIComponent(map)}&band=${encodeURIComponent(band)}${box}`);
  } catch (e) { if (mine === layerRequests) $("grid-note").textContent = e.message; return; }
  if (mine !== layerRequests) return;  // another layer was picked meanwhile
  if (!box && layer.block > 1) { layerCoarse = true; if (state.box) return loadLayer(); }
  lastLayer = layer;
  $("grid-note").textContent = `${layer.cells_with_values} cells with values` + (layer.block > 1 ?
    `; shown in blocks of ${layer.block} × ${layer.block} cells (${fmt(layer.shown_cell_m)} m: their ${layer.how})` : "");
  await drawOverview();
}

function gridTrace(layer) {
  const unit = layer.unit ? ` (${layer.unit})` : "";
  return { type: "heatmap", name: layer.label, meta: "grid", x0: layer.x0, dx: layer.dx, y0: layer.y0, dy: layer.dy,
    // greys from light (low) to dark (high): the echoes' colours (dark low, yellow high) stay readable over them
    z: layer.z, zmin: layer.cmin ?? 0, zmax: layer.cmax ?? 1, colorscale: [[0, "#f4f4f4"], [1, "#5a5a5a"]],
    hoverongaps: false, hovertemplate: `%{z:.4g}${layer.unit ? " " + layer.unit : ""}<extra>grid</extra>`,
    // across the top: the echoes' colour bar keeps the right side
    colorbar: { title: { text: `grid: ${layer.label}${unit}, 2nd–98th pct`, side: "top" }, orientation: "h",
      thickness: 10, len: 0.6, x: 0, xanchor: "left", y: 1.01, yanchor: "bottom", ypad: 0 } };  // left: the toolbar is right
}

let bound = false;
function bindPlotEvents() {
  if (bound) return;
  bound = true;
  const onClick = (event) => {
    const p = (event.points || []).find((q) => q.customdata);  // an echo, not a mark over it
    if (p) showPulse(p.customdata[0], p.customdata[1]);
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
    timer = setTimeout(() => {
      loadEchoes();
      if (lastLayer && layerCoarse) loadLayer().catch((e) => say(e.message));  // the box's cells, finer
    }, 250);
  });
}

// ---------------------------------------------------------------- pulse list

async function loadPulseList() {
  if (!state.run) return;
  const data = await api(`/api/pulses?run=${encodeURIComponent(state.run)}&order=${encodeURIComponent($("pulse-order").value)}&limit=40`);
  const list = $("pulses");
  list.replaceChildren();
  for (const p of data.pulses) {
    const li = listItem(`${p.pulse_id}`, `${p.source_file} · ${p.n_echoes} echoes (${p.n_echoes_kept} kept) · R² ${fmt(p.r2, 3)}`, "pulse");
    li.dataset.file = p.source_file;
    li.dataset.pulse = p.pulse_id;
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
    name: `echo ${k}${e.kept ? "" : " ✗"}`, hovertext: e.kept ? "kept" : `spurious: ${e.reject_reason}`,
    line: { color: e.kept ? ECHO_COLOURS[k % ECHO_COLOURS.length] : "#d62728", width: 1.5, dash: e.kept ? "dash" : "dot" },
  }));
  traces.push({ type: "scatter", mode: "lines", name: "model", meta: "model", x: ns(fit.fine_time_ps), y: fit.model,
    line: { color: "#111", width: 2 } });
  if (fit.response) traces.push({ type: "scatter", mode: "lines", name: "system response",
    meta: "response", x: ns(fit.response.time_ps), y: fit.response.counts, visible: "legendonly",
    hovertext: fit.response.source, line: { color: "#666", width: 1, dash: "dot" } });
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
  const pad = Math.max(3 * (fit.pulse.fwhm_ps || 4000), 0.05 * end);
  return [Math.max(0, Math.min(...times) - pad) / NS, Math.min(end, Math.max(...times) + pad) / NS];
}

// the pulse's ground (its lowest mode) and RH25/50/75/98, where the run measured them (fwcore.metrics)
function forestShapes(forest) {
  if (!forest) return [];
  const line = (t, color, dash) => ({ type: "line", xref: "x", yref: "paper", x0: t / NS, x1: t / NS, y0: 0, y1: 1,
    line: { color, width: 1.5, dash } });
  return [line(forest.ground_time_ps, "#7a4a10", "solid"),
    ...forest.rh.map((r) => line(r.time_ps, "rgba(40,130,60,0.8)", "dot"))];
}

function forestAnnotations(forest) {
  if (!forest) return [];
  const note = (t, text, color) => ({ x: t / NS, y: 0.02, xref: "x", yref: "paper", text, showarrow: false,
    textangle: -90, xanchor: "right", font: { size: 10, color } });
  return [note(forest.ground_time_ps, "ground", "#7a4a10"),
    ...forest.rh.map((r) => note(r.time_ps, `RH${r.k} ${r.height_m.toFixed(2)} m`, "#287c3c"))];
}

function waveformLayout(returns, fit, forest = null) {
  // the legend below the plot, in rows: the plot keeps its width
  return { margin: { l: 55, r: 10, t: 18, b: 95 },
    xaxis: { title: { text: "time (ns from the first sample)" }, range: signalRange(fit, returns) },
    yaxis: { title: { text: "amplitude (DN)" } },
    shapes: [...returnShapes(returns), ...forestShapes(forest)],
    annotations: [...returnAnnotations(returns), ...forestAnnotations(forest)],
    legend: { orientation: "h", x: 0, y: -0.2, yanchor: "top", font: { size: 10 } } };
}

// y of a curve at time t (ps), linear between its samples
function curveAt(times, values, t) {
  let i = 1;
  while (i < times.length - 1 && times[i] < t) i++;
  const w = (t - times[i - 1]) / (times[i] - times[i - 1]);
  return values[i - 1] + Math.min(1, Math.max(0, w)) * (values[i] - values[i - 1]);
}

// the waveform's detected modes (the run's mode_z) on its denoised curve: the ground and those above it, and the
// ones below it that the selected L2A algorithm passed over
function modeTraces(fit, forest) {
  if (!forest || !forest.modes || !forest.modes.length || fit.time_ps.length < 2) return [];
  const traces = [];
  for (const passed of [false, true]) {
    const modes = forest.modes.filter((m) => m.passed_over === passed);
    if (!modes.length) continue;
    traces.push({ type: "scatter", mode: "markers", meta: passed ? "passed-over" : "modes",
      name: passed ? "passed-over modes (below the ground)" : "modes (the ground and above)",
      x: modes.map((m) => m.time_ps / NS), y: modes.map((m) => curveAt(fit.time_ps, fit.denoised, m.time_ps)),
      customdata: modes.map((m) => m.z), hovertemplate: "mode at %{customdata:.2f} m<extra>%{fullData.name}</extra>",
      marker: passed ? { color: "#d62728", size: 11, symbol: "x-thin-open", line: { width: 2.5, color: "#d62728" } }
        : { color: "#7a4a10", size: 9, symbol: "triangle-down" } });
  }
  return traces;
}

// what the products say of the shot (GEDI L2A's algorithm, L4A's biomass, LVIS's LFID and shot number), as
// far as the run wrote their columns
function shotTable(shot, forest) {
  const rows = [];
  if ("shot_number" in shot) rows.push(["shot number", shot.shot_number ?? "–"]);
  if ("lfid" in shot) rows.push(["LFID", shot.lfid ?? "–"]);
  if ("selected_algorithm" in shot) rows.push(["L2A algorithm", shot.selected_algorithm === null ? "–" : `a${shot.selected_algorithm}`]);
  if (forest && forest.modes && forest.modes.length) {
    const passed = forest.modes.filter((m) => m.passed_over).length;
    rows.push(["modes", `${forest.modes.length}, ${passed} passed over (below the ground)`]);
  }
  if (forest) rows.push(["ground", fmt(forest.ground_z, 2, "m")]);
  if ("top_z" in shot) rows.push(["highest return", fmt(shot.top_z, 2, "m")]);
  if ("agbd" in shot) {
    const se = shot.agbd_se === null || shot.agbd_se === undefined ? "" : ` ± ${fmt(shot.agbd_se, 1)}`;
    const text = shot.agbd === null ? `– ${shot.agbd_reason ? `(${shot.agbd_reason})` : ""}` :
      `${fmt(shot.agbd, 1)}${se} Mg/ha`;
    rows.push(["biomass (agbd)", { text, title: "aboveground biomass density, L4A's model of the shot's stratum" }]);
    if (shot.agbd_stratum) rows.push(["L4A stratum", shot.agbd_stratum]);
  }
  const table = fillTable(el("table", null, { id: "pulse-shot" }), null, rows);
  return table;
}

function metricsTable(table, fit, extra = []) {
  return fillTable(table, null, [["fit error (Eq. 9)", fmt(fit.fit_error)], ["fit error vs raw", fmt(fit.fit_error_raw)],
    ["RMSE", fmt(fit.rmse, 2, "DN")], ["R²", fmt(fit.r2, 4)], ["background", fmt(fit.background, 2, "DN")],
    ["noise σ", fmt(fit.noise_sigma, 2, "DN")], ["initial echoes", fmt(fit.n_echoes_initial)],
    ["model evaluations", fmt(fit.model_evaluations)], ...extra]);
}

// the run's rows carry radiometry (fwcore.radiometry.equations); a refit's echoes do not, and show "–"
function echoTable(table, rows) {
  const relative = rows.some((e) => e.radiometry === "relative") ? " (relative)" : "";
  const head = ["#", "kept / reason", "amplitude (DN)", "time (ns)",
    { text: "σ (Chauve)", title: "Chauve's sigma, in ps^(α²/2): its unit depends on α" }, "α", "FWHM (ns)",
    "energy (DN·ns)", "range (m)", "incidence (°)", `reflectance${relative}`];
  return fillTable(table, head, rows.map((e) => [e.echo_index, e.kept ? "kept" : e.reject_reason, fmt(e.amplitude, 2),
    fmt(e.time_ps / NS, 3), fmt(e.sigma_chauve, 3), fmt(e.alpha, 3), fmt(e.fwhm_ps / NS, 2),
    fmt(e.energy / NS, 1), { text: fmt(e.range_m, 3), class: "radiometry" }, fmt(e.incidence_deg, 1), fmt(e.reflectance, 3)]),
    (i) => `echo-row ${rows[i].kept ? "kept" : "spurious"}`);
}

function markPicked(data) {
  picked = data ? data.map : null;
  if (lastEchoes) drawOverview().catch((e) => say(e.message));
}

async function showPulse(file, typed) {
  const pulse = pulseText(typed);
  if (pulse === null) {  // said beside the box where it was typed; the shown pulse stays
    $("pulse-error").textContent = `${JSON.stringify(String(typed))} is no pulse id: type a whole number`;
    return;
  }
  $("pulse-error").textContent = "";
  state.file = file; state.pulse = pulse;
  writeUrl();
  $("pulse-id").value = state.pulse;
  $("pulse-file").value = file;
  for (const li of document.querySelectorAll("#pulses li")) li.classList.toggle("active", li.dataset.pulse === String(state.pulse) && li.dataset.file === file);
  $("pulse-title").textContent = `Pulse ${pulse} of ${file}: reading and decomposing…`;
  let data;
  try {
    data = await api(`/api/pulse?run=${encodeURIComponent(state.run)}&file=${encodeURIComponent(file)}&pulse=${encodeURIComponent(pulse)}&page=${PAGE}`);
  } catch (e) { if (e.status !== 409) $("pulse-title").textContent = `Pulse ${pulse}: ${e.message}`; return; }
  if (data.pulse_id !== state.pulse || data.file !== state.file) return;  // a later click won
  const fit = data.fit;
  $("pulse-title").textContent = `Pulse ${data.pulse_id} of ${data.file}: ${data.echo_rows.length} echoes ` +
    `(${data.echo_rows.filter((e) => e.kept).length} kept), ${data.system_returns.length} system returns, ` +
    `${fit.config.optimizer} / ${fit.config.model}`;
  const plot = $("waveform");
  await Plotly.react(plot, [...waveformTraces(fit), ...modeTraces(fit, data.forest)],
    waveformLayout(data.system_returns, fit, data.forest), { responsive: true, displaylogo: false });
  plot.dataset.pulse = data.pulse_id;
  plot.dataset.file = data.file;
  plot.dataset.components = fit.echoes.length;
  const metrics = $("pulse-metrics");
  metrics.replaceChildren(metricsTable(el("table"), fit, [["system pulse FWHM", fmt(fit.pulse.fwhm_ps / NS, 2, "ns")]]));
  metrics.appendChild(data.reproduced ? el("div", "the refit reproduces the run's echoes", { class: "ok" })
    : el("div", `today's engine gives ${fit.echoes.length} echoes here; the run's table (below) holds ${data.echo_rows.length}`, { class: "bad" }));
  if (data.shot) metrics.appendChild(shotTable(data.shot, data.forest));
  echoTable($("pulse-echoes"), data.echo_rows);
  $("pulse-returns").replaceChildren(el("b", "system returns "), document.createTextNode(data.system_returns.map((r) =>
    `#${r.return_number} at ${fmt(r.time_ps / NS, 3)} ns (intensity ${r.intensity} DN)`).join(", ") || "none"));
  markPicked(data);
  if (state.tab === "try") runTry();
}

// ---------------------------------------------------------------- try

const WHOLE = ["max_echoes", "generations", "population"];

// the form's settings, each checked where it was typed: a reason beside the form, nothing sent
function tryBody() {
  const form = $("try-form");
  const changes = {};
  for (const name of ["optimizer", "model"]) if (form.elements[name].value) changes[name] = form.elements[name].value;
  for (const name of ["noise_threshold", "min_snr", "min_amplitude_ratio", ...WHOLE]) {
    const input = form.elements[name];
    const v = input.value.trim();
    input.classList.remove("invalid");
    if (v === "") continue;
    const number = Number(v);
    if (!isFinite(number) || (WHOLE.includes(name) && !Number.isInteger(number))) {
      input.classList.add("invalid");
      throw new Error(`${name.replaceAll("_", " ")} must be ${WHOLE.includes(name) ? "a whole number" : "a number"}, not ${JSON.stringify(v)}`);
    }
    changes[name] = number;
  }
  return { run: state.run, file: state.file, pulse: state.pulse, preset: form.elements.preset.value, changes, page: PAGE };
}

let tries = 0;
async function runTry() {
  if (state.pulse === null) { $("try-status").textContent = "pick a pulse first"; return; }
  const mine = ++tries;
  let data;
  try {
    const body = tryBody();
    $("try-status").textContent = `refitting pulse ${state.pulse}…`;
    $("try-status").className = "";
    data = await api("/api/try", body);
  } catch (e) {
    if (mine === tries && e.status !== 409) { $("try-status").textContent = e.message; $("try-status").className = "bad"; }
    return;
  }
  if (mine !== tries) return;  // a later refit was asked for: its answer is the one to show
  $("try-status").textContent = `pulse ${data.pulse_id}: changed ${Object.keys(data.changed).map((k) => `${k}=${data.changed[k]}`).join(", ") || "nothing"}`;
  for (const [side, fit] of [["a", data.a], ["b", data.b]]) {
    const kept = fit.echoes.filter((e) => e.kept).length;
    $(`try-${side}-title`).textContent = `${side === "a" ? "the run's" : "yours"}: ${fit.config.optimizer} / ${fit.config.model}, ` +
      `${fit.echoes.length} echoes (${kept} kept), R² ${fmt(fit.r2, 4)}`;
    await Plotly.react(`try-${side}`, waveformTraces(fit), waveformLayout(data.system_returns, data.a), { responsive: true, displaylogo: false });
    $(`try-${side}-metrics`).replaceChildren(metricsTable(el("table"), fit), echoTable(el("table"), fit.echoes));
  }
}

// ---------------------------------------------------------------- summary

function keyValueRows(table, pairs) {
  return fillTable(table, null, pairs.map(([k, v]) => [k, typeof v === "object" && v !== null ? JSON.stringify(v) : fmt(v)]));
}

function histogram(div, series, title, xtitle) {
  const traces = series.map(([name, h, colour]) => ({
    type: "bar", name, x: h.edges.slice(0, -1).map((e, i) => (e + h.edges[i + 1]) / 2), y: h.counts,
    width: h.edges.length > 1 ? h.edges[1] - h.edges[0] : 1, marker: { color: colour }, opacity: 0.75 }));
  // the title left and the toolbar hidden: nothing sits over the title
  Plotly.react(div, traces, { title: { text: title, font: { size: 12 }, x: 0.02, xanchor: "left", y: 0.97 },
    barmode: "overlay", margin: { l: 50, r: 10, t: 34, b: 40 },
    xaxis: { title: { text: xtitle } }, yaxis: { title: { text: "pulses" } }, legend: { orientation: "h", y: -0.3 } },
  { responsive: true, displaylogo: false, displayModeBar: false });
}

function drawSummary() {
  const s = summary, c = s.counts;
  keyValueRows($("counts"), [["inputs", s.inputs.join(", ")], ["status", s.status], ["pulses read", c.pulses_read],
    ["decomposed", c.pulses_decomposed], ["rejected", c.pulses_rejected], ["files rejected", c.files_rejected],
    ["echoes kept", c.echoes_kept], ["echoes spurious", c.echoes_spurious], ["seconds", s.seconds]]);
  $("counts").appendChild(rowOf("td", [{ text: `read ${s.read_adds_up ? "=" : "≠"} decomposed + rejected`, colspan: 2,
    class: s.read_adds_up ? "ok" : "bad" }]));
  keyValueRows($("config"), Object.entries(s.config));
  $("rejected-total").textContent = `(${s.rejected.total})`;
  fillTable($("rejected-reasons"), ["stage", "reason", "pulses"], s.rejected.reasons.map((r) => [r.stage, r.reason, r.count]));
  fillTable($("rejected-rows"), ["file", "pulse", "stage", "reason"],
    s.rejected.rows.map((r) => [r.source_file, r.pulse_id, r.stage, r.reason]));
  const d = s.distributions;
  if (d.echoes_per_pulse) histogram("hist-echoes", [["all", d.echoes_per_pulse, "#7f9fc0"], ["kept", d.kept_echoes_per_pulse, "#2a7a2a"]],
    "echoes per pulse", "echoes");
  if (d.fit_error) histogram("hist-fit", [["pulses", d.fit_error, "#9467bd"]], "fit error per pulse", "fit error (Eq. 9)");
  if (d.amplitude_kept) histogram("hist-amplitude", [["kept", d.amplitude_kept, "#2a7a2a"], ["spurious", d.amplitude_spurious, "#d62728"]],
    "echo amplitude", "amplitude (DN)");
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
  for (const option of $("colour").options) option.dataset.label = option.textContent;
  readUrl();
  if (![...$("colour").options].some((o) => o.value === state.colour)) {
    say(`colour ${JSON.stringify(state.colour)} is not one of the page's: height shown`);
    state.colour = "height";
  }
  $("colour").value = state.colour;
  for (const b of document.querySelectorAll("#tabs button")) b.onclick = () => showTab(b.dataset.tab);
  $("colour").onchange = () => { state.colour = $("colour").value; writeUrl(); loadEchoes(); };
  $("kept-only").onchange = loadEchoes;
  $("show-returns").onchange = loadEchoes;
  $("grid-layer").onchange = () => {
    state.layer = $("grid-layer").value || null;
    layerCoarse = false;
    writeUrl();
    loadLayer().catch((e) => say(e.message));
  };
  $("pulse-order").onchange = loadPulseList;
  $("pulse-form").onsubmit = (e) => { e.preventDefault(); showPulse($("pulse-file").value, $("pulse-id").value.trim()); };
  $("try-form").onsubmit = (e) => { e.preventDefault(); runTry(); };
  showTab(state.tab);
  try {
    const catalog = await loadCatalog();
    const run = state.run && catalog.runs.some((r) => r.id === state.run) ? state.run : (catalog.runs[0] || {}).id;
    if (run !== undefined) await pickRun(run);
  } catch (e) { say(e.message); } finally { document.body.dataset.ready = "1"; }
}

start();
