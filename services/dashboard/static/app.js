// The dashboard: lists, a skill's page, live executions, a sweep's page. Plain ES module, data from the API only
// (same origin; the bearer token, if the service wants one, from the field in the header, kept in localStorage).
import { linePlot, stripPlot } from "/dashboard/static/plot.js";
// The 3-D scene (three.js, 0.7 MB) is loaded by the pages that draw one, not by the lists.
// A retry names the module anew: a browser may keep a failed import's outcome for its URL.
const scene3d = (attempt = 0) => (attempt ? import(`/dashboard/static/scene3d.js?retry=${attempt}`)
  : import("/dashboard/static/scene3d.js"));

const main = document.getElementById("main");
const tokenField = document.getElementById("token");
const connection = document.getElementById("connection");
const PHASES = ["pending", "settle", "free", "approach", "contact", "retreat", "done", "aborted", "failed"];
const FINAL = ["done", "aborted", "failed"];
const LIST_PERIOD_MS = 2000;
const RETRY_MS = [250, 500, 1000, 2000, 3000];   // reconnect back-off of a live stream

tokenField.value = localStorage.getItem("contact-skills-token") || "";
tokenField.addEventListener("change", () => { localStorage.setItem("contact-skills-token", tokenField.value); route(); });

function headers(extra = {}) {
  return tokenField.value ? { ...extra, Authorization: `Bearer ${tokenField.value}` } : extra;
}

function say(text) { document.getElementById("message").textContent = text; }

async function api(path, options = {}) {
  const response = await fetch(path, { ...options, headers: headers(options.headers || {}) });
  const body = response.headers.get("content-type")?.includes("json") ? await response.json() : await response.text();
  if (!response.ok) {
    const detail = Array.isArray(body?.detail)
      ? body.detail.map((d) => `${(d.loc || []).join(".")}: ${d.msg}`).join("; ")
      : body?.detail || body;
    throw new Error(`${response.status}: ${detail}`);
  }
  return body;
}

// A list's first `wanted` items, following its pages: a page stops before the API's byte budget and names the next
// one's offset in X-Next-Offset (docs/API.md).
async function listed(path, wanted) {
  const items = [];
  let offset = 0;
  while (items.length < wanted) {
    const response = await fetch(`${path}?limit=${wanted - items.length}&offset=${offset}`, { headers: headers() });
    const page = await response.json();
    if (!response.ok) throw new Error(`${response.status}: ${JSON.stringify(page.detail ?? page)}`);
    items.push(...page);
    const next = response.headers.get("X-Next-Offset");
    if (next === null) break;
    offset = Number(next);
  }
  return items;
}

const el = (tag, attrs = {}, ...children) => {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k.startsWith("on")) node.addEventListener(k.slice(2), v); else if (v !== undefined && v !== null) node.setAttribute(k, v);
  }
  node.append(...children.flat().filter((c) => c !== null && c !== undefined));
  return node;
};
const fmt = (v, digits = 2) => (v === null || v === undefined ? "–" : typeof v === "number" ? v.toFixed(digits) : String(v));
const when = (unix) => new Date(unix * 1000).toLocaleString();
const badge = (text) => el("span", { class: String(text) }, String(text ?? "–"));

function table(columns, rows, rowId) {
  return el("table", {},
    el("thead", {}, el("tr", {}, columns.map(([name]) => el("th", {}, name)))),
    el("tbody", {}, rows.map((row) => el("tr", { "data-id": rowId ? rowId(row) : null }, columns.map(([, cell]) => el("td", {}, cell(row)))))));
}

// ------------------------------------------------------------------------------------------------ lists

let listTimer = null;
let listRefresh = null;   // the lists page's refresh, to show an upload at once

