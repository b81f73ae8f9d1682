// calibd web page, result views: headline numbers first (every kind), the parameter
// table with each parameter's observability, the plots inline (SVG in the page, so a
// reader or a test can read what was drawn), a campaign's journal, live plot and log,
// the cells' current models and history, and job files that name data files.
// Uses the helpers of app.js (el, api, fmt, table, headers, time).
"use strict";

// [label, before pointer, after pointer, unit (a pointer or a literal)]
const HEADLINES = [
  ["Marker RMSE, calibration set", "/rmse_before_mm", "/rmse_after_mm", "mm"],
  ["Held-out marker RMSE (cross-validation)", "/cross_validation/rmse_nominal_mm", "/cross_validation/rmse_calibrated_mm", "mm"],
  ["Position error e_P mean, calibration set", "/model_error/calibration/e_P/nominal/mean", "/model_error/calibration/e_P/identified/mean", "/model_error/calibration/e_P/unit"],
  ["Orientation error e_θ mean, calibration set", "/model_error/calibration/e_theta/nominal/mean", "/model_error/calibration/e_theta/identified/mean", "/model_error/calibration/e_theta/unit"],
  ["Position error e_P mean, validation set", "/model_error/validation/e_P/nominal/mean", "/model_error/validation/e_P/identified/mean", "/model_error/validation/e_P/unit"],
  ["Held-out error mean, validation set", "/validation/before/mean", "/validation/after/mean", "/validation/after/unit"],
  ["Held-out error max, validation set", "/validation/before/max", "/validation/after/max", "/validation/after/unit"],
  ["Residual mean, calibration set", "/residuals/before/mean", "/residuals/after/mean", "/residuals/after/unit"],
  ["Residual max, calibration set", "/residuals/before/max", "/residuals/after/max", "/residuals/after/unit"],
];
const ptr = (o, p) => p.split("/").slice(1).reduce((a, k) => (a == null ? undefined : a[k]), o);

/** The parameter rows of an identification (null for kinds whose `parameters` are names). */
const paramRows = (r) => (Array.isArray(r.parameters) && r.parameters.length && r.parameters.every((p) => p && typeof p === "object") ? r.parameters : null);

/** The before/after numbers of a result, first thing in its view (null when none). */
function headline(r) {
  const rows = [];
  // PCR: the held-out errors are Table 3's validation e_P (in m, not um): shown once.
  const table3 = ptr(r, "/model_error/validation/e_P/nominal/mean") !== undefined;
  for (const [label, b, a, u] of HEADLINES) {
    if (table3 && b.startsWith("/validation/")) continue;
    const before = ptr(r, b), after = ptr(r, a);
    if (typeof before !== "number" || typeof after !== "number") continue;
    const unit = u.startsWith("/") ? ptr(r, u) || "" : u;
    rows.push(el("tr", { "data-key": a },
      el("th", {}, label), el("td", { class: "num" }, fmt(before)), el("td", { class: "num after" }, fmt(after)),
      el("td", {}, unit), el("td", { class: "num" }, after > 0 ? fmt(before / after, 1) + "×" : "")));
  }
  const ps = paramRows(r);
  const ident = ps ? ps.filter((p) => p.identifiable !== false).length : 0;
  if (!rows.length && !ps) return null;
  // A campaign says what its "before" model is (nominal, or the cell's calibration #k).
  const before = r.started_from ? `before: ${r.started_from}` : "before";
  return el("div", { class: "headline", id: "headline" },
    rows.length ? el("table", {}, el("thead", {}, el("tr", {}, ...["", before, "after", "unit", "before / after"].map((c) => el("th", c === before ? { "data-before": "" } : {}, c)))), el("tbody", {}, ...rows)) : "",
    ps ? el("p", {}, `${ident} of ${ps.length} parameters identified (${ps.length - ident} held at nominal)`) : "");
}

/** An identification's verdict and its reasons, the first thing in its view (null for
 * kinds without one): accepted, review (read the reasons) or rejected (nothing usable). */
function verdictBox(r) {
  if (typeof r.verdict !== "string") return null;
  const words = { accepted: "accepted: use this calibration", review: "review: usable only after a person read the reasons", rejected: "rejected: nothing usable was made (no calibrated model)" };
  const reasons = Array.isArray(r.reasons) ? r.reasons : [];
  return el("div", { class: `verdict ${r.verdict}`, id: "verdict", "data-verdict": r.verdict },
    el("strong", {}, `Verdict — ${words[r.verdict] || r.verdict}`),
    reasons.length ? el("ul", {}, ...reasons.map((x) => el("li", { "data-code": x.code }, el("code", {}, x.code), ` (${x.severity}): ${x.message}`))) : "",
    typeof r.dof === "number" ? el("p", { class: "hint" }, `residual degrees of freedom: ${r.dof}`) : "");
}

