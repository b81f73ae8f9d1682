// calibd web page: talks to /v1 with the bearer token kept in localStorage.
"use strict";
const $ = (s) => document.querySelector(s);
const el = (tag, attrs = {}, ...kids) => {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    // Styles through the CSSOM: the Content-Security-Policy forbids style attributes.
    if (k === "class") e.className = v; else if (k === "style") e.style.cssText = v; else if (k.startsWith("on")) e.addEventListener(k.slice(2), v); else e.setAttribute(k, v);
  }
  for (const k of kids) e.append(k instanceof Node ? k : document.createTextNode(k ?? ""));
  return e;
};
const jobs = new Map();
let selected = null, oldest = null;

function headers(extra = {}) {
  const t = $("#token").value.trim();
  return t ? { ...extra, Authorization: "Bearer " + t } : extra;
}
async function api(path, opts = {}) {
  const res = await fetch(path, { ...opts, headers: headers(opts.headers || {}) });
  const text = await res.text();
  let body = null;
  try { body = text ? JSON.parse(text) : null; } catch { body = text; }
  if (!res.ok) throw new Error((body && body.error && body.error.message) || res.status + " " + res.statusText);
  return body;
}
// Integers (counts, indices, ids) as written; other numbers with `d` decimals or in
// exponent form when very small or large.
const fmt = (x, d = 4) => (typeof x === "number" ? (Number.isInteger(x) && Math.abs(x) < 1e15 ? String(x) : Math.abs(x) >= 1e5 || (x !== 0 && Math.abs(x) < 1e-3) ? x.toExponential(3) : x.toFixed(d)) : x ?? "");
const time = (s) => (s ? new Date(s).toLocaleString() : "");

function row(j) {
  let tr = document.querySelector(`#jobs tr[data-id="${j.id}"]`);
  const bar = el("div", { class: "bar" }, el("div", { style: `width:${Math.round(100 * (j.progress || 0))}%` }));
  const cancel = (j.state === "queued" || j.state === "running")
    ? el("button", { type: "button", class: "cancel", onclick: (e) => { e.stopPropagation(); cancelJob(j.id); } }, "cancel") : "";
  const cells = [el("td", {}, String(j.id)), el("td", {}, j.kind), el("td", { class: "state state-" + j.state }, j.state),
    el("td", { title: [j.stage, j.message].filter(Boolean).join(": ") }, bar,
      j.state === "running" && j.message ? el("small", { class: "hint" }, j.message) : ""),
    el("td", {}, time(j.submitted_at)), el("td", {}, cancel)];
  const fresh = el("tr", { "data-id": j.id, onclick: () => showJob(j.id) }, ...cells);
  if (selected === j.id) fresh.classList.add("sel");
  if (tr) tr.replaceWith(fresh);
  else {
    const body = $("#jobs tbody");
    const after = [...body.children].find((r) => Number(r.dataset.id) < j.id);
    body.insertBefore(fresh, after || null);
  }
}

async function loadJobs(more = false) {
  const st = $("#state-filter").value;
  const q = new URLSearchParams({ limit: "50" });
  if (st) q.set("state", st);
  if (more && oldest) q.set("before", oldest);
  const r = await api("/v1/jobs?" + q);
  if (!more) { $("#jobs tbody").replaceChildren(); jobs.clear(); }
  for (const j of r.jobs) { jobs.set(j.id, j); row(j); }
  oldest = r.next_before;
  $("#more").hidden = !r.next_before;
}

async function refreshJob(id) {
  const j = await api("/v1/jobs/" + id);
  jobs.set(id, j);
  const st = $("#state-filter").value;
  if (!st || st === j.state) row(j);
  if (selected === id) showJob(id);
}