async function listsPage() {
  const demos = el("section", { id: "demonstrations" }, el("h2", {}, "Demonstrations"));
  const skills = el("section", { id: "skills" }, el("h2", {}, "Skills"));
  const executions = el("section", { id: "executions" }, el("h2", {}, "Executions"));
  const sweeps = el("section", { id: "sweeps" }, el("h2", {}, "Sweeps"));
  const scenario = el("input", { id: "scenario", value: "slide_flat", size: 16 });
  const file = el("input", { id: "upload-file", type: "file", accept: ".csv,.json,.mcap,.db3,.bag" });
  const options = el("div", { id: "import-options" });
  const uploadForm = el("form", { id: "upload-form", onsubmit: (e) => { e.preventDefault(); upload(uploadForm, file.files[0]); } },
    el("div", { class: "inline" }, el("label", {}, "recording (CSV, JSON, ROS bag)", file), el("button", { id: "upload", type: "submit" }, "Upload")),
    options, el("div", { id: "upload-result" }));
  file.addEventListener("change", () => showImportOptions(options, file.files[0]));
  const add = el("section", {}, el("h2", {}, "Add a demonstration"),
    el("form", { class: "inline", onsubmit: (e) => { e.preventDefault(); record(scenario.value); } },
      el("label", {}, "teacher scenario", scenario), el("button", { id: "record", type: "submit" }, "Record in simulation")),
    uploadForm);
  main.replaceChildren(add, demos, skills, executions, sweeps);
  // The demonstrations ticked to learn together: kept across the redraws, in the order they were ticked.
  const chosen = new Set();
  const together = el("div", { class: "inline" },
    el("button", { id: "learn-together", type: "button", onclick: () => learn({ demonstration_ids: [...chosen] }) }, "Learn together"),
    el("span", { class: "help" }, "the ticked demonstrations of one task, learned as one skill"));
  let shown = "";
  const refresh = async () => {
    try {
      const [d, s, x, w] = await Promise.all(["/demonstrations", "/skills", "/executions", "/sweeps"].map((p) => listed(p, 50)));
      connected(true);
      const now = JSON.stringify([d, s, x, w]);
      if (now === shown) return;   // redraw only what changed: a button under the pointer stays where it is
      shown = now;
      for (const id of chosen) if (!d.some((r) => r.id === id)) chosen.delete(id);   // deleted meanwhile
      demos.replaceChildren(demos.firstChild, together, table([
        ["", (r) => el("input", { type: "checkbox", class: "choose", checked: chosen.has(r.id) ? "" : null,
          onchange: (e) => (e.target.checked ? chosen.add(r.id) : chosen.delete(r.id)) })],
        ["id", (r) => r.id], ["created", (r) => when(r.created)], ["name", (r) => r.name], ["source", (r) => r.source],
        ["samples", (r) => r.summary?.n_samples ?? r.problem], ["s", (r) => fmt(r.summary?.duration_s, 1)],
        ["", (r) => el("button", { class: "learn", onclick: () => learn({ demonstration_id: r.id }) }, "Learn")],
      ], d, (r) => r.id));
      skills.replaceChildren(skills.firstChild, table([
        ["id", (r) => el("a", { href: `#/skill/${r.id}` }, r.id)], ["created", (r) => when(r.created)],
        ["type", (r) => r.skill_type], ["segments", (r) => r.segments], ["confidence", (r) => fmt(r.confidence)],
        ["checks", (r) => (r.failed_checks ? badge("fail") : badge("pass"))], ["from", (r) => r.demonstration_name],
      ], s, (r) => r.id));
      executions.replaceChildren(executions.firstChild, table([
        ["id", (r) => el("a", { href: `#/execution/${r.id}` }, r.id)], ["created", (r) => when(r.created)],
        ["status", (r) => badge(r.status)], ["verdict", (r) => badge(r.verdict)], ["controller", (r) => r.request?.controller],
        ["true RMS %", (r) => fmt(r.metrics?.true_force_rms_error_pct)], ["CF-z RMS %", (r) => fmt(r.metrics?.force_rms_error_pct)],
        ["contact", (r) => pct(r.metrics?.contact_ratio)], ["path RMS", (r) => mm(r.metrics?.path_rms_m)],
        ["s", (r) => fmt(r.metrics?.duration_s, 1)],
      ], x, (r) => r.id));
      const running = x.filter((r) => !FINAL.includes(r.status)).map((r) => r.id);
      if (running.length > 1) executions.append(el("a", { href: `#/execution/${running.join(",")}` }, `watch the ${running.length} running`));
      sweeps.replaceChildren(sweeps.firstChild, table([
        ["id", (r) => el("a", { href: `#/sweep/${r.id}` }, r.id)], ["created", (r) => when(r.created)], ["status", (r) => badge(r.status)],
        ["trials", (r) => `${r.counts?.finished ?? 0}/${r.counts?.total ?? 0}`],
        ["success", (r) => (r.controllers || []).map((c) => `${c.controller} ${pct(c.success_rate)}`).join(", ")],
      ], w, (r) => r.id));
    } catch (error) { connected(false); say(error.message); }
  };
  listRefresh = refresh;
  await refresh();
  listTimer = setInterval(refresh, LIST_PERIOD_MS);
}

function connected(up) {
  connection.textContent = up ? "connected" : "API unreachable: retrying";
  connection.style.background = up ? "#d7f5dd" : "#fde2e2";
}

async function record(scenario) {
  say(`recording ${scenario}…`);
  try {
    const demo = await api("/demonstrations/record", { method: "POST", headers: { "content-type": "application/json" },
      body: JSON.stringify({ scenario, seed: 0 }) });
    say(`recorded ${demo.id} (${demo.summary.n_samples} samples)`);
    route();
  } catch (error) { say(`record: ${error.message}`); }
}

// ------------------------------------------------------------------------------------------------ upload

// The import options of an upload, generated from the API's JSON schema of the options model (the same model gives
// `contact-skills learn FILE` its flags and POST /demonstrations/csv|bag its form fields): field names, types,
// closed sets, defaults and descriptions all come from it.
let importSchemas = null;
const UPLOAD_FIELD = "file";   // the form's file, not an option

const uploadKind = (file) => {
  const name = file?.name.toLowerCase() || "";
  return name.endsWith(".json") ? "json" : name.endsWith(".csv") ? "csv" : file ? "bag" : null;
};

async function showImportOptions(container, file) {
  const kind = uploadKind(file);
  container.dataset.kind = kind || "";
  if (!kind || kind === "json") {
    container.replaceChildren(kind ? el("p", { class: "help" }, "A JSON Demonstration is stored as it is: no import options.") : "");
    return;
  }
  importSchemas ??= await api("/dashboard/api/import-options");
  const schema = importSchemas[kind];
  const fields = Object.entries(schema.properties).filter(([name]) => name !== UPLOAD_FIELD).map(([name, property]) => {
    const choices = [property, ...(property.anyOf || [])].map((p) => (p.$ref ? schema.$defs[p.$ref.split("/").pop()] : p)).find((p) => p.enum);
    const help = property.description || "";
    let input;
    if (choices) {
      input = el("select", { name }, property.default === undefined || property.default === null ? el("option", { value: "" }, "(from the file)") : null,
        choices.enum.map((v) => el("option", { value: v, selected: v === property.default ? "" : null }, v)));
    } else if (property.type === "boolean") {
      input = el("input", { type: "checkbox", name, checked: property.default ? "" : null });
    } else {
      const numeric = [property, ...(property.anyOf || [])].some((p) => p.type === "number");
      const list = [property, ...(property.anyOf || [])].some((p) => p.type === "array");
      const example = property.examples?.[0];
      input = el("input", { name, type: numeric ? "number" : "text", step: numeric ? "any" : null, size: list ? 14 : 18,
        placeholder: example === undefined ? "" : Array.isArray(example) ? example.join(",") : String(example) });
    }
    input.dataset.default = JSON.stringify(property.default ?? null);
    return el("label", { title: help }, name, input);
  });
  const route = kind === "csv" ? "POST /demonstrations/csv" : "POST /demonstrations/bag";
  container.replaceChildren(el("details", { open: "" },
    el("summary", {}, `import options (those of contact-skills learn FILE and ${route}; hover a field for what it does)`),
    el("div", { class: "inline options" }, fields)));
}