/** Status of one parameter: identified, weakly observable, at a bound, or held and why. */
function paramStatus(r, p) {
  const names = (k) => (r[k] || []).map((x) => (typeof x === "string" ? x : x.name));
  if (p.identifiable === false) return names("unobservable").includes(p.name) ? "held: effect below the noise" : "held: not identifiable";
  if (names("weakly_observable").includes(p.name)) return "weakly observable";
  if (p.at_bound) return `at ${p.at_bound} bound`;
  return "identified";
}

/** The parameter table (folded away when long: a humanoid has about 90 rows). */
function paramTable(r) {
  const ps = r.parameters;
  const t = table(["name", "unit", "nominal", "identified", "std", "status", "effect size"],
    ps.map((p) => [p.name, p.unit, p.nominal, p.value, p.std, paramStatus(r, p), p.effect_size]));
  t.classList.add("params");
  t.querySelectorAll("tbody tr").forEach((tr, i) => { if (ps[i].identifiable === false) tr.classList.add("held"); });
  const note = el("p", { class: "hint" }, r.start_model || r.cell
    ? "nominal: the cell's model when the campaign started (the previous calibration, if one was accepted; see Cells)"
    : "nominal: the model the job started from");
  if (ps.length <= 40) return [el("h3", {}, "Parameters"), note, t];
  const ident = ps.filter((p) => p.identifiable !== false).length;
  return [el("details", {}, el("summary", {}, `Parameters: ${ident} of ${ps.length} identified (show the table)`), note, t)];
}

/** A design (`serial.design`): what was chosen from the pool, O1..O5 of the selection
 * against the pool, the selected configurations (with their download) and the DETMAX
 * history; empty for other kinds. */
function designView(id, r) {
  const o = r.observability;
  if (!o || !o.selection || !o.pool || !Array.isArray(r.selected)) return [];
  const out = [el("div", { class: "design", id: "design" },
    el("p", {}, `${r.n} of ${o.pool.configurations} pool configurations chosen by DETMAX (seed ${r.seed}, ${r.exchanges} exchanges) for ${(r.parameters || []).length} identifiable parameters` +
      ((r.unidentifiable || []).length ? `; the pool cannot identify ${r.unidentifiable.join(", ")}` : "")))];
  const defs = { o1: "(s1 … sm)^(1/m) / √n", o2: "sm / s1", o3: "sm", o4: "sm² / s1", o5: "1 / Σ(1 / si)" };
  const obs = table(["index", "definition", "selection", "pool"], Object.entries(defs).map(([k, d]) => [k.toUpperCase(), d, o.selection[k], o.pool[k]]));
  obs.id = "design-observability";
  out.push(el("h3", {}, "Observability: selection against pool (dimensionless)"), obs);
  const rows = Array.isArray(r.rows) ? r.rows : [];
  const cols = rows.length ? Object.keys(rows[0]) : [];
  const sel = table(["#", "pool row", ...cols], rows.map((x, i) => [i + 1, r.selected[i] + 1 - (r.row_index_base || 0), ...cols.map((c) => x[c])]));
  sel.id = "design-selected";
  out.push(el("h3", {}, `Selected configurations (${rows.length})`),
    el("p", {}, el("a", { href: "#", id: "design-download", onclick: (e) => { e.preventDefault(); download(`/v1/jobs/${id}/table`, `job-${id}-selected.csv`); } }, "download the selected configurations (CSV)"),
      " — pool rows counted from 1, the pool's own columns and units"),
    el("details", { open: "" }, el("summary", {}, "table"), sel));
  const steps = (r.history && r.history.steps) || [];
  out.push(el("h3", {}, "DETMAX history"), table(["improving excursions", "O1", "log det(JᵀJ)"], steps.map((s) => [s.exchanges, s.o1, s.log_det])));
  return out;
}

/** A campaign's instruments (as they identified themselves) and its declared tolerance. */
function instrumentsView(r) {
  const out = [];
  if (r.tolerance) {
    const t = r.tolerance;
    out.push(el("p", { class: `tolerance ${t.outcome === "pass" ? "pass" : t.outcome === "fail" ? "fail" : ""}`, id: "tolerance" },
      `Tolerance: ${t.outcome} — ${t.compared || "held-out max error after calibration"} ${fmt(t.held_out_max)} ${t.unit} against the declared ${fmt(t.declared)} ${t.unit}`));
  }
  if (Array.isArray(r.instruments) && r.instruments.length) {
    out.push(el("h3", {}, "Instruments (as they identified themselves at the start)"),
      table(["device", "what", "address", "identity"], r.instruments.map((i) => [i.device, i.kind, i.address, i.identity])));
  }
  return out;
}

