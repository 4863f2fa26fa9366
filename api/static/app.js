// The planners' page: plain DOM and SVG, no library, no build step. It talks only to this
// service's own API (same origin), so it works offline.
"use strict";

const $ = (sel, root = document) => root.querySelector(sel);
const SVG_NS = "http://www.w3.org/2000/svg";
const state = { rigs: [], uploadedRig: null, report: null, track: null, sort: { key: null, dir: 1 }, job: null, schema: null,
  scenes: { bundled: [], uploaded: [] }, outlines: {}, outline: null };

function el(tag, attrs = {}, ...children) {
  const node = tag.startsWith("svg:") ? document.createElementNS(SVG_NS, tag.slice(4)) : document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (v === null || v === undefined || v === false) continue;
    if (k === "text") node.textContent = v;
    else if (k === "style") node.style.cssText = v; // CSSOM: allowed by the page's CSP, an attribute is not
    else node.setAttribute(k, v === true ? "" : v);
  }
  for (const c of children) if (c !== null && c !== undefined) node.append(c);
  return node;
}

// The units a calibration engineer reads, as the command line shows them (excite.core.units):
// SI unit of the report → [factor, unit shown].
const DISPLAY_UNITS = {
  "rad": [180 / Math.PI, "deg"], "m": [100, "cm"], "s": [1000, "ms"],
  "rad/s": [180 / Math.PI, "deg/s"], "m/s^2": [1, "m/s²"], "1": [1, ""],
};

function shown(value, unit) {
  const [f, u] = DISPLAY_UNITS[unit] || [1, unit];
  return { value: value === null || value === undefined ? value : value * f, unit: u };
}

function fmt(x, digits = 3) {
  if (x === null || x === undefined) return "—";
  if (x === 0) return "0";
  const a = Math.abs(x);
  return a >= 1e4 || a < 1e-3 ? x.toExponential(digits - 1) : x.toPrecision(digits);
}

// ------------------------------------------------------------------------------------------
// Talking to the service: JSON in, JSON or problem+json out.

class Problem extends Error {
  constructor(body, status) {
    super(body.detail || `HTTP ${status}`);
    this.status = status;
    this.errors = body.errors || [];
  }
}

// The API key, when the server needs one: kept for this tab only (sessionStorage), sent as a
// header (never in a URL). Every request also says it comes from this page (X-Excite-Client),
// which a cross-site form cannot.
function authHeaders() {
  const key = sessionStorage.getItem("excite-key");
  return { "X-Excite-Client": "page", ...(key ? { "X-API-Key": key } : {}) };
}

async function authFetch(path, init = {}) {
  const r = await fetch(path, { ...init, headers: { ...(init.headers || {}), ...authHeaders() } });
  if (r.status === 401) $("#key-error").textContent = "this server needs a valid API key";
  else if (r.ok) $("#key-error").textContent = "";
  return r;
}

// A download with the key: fetched, then saved from a blob (a plain link would carry no header).
async function download(ev) {
  ev.preventDefault();
  const a = ev.currentTarget;
  const r = await authFetch(a.getAttribute("href"));
  if (!r.ok) return;
  const name = (r.headers.get("content-disposition") || "").match(/filename="([^"]+)"/);
  const url = URL.createObjectURL(await r.blob());
  const tmp = el("a", { href: url, download: name ? name[1] : "" });
  document.body.append(tmp);
  tmp.click();
  tmp.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10_000);
}

async function api(method, path, body) {
  const init = { method, headers: { Accept: "application/json" } };
  if (body !== undefined) {
    init.headers["Content-Type"] = "application/json";
    init.body = JSON.stringify(body);
  }
  const r = await authFetch(path, init);
  const type = r.headers.get("content-type") || "";
  const data = type.includes("json") ? await r.json() : await r.text();
  if (!r.ok) throw new Problem(typeof data === "object" ? data : { detail: String(data) }, r.status);
  return data;
}

// Show each of a problem's errors next to the field it names. An error element claims the
// fields listed in its data-field (a name or a dotted prefix: "route" takes "route.text").
function showProblem(form, problem, fallback) {
  clearErrors(form);
  const targets = [...document.querySelectorAll(".error[data-field]")].filter((e) => e.dataset.field);
  const errors = problem.errors && problem.errors.length ? problem.errors : [{ field: "", message: problem.message }];
  for (const err of errors) {
    const f = err.field || "";
    let best = null, bestLen = -1;
    for (const t of targets) {
      for (const name of t.dataset.field.split(" ")) {
        if ((f === name || f.startsWith(name + ".") || f.startsWith(name + "[")) && name.length > bestLen) {
          best = t; bestLen = name.length;
        }
      }
    }
    const target = best || fallback;
    target.textContent = (target.textContent ? target.textContent + " " : "") + (best ? err.message : `${f ? f + ": " : ""}${err.message}`);
    const input = target.id && document.querySelector(`[aria-describedby~="${target.id}"]`);
    if (input) input.setAttribute("aria-invalid", "true");
  }
}

function clearErrors(form) {
  for (const e of document.querySelectorAll(".error")) if (form.contains(e) || e.id === "rig-error") e.textContent = "";
  for (const i of document.querySelectorAll("[aria-invalid]")) i.removeAttribute("aria-invalid");
}

// ------------------------------------------------------------------------------------------
// Tabs

function selectTab(tab) {
  for (const t of document.querySelectorAll('[role="tab"]')) {
    const on = t === tab;
    t.setAttribute("aria-selected", String(on));
    t.tabIndex = on ? 0 : -1;
    document.getElementById(t.getAttribute("aria-controls")).hidden = !on;
  }
  if (tab.id === "tab-plan") loadSchema();
}

function initTabs() {
  const tabs = [...document.querySelectorAll('[role="tab"]')];
  tabs.forEach((t, i) => {
    t.addEventListener("click", () => selectTab(t));
    t.addEventListener("keydown", (ev) => {
      const d = ev.key === "ArrowRight" ? 1 : ev.key === "ArrowLeft" ? -1 : 0;
      if (!d) return;
      const next = tabs[(i + d + tabs.length) % tabs.length];
      selectTab(next);
      next.focus();
    });
  });
}

// ------------------------------------------------------------------------------------------
// Rig: a bundled one by name, or an uploaded YAML the service reads for us.

async function initRigs() {
  const select = $("#rig-select");
  const { rigs } = await api("GET", "/v1/rigs");
  state.rigs = rigs;
  select.replaceChildren(...rigs.map((r) => el("option", { value: r.name, text: `${r.name} — ${r.description}` })),
    el("option", { value: "@upload", text: "upload a rig YAML…" }));
  if (!state.rigsWired) {
    state.rigsWired = true;
    select.addEventListener("change", onRigChange);
    $("#rig-file").addEventListener("change", onRigFile);
  }
  onRigChange();
}

function onRigChange() {
  const upload = $("#rig-select").value === "@upload";
  $("#rig-upload").hidden = !upload;
  $("#rig-error").textContent = "";
  const rig = upload ? state.uploadedRig && state.uploadedRig.summary : state.rigs.find((r) => r.name === $("#rig-select").value);
  $("#rig-info").textContent = rig ? `${rig.parameters.length} parameters; measures: ${rig.measurements.map((m) => m.name).join(", ")}` : "choose a YAML file";
}