function importOptionValues(form) {
  // The options set to other than their defaults, as the form fields the route takes.
  const values = {};
  for (const input of form.querySelectorAll("#import-options [name]")) {
    const standard = JSON.parse(input.dataset.default);
    if (input.type === "checkbox") { if (input.checked !== standard) values[input.name] = String(input.checked); }
    else if (input.value !== "" && input.value !== (standard ?? "")) values[input.name] = input.value;
  }
  return values;
}

async function upload(form, file, replacing = null) {
  if (!file) { say("choose a file first"); return; }
  const kind = uploadKind(file);
  const result = form.querySelector("#upload-result");
  say(`uploading ${file.name}…`);
  try {
    let demo;
    if (kind === "json") {
      demo = await api("/demonstrations", { method: "POST", headers: { "content-type": "application/json" }, body: await file.text() });
    } else {
      const body = new FormData();
      body.append(UPLOAD_FIELD, file);
      for (const [name, value] of Object.entries(importOptionValues(form))) body.append(name, value);
      demo = await api(`/demonstrations/${kind}`, { method: "POST", body });
    }
    if (replacing) await api(`/demonstrations/${replacing}`, { method: "DELETE" });
    const readings = demo.extra?.plausible_readings || [];
    result.replaceChildren(el("div", { class: "upload-note", "data-demonstration": demo.id },
      el("b", {}, `stored ${demo.id}${replacing ? ` (re-imported; ${replacing} deleted)` : ""}`),
      el("ul", {}, (demo.import_notes || []).map((n) => el("li", {}, n))),
      readings.length ? el("p", {}, "The import found these readings of the wrench plausible: ",
        readings.map((reading) => el("button", { type: "button", class: "use-reading",
          onclick: () => useReading(form, file, reading, demo.id) },
        `re-import with ${Object.entries(reading).map(([k, v]) => `${k} = ${v}`).join(", ")}`))) : null));
    say(`stored ${demo.id}`);
    if (!location.hash || location.hash === "#/") listRefresh?.();
  } catch (error) { result.replaceChildren(el("p", { class: "failed" }, `upload: ${error.message}`)); say(`upload: ${error.message}`); }
}

function useReading(form, file, reading, wrongId) {
  // One click: set the reading's options in the form and import the same file again; the first import is deleted.
  for (const [name, value] of Object.entries(reading)) {
    const field = form.querySelector(`#import-options [name='${name}']`);
    if (field) field.value = value;
  }
  upload(form, file, wrongId);
}

async function learn(source) {
  // source: { demonstration_id } (one) or { demonstration_ids } (several of one task, learned together).
  say(`learning from ${source.demonstration_id ?? source.demonstration_ids.join(", ")}…`);
  try {
    const skill = await api("/skills", { method: "POST", headers: { "content-type": "application/json" },
      body: JSON.stringify({ ...source, skill_type: "auto" }) });
    say(`learned ${skill.id} (${skill.skill.skill_type})`);
    location.hash = `#/skill/${skill.id}`;
  } catch (error) { say(`learn: ${error.message}`); }
}

// ------------------------------------------------------------------------------------------------ a skill

const SEGMENT_COLORS = { contact: "#ffcc80", free: "#e0e0e0" };
const BAND_COLOR = "rgba(46,125,50,.25)";   // the press several demonstrations showed (Segment.force_band)
const BOUND_SIGNS = { ">=": "≥", "<=": "≤" };   // schemas.skill.CheckBound, as a reader writes it