function handleEvent(name, data) {
  if (name === "progress") {
    const j = jobs.get(data.id);
    if (j) {
      j.progress = data.fraction; j.stage = data.stage; j.state = "running";
      if (data.message) j.message = data.message;
      row(j);
      const live = document.getElementById("detail-progress");
      if (live && selected === data.id) live.textContent = ` — ${j.stage} (${Math.round(100 * j.progress)} %) ${j.message || ""}`;
      if (selected === data.id) campaignProgress(data.id);
    }
  } else if (name === "state") {
    refreshJob(data.id).catch(() => {});
  } else if (name === "lagged") {
    loadJobs().catch(() => {});
  }
}

// Server-Sent Events over fetch (EventSource cannot send the Authorization header).
async function stream() {
  try {
    const res = await fetch("/v1/events", { headers: headers() });
    if (!res.ok) throw new Error(res.status);
    $("#live").textContent = "live"; $("#live").classList.add("on");
    // Events sent while the stream was down (no token yet, daemon restart) are gone: catch up.
    loadJobs().catch(() => {});
    if (selected !== null) showJob(selected).catch(() => {});
    const reader = res.body.getReader(), dec = new TextDecoder();
    let buf = "";
    for (;;) {
      const { value, done } = await reader.read();
      if (done) break;
      buf += dec.decode(value, { stream: true });
      let i;
      while ((i = buf.indexOf("\n\n")) >= 0) {
        const chunk = buf.slice(0, i); buf = buf.slice(i + 2);
        let name = "message", data = "";
        for (const line of chunk.split("\n")) {
          if (line.startsWith("event:")) name = line.slice(6).trim();
          else if (line.startsWith("data:")) data += line.slice(5).trim();
        }
        if (data) { try { handleEvent(name, JSON.parse(data)); } catch { /* ignore */ } }
      }
    }
  } catch { /* reconnect below */ }
  $("#live").textContent = "offline"; $("#live").classList.remove("on");
  setTimeout(stream, 2000);
}

async function blobUrl(path) {
  const res = await fetch(path, { headers: headers() });
  if (!res.ok) throw new Error(res.status);
  return URL.createObjectURL(await res.blob());
}

function table(cols, rows) {
  return el("table", {}, el("thead", {}, el("tr", {}, ...cols.map((c) => el("th", {}, c)))),
    el("tbody", {}, ...rows.map((r) => el("tr", {}, ...r.map((c) => el("td", {}, typeof c === "number" ? fmt(c) : String(c ?? "")))))));
}

function statsTable(title, obj) {
  if (!obj || !obj.before || !obj.after) return null;
  const keys = ["mean", "median", "std", "max"];
  return [el("h3", {}, title + (obj.after.unit ? ` (${obj.after.unit})` : "")),
    table(["", ...keys], [["before", ...keys.map((k) => obj.before[k])], ["after", ...keys.map((k) => obj.after[k])]])];
}