async function onRigFile() {
  const file = $("#rig-file").files[0];
  state.uploadedRig = null;
  if (!file) return onRigChange();
  try {
    state.uploadedRig = await api("POST", "/v1/rigs/parse", { yaml: await file.text() });
    onRigChange();
  } catch (err) {
    if (!(err instanceof Problem)) throw err;
    onRigChange();
    $("#rig-error").textContent = err.errors.map((e) => `${e.field}: ${e.message}`).join(" ") || err.message;
    $("#rig-file").setAttribute("aria-invalid", "true");
  }
}

function currentRig() {
  if ($("#rig-select").value !== "@upload") return $("#rig-select").value;
  if (!state.uploadedRig) throw new Problem({ errors: [{ field: "rig", message: "choose a rig YAML file first" }] }, 0);
  return state.uploadedRig.rig;
}

// ------------------------------------------------------------------------------------------
// Scene: a bundled one by name, or a file uploaded once (POST /v1/scenes) and named by its digest.

async function initScenes() {
  state.scenes = await api("GET", "/v1/scenes");
  fillScenes($("#scene-select").value);
  if (!state.scenesWired) {
    state.scenesWired = true;
    $("#scene-select").addEventListener("change", onSceneChange);
    $("#scene-file").addEventListener("change", onSceneFile);
  }
}

function fillScenes(selected) {
  const { bundled, uploaded } = state.scenes;
  const select = $("#scene-select");
  select.replaceChildren(el("option", { value: "", text: "none: scene-blind" }),
    ...bundled.map((n) => el("option", { value: n, text: `${n} (bundled)` })),
    ...uploaded.map((u) => el("option", { value: u.digest, text: `${u.name} (${u.digest.slice(0, 12)})` })),
    el("option", { value: "@upload", text: "upload a scene file…" }));
  select.value = [...select.options].some((o) => o.value === selected) ? selected : "";
  onSceneChange();
}

function onSceneChange() {
  $("#scene-upload").hidden = $("#scene-select").value !== "@upload";
  $("#scene-error").textContent = "";
}

async function onSceneFile() {
  const file = $("#scene-file").files[0];
  if (!file) return;
  const form = new FormData();
  form.append("file", file, file.name);
  $("#score-busy").textContent = "reading the scene…";
  try {
    const r = await authFetch("/v1/scenes", { method: "POST", body: form, headers: { Accept: "application/json" } });
    const data = (r.headers.get("content-type") || "").includes("json") ? await r.json() : { detail: await r.text() };
    if (!r.ok) throw new Problem(data, r.status);
    state.scenes.uploaded = [data, ...state.scenes.uploaded.filter((u) => u.digest !== data.digest)];
    fillScenes(data.digest);
  } catch (err) {
    if (!(err instanceof Problem)) throw err;
    showProblem($("#score-form"), err, $("#scene-error"));
  } finally {
    $("#score-busy").textContent = "";
  }
}

function currentScene() {
  const v = $("#scene-select").value;
  if (v === "@upload") throw new Problem({ errors: [{ field: "scene", message: "choose a scene file first" }] }, 0);
  return v || null;
}

// The scene's outline from above, fetched once per scene.
async function sceneOutline(ref) {
  if (!state.outlines[ref]) state.outlines[ref] = (await api("GET", `/v1/scenes/${encodeURIComponent(ref)}`)).outline;
  return state.outlines[ref];
}

// ------------------------------------------------------------------------------------------
// Score view