async function skillPage(id) {
  const view = await api(`/dashboard/api/skills/${id}`);
  const spans = view.segments.map((s) => ({ x0: s.t_start, x1: s.t_end, color: s.kind === "contact" ? "rgba(255,152,0,.15)" : "rgba(120,120,120,.08)" }));
  const timeline = el("canvas", { id: "timeline" });
  const force = el("canvas", { id: "skill-force" });
  const sceneBox = el("div", { id: "skill-scene" });
  const number = (name, value) => el("label", {}, name, el("input", { type: "number", step: "0.005", value, name }));
  const form = el("form", { class: "inline", id: "execute-form", onsubmit: (e) => { e.preventDefault(); execute(id, form); } },
    el("label", {}, "controller", el("select", { name: "controller" },
      ["hybrid_cf", "impedance", "impedance_found_surface", "hybrid_world_z"].map((c) => el("option", { value: c }, c)))),
    ["x", "y", "z"].map((a) => number(`known ${a} m`, 0)), ["x", "y", "z"].map((a) => number(`unknown ${a} m`, 0)),
    el("label", {}, "pace", el("select", { name: "pace" }, el("option", { value: "fast" }, "fast"), el("option", { value: "realtime" }, "realtime"))),
    el("button", { id: "execute", type: "submit" }, "Execute"));
  const auto = view.auto_selection;
  const key = (color, text, style = "") => el("span", {}, el("i", { style: `background:${color};${style}` }), text);
  const xRange = view.t.length ? [view.t[0], view.t[view.t.length - 1]]
    : [Math.min(...view.segments.map((s) => s.t_start)), Math.max(...view.segments.map((s) => s.t_end))];
  const pieceNote = view.work_piece
    ? el("span", {}, `work piece: the world of its latest execution, `, el("a", { href: `#/execution/${view.work_piece_execution}` }, view.work_piece_execution))
    : el("span", {}, "work piece: none drawn until the skill has run (the world an execution runs in comes from its worker)");
  const bandKey = view.force_bands.length
    ? key(BAND_COLOR, `force band of the ${view.force_bands[0].demonstrations} demonstrations (segment ${view.force_bands.map((b) => b.segment).join(", ")})`, "height:10px")
    : null;
  const uses = view.demonstrations;
  const learnedFrom = uses ? el("section", { id: "learned-from" }, el("h2", {}, `Learned from ${uses.length} demonstrations`), table([
    ["demonstration", (r) => el("a", { href: `/demonstrations/${encodeURIComponent(r.source)}` }, r.source)], ["name", (r) => r.name ?? "–"],
    ["weight", (r) => fmt(r.weight, 3)], ["reference", (r) => (r.reference ? "yes" : "no")],
    ["used", (r) => (r.misfit ? el("span", { class: "message" }, `left out (${r.misfit}): ${r.reason ?? ""}`) : "included")],
    ["type alone", (r) => r.skill_type ?? "–"], ["press in the others' band", (r) => pct(r.share_in_band)],
    ["CF z vs the others'", (r) => (r.normal_angle_deg === null ? "–" : `${fmt(r.normal_angle_deg, 1)}°`)],
  ], uses, (r) => r.source)) : null;
  const limit = (check, k) => `${BOUND_SIGNS[view.check_bounds[k]] ?? ""} ${fmt(check.limit, 3)} ${check.unit}`;
  main.replaceChildren(
    el("section", {}, el("h2", {}, `Skill ${id}: ${view.skill_type}, ${view.segments.length} segments`), form),
    el("section", {}, el("h2", {}, "Segments on the demonstration's time line"), timeline,
      el("div", { class: "legend" }, view.segments.map((s) => el("span", {}, el("i", { style: `background:${SEGMENT_COLORS[s.kind] || "#bbb"}; height:10px` }),
        `${s.index} ${s.kind} ${fmt(s.t_start)}–${fmt(s.t_end)} s${s.force_n !== null ? `, ${fmt(s.force_n, 1)} N` : ""}`)))),
    el("div", { class: "grid2" },
      el("section", {}, el("h2", {}, "Force along CF z: demonstrated vs learned (N)"), force,
        el("div", { class: "legend" }, key("#1565c0", "demonstrated"), key("#000", "learned (dashed)"), key("rgba(255,152,0,.4)", "contact segment", "height:10px"), bandKey)),
      el("section", {}, el("h2", {}, "Scene (world, m; drag to rotate, right-drag to pan, wheel to zoom)"), sceneBox,
        el("div", { class: "legend" }, key("#1d2330", "taught path (dashed)"), key("#d32f2f", "CF x"), key("#2e7d32", "CF y"),
          key("#1565c0", "CF z (into the surface)"), key("#c8a46e", "work piece", "height:10px"),
          view.joints ? el("span", {}, "arm: at the path's first pose") : el("span", {}, "arm: the path is out of its reach as recorded (an execution places it)")),
        el("div", { class: "legend" }, pieceNote))),
    learnedFrom,
    el("div", { class: "grid2 checks-row" },
      el("section", { id: "auto-selection" }, el("h2", {}, "Auto selection"), auto
        ? el("div", {}, el("p", {}, el("b", {}, auto.chosen), ` (confidence ${fmt(auto.confidence)}): ${auto.reason}`),
          table([["evidence", (r) => r[0]], ["value", (r) => fmt(r[1], 3)]],
            Object.entries({ ...(auto.evidence || {}), turning_within_planes_deg: auto.turning_within_planes_deg, plane_rms_m: auto.plane_rms_m, mixed: auto.mixed }).map(([k, v]) => [k, v])))
        : el("p", {}, "type given, not chosen")),
      el("section", { id: "checks" }, el("h2", {}, "The skill's checks"), table([
        ["check", (r) => r.name], ["segment", (r) => r.segment ?? "all"], ["", (r) => badge(r.passed ? "pass" : "fail")],
        ["value", (r) => `${fmt(r.value, 3)} ${r.unit}`], ["must be", (r) => limit(r, view.checks.indexOf(r))],
        ["what it says", (r) => el("span", { class: "message" }, r.message)],
      ], view.checks))));
  stripPlot(timeline, [{ label: "segment", spans: view.segments.map((s) => ({ x0: s.t_start, x1: s.t_end,
    color: SEGMENT_COLORS[s.kind] || "#bbb", text: `${s.index} ${s.kind}${s.force_n !== null ? ` ${fmt(s.force_n, 1)} N` : ""}` })) }],
  { xRange, xLabel: "t (s)", rowHeight: 26 });
  linePlot(force, [
    { x: view.t, y: view.force_cf_z, color: "#1565c0", width: 1 },
    { x: view.learned_t, y: view.learned_force, color: "#000", dash: [6, 3], width: 2 },
  ], { bands: spans, areas: view.force_bands.map((b) => ({ x: b.t, low: b.lower_n, high: b.upper_n, color: BAND_COLOR })),
    xLabel: "t (s)", yLabel: "N", xRange });
  // The bands drawn, for whoever checks them against the stored skill (tests).
  force.dataset.bands = JSON.stringify(view.force_bands.map((b) => ({ segment: b.segment, t0: b.t[0], t1: b.t[b.t.length - 1],
    lower_n: b.lower_n, upper_n: b.upper_n })));
  const { Scene3D, STYLE } = await scene3d();
  const scene = new Scene3D(sceneBox, { height: 440 });
  scene.setPath("taught", view.path.length ? view.path : view.triads.map((tr) => tr.origin), STYLE.taught);
  scene.setTriads(view.triads, view.triads.length > 3 ? 0.03 : 0.06);   // a slide's one frame per segment drawn larger
  if (view.work_piece) scene.setWorkPiece(view.work_piece);
  scene.setRobot(view.joints);   // asked first: the framing below includes the arm
  scene.fit();
  timeline.dataset.segments = String(view.segments.length);
}