async function showJob(id) {
  selected = id;
  document.querySelectorAll("#jobs tr.sel").forEach((r) => r.classList.remove("sel"));
  const tr = document.querySelector(`#jobs tr[data-id="${id}"]`);
  if (tr) tr.classList.add("sel");
  const d = $("#detail");
  d.hidden = false;
  const j = await api("/v1/jobs/" + id);
  // A commissioning step waiting for the operator: its pause reason is the prompt.
  const waiting = "waiting for the operator: ";
  const prompt = j.state === "paused" && j.error && j.error.startsWith(waiting) ? j.error.slice(waiting.length) : "";
  const parts = [el("h2", {}, `Job ${j.id}: ${j.kind}`),
    el("p", {}, el("span", { class: "state state-" + j.state, id: "detail-state" }, j.state),
      el("span", { id: "detail-progress" },
        j.state === "running" && j.stage ? ` — ${j.stage} (${Math.round(100 * j.progress)} %) ${j.message || ""}` : ""),
      j.error && !prompt ? el("div", { class: "msg err" }, j.error) : ""),
    prompt ? el("div", { class: "prompt" }, el("strong", {}, "Operator: "), prompt, liveIndicators(j),
      el("div", {}, el("button", { type: "button", class: "continue", onclick: () => resumeJob(j.id) }, "continue"))) : "",
    el("p", { class: "hint" }, `submitted ${time(j.submitted_at)} by ${j.submitted_by || "?"}` +
      (j.finished_at ? `, finished ${time(j.finished_at)}` : "")),
    el("button", { type: "button", onclick: () => rerun(j.id) }, "re-run"),
    (j.state === "paused" && !prompt) || j.state === "interrupted"
      ? el("button", { type: "button", onclick: () => resumeJob(j.id) }, "resume") : ""];
  const campaign = /campaign/.test(j.kind) ? el("div", { id: "campaign" }) : null;
  if (j.state === "succeeded") {
    const r = await api(`/v1/jobs/${id}/result`);
    const a = await api(`/v1/jobs/${id}/artefacts`);
    const head = headline(r);
    if (head) parts.splice(2, 0, head);
    const verdict = verdictBox(r);
    if (verdict) parts.splice(2, 0, verdict);
    const plots = el("div", { class: "plots" });
    parts.push(plots);
    inlinePlots(id, a.artefacts, plots);
    if (paramRows(r)) parts.push(...paramTable(r));
    parts.push(...designView(id, r));
    for (const [t, k] of [["Validation errors", "validation"], ["Residuals", "residuals"]]) {
      const s = statsTable(t, r[k]);
      if (s) parts.push(...s);
    }
    parts.push(...commissioning(r));
    parts.push(...instrumentsView(r));
    if (Array.isArray(r.sizes)) {
      parts.push(el("h3", {}, "Dispersion (mean validation error)"),
        table(["n", "min", "q1", "median", "q3", "max"], r.sizes.map((s) => [s.n, s.mean_error.min, s.mean_error.q1, s.mean_error.median, s.mean_error.q3, s.mean_error.max])));
    }
    const links = el("ul", { id: "artefacts" });
    links.append(el("li", {}, el("a", { href: "#", id: "report-link", onclick: (e) => { e.preventDefault(); download(`/v1/jobs/${id}/report`, `job-${id}-report.html`); } }, "printable report (HTML)"), " — open the file in a browser to read, print and sign it off"));
    for (const f of a.artefacts) {
      links.append(el("li", {}, el("a", { href: "#", "data-name": f.name, onclick: (e) => { e.preventDefault(); download(`/v1/jobs/${id}/artefacts/${encodeURIComponent(f.name)}`, f.name); } }, f.name), ` (${f.media_type}, ${f.size} bytes)`));
    }
    links.append(el("li", {}, el("a", { href: "#", onclick: (e) => { e.preventDefault(); download(`/v1/jobs/${id}/result`, `job-${id}-result.json`); } }, "result.json")));
    parts.push(el("h3", {}, "Downloads"), links, el("details", {}, el("summary", {}, "result JSON"), el("pre", {}, JSON.stringify(r, null, 2))));
  }
  if (campaign) { parts.push(campaign); campaignView(id, campaign).catch(() => {}); }
  if (selected === id) d.replaceChildren(...parts);
}

/** Live readings of a waiting TriCal job's indicators, polled each second while shown. */
function liveIndicators(j) {
  const uw = (j.devices || []).find((d) => d.endsWith(".uwave"));
  if (!uw) return "";
  const cell = uw.slice(0, -".uwave".length);
  const span = el("div", { class: "indicators" }, "indicators: …");
  const poll = async () => {
    if (!span.isConnected && span.dataset.started) return;
    span.dataset.started = "1";
    try {
      const r = await api(`/v1/cells/${encodeURIComponent(cell)}/indicators`);
      span.textContent = r.reading_mm ? "indicators (mm): " + r.reading_mm.map((x) => x.toFixed(3)).join("  ") : "indicators: " + r.error;
    } catch (e) { span.textContent = "indicators: " + e.message; }
    setTimeout(poll, 1000);
  };
  poll();
  return span;
}