function detectFormat(name, text) {
  const lower = name.toLowerCase();
  if (lower.endsWith(".tum")) return "tum";
  if (lower.endsWith(".geojson") || lower.endsWith(".json")) return "geojson";
  const lines = text.split("\n").map((l) => l.trim()).filter((l) => l);
  const first = lines[0] || "";
  if (lower.endsWith(".csv")) {
    // as the service reads a CSV file: comments first (excite's control files open with two),
    // then the header or the first row decides
    const comments = lines.filter((l) => l.startsWith("#"));
    const row = lines.find((l) => !l.startsWith("#")) || "";
    if (comments.some((l) => /^#\s*timestamp/i.test(l)) || /p_RS_R/.test(row)) return "euroc";
    if (comments.some((l) => /^#\s*start:/i.test(l)) || /curvature/i.test(row)) return "control_csv";
    return "waypoints_csv";
  }
  const cols = first.trim().split(/\s+/).length;
  return cols === 12 ? "kitti" : "tum";
}

async function routeFromInputs() {
  const file = $("#route-file").files[0];
  if (!file) throw new Problem({ errors: [{ field: "route", message: "choose or drop a route file" }] }, 0);
  const text = await file.text();
  let format = $("#route-format").value || detectFormat(file.name, text);
  const route = { name: file.name.replace(/\.[^.]*$/, "").replace(/[^A-Za-z0-9_.-]/g, "_").replace(/^[.-]+/, "").slice(0, 64) || "route", format, text };
  if (format === "kitti") {
    const times = $("#times-file").files[0];
    if (!times) throw new Problem({ errors: [{ field: "route.times_text", message: "KITTI poses need their times file" }] }, 0);
    route.times_text = await times.text();
  }
  return route;
}

function isBag(file) {
  return !!file && /\.(bag|mcap)$/i.test(file.name);
}

function updateFormatFields() {
  const file = $("#route-file").files[0];
  const chosen = $("#route-format").value;
  const guess = file && /\.txt$/i.test(file.name) ? "kitti" : "";
  $("#times-field").hidden = (chosen || guess) !== "kitti";
  $("#topic-field").hidden = !isBag(file);
  $("#route-format").disabled = isBag(file);
}

// A bag (ROS 1 .bag or .mcap) is posted as it is, multipart, to /v1/score/bag; the service
// reads the poses of its topic (or TF chain /tf:PARENT.CHILD).
async function scoreBag(file) {
  const topic = $("#route-topic").value.trim();
  if (!topic) throw new Problem({ errors: [{ field: "topic", message: "name the pose topic or TF chain (/tf:odom.base_link)" }] }, 0);
  const form = new FormData();
  form.append("bag", file, file.name);
  form.append("topic", topic);
  const scene = currentScene();
  if (scene) form.append("scene", scene);
  const rig = currentRig();
  form.append("rig", typeof rig === "string" ? rig : JSON.stringify(rig));
  form.append("segments", String(Number($("#segments").value)));
  const r = await authFetch("/v1/score/bag", { method: "POST", body: form, headers: { Accept: "application/json" } });
  const data = (r.headers.get("content-type") || "").includes("json") ? await r.json() : { detail: await r.text() };
  if (!r.ok) throw new Problem(data, r.status);
  return data;
}

// One click: the bundled 90 s figure-eight (trajectories/figure_eight_control.csv, served with
// the page), scored with the chosen rig — what the page does before the visitor has a file.
async function onScoreReference() {
  const form = $("#score-form");
  clearErrors(form);
  $("#score-busy").textContent = "scoring the bundled figure-eight…";
  try {
    const text = await (await fetch("/static/figure_eight_control.csv")).text();
    const route = { name: "figure_eight_control", format: "control_csv", text };
    const scene = currentScene();
    await showReport(await api("POST", "/v1/score", { route, rig: currentRig(), segments: Number($("#segments").value), track_points: 1500,
      ...(scene ? { scene } : {}) }), scene);
  } catch (err) {
    if (!(err instanceof Problem)) throw err;
    showProblem(form, err, $("#score-error"));
  } finally {
    $("#score-busy").textContent = "";
  }
}

async function onScore(ev) {
  ev.preventDefault();
  const form = $("#score-form");
  clearErrors(form);
  const busy = $("#score-busy");
  $("#score-button").disabled = true;
  busy.textContent = "scoring…";
  try {
    const file = $("#route-file").files[0];
    const scene = currentScene();
    const report = isBag(file) ? await scoreBag(file)
      : await api("POST", "/v1/score", { route: await routeFromInputs(), rig: currentRig(), segments: Number($("#segments").value), track_points: 1500,
        ...(scene ? { scene } : {}) });
    await showReport(report, scene);
  } catch (err) {
    if (!(err instanceof Problem)) throw err;
    $("#score-result").hidden = true;
    showProblem(form, err, $("#score-error"));
  } finally {
    $("#score-button").disabled = false;
    busy.textContent = "";
  }
}

async function showReport(rep, scene) {
  state.report = rep;
  state.outline = null;
  if (scene && rep.track) {
    try {
      state.outline = await sceneOutline(scene);
    } catch (err) {
      if (!(err instanceof Problem)) throw err;
      $("#scene-error").textContent = `the scene's outline cannot be drawn: ${err.message}`;
    }
  }
  $("#score-result").hidden = false;
  const badge = el("span", { class: rep.passed ? "badge pass" : "badge fail", text: rep.passed ? "PASS" : "FAIL" });
  $("#summary").replaceChildren(
    el("div", { class: "big" }, el("span", { class: "label", text: "score " }), el("output", { id: "score-value", text: fmt(rep.score, 4) }), " ", badge),
    el("div", { class: "facts", text: `${rep.route} · rig ${rep.rig}` +
      (rep.scene ? ` · scene ${rep.scene.name} (sha256 ${rep.scene.digest.slice(0, 12)})` : "") +
      ` · ${rep.duration_s.toFixed(1)} s · ${rep.length_m.toFixed(0)} m · ` +
      `rank ${rep.rank} of ${rep.column_map.length}` + (rep.nullity ? ` (${rep.nullity} unobservable)` : "") +
      ` · score ≥ 1 means every σ within its target` }),
    ...(rep.warnings || []).map((w) => el("div", { class: "warning", role: "alert", text: `warning: ${w}` })));
  const names = rep.column_map.map((c) => c.name);
  $("#colour-by").replaceChildren(
    ...(rep.scene_track && rep.scene_track.length ? [el("option", { value: "@scene", text: "the lidar's information along its weakest direction (scene)" })] : []),
    el("option", { value: "@weak", text: "information on the weakest mode" }),
    el("option", { value: "@score", text: "segment score (its own λ_min)" }),
    ...names.map((n) => el("option", { value: n, text: `information on ${n}` })));
  renderParams();
  renderModes(rep);
  drawRoute();
}

// σ/target table ---------------------------------------------------------------------------

function paramRows() {
  return state.report.parameters.map((p) => ({ ...p, ratio: p.sigma === null ? Infinity : p.sigma / p.target }));
}

function renderParams() {
  const { key, dir } = state.sort;
  const rows = paramRows();
  if (key) rows.sort((a, b) => {
    const x = a[key] === null ? Infinity : a[key], y = b[key] === null ? Infinity : b[key];
    return (x < y ? -1 : x > y ? 1 : 0) * dir;
  });
  for (const th of document.querySelectorAll("#params thead th:has(button)")) {
    const k = $("button", th).dataset.key;
    th.setAttribute("aria-sort", k === key ? (dir > 0 ? "ascending" : "descending") : "none");
  }
  $("#params tbody").replaceChildren(...rows.map((p) => {
    const unobs = p.sigma === null;
    const status = unobs ? "unobservable" : p.ok ? "ok" : "over";
    const sigma = shown(p.sigma, p.unit), target = shown(p.target, p.unit);
    return el("tr", { class: unobs ? "unobservable" : p.ok ? "ok" : "bad", "data-name": p.name },
      el("th", { scope: "row", text: p.name }),
      el("td", { text: unobs ? "∞" : fmt(sigma.value) }),
      el("td", { text: fmt(target.value) }),
      el("td", { class: "unit", text: sigma.unit }),
      el("td", { text: unobs ? "∞" : fmt(p.ratio) }),
      el("td", { text: status }));
  }));
}

function initSort() {
  for (const b of document.querySelectorAll("#params th button")) {
    b.addEventListener("click", () => {
      const k = b.dataset.key;
      state.sort = { key: k, dir: state.sort.key === k ? -state.sort.dir : 1 };
      renderParams();
    });
  }
}

function renderModes(rep) {
  const modes = rep.weak_modes.filter((m) => m.status !== "ok");
  const shown = modes.length ? modes : rep.weak_modes.slice(0, 1);
  $("#modes").replaceChildren(...shown.map((m) => el("li", { class: m.status },
    el("strong", { text: `${m.status} ` }),
    el("span", { text: `λ = ${fmt(m.eigenvalue_scaled)}` + (m.sigma_in_targets === null ? "" : `, σ along it = ${fmt(m.sigma_in_targets)} targets`) }),
    el("div", { class: "coords", text: m.coordinates.map(([n, v]) => `${v >= 0 ? "+" : "−"}${Math.abs(v).toFixed(2)} ${n}`).join("  ") }),
    el("div", { class: "advice", text: m.advice }))));
  if (!modes.length) $("#modes").prepend(el("li", { class: "ok", text: "No weak modes: the weakest direction is shown." }));
}

// Route map --------------------------------------------------------------------------------

const VIRIDIS = [[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]];

function colour(u) {
  const x = Math.min(1, Math.max(0, u)) * (VIRIDIS.length - 1);
  const i = Math.min(VIRIDIS.length - 2, Math.floor(x)), f = x - i;
  const c = VIRIDIS[i].map((a, k) => Math.round(a + f * (VIRIDIS[i + 1][k] - a)));
  return `rgb(${c[0]},${c[1]},${c[2]})`;
}

function segmentValue(seg, key) {
  if (key === "@weak") return seg.weakest_mode_information;
  if (key === "@score") return seg.score;
  return seg.parameter_information[key];
}

// A log colour scale over the positive values (zeros get the bottom colour).
function logScale(values) {
  const pos = values.filter((v) => v > 0);
  if (!pos.length) return { lo: 0, hi: 0, u: () => 0 };
  const lo = Math.log10(Math.min(...pos)), hi = Math.log10(Math.max(...pos));
  return { lo, hi, u: (v) => (v > 0 && hi > lo ? (Math.log10(v) - lo) / (hi - lo) : v > 0 ? 1 : 0) };
}

function fitBox(xs, ys, pad) {
  const x0 = Math.min(...xs), x1 = Math.max(...xs), y0 = Math.min(...ys), y1 = Math.max(...ys);
  const w = Math.max(x1 - x0, 1), h = Math.max(y1 - y0, 1), p = pad * Math.max(w, h);
  return [x0 - p, -y1 - p, w + 2 * p, h + 2 * p];  // SVG y points down: draw at -y
}

function makeZoomable(svg, box) {
  svg.dataset.home = box.join(" ");
  svg.setAttribute("viewBox", svg.dataset.home);
  if (svg.dataset.zoomable) return;
  svg.dataset.zoomable = "1";
  const get = () => svg.getAttribute("viewBox").split(" ").map(Number);
  const zoom = (factor, cx, cy) => {
    const [x, y, w, h] = get();
    cx = cx === undefined ? x + w / 2 : cx; cy = cy === undefined ? y + h / 2 : cy;
    svg.setAttribute("viewBox", [cx - (cx - x) * factor, cy - (cy - y) * factor, w * factor, h * factor].join(" "));
  };
  const pan = (fx, fy) => { const [x, y, w, h] = get(); svg.setAttribute("viewBox", [x + fx * w, y + fy * h, w, h].join(" ")); };
  const toUser = (ev) => {
    const pt = new DOMPoint(ev.clientX, ev.clientY).matrixTransform(svg.getScreenCTM().inverse());
    return [pt.x, pt.y];
  };
  svg.addEventListener("wheel", (ev) => { ev.preventDefault(); const [cx, cy] = toUser(ev); zoom(ev.deltaY > 0 ? 1.2 : 1 / 1.2, cx, cy); }, { passive: false });
  let drag = null;
  svg.addEventListener("pointerdown", (ev) => { drag = toUser(ev); svg.setPointerCapture(ev.pointerId); });
  svg.addEventListener("pointermove", (ev) => {
    if (!drag || !svg.hasPointerCapture(ev.pointerId)) return;
    const [x, y, w, h] = get(), [ux, uy] = toUser(ev);
    svg.setAttribute("viewBox", [x - (ux - drag[0]), y - (uy - drag[1]), w, h].join(" "));
  });
  svg.addEventListener("pointerup", () => { drag = null; });
  svg.addEventListener("keydown", (ev) => {
    const keys = { "+": () => zoom(1 / 1.25), "=": () => zoom(1 / 1.25), "-": () => zoom(1.25), "0": () => svg.setAttribute("viewBox", svg.dataset.home),
      ArrowLeft: () => pan(-0.1, 0), ArrowRight: () => pan(0.1, 0), ArrowUp: () => pan(0, -0.1), ArrowDown: () => pan(0, 0.1) };
    if (keys[ev.key] && ev.target === svg) { ev.preventDefault(); keys[ev.key](); }
  });
  const box2 = svg.closest(".map-box");
  for (const b of box2.querySelectorAll("[data-zoom]")) {
    b.addEventListener("click", () => (b.dataset.zoom === "in" ? zoom(1 / 1.25) : b.dataset.zoom === "out" ? zoom(1.25) : svg.setAttribute("viewBox", svg.dataset.home)));
  }
}

function polylinePoints(xs, ys, i0, i1) {
  const pts = [];
  for (let i = i0; i <= i1; i++) pts.push(`${xs[i].toFixed(2)},${(-ys[i]).toFixed(2)}`);
  return pts.join(" ");
}

// The scene under the route: each surface's outline from above, one path a surface.
function sceneShapes(outline) {
  return outline.surfaces.map((s) => el("svg:path", {
    d: s.segments.map(([x0, y0, x1, y1]) => `M${x0} ${-y0}L${x1} ${-y1}`).join(""),
    class: `scene scene-${s.kind}${s.boxed ? " boxed" : ""}` }, el("svg:title", { text: `${s.kind}${s.name ? ": " + s.name : ""}` })));
}

// What one scan along the route leaves undetermined, in words.
function readingText(r) {
  const parts = [];
  if (r.unobservable.length) parts.push(`no information along ${r.unobservable.join(", ")}`);
  if (r.weak.length) parts.push(`weak along ${r.weak.join(", ")}`);
  if (r.status === "blind") parts.push("nothing in range");
  if (!parts.length) parts.push("every direction determined");
  return parts.join("; ");
}

// Information along the weakest direction of one scan, in (drift per scan pair)⁻²; 0 without any.
function readingValue(r) {
  if (r.status === "degenerate" || r.status === "blind" || r.weakest_sigma_in_reference === null) return 0;
  return 1 / (r.weakest_sigma_in_reference * r.weakest_sigma_in_reference);
}

function drawSceneTrack(tr, children, idx) {
  const readings = state.report.scene_track;
  const scale = logScale(readings.map(readingValue));
  readings.forEach((r, k) => {
    const a = k ? (readings[k - 1].t_s + r.t_s) / 2 : tr.t_s[0];
    const b = k + 1 < readings.length ? (r.t_s + readings[k + 1].t_s) / 2 : tr.t_s[tr.t_s.length - 1];
    const i0 = Math.max(0, idx(a) - (k ? 1 : 0)), i1 = idx(b);
    if (i1 <= i0) return;
    const v = readingValue(r);
    children.push(el("svg:polyline", { points: polylinePoints(tr.x_m, tr.y_m, i0, i1), class: v > 0 ? "seg" : "seg none",
      stroke: v > 0 ? colour(scale.u(v)) : null, tabindex: "0", "data-reading": String(k),
      "aria-label": `scan at ${r.t_s.toFixed(1)} s: ${readingText(r)}` }));
  });
  return scale;
}

function drawRoute() {
  const rep = state.report, tr = rep.track, svg = $("#route-map");
  $("#map-figure").hidden = !tr;  // a bag's report carries no path to draw
  if (!tr) return;
  const key = $("#colour-by").value || "@weak";
  const box = fitBox(tr.x_m, tr.y_m, 0.05);
  makeZoomable(svg, box);
  const segs = rep.segments;
  const children = state.outline ? [el("svg:g", { class: "scene-outline" }, ...sceneShapes(state.outline))] : [];
  children.push(el("svg:polyline", { points: polylinePoints(tr.x_m, tr.y_m, 0, tr.t_s.length - 1), class: "base" }));
  const idx = (t) => { let i = 0; while (i < tr.t_s.length - 1 && tr.t_s[i] < t - 1e-9) i++; return i; };
  if (key === "@scene") {
    const scale = drawSceneTrack(tr, children, idx);
    children.push(el("svg:circle", { cx: tr.x_m[0], cy: -tr.y_m[0], r: 0.008 * Math.max(box[2], box[3]), class: "start" }));
    svg.replaceChildren(...children);
    $("#legend").replaceChildren(el("span", { text: "the lidar's information along its weakest direction, per scan [(drift per scan pair)⁻²], log scale: " }),
      el("span", { class: "ramp", style: `background: linear-gradient(to right, ${[0, 0.25, 0.5, 0.75, 1].map(colour).join(",")})` }),
      el("span", { text: scale.hi > scale.lo ? ` ${fmt(10 ** scale.lo)} … ${fmt(10 ** scale.hi)}` : "" }),
      el("span", { class: "none-key", text: " · red: a direction without information" }),
      el("span", { class: "hint", text: " · ● start · hover or Tab to the route for what the scene leaves weak there" }));
    return;
  }
  const scale = logScale(segs.map((s) => segmentValue(s, key)));
  segs.forEach((s, k) => {
    const i0 = Math.max(0, idx(s.t_start_s) - (k ? 1 : 0)), i1 = idx(s.t_end_s);
    if (i1 <= i0) return;
    const v = segmentValue(s, key);
    children.push(el("svg:polyline", { points: polylinePoints(tr.x_m, tr.y_m, i0, i1), class: "seg", stroke: colour(scale.u(v)),
      tabindex: "0", "data-index": String(k), "aria-label": `segment ${k + 1}: ${s.t_start_s.toFixed(1)}–${s.t_end_s.toFixed(1)} s, value ${fmt(v)}` }));
  });
  children.push(el("svg:circle", { cx: tr.x_m[0], cy: -tr.y_m[0], r: 0.008 * Math.max(box[2], box[3]), class: "start" }));
  svg.replaceChildren(...children);
  const what = key === "@weak" ? "information on the weakest mode" : key === "@score" ? "segment score" : `information on ${key}`;
  $("#legend").replaceChildren(el("span", { text: `${what} [targets⁻²], log scale: ` }),
    el("span", { class: "ramp", style: `background: linear-gradient(to right, ${[0, 0.25, 0.5, 0.75, 1].map(colour).join(",")})` }),
    el("span", { text: scale.hi > scale.lo ? ` ${fmt(10 ** scale.lo)} … ${fmt(10 ** scale.hi)}` : "" }),
    el("span", { class: "hint", text: " · ● start · hover or Tab to a segment for its information" }));
}

function showSegment(target, ev) {
  const k = target?.dataset?.index;  // undefined off a segment, and for null (pointer left, focus out)
  const j = target?.dataset?.reading;  // a scan along the route, coloured by the scene
  const tip = $("#tooltip");
  if (k === undefined && j === undefined) { tip.hidden = true; return; }
  if (j !== undefined) {
    const r = state.report.scene_track[Number(j)];
    tip.replaceChildren(el("strong", { text: `scan at ${r.t_s.toFixed(1)} s (x ${r.x_m.toFixed(1)} m, y ${r.y_m.toFixed(1)} m)` }),
      el("div", { text: readingText(r) }),
      el("div", { class: "hint", text: r.weakest_sigma_in_reference === null ? "" :
        `σ along the weakest direction with information: ${fmt(r.weakest_sigma_in_reference)} × the drift per scan pair (2 cm, 0.05°)` }));
  } else {
    const s = state.report.segments[Number(k)];
    const top = Object.entries(s.parameter_information).sort((a, b) => a[1] - b[1]);
    tip.replaceChildren(el("strong", { text: `segment ${Number(k) + 1}: ${s.t_start_s.toFixed(1)}–${s.t_end_s.toFixed(1)} s` }),
      el("div", { text: `segment score ${fmt(s.score)} · weakest-mode information ${fmt(s.weakest_mode_information)}` }),
      el("div", { class: "hint", text: "least informed parameters here [targets⁻²]:" }),
      el("table", {}, el("tbody", {}, ...top.slice(0, 6).map(([n, v]) => el("tr", {}, el("th", { text: n }), el("td", { text: fmt(v) }))))));
  }
  tip.hidden = false;
  const box = $("#route-map").closest(".map-box").getBoundingClientRect();
  const r = ev && ev.clientX !== undefined ? { x: ev.clientX, y: ev.clientY } : (() => { const b = target.getBoundingClientRect(); return { x: b.right, y: b.top }; })();
  tip.style.left = `${Math.min(r.x - box.left + 12, box.width - 260)}px`;
  tip.style.top = `${r.y - box.top + 12}px`;
}

function initMap() {
  const svg = $("#route-map");
  svg.addEventListener("pointerover", (ev) => showSegment(ev.target, ev));
  svg.addEventListener("pointermove", (ev) => { if (ev.target.dataset.index !== undefined || ev.target.dataset.reading !== undefined) showSegment(ev.target, ev); });
  svg.addEventListener("pointerleave", () => showSegment(null));
  svg.addEventListener("focusin", (ev) => showSegment(ev.target));
  svg.addEventListener("focusout", () => showSegment(null));
  $("#colour-by").addEventListener("change", drawRoute);
}

function initDrop() {
  const zone = $("#drop"), input = $("#route-file");
  zone.addEventListener("dragover", (ev) => { ev.preventDefault(); zone.classList.add("over"); });
  zone.addEventListener("dragleave", () => zone.classList.remove("over"));
  zone.addEventListener("drop", (ev) => {
    ev.preventDefault();
    zone.classList.remove("over");
    if (ev.dataTransfer.files.length) { input.files = ev.dataTransfer.files; updateFormatFields(); }
  });
}

// ------------------------------------------------------------------------------------------
// Plan view: defaults and limits come from the service's own OpenAPI schema.

async function loadSchema() {
  if (state.schema) return;
  state.schema = await api("GET", "/openapi.json");
  const s = state.schema.components.schemas;
  for (const [name, prop] of Object.entries(s.ManeuverRequest.properties)) {
    const input = document.getElementById(`plan-${name}`);
    if (input && prop.default !== undefined && input.type === "number") input.value = prop.default;
  }
  $("#limits-fields").replaceChildren(...Object.entries(s.LimitsIn.properties).map(([name, prop]) =>
    el("div", { class: "field" },
      el("label", { for: `plan-limits-${name}`, text: name.replace(/_/g, " ") }),
      el("input", { type: "number", id: `plan-limits-${name}`, "data-limit": name, value: prop.default, step: "any", "aria-describedby": `plan-limits-${name}-error` }),
      el("p", { id: `plan-limits-${name}-error`, class: "error", role: "alert", "data-field": `limits.${name}` }))));
}

function numberOf(id) {
  const v = $(`#${id}`).value;
  return v === "" ? null : Number(v);
}

async function maneuverRequest() {
  const req = { rig: currentRig(), limits: {} };
  for (const name of ["duration_s", "lot_x_m", "lot_y_m", "time_budget_s", "n_random", "seed"]) req[name] = numberOf(`plan-${name}`);
  req.closed = $("#plan-closed").checked;
  req.criterion = $("#plan-criterion").value;
  if ($("#plan-drivable").checked) req.drivable = true;
  const file = $("#plan-lot-file").files[0];
  if (file) {
    try {
      req.lot = JSON.parse(await file.text());
    } catch (err) {
      const detail = `${file.name} is not JSON: ${err.message}`;
      throw new Problem({ detail, errors: [{ field: "lot", message: detail }] }, 0);
    }
  }
  for (const input of document.querySelectorAll("[data-limit]")) req.limits[input.dataset.limit] = input.value === "" ? null : Number(input.value);
  const lon = numberOf("plan-lon_deg"), lat = numberOf("plan-lat_deg");
  if (lon !== null || lat !== null) req.origin = { lon_deg: lon, lat_deg: lat };
  return req;
}

async function onPlan(ev) {
  ev.preventDefault();
  const form = $("#plan-form");
  clearErrors(form);
  await loadSchema();
  try {
    const job = await api("POST", "/v1/maneuvers", await maneuverRequest());
    state.job = job;
    $("#plan-result").hidden = true;
    $("#job").hidden = false;
    $("#job-id").textContent = job.id;
    $("#plan-button").disabled = true;
    $("#cancel-button").disabled = false;
    showJob(job);
    poll(job.id);
  } catch (err) {
    if (!(err instanceof Problem)) throw err;
    showProblem(form, err, $("#plan-error"));
  }
}

function showJob(job) {
  const p = job.progress || {};
  $("#job-status").textContent = job.status + (job.cancel_requested && job.status === "running" ? " (cancelling)" : "");
  $("#job-phase").textContent = p.phase || "—";
  $("#job-iteration").textContent = p.iteration ?? "—";
  $("#job-score").textContent = p.score === undefined || p.score === null ? "—" : fmt(p.score, 4);
  $("#job-elapsed").textContent = p.elapsed_s ? `${p.elapsed_s.toFixed(1)} s` : "—";
  const budget = numberOf("plan-time_budget_s") || 1;
  const bar = $("#job-progress");
  if (["succeeded", "failed", "cancelled"].includes(job.status)) bar.value = 1;
  else bar.value = Math.min(1, (p.elapsed_s || 0) / budget);
  $("#job-message").textContent = job.error ? job.error.detail : job.result ? job.result.message || "" : "";
}

async function poll(id) {
  let job;
  try {
    job = await api("GET", `/v1/jobs/${id}`);
  } catch (err) {
    if (!(err instanceof Problem)) throw err;
    $("#plan-error").textContent = err.message;
    return finishJob();
  }
  if (!state.job || state.job.id !== id) return;
  state.job = job;
  showJob(job);
  if (["queued", "running"].includes(job.status)) { setTimeout(() => poll(id), 500); return; }
  finishJob();
  if (job.result) await showPlan(job);
}

function finishJob() {
  $("#plan-button").disabled = false;
  $("#cancel-button").disabled = true;
}

async function onCancel() {
  if (!state.job) return;
  $("#cancel-button").disabled = true;
  try {
    showJob(await api("DELETE", `/v1/jobs/${state.job.id}`));
  } catch (err) {
    if (!(err instanceof Problem)) throw err;
    $("#plan-error").textContent = err.message;
  }
}

function parseCsv(text) {
  const lines = text.trim().split("\n");
  const head = lines[0].split(",");
  return lines.slice(1).map((l) => Object.fromEntries(l.split(",").map((v, i) => [head[i].trim(), Number(v)])));
}

async function showPlan(job) {
  const res = job.result, rep = res.report;
  const base = `/v1/jobs/${job.id}/maneuver`;
  const pts = parseCsv(await (await authFetch(`${base}?format=csv`)).text());
  $("#plan-result").hidden = false;
  drawLot(pts, job);
  $("#plan-summary").replaceChildren(el("div", { class: "big" }, el("span", { class: "label", text: "planned maneuver score " }),
    el("output", { id: "plan-score", text: fmt(res.score, 4) }), " ",
    el("span", { class: rep.passed ? "badge pass" : "badge fail", text: rep.passed ? "PASS" : "FAIL" })),
  el("div", { class: "facts", text: `${job.status} · ` + (res.drivable ? `a drivable plan, chosen among ${res.comparison.length} in ` :
    `${res.status} after ${res.iterations} iterations in `) + `${res.elapsed_s.toFixed(1)} s · ${rep.duration_s.toFixed(0)} s, ${rep.length_m.toFixed(0)} m` }));
  const cols = [["name", "maneuver"], ["kind", "kind"], ["score", "score"], ["ratio", "planned ÷ this"], ["feasible", "feasible"]];
  const cell = (v) => (v === null || v === undefined ? "—" : typeof v === "number" ? fmt(v, 3) : typeof v === "boolean" ? (v ? "yes" : "no") : String(v));
  $("#comparison thead").replaceChildren(el("tr", {}, ...cols.map(([, t]) => el("th", { scope: "col", text: t }))));
  $("#comparison tbody").replaceChildren(...res.comparison.map((r) => el("tr", { class: r.kind === "optimized" || r.result ? "mine" : null,
    title: r.violations && r.violations.length ? `violations: ${r.violations.join("; ")}` : null },
  ...cols.map(([c]) => el("td", { text: cell(r[c]) })))));
  const origin = res.origin;
  const lon = origin ? origin.lon_deg : numberOf("plan-lon_deg"), lat = origin ? origin.lat_deg : numberOf("plan-lat_deg");
  const links = [["tum", "TUM poses"], ["csv", "waypoints CSV"], ["control", "control CSV"]].map(([f, t]) => el("li", {}, el("a", { href: `${base}?format=${f}`, download: "", text: t })));
  links.push(el("li", {}, lon !== null && lat !== null
    ? el("a", { href: origin ? `${base}?format=geojson` : `${base}?format=geojson&lon_deg=${lon}&lat_deg=${lat}`, download: "", text: "GeoJSON (WGS84)" })
    : el("span", { class: "hint", text: "GeoJSON: set the lot's origin longitude and latitude" })));
  if (res.drivable) for (const [f, t] of [["sheet_pdf", "driver's sheet (PDF)"], ["sheet_png", "driver's sheet (PNG)"],
    ["cones", "cone layout (GeoJSON)"], ["plan", "plan (JSON)"]]) links.unshift(el("li", {}, el("a", { href: `${base}?format=${f}`, download: "", text: t })));
  $("#downloads").replaceChildren(...links);
  if (sessionStorage.getItem("excite-key")) for (const a of $("#downloads").querySelectorAll("a")) a.addEventListener("click", download);
  await showDrivable(job);
}

// A drivable plan: its instructions, its robust score, its cones on the map and its sheet.
async function showDrivable(job) {
  const d = job.result.drivable;
  $("#drivable-result").hidden = !d;
  if (!d) return;
  const r = d.robust;
  $("#plan-summary").append(el("div", { class: "facts", text: `drivable plan · 10th percentile over ${r.draws} drives by the driver model ` +
    `${fmt(r.score_quantile, 4)} (${Math.round(100 * r.quantile_over_nominal)} % of its score) · ${d.cones.features.filter((f) => f.properties.role === "cone").length} cones` }));
  $("#instructions").replaceChildren(...d.instructions.map((t) => el("li", { text: t })));
  const svg = $("#lot-map");
  const box = svg.getAttribute("viewBox").split(" ").map(Number);
  const size = 0.012 * Math.max(box[2], box[3]);
  for (const f of d.cones.features) {
    if (f.properties.role !== "cone") continue;
    const [x, y] = f.geometry.coordinates;
    svg.append(el("svg:path", { d: `M${x} ${-y - size}L${x + size} ${-y + size}L${x - size} ${-y + size}Z`, class: "cone" },
      el("svg:title", { text: `cone ${f.properties.label} (${f.properties.cone_role})` })));
  }
  const r2 = await authFetch(`/v1/jobs/${job.id}/maneuver?format=sheet_png`);
  if (r2.ok) {
    const img = $("#sheet");
    if (img.src.startsWith("blob:")) URL.revokeObjectURL(img.src);
    img.src = URL.createObjectURL(await r2.blob());
  }
}

function ringPath(ring) {
  return ring.map(([x, y], i) => `${i ? "L" : "M"}${x} ${-y}`).join(" ") + " Z";
}

function drawLot(pts, job) {
  const svg = $("#lot-map");
  const lot = job.result.lot;  // the lot the service planned in, in local metres
  const xs = pts.map((p) => p.x_m).concat(lot.polygon.map((q) => q[0]));
  const ys = pts.map((p) => p.y_m).concat(lot.polygon.map((q) => q[1]));
  const box = fitBox(xs, ys, 0.06);
  svg.setAttribute("viewBox", box.join(" "));
  const vmax = Math.max(...pts.map((p) => p.speed_mps), 1e-9);
  const kids = [el("svg:path", { d: [lot.polygon, ...lot.holes].map(ringPath).join(" "), "fill-rule": "evenodd", class: "lot" })];
  for (const f of lot.terrain) kids.push(el("svg:path", { d: ringPath(f.polygon), class: `terrain ${f.role}` }, el("svg:title", { text: f.role })));
  for (let i = 1; i < pts.length; i++) {
    const a = pts[i - 1], b = pts[i];
    kids.push(el("svg:line", { x1: a.x_m, y1: -a.y_m, x2: b.x_m, y2: -b.y_m, stroke: colour(b.speed_mps / vmax), class: "seg" }));
  }
  kids.push(el("svg:circle", { cx: pts[0].x_m, cy: -pts[0].y_m, r: 0.012 * Math.max(box[2], box[3]), class: "start" }));
  svg.replaceChildren(...kids);
  const w = Math.max(...lot.polygon.map((q) => q[0])) - Math.min(...lot.polygon.map((q) => q[0]));
  const h = Math.max(...lot.polygon.map((q) => q[1])) - Math.min(...lot.polygon.map((q) => q[1]));
  const what = `lot ${w.toFixed(0)} × ${h.toFixed(0)} m` + (lot.holes.length ? `, ${lot.holes.length} keep-out` : "") +
    (lot.terrain.length ? `, ${lot.terrain.map((f) => f.role).join(", ")}` : "");
  $("#lot-legend").replaceChildren(el("span", { text: "speed: 0 " }),
    el("span", { class: "ramp", style: `background: linear-gradient(to right, ${[0, 0.25, 0.5, 0.75, 1].map(colour).join(",")})` }),
    el("span", { text: ` ${vmax.toFixed(1)} m/s · ${what} · ● start` }));
  svg.setAttribute("aria-label", `Planned maneuver of job ${job.id} in the ${what}`);
}

// ------------------------------------------------------------------------------------------
// Live view: a recorded drive replayed to the live-guidance WebSocket (/v1/live) as a vehicle
// streams it. Poses go out paced by their time stamps (divided by the replay speed), all those
// that are due every LIVE_TICK_MS in one message; the service answers "update" (about one per
// second of drive), "done" (passed: once; or nothing more to gain from the motion so far), and "final" (the batch evaluator on every pose) after "end".

const LIVE_TICK_MS = 100;
const LIVE_MAX_POSES = 5000; // per message: the service's limit

function parseTum(text) {
  const poses = [];
  const lines = text.split(/\r?\n/);
  const refuse = (message) => { throw new Problem({ errors: [{ field: "poses", message }] }, 0); };
  for (let i = 0; i < lines.length; i++) {
    const line = lines[i].trim();
    if (!line || line.startsWith("#")) continue;
    const cols = line.split(/\s+/);
    const row = cols.map(Number);
    if (cols.length !== 8 || !row.every(Number.isFinite)) refuse(`line ${i + 1}: expected 8 numbers (t x y z qx qy qz qw), got "${line.slice(0, 60)}"`);
    if (poses.length && !(row[0] > poses[poses.length - 1][0])) refuse(`line ${i + 1}: time ${row[0]} does not increase`);
    poses.push(row);
  }
  if (poses.length < 2) refuse("the file holds no poses (TUM: t x y z qx qy qz qw per line)");
  return poses;
}

function setLivePhase(phase, text) {
  $("#live-result").dataset.phase = phase;
  if (text !== undefined) $("#live-status").textContent = text;
}

async function onLiveStart(ev) {
  ev.preventDefault();
  const form = $("#live-form");
  clearErrors(form);
  stopLive("restarted");
  let poses, rig;
  try {
    const file = $("#live-file").files[0];
    if (!file) throw new Problem({ errors: [{ field: "poses", message: "choose a TUM file of the drive's poses" }] }, 0);
    poses = parseTum(await file.text());
    rig = currentRig();
  } catch (err) {
    if (!(err instanceof Problem)) throw err;
    showProblem(form, err, $("#live-error"));
    return;
  }
  const name = $("#live-file").files[0].name.slice(0, 200);
  const protocols = ["excite-live"];
  if (sessionStorage.getItem("excite-key")) {  // a WebSocket carries no header: a single-use ticket, offered as a subprotocol
    try {
      const { ticket } = await api("POST", "/v1/live/tickets");
      if (ticket) protocols.push(`excite-ticket.${ticket}`);
    } catch (err) {
      if (!(err instanceof Problem)) throw err;
      showProblem(form, err, $("#live-error"));
      return;
    }
  }
  const ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/v1/live`, protocols);
  const live = { ws, poses, next: 0, speed: Number($("#live-speed").value), updates: 0, timer: null, over: false };
  state.live = live;
  $("#live-start").disabled = true;
  $("#live-stop").disabled = false;
  $("#live-result").hidden = false;
  $("#live-result").dataset.updates = "0";
  $("#live-done").hidden = true;
  $("#live-weakest").textContent = "";
  $("#live-params tbody").replaceChildren();
  setLivePhase("connecting", "connecting…");
  ws.onopen = () => ws.send(JSON.stringify({ type: "start", rig, name }));
  ws.onmessage = (m) => onLiveMessage(live, JSON.parse(m.data));
  ws.onclose = (e) => onLiveClose(live, e);
}

function liveTick(live) {
  if (live.ws.readyState !== WebSocket.OPEN || live.next >= live.poses.length) return;
  const due = live.t0 + ((performance.now() - live.wall0) / 1000) * live.speed;
  let end = live.next;
  while (end < live.poses.length && live.poses[end][0] <= due && end - live.next < LIVE_MAX_POSES) end++;
  if (end > live.next) {
    live.ws.send(JSON.stringify({ type: "poses", poses: live.poses.slice(live.next, end) }));
    live.next = end;
  }
  if (live.next === live.poses.length) {
    clearInterval(live.timer);
    live.ws.send(JSON.stringify({ type: "end" }));
    setLivePhase("ending", `all ${live.poses.length} poses sent (${live.updates} updates): waiting for the final evaluation…`);
  } else if (!live.last) {
    setLivePhase("streaming", `streaming: ${live.next} of ${live.poses.length} poses sent, waiting for the first update…`);
  }
}

function onLiveMessage(live, msg) {
  if (live !== state.live) return;
  if (msg.type === "started") {
    $("#live-params tbody").replaceChildren(...msg.parameters.map((n) => liveRow(n)));
    live.t0 = live.poses[0][0];
    live.wall0 = performance.now();
    live.timer = setInterval(() => liveTick(live), LIVE_TICK_MS);
    liveTick(live);
  } else if (msg.type === "update" || msg.type === "final") {
    live.last = msg;
    if (msg.type === "update") $("#live-result").dataset.updates = String(++live.updates);
    // a "nothing more to gain" banner goes once the motion changed and a parameter gains again
    if (live.stalled && msg.parameters.some((p) => p.status === "gaining")) {
      live.stalled = false;
      $("#live-done").hidden = true;
    }
    renderLive(live, msg);
  } else if (msg.type === "done") {
    const banner = $("#live-done");
    live.stalled = !msg.passed;
    banner.textContent = msg.passed
      ? `Done at t = ${msg.t_s.toFixed(1)} s of drive: ${msg.reason} (score ${fmt(msg.score)}). The drive can stop here.`
      : `At t = ${msg.t_s.toFixed(1)} s of drive, ${msg.reason}. Change the motion or stop: `
        + msg.needs.map((n) => `${n.name}: ${n.advice}`).join("; ");
    banner.hidden = false;
  } else if (msg.type === "error") {
    live.over = true;
    clearInterval(live.timer);
    showProblem($("#live-form"), new Problem(msg.problem, msg.problem.status), $("#live-error"));
    setLivePhase("error", `refused by the service after ${live.next} of ${live.poses.length} poses: ${msg.problem.detail}`);
  }
}

function liveRow(name) {
  const bar = el("progress", { max: "1", value: "0", "aria-label": `${name}: 0 % of target reached` });
  return el("tr", { "data-name": name }, el("th", { scope: "row", text: name }),
    el("td", {}, bar, el("span", { class: "pct", text: "—" })),
    el("td", { text: "—" }), el("td", { text: "—" }), el("td", { class: "unit" }), el("td", { text: "—" }),
    el("td", { text: "—" }), el("td", { class: "needs" }));
}

function renderLive(live, msg) {
  const final = msg.type === "final";
  const tbody = $("#live-params tbody");
  let within = 0;
  for (const p of msg.parameters) {
    let row = tbody.querySelector(`tr[data-name="${CSS.escape(p.name)}"]`);
    if (!row) tbody.append((row = liveRow(p.name)));
    const pct = Math.floor(100 * p.progress);
    const cells = row.querySelectorAll("td");
    const bar = cells[0].querySelector("progress");
    bar.value = p.progress;
    bar.setAttribute("aria-label", `${p.name}: ${pct} % of target reached`);
    cells[0].querySelector(".pct").textContent = `${pct} %`;
    cells[1].textContent = p.sigma === null ? "∞" : fmt(shown(p.sigma, p.unit).value);
    cells[2].textContent = fmt(shown(p.target, p.unit).value);
    cells[3].textContent = shown(p.target, p.unit).unit;
    cells[4].textContent = p.sigma === null ? "∞" : (p.sigma / p.target).toFixed(2);
    // an ETA only while the parameter is gaining (within the service's horizon), as `excite live`
    cells[5].textContent = p.status === "ok" ? "" : p.status === "gaining" && p.eta_s !== null ? `${Math.round(p.eta_s)} s` : "—";
    cells[6].textContent = p.status === "ok" ? "within target" : p.advice || "";
    row.className = p.status;
    if (p.status === "ok") within++;
  }
  const w = msg.weakest;
  $("#live-weakest").textContent = w ? `Weakest direction (σ ${fmt(w.sigma_in_targets)} × target; ` +
    `${w.coordinates.slice(0, 3).map(([n, c]) => `${n} ${c >= 0 ? "+" : "−"}${Math.abs(c).toFixed(2)}`).join(", ")}): ${w.advice}` : "";
  const facts = `t = ${msg.t_s.toFixed(1)} s · ${(msg.length_m / 1000).toFixed(2)} km · score ${fmt(msg.score)} · ` +
    `${within} of ${msg.parameters.length} parameters within target`;
  if (final) {
    const verdict = msg.done ? "done" : "not yet: the drive ended before every parameter reached its target";
    setLivePhase("final", `Final (the batch evaluator on all ${live.poses.length} poses): ${facts} · ${verdict}`);
  } else {
    setLivePhase(live.next === live.poses.length ? "ending" : "streaming",
      `Live (${live.updates} updates, ${live.next} of ${live.poses.length} poses sent at ${live.speed}×): ${facts}`);
  }
}

function onLiveClose(live, ev) {
  clearInterval(live.timer);
  if (live !== state.live) return;
  $("#live-start").disabled = false;
  $("#live-stop").disabled = true;
  const phase = $("#live-result").dataset.phase;
  if (!live.over && phase !== "final") {
    setLivePhase("closed", `the connection closed (code ${ev.code}${ev.reason ? ": " + ev.reason : ""}) after ${live.next} of ${live.poses.length} poses, before the final evaluation`);
  }
}

function stopLive(why) {
  const live = state.live;
  if (!live) return;
  state.live = null;
  clearInterval(live.timer);
  if (live.ws.readyState <= WebSocket.OPEN) live.ws.close(1000, why);
  $("#live-start").disabled = false;
  $("#live-stop").disabled = true;
  if (why === "stopped") setLivePhase("stopped", `stopped after ${live.next} of ${live.poses.length} poses (${live.updates} updates); nothing is kept on the service`);
}

// ------------------------------------------------------------------------------------------

function main() {
  initTabs();
  initSort();
  initMap();
  initDrop();
  $("#route-file").addEventListener("change", updateFormatFields);
  $("#route-format").addEventListener("change", updateFormatFields);
  $("#score-form").addEventListener("submit", onScore);
  $("#score-reference").addEventListener("click", onScoreReference);
  $("#plan-form").addEventListener("submit", onPlan);
  $("#cancel-button").addEventListener("click", onCancel);
  $("#live-form").addEventListener("submit", onLiveStart);
  $("#live-stop").addEventListener("click", () => stopLive("stopped"));
  const key = $("#api-key");
  key.value = sessionStorage.getItem("excite-key") || "";
  key.addEventListener("change", () => {
    if (key.value.trim()) sessionStorage.setItem("excite-key", key.value.trim());
    else sessionStorage.removeItem("excite-key");
    $("#key-error").textContent = "";
    state.schema = null;
    state.outlines = {};
    initRigs().catch((err) => { $("#rig-error").textContent = `cannot list the rigs: ${err.message}`; });
    initScenes().catch((err) => { $("#scene-error").textContent = `cannot list the scenes: ${err.message}`; });
  });
  initRigs().catch((err) => { $("#rig-error").textContent = `cannot list the rigs: ${err.message}`; });
  initScenes().catch((err) => { $("#scene-error").textContent = `cannot list the scenes: ${err.message}`; });
  document.body.dataset.ready = "1";
}

document.addEventListener("DOMContentLoaded", main);