async function execute(skillId, form) {
  const data = new FormData(form);
  const values = [...form.querySelectorAll("input[type=number]")].map((i) => Number(i.value));
  const body = { skill_id: skillId, controller: data.get("controller"), pace: data.get("pace"),
    environment: { offset: values.slice(0, 3), unknown_offset: values.slice(3, 6) } };
  try {
    const created = await api("/executions", { method: "POST", headers: { "content-type": "application/json" }, body: JSON.stringify(body) });
    location.hash = `#/execution/${created.id}`;
  } catch (error) { say(`execute: ${error.message}`); }
}

// ------------------------------------------------------------------------------------------------ live executions

const streams = new Set();   // the live streams of the page shown (closed when leaving it)
const TRUE_COLOR = "#c62828";                    // the true normal force (the simulator's contact points)
const CFZ_COLOR = "#1565c0";                     // the measured force along CF z (what the controller reads)
const CONTACT_COLOR = "#2e7d32";                 // the tool touching (the simulator's contact points)
const PHASE_COLORS = { settle: "#cfd8dc", free: "#bbdefb", approach: "#fff59d", contact: "#ffcc80", retreat: "#d1c4e9" };
const TRIAD_SPACING_M = 0.015;                   // a CF triad every 1.5 cm of path in the contact phase
const SCENE_RETRY_MS = 1000;                     // how often a live page asks for the work piece until it has it
const SCENE_PERIOD_MS = 500;                     // the live 3-D scene is redrawn twice a second at most
const COMMANDS = {                               // which command each state allows (the buttons follow the run)
  queued: ["abort"], starting: ["abort"], running: ["pause", "abort"], paused: ["resume", "abort"],
};

function extendSpans(spans, t, key, style) {
  // Grow the open span of `spans` to time t while its key stays `key`; on a change close it there (spans meet) and
  // open one for the new key (null: none).
  const last = spans[spans.length - 1];
  if (last?.open && last.key === key) { last.x1 = t; return; }
  if (last?.open) { last.open = false; last.x1 = t; }
  if (key !== null) spans.push({ x0: t, x1: t, key, open: true, ...style });
}
window.__drawLog = [];        // [stream index of the last point drawn, Date.now()] per frame: the benchmark reads it

// A metric as an engineer reads it: lengths in mm, ratios in %, forces in N with their % of the reference.
const mm = (m) => (m === null || m === undefined ? "–" : `${(m * 1000).toFixed(2)} mm`);
const pct = (ratio) => (ratio === null || ratio === undefined ? "–" : `${(ratio * 100).toFixed(1)} %`);
const newtons = (n, p) => (n === null || n === undefined ? "–" : `${n.toFixed(2)} N${p === null || p === undefined ? "" : ` (${p.toFixed(2)} %)`}`);
const seconds = (s) => (s === null || s === undefined ? "–" : `${s.toFixed(2)} s`);

class LivePanel {
  constructor(id) {
    this.id = id; this.cursor = 0; this.attempt = 0; this.closed = false; this.ended = false; this.pending = false;
    this.t = []; this.fz = []; this.fd = []; this.fw = []; this.ft = []; this.index = []; this.maxGap = 0;
    this.errTrue = []; this.errCfz = [];
    this.tool = []; this.reference = []; this.phaseSpans = []; this.contactSpans = []; this.triads = []; this.joints = null;
    this.workPiece = null; this.sceneAsked = false; this.sceneAskedAt = 0; this.drawnTriads = 0; this.fitted = 0;
    this.sceneDrawn = -Infinity; this.sceneLater = null;
    this.head = el("div", { class: "live-head" });
    this.force = el("canvas", { class: "live-force", "data-execution": id });
    this.error = el("canvas", { class: "live-error" });
    this.strips = el("canvas", { class: "live-strips" });
    this.sceneBox = el("div", { class: "live-scene" });
    this.final = el("div", { class: "final" });
    this.buttons = Object.fromEntries(["pause", "resume", "abort"].map((name) =>
      [name, el("button", { class: name, disabled: "", onclick: () => this.command(name) }, name)]));
    const key = (color, text, style = "") => el("span", {}, el("i", { style: `background:${color};${style}` }), text);
    this.root = el("section", { class: "live", "data-execution": id },
      el("h2", {}, `Execution ${id} `, this.buttons.pause, " ", this.buttons.resume, " ", this.buttons.abort), this.head,
      el("div", { class: "grid2" },
        el("div", {},
          el("h3", {}, "Force (N)"), this.force, el("div", { class: "legend" },
            key(TRUE_COLOR, "true normal force"), key(CFZ_COLOR, "CF-z measured"), key("#000", "desired (dashed)"),
            key("#9e9e9e", "|F| world")),
          el("h3", {}, "Force error in the contact phase (N): force − desired"), this.error, el("div", { class: "legend" },
            key(TRUE_COLOR, "true normal force − desired"), key(CFZ_COLOR, "CF-z − desired")),
          this.strips, el("div", { class: "legend" },
            ...Object.entries(PHASE_COLORS).map(([name, color]) => key(color, name, "height:10px")),
            key(CONTACT_COLOR, "tool touching", "height:10px"))),
        el("div", {}, el("h3", {}, "Scene (world, m; drag to rotate, right-drag to pan, wheel to zoom)"), this.sceneBox,
          el("div", { class: "legend" }, key("#1d2330", "taught path (the reference, dashed)"), key("#ff6d00", "executed tool path"),
            key("#d32f2f", "CF x"), key("#2e7d32", "CF y"), key("#1565c0", "CF z (into the surface)"), key("#c8a46e", "work piece", "height:10px")))),
      this.final);
    this.scene = null;   // until three.js has loaded
    this.loadScene();
    streams.add(this);
    this.status = { status: "…", phase: "…" };
    this.connect();
  }