const PLOT_ORDER = ["errors_per_configuration.svg", "validation_errors.svg", "marker_rmse.svg", "rmse_by_model.svg", "posture_rmse.svg", "design_history.svg", "dispersion_mean_error.svg", "dispersion_std_error.svg", "errors_per_axis.svg", "sensitivity_position.svg", "sensitivity_orientation.svg", "error_cdf.svg", "validation_cdf.svg", "error_histogram.svg"];

/** The SVG plots of a job, parsed and shown inline (without scripts or handlers). */
function inlinePlots(id, artefacts, box) {
  const rank = (n) => { const i = PLOT_ORDER.indexOf(n); return i < 0 ? 99 : i; };
  const svgs = artefacts.filter((f) => f.media_type === "image/svg+xml").sort((a, b) => rank(a.name) - rank(b.name));
  const slots = svgs.map((f) => { const fig = el("figure", { class: "plot", "data-name": f.name }); box.append(fig); return [f, fig]; });
  for (const [f, fig] of slots) {
    fetch(`/v1/jobs/${id}/artefacts/${encodeURIComponent(f.name)}`, { headers: headers() }).then((r) => r.text()).then((text) => {
      const doc = new DOMParser().parseFromString(text, "image/svg+xml");
      const root = doc.documentElement;
      if (!root || root.nodeName !== "svg") return;
      root.querySelectorAll("script, foreignObject").forEach((n) => n.remove());
      root.querySelectorAll("*").forEach((n) => [...n.attributes].forEach((a) => { if (/^on/i.test(a.name) || /href$/i.test(a.name)) n.removeAttribute(a.name); }));
      fig.append(document.importNode(root, true));
    }).catch(() => {});
  }
}

/** A campaign's journal: a live plot of each configuration's figure and the table. */
function journalView(entries) {
  const key = (d) => ["residual_mm", "rmse_mm", "error_mm", "e_p_um"].find((k) => typeof d[k] === "number") || Object.keys(d).find((k) => typeof d[k] === "number");
  const pts = entries.filter((e) => e.status === "measured" && e.data && typeof e.data === "object").map((e) => [e.index, e.data[key(e.data)], key(e.data)]).filter((p) => typeof p[1] === "number");
  const parts = [el("h3", {}, `Measurement journal (${entries.length} entries)`)];
  if (pts.length) {
    const W = 640, H = 200, L = 60, B = 30, T = 14;
    const xs = pts.map((p) => p[0]), ys = pts.map((p) => p[1]);
    const x0 = Math.min(...xs), x1 = Math.max(...xs, x0 + 1), y1 = Math.max(...ys, 1e-12) * 1.1;
    const ns = "http://www.w3.org/2000/svg";
    const svg = document.createElementNS(ns, "svg");
    const mk = (tag, attrs, text) => { const n = document.createElementNS(ns, tag); for (const [k, v] of Object.entries(attrs)) n.setAttribute(k, v); if (text) n.textContent = text; svg.append(n); return n; };
    svg.setAttribute("viewBox", `0 0 ${W} ${H}`); svg.setAttribute("width", W); svg.setAttribute("height", H); svg.setAttribute("class", "journal-plot");
    mk("path", { d: `M${L} ${T} V${H - B} H${W - 10}`, fill: "none", stroke: "#333" });
    mk("text", { x: 4, y: T + 4, "font-size": 11 }, fmt(y1, 3));
    mk("text", { x: 4, y: H - B, "font-size": 11 }, "0");
    mk("text", { x: L, y: H - 8, "font-size": 11 }, `configuration (journal index ${x0}–${x1}); y: ${pts[0][2]} of each as it was measured`);
    for (const [x, y] of pts) {
      mk("circle", { cx: L + ((x - x0) / (x1 - x0)) * (W - L - 20), cy: H - B - (y / y1) * (H - B - T), r: 3, fill: "#0072B2", "data-series": "journal", "data-value": y });
    }
    parts.push(svg);
  }
  const cols = [...new Set(entries.flatMap((e) => (e.data && typeof e.data === "object" ? Object.keys(e.data).filter((k) => typeof e.data[k] !== "object") : [])))].slice(0, 6);
  // Journals store balls from 0; the page counts them from 1, as results and reports do.
  const shown = (d, c) => (c === "ball" && typeof d[c] === "number" ? d[c] + 1 : d[c]);
  parts.push(el("details", { open: "" }, el("summary", {}, "journal table"),
    table(["index", "status", ...cols], entries.map((e) => [e.index, e.status, ...cols.map((c) => shown(e.data || {}, c))]))));
  return parts;
}

