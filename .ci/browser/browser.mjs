// Drives the calibd web page in headless Chromium: load the page, enter the token, load the
// IRB 120 identification example, submit it, watch it finish through the live job list,
// check the result tables and plots, download the calibrated model, check that an uploaded
// HTML dataset opens as an inert download (no script runs), save a screenshot. Then open a
// finished PCR and humanoid job (JOBS env), check their headline numbers and that each
// plot's "after" series is drawn at a visible size (and the PCR Table 2 bars), open a
// finished serial.design (its DETMAX O1 history) and serial.dispersion (its box plots on a
// log axis), and follow a running TriCal campaign's live journal. Screenshots go next to SCREENSHOT.png.
// Usage: node browser.mjs URL TOKEN SCREENSHOT.png
import { chromium } from "playwright-core";
import { readFileSync } from "node:fs";

const [url, token, shot] = process.argv.slice(2);
const dir = shot.replace(/\/[^/]*$/, "");
// JOBS="pcr:12,humanoid:13": finished jobs of the other methods to open.
const jobIds = Object.fromEntries((process.env.JOBS || "").split(",").filter(Boolean).map((p) => p.split(":")));
const fail = (msg) => { console.error("browser test FAILED: " + msg); process.exit(1); };
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
  args: ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
    "--disable-component-update", "--disable-sync", "--no-first-run", "--disable-quic"],
});
const errors = [];

/** The plots of the shown job: each named one is inline SVG, and its "after" marks (bars or
 *  points, read from the SVG in the DOM) have a visible extent. */
async function checkPlots(page, method, names) {
  for (const name of names) {
    const sel = `#detail figure[data-name="${name}"] svg`;
    await page.waitForSelector(sel, { timeout: 20000 }).catch(() => fail(`${method}: no plot ${name}`));
    const m = await page.$eval(sel, (svg) => {
      const marks = [...svg.querySelectorAll('[data-series="after"]')];
      const ext = marks.map((n) => n.getBoundingClientRect()).map((b) => Math.max(b.height, 0));
      const before = [...svg.querySelectorAll('[data-series="before"]')].map((n) => n.getBoundingClientRect().height);
      return { n: marks.length, visible: ext.filter((h) => h >= 2).length, min: Math.min(...ext), max: Math.max(...ext), beforeMax: Math.max(...before), dataset: (svg.querySelector(".dataset") || {}).textContent };
    });
    if (m.n === 0 || m.visible < 0.9 * m.n) fail(`${method} ${name}: after series not visible: ${JSON.stringify(m)}`);
    console.log(`${method} ${name}: ${m.visible}/${m.n} after marks visible (${m.min.toFixed(1)}-${m.max.toFixed(1)} px; before up to ${m.beforeMax.toFixed(1)} px); data set: ${m.dataset}`);
  }
}
/** One plot of the shown job: its marks of `series` (bars, points or boxes read from the SVG
 *  in the DOM) are all there and at least `share` of them have a visible extent (points:
 *  their height above the plot's bottom edge). Returns the marks' data values. */
async function checkSeries(page, method, name, series, share = 1) {
  const sel = `#detail figure[data-name="${name}"] svg`;
  await page.waitForSelector(sel, { timeout: 20000 }).catch(() => fail(`${method}: no plot ${name}`));
  const m = await page.$eval(sel, (svg, series) => {
    const bottom = [...svg.querySelectorAll("path")].map((p) => p.getBoundingClientRect()).reduce((a, b) => Math.max(a, b.bottom), 0);
    const marks = [...svg.querySelectorAll(`[data-series="${series}"]`)].filter((n) => n.hasAttribute("data-value"));
    const ext = marks.map((n) => { const b = n.getBoundingClientRect(); return n.tagName === "circle" ? bottom - (b.top + b.bottom) / 2 : b.height; });
    return { n: marks.length, values: marks.map((n) => Number(n.getAttribute("data-value"))), visible: ext.filter((h) => h >= 2).length, min: Math.min(...ext), max: Math.max(...ext), log: svg.getAttribute("data-y-scale") === "log", dataset: (svg.querySelector(".dataset") || {}).textContent };
  }, series);
  if (m.n === 0 || m.visible < share * m.n) fail(`${method} ${name}: ${series} marks not visible: ${JSON.stringify(m)}`);
  console.log(`${method} ${name}: ${m.visible}/${m.n} ${series} marks visible (${m.min.toFixed(1)}-${m.max.toFixed(1)} px${m.log ? ", log axis" : ""}); data set: ${m.dataset}`);
  return m;
}