/** Tables of the commissioning kinds' results (zero check, TCP, balls). */
function commissioning(r) {
  const out = [];
  const xyz = (v) => (v || []).map((x) => fmt(x)).join(", ");
  if (r.out_of_tolerance && r.mean_mm) {
    out.push(el("h3", {}, `Zero check: ${r.passed ? "passed" : "out of tolerance"} (±${r.tolerance_mm} mm)`),
      table(["indicator", "mean (mm)", "max |reading| (mm)"], [0, 1, 2].map((k) => [k + 1, r.mean_mm[k], r.max_abs_mm[k]])),
      el("p", { class: r.passed ? "hint" : "msg err" }, r.message));
  }
  if (r.tcp_mm && r.points) {
    out.push(el("h3", {}, "TCP (flange frame, mm)"),
      table(["", "x", "y", "z"], [["identified", ...r.tcp_mm], ["std", ...r.tcp_std_mm], ["previous", ...r.previous_tcp_mm]]),
      el("p", { class: "hint" }, `spread of the centred points ${fmt(r.spread_rms_mm)} mm (previous TCP ${fmt(r.previous_spread_rms_mm)} mm); largest rotation ${fmt(r.max_rotation_deg)} deg`),
      table(["configuration", "distance (mm)", "previous (mm)"], r.points.map((p) => [p.configuration, p.distance_mm, p.previous_distance_mm])));
  }
  if (r.balls && r.distances) {
    out.push(el("h3", {}, "Balls in the robot frame (mm)"),
      table(["ball", "position", "std", "fit residual"], r.balls.map((b) => [b.ball, xyz(b.in_robot_mm), xyz(b.std_mm), b.fit_residual_mm])),
      table(["pair", "measured (mm)", "std", "ballbar (mm)", "difference (mm)"], r.distances.map((d) => [d.pair, d.measured_mm, d.std_mm, d.ballbar_mm, d.difference_mm])),
      el("h3", {}, "Base frame {0} in {W}"),
      table(["", "x (mm)", "y", "z", "a (deg)", "b", "c"], [["fitted", r.base], ["previous", r.previous_base]].map(([n, b]) => [n, b.x_mm, b.y_mm, b.z_mm, b.a_deg, b.b_deg, b.c_deg])),
      el("p", { class: "hint" }, `balls against the plate: ${fmt(r.fit_residual_rms_mm)} mm RMS (previous base ${fmt(r.previous_residual_rms_mm)} mm)`));
  }
  return out;
}

async function download(path, name) {
  const u = await blobUrl(path);
  const a = el("a", { href: u, download: name });
  document.body.append(a); a.click(); a.remove();
  setTimeout(() => URL.revokeObjectURL(u), 10000);
}

async function cancelJob(id) {
  try { await api(`/v1/jobs/${id}/cancel`, { method: "POST" }); } catch (e) { alert(e.message); }
}
async function resumeJob(id) {
  try { await api(`/v1/jobs/${id}/resume`, { method: "POST" }); await refreshJob(id); } catch (e) { alert(e.message); }
}

async function rerun(id) {
  try { const r = await api(`/v1/jobs/${id}/rerun`, { method: "POST" }); await refreshJob(r.id); showJob(r.id); } catch (e) { alert(e.message); }
}

async function submit() {
  const msg = $("#submit-msg");
  msg.className = "msg"; msg.textContent = "submitting…"; delete msg.dataset.token;
  try {
    const prio = parseInt($("#priority").value || "0", 10);
    const r = await api("/v1/jobs?priority=" + prio, { method: "POST", headers: { "Content-Type": "application/json" }, body: $("#job-text").value });
    msg.textContent = `job ${r.id} queued`;
    await refreshJob(r.id);
    showJob(r.id);
  } catch (e) { msg.className = "msg err"; msg.textContent = e.message; }
}

async function upload() {
  const f = $("#dataset-file").files[0], msg = $("#upload-msg");
  if (!f) return;
  msg.className = "msg";
  try {
    const r = await api("/v1/datasets?name=" + encodeURIComponent(f.name), { method: "POST", headers: { "Content-Type": f.type || "application/octet-stream" }, body: f });
    msg.textContent = `dataset id: ${r.id}`;
  } catch (e) { msg.className = "msg err"; msg.textContent = e.message; }
}