/** The campaign part of a job's view: journal (with its plot) and job log; refreshed live. */
async function campaignView(id, box) {
  const [m, l] = await Promise.all([api(`/v1/jobs/${id}/measurements`), api(`/v1/jobs/${id}/logs`)]);
  box.replaceChildren(...journalView(m.entries || []), el("h3", {}, "Job log"),
    table(["at", "level", "message"], (l.logs || []).map((x) => [time(x.at), x.level, x.message])));
}
let campaignTimer = null;
/** Refresh the shown campaign at most once a second while it measures. */
function campaignProgress(id) {
  const box = document.getElementById("campaign");
  if (!box || campaignTimer) return;
  campaignTimer = setTimeout(() => { campaignTimer = null; if (selected === id) campaignView(id, box).catch(() => {}); }, 1000);
}

/** The cells with their current model and model history. */
async function loadCells() {
  try {
    const r = await api("/v1/cells");
    $("#cells").replaceChildren(...(r.cells.length ? r.cells.map((c) => {
      const cur = (c.models || []).find((m) => m.state === "current");
      return el("div", { class: "cell", "data-cell": c.name }, el("h3", {}, `${c.name} (${c.kind})`),
        el("p", {}, cur ? `current model: from job ${cur.job_id ?? "?"}, accepted ${time(cur.at)}: ${cur.reason}` : "current model: nominal (no calibration accepted yet)"),
        (c.models || []).length ? table(["state", "job", "when", "reason"], c.models.map((m) => [m.state, m.job_id ?? "", time(m.at), m.reason])) : "",
        c.kind === "ball_centring" ? driftChart(c.name) : "");
    }) : [el("p", { class: "hint" }, "no cells configured")]));
  } catch { /* shown as offline */ }
}

/** The cell's verifications (AP, RP) against its last calibration: the chart the daemon draws. */
function driftChart(cell) {
  const fig = el("figure", { class: "plot drift", "data-cell": cell });
  api(`/v1/cells/${encodeURIComponent(cell)}/drift`).then((h) => {
    if (!h.points.length) { fig.append(el("p", { class: "hint" }, "no verification (cell.verify) yet")); return; }
    const root = new DOMParser().parseFromString(h.svg, "image/svg+xml").documentElement;
    if (!root || root.nodeName !== "svg") return;
    root.querySelectorAll("script, foreignObject").forEach((n) => n.remove());
    root.querySelectorAll("*").forEach((n) => [...n.attributes].forEach((a) => { if (/^on/i.test(a.name) || /href$/i.test(a.name)) n.removeAttribute(a.name); }));
    fig.append(document.importNode(root, true));
  }).catch(() => {});
  return fig;
}

const looksLikeFile = (s) => typeof s === "string" && !s.includes("\n") && (s.includes("/") || /\.(csv|json|urdf|xml|srdf|txt|tsv)$/i.test(s.trim()));

/** A job file chosen with its data files: upload the files it names and put their ids in;
 *  say which named files were not chosen. */
async function loadJobFiles(files) {
  const msg = $("#submit-msg");
  let job = null, doc = null;
  for (const f of files) {
    try { const d = JSON.parse(await f.text()); if (d && typeof d === "object" && d.kind) { job = f; doc = d; break; } } catch { /* a data file */ }
  }
  if (!doc) { msg.className = "msg err"; msg.textContent = "none of the chosen files is a job file (JSON with a `kind`)"; return; }
  const missing = [];
  for (const [k, v] of Object.entries(doc)) {
    if (k === "kind" || !looksLikeFile(v)) continue;
    const base = v.split("/").pop();
    const f = [...files].find((x) => x !== job && x.name === base);
    if (!f) { missing.push(`${k}: ${v}`); continue; }
    const r = await api("/v1/datasets?name=" + encodeURIComponent(f.name), { method: "POST", headers: { "Content-Type": f.type || "application/octet-stream" }, body: f });
    doc[k] = r.id;
  }
  $("#job-text").value = JSON.stringify(doc, null, 1);
  msg.className = missing.length ? "msg err" : "msg";
  msg.textContent = missing.length ? `the job names files that were not chosen (choose them together with the job file): ${missing.join(", ")}` : `${job.name} loaded; the files it names are uploaded`;
}