/** Open a finished job of the list in the detail view. */
async function openJob(page, id) {
  await page.goto(url, { waitUntil: "load" });
  await page.waitForSelector(`#jobs tr[data-id="${id}"] td.state-succeeded`, { timeout: 600000 });
  await page.click(`#jobs tr[data-id="${id}"]`);
  await page.waitForSelector("#detail-state.state-succeeded", { timeout: 20000 });
}

try {
  const page = await browser.newPage({ viewport: { width: 1400, height: 1100 }, acceptDownloads: true });
  page.on("pageerror", (e) => errors.push(e.message));
  page.on("console", (m) => { if (m.type() === "error") errors.push(m.text()); });
  await page.goto(url, { waitUntil: "load" });
  // Without a token the page can read nothing (401s) and says so.
  await page.waitForFunction(() => /Enter a token/.test(document.querySelector("#submit-msg").textContent));
  await page.fill("#token", token);
  await page.dispatchEvent("#token", "change");
  await page.waitForSelector('#example-select option[value="irb120-identify"]', { state: "attached" });
  errors.length = 0; // the 401s of the reads before the token was entered
  await page.selectOption("#example-select", "irb120-identify");
  await page.click("#load-example");
  await page.waitForFunction(() => document.querySelector("#job-text").value.includes("serial.identify"));
  await page.click("#submit");
  await page.waitForFunction(() => /job \d+ queued/.test(document.querySelector("#submit-msg").textContent), null, { timeout: 20000 });
  const id = (await page.textContent("#submit-msg")).match(/job (\d+)/)[1];
  console.log(`submitted job ${id}`);
  // The live list (SSE) shows the job finishing.
  await page.waitForSelector(`#jobs tr[data-id="${id}"] td.state-succeeded`, { timeout: 120000 });
  console.log(`job ${id} succeeded in the job list`);
  await page.waitForSelector("#detail-state.state-succeeded", { timeout: 20000 });
  await page.waitForSelector("#detail table", { timeout: 20000 });
  const rows = await page.$$eval("#detail table.params tbody tr", (r) => r.length);
  if (rows < 20) fail(`parameters table has ${rows} rows`);
  await page.waitForSelector("#headline", { timeout: 20000 });
  await checkPlots(page, "serial", ["errors_per_configuration.svg", "validation_errors.svg"]);
  const link = `#artefacts a[data-name="calibrated_model.json"]`;
  await page.waitForSelector(link);
  const [download] = await Promise.all([page.waitForEvent("download"), page.click(link)]);
  const model = JSON.parse(readFileSync(await download.path(), "utf8"));
  if (!model || typeof model !== "object" || Object.keys(model).length === 0) fail("calibrated model download is empty");
  console.log(`downloaded ${download.suggestedFilename()} (${Object.keys(model).length} top-level fields)`);
  await page.screenshot({ path: shot, fullPage: true });
  console.log(`screenshot: ${shot}`);
  await page.screenshot({ path: `${dir}/serial-identify.png`, fullPage: true });
  console.log(`screenshot: ${dir}/serial-identify.png`);
  if (errors.length) fail("page errors: " + errors.join("; "));
  // Stored XSS: a submitter uploads an HTML page as a dataset; opening its link must not run
  // it in the page's origin (where the token lives in localStorage).
  const hits = [];
  page.context().on("request", (r) => { if (r.url().includes("xss-marker")) hits.push(r.url()); });
  const evil = "<html><head><title>x</title></head><body><script>document.title='pwned';" +
    "fetch('/xss-marker?t='+localStorage.getItem('calibd-token'))</script></body></html>";
  const dsId = await page.evaluate(async ([t, body]) => {
    const r = await fetch("/v1/datasets?name=evil.html", { method: "POST", headers: { Authorization: "Bearer " + t, "Content-Type": "text/html" }, body });
    return (await r.json()).id;
  }, [token, evil]);
  // Opened in the same tab, on the origin whose localStorage holds the token.
  await page.setExtraHTTPHeaders({ Authorization: "Bearer " + token });
  const dl = page.waitForEvent("download", { timeout: 20000 });
  try { await page.goto(`${url}/v1/datasets/${dsId}`); } catch (e) { /* a download aborts the navigation */ }
  const evilFile = await dl;
  const got = readFileSync(await evilFile.path(), "utf8");
  if (got !== evil) fail("the uploaded dataset did not come back byte for byte");
  if ((await page.title()) === "pwned") fail("the uploaded HTML ran as a page");
  if (hits.length) fail("the uploaded script ran: " + hits.join(", "));
  console.log(`uploaded HTML dataset ${dsId.slice(0, 12)}... came back as a download (${evilFile.suggestedFilename()}); no script ran`);

  // The lab check: every device of the simulated lab says who it is.
  await page.click("#lab-check");
  await page.waitForFunction(() => {
    const rows = [...document.querySelectorAll("#lab tbody tr[data-device]")];
    return rows.length >= 6 && rows.every((r) => r.children[2].textContent === "ok");
  }, null, { timeout: 20000 });
  const rws = await page.textContent('#lab tr[data-device="irb120.rws"]');
  if (!/ABB IRC5/.test(rws)) fail("the lab check row of irb120.rws says " + rws);
  console.log("lab check on the page: " + rws.replace(/\s+/g, " "));

  // A finished job of the two other methods (submitted by the check with `calibd submit`).
  for (const [method, id, plots] of [["pcr", jobIds.pcr, ["errors_per_configuration.svg", "validation_errors.svg"]],
    ["humanoid", jobIds.humanoid, ["marker_rmse.svg", "validation_errors.svg"]]]) {
    if (!id) fail(`no ${method} job id given (JOBS=${process.env.JOBS})`);
    await openJob(page, id);
    await page.waitForSelector("#headline", { timeout: 20000 });
    await checkPlots(page, method, plots);
    if (method === "pcr") {
      // Table 2 of the nominal model: one bar per non-zero sensitivity (E without load is 0).
      for (const [name, series] of [["sensitivity_position.svg", "dx"], ["sensitivity_position.svg", "dy"], ["sensitivity_orientation.svg", "dtheta"]]) {
        const m = await checkSeries(page, method, name, series);
        if (m.n < 8) fail(`pcr ${name}: only ${m.n} ${series} bars`);
      }
    }
    if (method === "humanoid") {
      const rmse = await page.$eval("#headline", (h) => {
        const r = h.querySelector('tr[data-key="/rmse_after_mm"]');
        return r ? [...r.children].map((c) => c.textContent) : null;
      });
      if (!rmse || !/Marker RMSE/.test(rmse[0]) || !(Number(rmse[1]) > Number(rmse[2]))) fail("the humanoid view does not show the marker RMSE before/after: " + rmse);
      console.log(`humanoid headline: ${rmse.slice(0, 4).join(" | ")}`);
    }
    await page.screenshot({ path: `${dir}/${method}-identify.png`, fullPage: true });
    console.log(`screenshot: ${dir}/${method}-identify.png`);
  }

  // A design: the DETMAX O1 history, ending at the O1 the result reports.
  if (!jobIds.design || !jobIds.dispersion) fail(`no design/dispersion job id given (JOBS=${process.env.JOBS})`);
  await openJob(page, jobIds.design);
  const hist = await checkSeries(page, "design", "design_history.svg", "history");
  const design = await page.evaluate(async ([t, id]) => (await fetch(`/v1/jobs/${id}/result`, { headers: { Authorization: "Bearer " + t } })).json(), [token, jobIds.design]);
  if (hist.n !== design.history.steps.length || hist.values[hist.n - 1] !== design.observability.selection.o1) fail(`design history ${JSON.stringify(hist.values)} does not end at O1 ${design.observability.selection.o1}`);
  // The design view: the selected configurations are the result's rows, O1..O5 of the
  // selection and of the pool are the result's, and there is no parameter table.
  await page.waitForSelector("#design-selected", { timeout: 20000 });
  const view = await page.evaluate(() => ({
    selected: [...document.querySelectorAll("#design-selected tbody tr")].map((tr) => [...tr.children].map((td) => td.textContent)),
    obs: [...document.querySelectorAll("#design-observability tbody tr")].map((tr) => [...tr.children].map((td) => td.textContent)),
    params: !!document.querySelector("table.params"),
    identified: /parameters identified/.test(document.querySelector("#detail").textContent),
    download: !!document.querySelector("#design-download"),
  }));
  const near = (text, v) => Math.abs(Number(text) - v) <= 5e-5 + 1e-3 * Math.abs(v);
  if (view.selected.length !== design.rows.length || view.selected.length !== design.selected.length) fail(`design: ${view.selected.length} selected rows shown, the result has ${design.rows.length}`);
  view.selected.forEach((row, i) => {
    if (Number(row[1]) !== design.selected[i] + 1) fail(`design row ${i + 1}: pool row ${row[1]}, the result selected ${design.selected[i]} (from 0)`);
    const cols = Object.keys(design.rows[i]);
    cols.forEach((c, k) => { if (!near(row[2 + k], design.rows[i][c])) fail(`design row ${i + 1} ${c}: shown ${row[2 + k]}, result ${design.rows[i][c]}`); });
  });
  if (view.obs.length !== 5) fail(`design: ${view.obs.length} observability rows, want O1..O5`);
  view.obs.forEach((row, k) => {
    const key = `o${k + 1}`;
    if (row[0] !== key.toUpperCase() || !near(row[2], design.observability.selection[key]) || !near(row[3], design.observability.pool[key])) fail(`design ${key}: shown ${row}, result ${design.observability.selection[key]} / ${design.observability.pool[key]}`);
  });
  if (view.params || view.identified) fail("the design view shows a parameter table or an identified count");
  if (!view.download) fail("the design view has no download of the selected configurations");
  console.log(`design view: ${view.selected.length} selected configurations; ${view.obs.map((r) => `${r[0]} ${r[2]} (pool ${r[3]})`).join(", ")}`);
  await page.screenshot({ path: `${dir}/serial-design.png`, fullPage: true });
  console.log(`design: ${hist.n} DETMAX steps, O1 ${hist.values[0].toPrecision(4)} -> ${hist.values[hist.n - 1].toPrecision(4)}; screenshot: ${dir}/serial-design.png`);
  // A dispersion study: a box per set size on a log error axis.
  await openJob(page, jobIds.dispersion);
  for (const name of ["dispersion_mean_error.svg", "dispersion_std_error.svg"]) {
    const m = await checkSeries(page, "dispersion", name, name.replace("dispersion_", "").replace(".svg", ""), 0.5);
    if (!m.log || m.n !== 2) fail(`dispersion ${name}: ${m.n} boxes, log axis ${m.log}`);
  }
  await page.screenshot({ path: `${dir}/serial-dispersion.png`, fullPage: true });
  console.log(`screenshot: ${dir}/serial-dispersion.png`);

  // A running campaign from the example list: its journal fills and its plot grows.
  await page.goto(url, { waitUntil: "load" });
  await page.waitForSelector('#example-select option[value="trical-campaign"]', { state: "attached" });
  await page.selectOption("#example-select", "trical-campaign");
  await page.click("#load-example");
  await page.waitForFunction(() => document.querySelector("#job-text").value.includes("cell.trical_campaign"));
  await page.click("#submit");
  await page.waitForFunction(() => /job \d+ queued/.test(document.querySelector("#submit-msg").textContent), null, { timeout: 20000 });
  const cid = (await page.textContent("#submit-msg")).match(/job (\d+)/)[1];
  await page.waitForFunction(() => document.querySelectorAll("#campaign .journal-plot circle").length >= 3, null, { timeout: 300000 });
  const state = await page.textContent("#detail-state");
  const points = await page.$$eval("#campaign .journal-plot circle", (c) => c.length);
  await page.screenshot({ path: `${dir}/campaign-running.png`, fullPage: true });
  console.log(`campaign job ${cid} (${state}): ${points} configurations in the live journal plot; screenshot: ${dir}/campaign-running.png`);
  await page.evaluate(async ([t, id]) => fetch(`/v1/jobs/${id}/cancel`, { method: "POST", headers: { Authorization: "Bearer " + t } }), [token, cid]);
  if (errors.length) fail("page errors: " + errors.join("; "));

  console.log("browser test passed");
} catch (e) {
  // Say what the page showed: its errors and the job list.
  const pages = browser.contexts().flatMap((c) => c.pages());
  for (const p of pages) {
    try { await p.screenshot({ path: shot.replace(/\.png$/, "-failed.png"), fullPage: true }); } catch { /* closed */ }
    try { console.error("job list: " + (await p.textContent("#jobs"))); } catch { /* none */ }
    try { console.error("live: " + (await p.textContent("#live")) + "; message: " + (await p.textContent("#submit-msg"))); } catch { /* none */ }
  }
  fail(e.message + (errors.length ? "; page errors: " + errors.join("; ") : ""));
} finally {
  await browser.close();
}