  async command(name) {
    try { await api(`/executions/${this.id}/${name}`, { method: "POST" }); say(`${name} sent to ${this.id}`); } catch (error) { say(`${name}: ${error.message}`); }
  }

  async connect() {
    // Server-sent events read with fetch (EventSource cannot send the bearer token); on a lost connection (the API
    // restarted) go on from the last event's id: nothing is missed, nothing drawn twice.
    while (!this.closed && !this.ended) {
      try {
        const response = await fetch(`/executions/${this.id}/live?cursor=${this.cursor}`, { headers: headers() });
        if (!response.ok) throw new Error(`${response.status}: ${(await response.text()).slice(0, 200)}`);
        if (this.attempt) say(`${this.id}: reconnected`);
        connected(true); this.attempt = 0; this.root.dataset.connected = "1";
        const reader = response.body.getReader();
        const decoder = new TextDecoder();
        let buffer = "";
        for (;;) {
          const { value, done } = await reader.read();
          if (done || this.closed) break;
          buffer += decoder.decode(value, { stream: true });
          let cut;
          while ((cut = buffer.indexOf("\n\n")) >= 0) { this.onEvent(buffer.slice(0, cut)); buffer = buffer.slice(cut + 2); }
        }
      } catch (error) { connected(false); say(`${this.id}: ${error.message}; reconnecting`); }
      this.root.dataset.connected = "0";
      if (!this.ended && !this.closed) await new Promise((r) => setTimeout(r, RETRY_MS[Math.min(this.attempt++, RETRY_MS.length - 1)]));
    }
  }

  onEvent(text) {
    let kind = "message", data = "", id = null;
    for (const line of text.split("\n")) {
      if (line.startsWith("event: ")) kind = line.slice(7);
      else if (line.startsWith("data: ")) data += line.slice(6);
      else if (line.startsWith("id: ")) id = Number(line.slice(4));
    }
    const body = JSON.parse(data || "{}");
    if (kind === "telemetry") { this.addTelemetry(body); this.askScene(); }
    else if (kind === "status") { this.status = body; this.askScene(); }
    else if (kind === "end") { this.ended = true; this.status = { ...this.status, ...body }; this.askScene(true); this.showFinal(body); }
    if (id !== null) this.cursor = id;
    this.schedule();
  }

  async askScene(last = false) {
    // The work piece its worker reported when it started the run (none before): asked at each event until it comes,
    // once a second at most.
    if (this.workPiece || (this.sceneAsked && !last) || (!last && Date.now() - this.sceneAskedAt < SCENE_RETRY_MS)) return;
    this.sceneAsked = true;
    this.sceneAskedAt = Date.now();
    try {
      const scene = await api(`/dashboard/api/executions/${this.id}/scene`);
      if (scene.work_piece) { this.workPiece = scene.work_piece; this.scene?.setWorkPiece(scene.work_piece); this.schedule(); }
    } catch (error) { say(`scene: ${error.message}`); }
    this.sceneAsked = false;
  }

  addTelemetry(b) {
    for (let k = 0; k < b.t.length; k++) {
      const t = b.t[k];
      if (this.index.length) this.maxGap = Math.max(this.maxGap, b.index[k] - this.index[this.index.length - 1]);
      const phase = PHASES[b.phase[k]];
      const [fz, fd, ft] = [b.wrench_cf[k][2], b.desired_force_cf_z_n[k], b.normal_force_true_n[k]];
      this.t.push(t); this.index.push(b.index[k]);
      this.fz.push(fz); this.fd.push(fd);
      this.ft.push(ft);   // null where not recorded: a gap in the line, not a 0
      const pressing = phase === "contact";   // the errors the metrics judge: the controller's contact phase
      this.errTrue.push(pressing && ft !== null && fd !== null ? ft - fd : null);
      this.errCfz.push(pressing && fz !== null && fd !== null ? fz - fd : null);
      const f = b.wrench_world[k]; this.fw.push(Math.hypot(f[0], f[1], f[2]));
      this.tool.push(b.tool_position[k]); this.reference.push(b.reference_position[k]);
      extendSpans(this.phaseSpans, t, phase, { color: PHASE_COLORS[phase] || "#eee", text: phase });
      extendSpans(this.contactSpans, t, b.in_contact[k] === true ? "touching" : null, { color: CONTACT_COLOR });
      const R = b.cf_axes?.[k];
      const last = this.triads[this.triads.length - 1];
      const p = b.tool_position[k];
      if (pressing && R && (!last || Math.hypot(...p.map((v, i) => v - last.origin[i])) >= TRIAD_SPACING_M)) {
        this.triads.push({ origin: p, axes: [0, 1, 2].map((j) => [R[0][j], R[1][j], R[2][j]]) });
      }
    }
    if (b.joints) this.joints = b.joints;
    this.latest = b;
  }

  schedule() {
    if (this.pending) return;
    this.pending = true;
    requestAnimationFrame(() => { this.pending = false; this.draw(); });
  }

