// Drives the calibd web page in headless Chromium: load the page, enter the token, load the
// IRB 120 identification example, submit it, watch it finish through the live job list,
// check the result tables and plots, download the calibrated model, check that an uploaded
// HTML dataset opens as an inert download (no script runs), save a screenshot.
// Usage: node browser.mjs URL TOKEN SCREENSHOT.png
import { chromium } from "playwright-core";
import { readFileSync } from "node:fs";

const [url, token, shot] = process.argv.slice(2);
const fail = (msg) => { console.error("browser test FAILED: " + msg); process.exit(1); };
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
  args: ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
    "--disable-component-update", "--disable-sync", "--no-first-run", "--disable-quic"],
});
const errors = [];
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
  const rows = await page.$$eval("#detail table:first-of-type tbody tr", (r) => r.length);
  if (rows < 20) fail(`parameters table has ${rows} rows`);
  await page.waitForFunction(() => document.querySelectorAll("#detail .plots img").length >= 2, null, { timeout: 20000 });
  await page.waitForFunction(() => [...document.querySelectorAll("#detail .plots img")].every((i) => i.complete && i.naturalWidth > 0));
  const link = `#artefacts a[data-name="calibrated_model.json"]`;
  await page.waitForSelector(link);
  const [download] = await Promise.all([page.waitForEvent("download"), page.click(link)]);
  const model = JSON.parse(readFileSync(await download.path(), "utf8"));
  if (!model || typeof model !== "object" || Object.keys(model).length === 0) fail("calibrated model download is empty");
  console.log(`downloaded ${download.suggestedFilename()} (${Object.keys(model).length} top-level fields)`);
  await page.screenshot({ path: shot, fullPage: true });
  console.log(`screenshot: ${shot}`);
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