async function loadDevices() {
  try {
    const r = await api("/v1/devices");
    $("#devices tbody").replaceChildren(...(r.devices.length ? r.devices.map((d) => el("tr", {}, el("td", {}, d.name), el("td", {}, d.state), el("td", {}, d.job ?? ""), el("td", {}, String(d.waiting))))
      : [el("tr", {}, el("td", { colspan: "4", class: "hint" }, "no devices configured"))]));
  } catch { /* shown as offline */ }
}

async function loadLab(refresh = false) {
  try {
    const r = await api("/v1/lab" + (refresh ? "?refresh=true" : ""));
    $("#sim-banner").hidden = !r.simulated;
    $("#lab-cells").replaceChildren(...r.cells.map((c) => el("div", { class: c.available ? "cell-ok" : "cell-down" },
      `${c.name} (${c.kind}): ${c.available ? "available" : c.reason}`)));
    const text = (d) => d.state === "ok" ? `${d.kind}: ${d.identity.summary}` : d.state === "failed" ? `${d.kind}: ${d.error} — fix: ${d.fix}` : "not checked yet";
    $("#lab tbody").replaceChildren(...(r.devices.length ? r.devices.map((d) => el("tr", { "data-device": d.device },
      el("td", {}, d.device), el("td", {}, d.address), el("td", { class: "lab-" + d.state }, d.state), el("td", {}, text(d))))
      : [el("tr", {}, el("td", { colspan: "4", class: "hint" }, "no lab configured"))]));
  } catch { /* shown as offline */ }
}

async function init() {
  $("#token").value = localStorage.getItem("calibd-token") || "";
  // Reads need the token too: everything is (re)loaded when it changes.
  $("#token").addEventListener("change", () => { localStorage.setItem("calibd-token", $("#token").value.trim()); loadAll(); });
  $("#submit").addEventListener("click", submit);
  $("#upload").addEventListener("click", upload);
  $("#more").addEventListener("click", () => loadJobs(true));
  $("#lab-check").addEventListener("click", () => loadLab(true));
  $("#state-filter").addEventListener("change", () => loadJobs());
  $("#job-file").addEventListener("change", () => { const f = $("#job-file").files; if (f.length) loadJobFiles(f).catch((e) => { $("#submit-msg").className = "msg err"; $("#submit-msg").textContent = e.message; }); });
  $("#load-example").addEventListener("click", async () => {
    const name = $("#example-select").value;
    const doc = await api("/v1/examples/" + encodeURIComponent(name));
    $("#job-text").value = JSON.stringify(doc, null, 1);
  });
  try {
    const v = await api("/v1/version");
    $("#version").textContent = "v" + v.calibd_version;
  } catch { /* shown as offline */ }
  await loadAll();
  setInterval(loadDevices, 5000);
  setInterval(loadLab, 10000);
  setInterval(loadCells, 10000);
  stream();
}

async function loadAll() {
  try {
    const ex = await api("/v1/examples");
    // Keep the operator's choice when the list is loaded again (a token change, a submit).
    const chosen = $("#example-select").value;
    $("#example-select").replaceChildren(...ex.examples.map((e) => el("option", { value: e.name, title: e.description }, `${e.name}: ${e.description.split(":")[0]}`)));
    if (chosen && ex.examples.some((e) => e.name === chosen)) $("#example-select").value = chosen;
    await loadJobs();
    if ($("#submit-msg").dataset.token === "missing") { $("#submit-msg").className = "msg"; $("#submit-msg").textContent = ""; delete $("#submit-msg").dataset.token; }
  } catch (e) {
    const m = $("#submit-msg"), has = !!$("#token").value.trim();
    m.className = "msg err";
    m.textContent = has ? e.message : "Enter a token (the daemon's operator.token, or one from `calibd token`) to see jobs and results.";
    if (!has) m.dataset.token = "missing";
  }
  loadDevices();
  loadLab();
  loadCells();
}
init();