  draw() {
    const n = this.t.length;
    const b = this.latest;
    const k = b ? b.t.length - 1 : -1;
    const phase = b ? PHASES[b.phase[k]] : this.status.phase;
    const touching = b ? b.in_contact[k] : null;   // null: not recorded (telemetry stored before it was streamed)
    const allowed = FINAL.includes(this.status.status) || this.ended ? [] : COMMANDS[this.status.status] || [];
    for (const [name, button] of Object.entries(this.buttons)) button.disabled = !allowed.includes(name);
    this.head.replaceChildren(...[
      el("span", {}, "status ", badge(this.status.status)), el("span", {}, "phase ", el("b", { class: "phase" }, phase)),
      el("span", {}, "segment ", el("b", {}, b ? String(b.segment_index[k]) : "–")),
      el("span", {}, "t ", el("b", {}, n ? `${this.t[n - 1].toFixed(3)} s` : "–")),
      el("span", {}, "true ", el("b", {}, newtons(b?.normal_force_true_n[k])),
        " / CF-z ", el("b", {}, newtons(b?.wrench_cf[k][2])), " / desired ", el("b", {}, newtons(b?.desired_force_cf_z_n[k]))),
      el("span", { class: touching ? "contact-on" : "contact-off" },
        touching === null || touching === undefined ? "contact not recorded" : touching ? "in contact" : "no contact"),
      this.status.error ? el("span", { class: "failed" }, this.status.error) : null].filter(Boolean));
    const xRange = n ? [this.t[0], Math.max(this.t[n - 1], this.t[0] + 1)] : [0, 1];
    linePlot(this.force, [
      // The true force wide and under the CF-z force, the desired force dashed on top: all three stay visible
      // where they agree (the controller's aim); their difference is the error plot below.
      { x: this.t, y: this.fw, color: "#9e9e9e", width: 1 },
      { x: this.t, y: this.ft, color: TRUE_COLOR, width: 2.5 },
      { x: this.t, y: this.fz, color: CFZ_COLOR, width: 1 },
      { x: this.t, y: this.fd, color: "#000", dash: [6, 3], width: 1.5 },
    ], { xLabel: "t (s)", yLabel: "N", xRange, height: 200 });
    linePlot(this.error, [
      { x: this.t, y: this.errTrue, color: TRUE_COLOR, width: 1.5 },
      { x: this.t, y: this.errCfz, color: CFZ_COLOR, width: 1 },
    ], { xLabel: "t (s)", yLabel: "N", xRange, height: 150, zero: true });
    stripPlot(this.strips, [{ label: "phase", spans: this.phaseSpans }, { label: "contact", spans: this.contactSpans }],
      { xRange, xLabel: "t (s)" });
    if (this.ended || performance.now() - this.sceneDrawn >= SCENE_PERIOD_MS) this.drawScene();
    else if (!this.sceneLater) this.sceneLater = setTimeout(() => { this.sceneLater = null; this.drawScene(); }, SCENE_PERIOD_MS);
    if (n) {
      // The plot's last point, for whoever checks it against the stored telemetry (tests, the benchmark).
      // lastFt, lastContact: "" where not recorded.
      Object.assign(this.force.dataset, { lastIndex: this.index[n - 1], lastT: this.t[n - 1], lastFz: this.fz[n - 1],
        lastFt: this.ft[n - 1] ?? "", lastContact: touching ?? "", points: n, maxGap: this.maxGap,
        lastErrTrue: this.errTrue[n - 1] ?? "", lastErrCfz: this.errCfz[n - 1] ?? "" });
      window.__drawLog.push([this.id, this.index[n - 1], Date.now()]);
    }
    this.root.dataset.status = this.status.status;
  }

  async loadScene() {
    // three.js and the scene's module come from the API: while it restarts the load fails, and is tried again.
    for (let attempt = 0; !this.closed; attempt++) {
      try {
        const { Scene3D, STYLE } = await scene3d(attempt);
        this.scene = new Scene3D(this.sceneBox, { height: 480 });
        this.style = STYLE;
        if (this.workPiece) this.scene.setWorkPiece(this.workPiece);
        this.drawScene();
        return;
      } catch (error) {
        say(`3-D scene: ${error.message}; trying again`);
        await new Promise((r) => setTimeout(r, RETRY_MS[Math.min(attempt, RETRY_MS.length - 1)]));
      }
    }
  }

  drawScene() {
    // At most every SCENE_PERIOD_MS: the 3-D scene costs far more a frame than the plots (software WebGL on a
    // machine without a GPU), and the plots must keep the live rate.
    if (!this.t.length || !this.scene) return;
    this.sceneDrawn = performance.now();
    this.scene.setPath("taught", this.reference, this.style.taught);
    this.scene.setPath("executed", this.tool, this.style.executed);
    if (this.triads.length !== this.drawnTriads) { this.scene.setTriads(this.triads); this.drawnTriads = this.triads.length; }
    if (this.joints) this.scene.setRobot(this.joints);
    // Framed on the first data, again when the work piece comes and when the run ends; else the user's camera stays.
    const stage = (this.workPiece ? 2 : 1) + (this.ended ? 1 : 0);
    if (stage > this.fitted) { this.scene.fit(this.fitted === 0 || !this.scene.userMoved); this.fitted = stage; }
  }

  showFinal(end) {
    const m = end.metrics || {};
    const v = m.verdict || {};
    const row = (name, value) => [name, value];
    this.final.replaceChildren(el("h2", {}, "Result: ", badge(end.verdict || end.status)),
      table([["metric", (r) => r[0]], ["value", (r) => r[1]]], [
        row("status", end.status),
        row("true normal force RMS error", newtons(m.true_force_rms_error_n, m.true_force_rms_error_pct)),
        row("true normal force max error", newtons(m.true_force_max_error_n, m.true_force_max_error_pct)),
        row("CF-z force RMS error (the controller's view)", newtons(m.force_rms_error_n, m.force_rms_error_pct)),
        row("reference force", newtons(m.force_reference_n)),
        row("contact ratio", pct(m.contact_ratio)),
        row("touch-down peak", m.touchdown_peak_n === null || m.touchdown_peak_n === undefined ? "–"
          : `${newtons(m.touchdown_peak_n)} (${fmt(m.touchdown_peak_ratio)} × the press)`),
        row("path RMS error (CF x-y)", mm(m.path_rms_m)),
        row("CF z vs true normal (mean / max)", m.cf_normal_angle_deg === null || m.cf_normal_angle_deg === undefined ? "–"
          : `${fmt(m.cf_normal_angle_deg, 1)}° / ${fmt(m.cf_normal_angle_max_deg, 1)}°`),
        row("steady contact", seconds(m.steady_contact_s)), row("duration", seconds(m.duration_s)),
        row("real-time factor", m.real_time_factor === undefined ? "–" : `${fmt(m.real_time_factor, 1)} ×`),
        row("work piece", m.work_piece ?? "–"), row("telemetry samples", String(end.samples)),
        row("abort reason", m.abort_reason || end.error || "–"),
      ]), el("ul", {}, [...(v.reasons || []), ...(v.warnings || []).map((w) => `warning: ${w}`)].map((r) => el("li", {}, r))));
    this.root.dataset.ended = "1";
  }

  close() { this.closed = true; clearTimeout(this.sceneLater); streams.delete(this); }
}

function executionPage(ids) {
  main.replaceChildren(...ids.map((id) => new LivePanel(id).root));
}

// ------------------------------------------------------------------------------------------------ a sweep

// A sweep parameter's value as an engineer reads it (schemas.sweep.SweepParameter: its name ends in its unit).
const PARAMETER_UNITS = [["_n_s_m", 1, "N·s/m"], ["_n_m", 1, "N/m"], ["_m", 1000, "mm"], ["_deg", 1, "°"], ["_n", 1, "N"]];
function parameter(name, value) {
  const [suffix, scale, unit] = PARAMETER_UNITS.find(([end]) => name.endsWith(end)) || ["", 1, ""];
  const label = name.slice(0, name.length - suffix.length).replaceAll("_", " ");
  const v = value * scale;
  const shown = Math.abs(v) >= 1000 ? v.toExponential(2) : v.toFixed(Math.abs(v) >= 100 ? 0 : 2);
  return `${label} ${v > 0 && suffix !== "" && !name.startsWith("contact") ? "+" : ""}${shown}${unit ? ` ${unit}` : ""}`;
}

async function sweepPage(id) {
  const [view, trials] = await Promise.all([api(`/sweeps/${id}`), api(`/sweeps/${id}/trials`)]);
  const image = el("img", { id: "sweep-figure", alt: "success rate and true force error along each parameter", style: "max-width:100%" });
  const verdict = (r) => (r.success === null || r.success === undefined ? badge(r.status) : badge(r.success ? "pass" : "fail"));
  main.replaceChildren(el("section", {}, el("h2", {}, `Sweep ${id}: `, badge(view.status)),
    table([["controller", (r) => r.controller], ["finished", (r) => `${r.finished}/${r.trials}`], ["success rate", (r) => pct(r.success_rate)],
      ["true RMS error p50", (r) => (r.true_force_rms_error_pct ? `${fmt(r.true_force_rms_error_pct.p50)} %` : "–")],
      ["p90", (r) => (r.true_force_rms_error_pct ? `${fmt(r.true_force_rms_error_pct.p90)} %` : "–")],
      ["failures", (r) => Object.entries(r.failures || {}).map(([k, v]) => `${k}: ${v}`).join(", ") || "none"]], view.controllers || [])),
  el("div", { class: "grid2 sweep-row" },
    el("section", { id: "sweep-trials" }, el("h2", {}, `Trials (${trials.length}): each row its execution`),
      table([
        ["trial", (r) => String(r.trial)], ["controller", (r) => r.controller],
        ["perturbation", (r) => Object.entries(r.parameters).flatMap(([k, v], j) => [j ? el("br") : null, parameter(k, v)])],
        ["verdict", verdict],
        ["true RMS error", (r) => (r.true_force_rms_error_pct === null ? "–" : `${fmt(r.true_force_rms_error_pct)} %`)],
        ["true max error", (r) => (r.true_force_max_error_pct === null ? "–" : `${fmt(r.true_force_max_error_pct)} %`)],
        ["contact", (r) => pct(r.contact_ratio)], ["touch-down peak", (r) => (r.touchdown_peak_ratio === null ? "–" : `${fmt(r.touchdown_peak_ratio)} ×`)],
        ["path RMS", (r) => mm(r.metrics?.path_rms_m)],
        ["execution", (r) => (r.execution_id ? el("a", { href: `#/execution/${r.execution_id}` }, r.execution_id) : "–")],
        ["why it failed", (r) => el("span", { class: "message" }, [...r.reasons, r.abort_reason].filter(Boolean).join("; "))],
      ], trials, (r) => `${r.trial}-${r.controller}`)),
    el("section", {}, el("h2", {}, "Summary: true RMS error and success rate along each varied parameter"), image)));
  const response = await fetch(`/dashboard/api/sweeps/${id}/figure.png`, { headers: headers() });
  if (response.ok) image.src = URL.createObjectURL(await response.blob());
}

// ------------------------------------------------------------------------------------------------ routing

async function route() {
  clearInterval(listTimer);
  for (const stream of [...streams]) stream.close();
  const [, page, id] = location.hash.split("/");
  try {
    if (page === "skill" && id) await skillPage(id);
    else if (page === "execution" && id) executionPage(id.split(","));
    else if (page === "sweep" && id) await sweepPage(id);
    else await listsPage();
    document.body.dataset.page = page || "lists";
  } catch (error) { say(error.message); connected(false); }
}

window.addEventListener("hashchange", route);
route();
