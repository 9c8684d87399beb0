// End-to-end test of covec's web page in headless Debian Chromium or Firefox ESR, driven by
// puppeteer-core (driver.mjs: the same test body in both). It starts a real `covec serve` on a
// free loopback port with a fresh data directory (or uses --url), uploads
// tests/fixtures/web_astronaut.png with a small budget, and checks what a person would see: the
// form bounded by the server's limits, refusals next to the file they concern, progress and
// stage previews, a running job's draft, the result, that each layer toggle changes the pixels, a recolour (by colour
// and by a reference image) through the edits API and its undo, the downloads (byte for byte
// the API's files, named after the input), a PNG of a chosen width, the job resumed from the
// page's address after a reload (finished and mid-job), several files at once, the sample
// photo, and that the browser's rendering of the inlined SVG matches covec's own renderer (the
// job's final composite preview) to a mean of 1.5/255.
//
//   node tests/browser/page.test.mjs --covec target/release/covec [--browser firefox] [--artifacts DIR]
//   node tests/browser/page.test.mjs --url http://127.0.0.1:8080
//
// --browser is chromium (the default) or firefox. Screenshots of every step go to
// tests/artifacts/browser/BROWSER/. Ends with "N passed, N failed".

import { spawn } from "node:child_process";
import { createHash } from "node:crypto";
import fs from "node:fs";
import net from "node:net";
import os from "node:os";
import path from "node:path";
import { fileURLToPath } from "node:url";
import { parseArgs } from "node:util";
import zlib from "node:zlib";

import { BROWSERS, launch } from "./driver.mjs";

const here = path.dirname(fileURLToPath(import.meta.url));
const repo = path.resolve(here, "../..");

const { values: args } = parseArgs({
  options: {
    covec: { type: "string" },
    url: { type: "string" },
    browser: { type: "string", default: "chromium" },
    /** The browser's executable, if not Debian's (driver.mjs, BROWSERS). */
    executable: { type: "string" },
    artifacts: { type: "string" },
  },
});
if (!args.covec === !args.url || !BROWSERS[args.browser]) {
  console.error(
    `usage: page.test.mjs (--covec PATH_TO_BINARY | --url http://HOST:PORT) [--browser ${Object.keys(BROWSERS).join("|")}] [--artifacts DIR]`,
  );
  process.exit(2);
}
args.artifacts ??= path.join(repo, "tests/artifacts/browser", args.browser);
/** The browser's name as the steps say it. */
const BROWSER_NAME = { chromium: "Chromium", firefox: "Firefox" }[args.browser];

const FIXTURE = path.join(repo, "tests/fixtures/web_astronaut.png");
/** Whether the API document has the edits route; then the recolour steps are required. */
const EDITS_DOCUMENTED = fs.readFileSync(path.join(repo, "api/openapi.yaml"), "utf8").includes("/v1/jobs/{id}/edits:");

/**
 * Why the recolour steps cannot run, or null: only when the edits route is neither documented
 * nor served are they skipped, loudly.
 */
async function missingEditsApi(base, jobId) {
  if (EDITS_DOCUMENTED) return null;
  const response = await fetch(new URL(`/v1/jobs/${jobId}/edits`, base), {
    method: "POST",
    headers: { "content-type": "application/json" },
    body: JSON.stringify({ changes: [] }),
  });
  const problem = await response.json().catch(() => ({}));
  return response.status === 404 && problem.code === "route-not-found"
    ? "this build has no POST /v1/jobs/{id}/edits, and api/openapi.yaml does not document it"
    : null;
}
/** A small budget and few iterations: the point is the page, not the quality. */
const JOB = {
  paths: "16",
  mode: "photo",
  maxSize: "64",
  iterations: { structure: "8", reconstruction: "8", "refine-rounds": "1", refine: "8", polish: "8" },
};
const JOB_TIMEOUT_MS = 120_000;
/** Structure iterations of the job that is watched while it runs, then canceled (4000 ran out
 * before the click once the structure stage got faster; the test server's iteration cap is raised
 * to match). */
const LONG_JOB_STRUCTURE_ITERATIONS = 40000;
const MAX_ITERATIONS = 100_000;
/** The request body limit the test's server gets, so that an oversized upload is quick to make. */
const MAX_BODY_BYTES = 1_000_000;
/** The bar for "the page's rendering matches our renderer". */
const PARITY_MEAN_MAX = 1.5;
/**
 * A layer toggle must move some pixels by more than rounding noise: at least this many
 * levels (0-255) on at least 0.1% of the image (a light layer may be small).
 */
const VISIBLE_CHANGE_LEVELS = 3;
const VISIBLE_CHANGE_SHARE = 0.001;
const visiblyChanged = (diff) => diff.max >= VISIBLE_CHANGE_LEVELS && diff.changed >= VISIBLE_CHANGE_SHARE;

const results = [];
const facts = {};

/**
 * Runs one check. A failed step is reported and the next runs, unless later ones need it. A step
 * with `skip_because` set is reported as skipped with that reason.
 */
async function step(name, body, { later_steps_need_it = false, skip_because = null } = {}) {
  if (skip_because) {
    results.push({ name, ok: true, skipped: true });
    console.log(`SKIP ${name}: ${skip_because}`);
    return;
  }
  const started = performance.now();
  try {
    await body();
    results.push({ name, ok: true });
    console.log(`ok   ${name} (${Math.round(performance.now() - started)} ms)`);
  } catch (error) {
    results.push({ name, ok: false });
    console.log(`FAIL ${name}: ${error.stack || error}`);
    if (later_steps_need_it) throw error;
  }
}

function check(condition, message) {
  if (!condition) throw new Error(message);
}

function sha256(bytes) {
  return createHash("sha256").update(bytes).digest("hex");
}

// ------------------------------------------------------------------ the server under test

async function freePort() {
  return new Promise((resolve, reject) => {
    const server = net.createServer();
    server.once("error", reject);
    server.listen(0, "127.0.0.1", () => {
      const { port } = server.address();
      server.close(() => resolve(port));
    });
  });
}

async function startServer(binary, extraFlags = []) {
  const port = await freePort();
  const dataDir = fs.mkdtempSync(path.join(os.tmpdir(), "covec-web-test-data-"));
  const log = fs.openSync(path.join(args.artifacts, "server.log"), "w");
  const flags = ["--addr", `127.0.0.1:${port}`, "--data-dir", dataDir, "--workers", "1", "--max-body-bytes", `${MAX_BODY_BYTES}`, "--max-iterations", `${MAX_ITERATIONS}`, ...extraFlags];
  const child = spawn(binary, ["serve", ...flags], {
    stdio: ["ignore", log, log],
    // Only the flags configure it: no API keys or limits from the caller's environment.
    env: Object.fromEntries([
      ...Object.entries(process.env).filter(([name]) => !name.startsWith("COVEC_")),
      ["COVEC_LOG", process.env.COVEC_LOG || "info"],
    ]),
  });
  let exited = null;
  child.on("exit", (code, signal) => (exited = { code, signal }));
  // Not left running if the test itself ends early (a broken pipe, an uncaught error).
  process.once("exit", () => exited || child.kill("SIGKILL"));
  const url = `http://127.0.0.1:${port}`;
  const deadline = Date.now() + 30_000;
  while (Date.now() < deadline) {
    if (exited) throw new Error(`covec serve exited early (${JSON.stringify(exited)}); see server.log`);
    try {
      if ((await fetch(`${url}/healthz`)).ok) break;
    } catch {
      // not listening yet
    }
    await new Promise((r) => setTimeout(r, 100));
  }
  check(!exited, "covec serve did not stay up");
  return {
    url,
    async stop() {
      if (!exited) {
        child.kill("SIGTERM");
        const gone = new Promise((r) => child.once("exit", r));
        const timer = setTimeout(() => child.kill("SIGKILL"), 10_000);
        await gone;
        clearTimeout(timer);
      }
      fs.rmSync(dataDir, { recursive: true, force: true });
    },
  };
}

async function apiBytes(base, url, headers = {}) {
  const response = await fetch(new URL(url, base), { headers });
  check(response.ok, `GET ${url}: ${response.status}`);
  return Buffer.from(await response.arrayBuffer());
}

/** The fill colours (`r g b rg`, as #rrggbb hex without #) of a PDF's deflated content streams. */
function pdfFills(pdf) {
  const colours = new Set();
  const text = pdf.toString("latin1");
  for (const match of text.matchAll(/stream\r?\n/g)) {
    const start = match.index + match[0].length;
    const end = text.indexOf("endstream", start);
    let content;
    try {
      content = zlib.inflateSync(pdf.subarray(start, end)).toString("latin1");
    } catch {
      continue;
    }
    for (const [, r, g, b] of content.matchAll(/([\d.]+) ([\d.]+) ([\d.]+) rg/g)) {
      colours.add([r, g, b].map((v) => Math.round(Number(v) * 255).toString(16).padStart(2, "0")).join(""));
    }
  }
  return colours;
}

// ------------------------------------------------------------------ pixels

/**
 * Decodes PNGs with the browser's decoder in a blank page (no CSP) and compares them there.
 * Each call gets base64 PNGs and returns plain numbers.
 */
class Pixels {
  constructor(page) {
    this.page = page;
  }

  /** Mean and max |Δ| over RGB (0-255 units), the share of pixels that differ, and p99. */
  async diff(pngA, pngB, points = null) {
    return this.page.evaluate(
      async ({ a, b, points }) => {
        const decode = async (b64) => {
          const blob = await (await fetch(`data:image/png;base64,${b64}`)).blob();
          const bitmap = await createImageBitmap(blob, { colorSpaceConversion: "none", premultiplyAlpha: "none" });
          const canvas = new OffscreenCanvas(bitmap.width, bitmap.height);
          const context = canvas.getContext("2d", { willReadFrequently: true });
          context.drawImage(bitmap, 0, 0);
          return { width: bitmap.width, height: bitmap.height, data: context.getImageData(0, 0, bitmap.width, bitmap.height).data };
        };
        const [ia, ib] = await Promise.all([decode(a), decode(b)]);
        if (ia.width !== ib.width || ia.height !== ib.height) {
          return { error: `sizes differ: ${ia.width}x${ia.height} vs ${ib.width}x${ib.height}` };
        }
        const samples = points ?? Array.from({ length: ia.width * ia.height }, (_, i) => [i % ia.width, Math.floor(i / ia.width)]);
        let sum = 0;
        let max = 0;
        let changed = 0;
        const perPixel = [];
        for (const [x, y] of samples) {
          const offset = (y * ia.width + x) * 4;
          let pixelMax = 0;
          for (let c = 0; c < 3; c++) {
            const d = Math.abs(ia.data[offset + c] - ib.data[offset + c]);
            sum += d;
            pixelMax = Math.max(pixelMax, d);
          }
          max = Math.max(max, pixelMax);
          if (pixelMax > 0) changed++;
          perPixel.push(pixelMax);
        }
        perPixel.sort((p, q) => p - q);
        return {
          width: ia.width,
          height: ia.height,
          samples: samples.length,
          mean: sum / (samples.length * 3),
          max,
          p99: perPixel[Math.min(perPixel.length - 1, Math.floor(perPixel.length * 0.99))],
          changed: changed / samples.length,
        };
      },
      { a: pngA.toString("base64"), b: pngB.toString("base64"), points },
    );
  }

  /** The SVG drawn by this browser `width` pixels wide (its aspect kept), as a PNG. */
  async svgToPng(svgBytes, width) {
    const b64 = await this.page.evaluate(
      async ({ svg, width }) => {
        const image = new Image();
        image.src = `data:image/svg+xml;base64,${svg}`;
        await image.decode();
        const height = Math.round((image.naturalHeight * width) / image.naturalWidth);
        const canvas = document.createElement("canvas");
        canvas.width = width;
        canvas.height = height;
        canvas.getContext("2d").drawImage(image, 0, 0, width, height);
        return canvas.toDataURL("image/png").split(",")[1];
      },
      { svg: svgBytes.toString("base64"), width },
    );
    return Buffer.from(b64, "base64");
  }

  async size(png) {
    return { width: png.readUInt32BE(16), height: png.readUInt32BE(20) };
  }
}

// ------------------------------------------------------------------ the test

async function main() {
  fs.mkdirSync(args.artifacts, { recursive: true });
  for (const old of fs.readdirSync(args.artifacts)) {
    if (old.endsWith(".png")) fs.rmSync(path.join(args.artifacts, old));
  }
  const server = args.covec ? await startServer(path.resolve(args.covec)) : { url: args.url, stop: async () => {} };
  const profile = fs.mkdtempSync(path.join(os.tmpdir(), "covec-web-test-profile-"));
  const downloads = fs.mkdtempSync(path.join(os.tmpdir(), "covec-web-test-downloads-"));
  let context;
  try {
    context = await launch(args.browser, {
      executable: args.executable,
      profile,
      downloads,
      viewport: { width: 1280, height: 900 },
    });
    facts.browser = context.version;
    await run(context, server.url);
  } catch {
    // already reported by step()
  } finally {
    await context?.close().catch(() => {});
    await server.stop();
    fs.rmSync(profile, { recursive: true, force: true });
    fs.rmSync(downloads, { recursive: true, force: true });
  }
  const skipped = results.filter((r) => r.skipped).length;
  const passed = results.filter((r) => r.ok && !r.skipped).length;
  const failed = results.length - passed - skipped;
  console.log(`facts: ${JSON.stringify(facts)}`);
  console.log(`screenshots: ${args.artifacts}`);
  console.log(`${args.browser}: ${passed} passed, ${failed} failed${skipped ? `, ${skipped} skipped` : ""}`);
  process.exit(failed === 0 && passed > 0 ? 0 : 1);
}

async function run(context, base) {
  const page = context.pages()[0] ?? (await context.newPage());
  const scratch = await context.newPage();
  const pixels = new Pixels(scratch);
  const problems = [];
  /** Requests that may fail: the upload the rejection step makes the server refuse. */
  let expectRejectedUpload = false;
  page.on("pageerror", (error) => problems.push(`page error: ${error.message}`));
  page.on("console", (message) => {
    // Failed loads are checked through their responses below, with their URLs.
    if (message.type() === "error" && !/^Failed to load resource/.test(message.text())) {
      problems.push(`console: ${message.text()}`);
    }
  });
  page.on("response", (response) => {
    const rejectedUpload = expectRejectedUpload && response.request().method() === "POST";
    if (response.status() >= 400 && !rejectedUpload) problems.push(`${response.status()} for ${response.url()}`);
  });
  page.on("requestfailed", (request) => {
    // The page closes a job's event stream itself once it knows the job ended (Chromium and
    // Firefox name the abort so).
    const closedStream = /\/events$/.test(request.url()) && /^(net::ERR_ABORTED|NS_BINDING_ABORTED)$/.test(request.failure()?.errorText);
    if (!closedStream) problems.push(`request failed: ${request.url()} ${request.failure()?.errorText}`);
  });
  let shot = 0;
  const screenshot = async (name, options = {}) => {
    shot += 1;
    const file = path.join(args.artifacts, `${String(shot).padStart(2, "0")}-${name}.png`);
    await page.screenshot({ path: file, fullPage: true, ...options });
    return file;
  };
  const svg = page.locator("#svg-host > svg");
  /** The job form filled with the small budget (the Advanced part opened first). */
  const fillForm = async (tab = page) => {
    if (!(await tab.evaluate(() => document.getElementById("advanced").open))) await tab.click("#advanced > summary");
    await tab.fill("#paths", JOB.paths);
    await tab.selectOption("#mode", JOB.mode);
    await tab.fill("#max-size", JOB.maxSize);
    for (const [key, value] of Object.entries(JOB.iterations)) await tab.fill(`#it-${key}`, value);
  };
  /**
   * Clicks a download link and returns the saved file's name and bytes; the file is then
   * removed, so that a later download of the same name is not renamed by the browser. Only a
   * file of the name the link gives counts (a name the test expects is checked by the caller).
   */
  const downloadFrom = async (link, tab = page) => {
    const name = (await link.getAttribute("download")) ?? undefined;
    const [download] = await Promise.all([tab.waitForEvent("download", { name }), link.click()]);
    const file = await download.path();
    const bytes = fs.readFileSync(file);
    fs.rmSync(file);
    return { name: download.suggestedFilename(), bytes };
  };
  /** The row of the file named `name` (for rowState: the newest, if it was given more than once). */
  const rowOf = (name) => `#jobs > li[data-name="${name}"]`;
  const rowState = (name) =>
    page.evaluate((name) => {
      const rows = document.querySelectorAll(`#jobs > li[data-name="${CSS.escape(name)}"]`);
      const row = rows[rows.length - 1];
      return row && { status: row.dataset.status, job: row.dataset.job, error: row.querySelector(".error").hidden ? "" : row.querySelector(".error").textContent, bar: row.querySelector("progress").value };
    }, name);
  /**
   * The vector image's own pixels, without the pick outline drawn over it: a clip of the SVG's
   * size. The SVG is first moved (relatively positioned, not transformed: Chromium draws a
   * fractional transform between pixels) to whole pixels of the document and scrolled there, to
   * the viewport's top, so that every capture sees covec's renderer's pixel grid. Left at its
   * fractional place, Firefox drew it up to a pixel off (a mean difference of 4.5/255 to the
   * renderer, and an undo that "differed").
   */
  const svgPixels = async () => {
    await page.evaluate(() => (document.getElementById("pick-overlay").style.visibility = "hidden"));
    await svg.evaluate((e) => {
      window.scrollTo({ left: 0, top: 0, behavior: "instant" });
      const box = e.getBoundingClientRect();
      e.style.position = "relative";
      e.style.left = `${Math.ceil(box.left) - box.left}px`;
      e.style.top = `${Math.ceil(box.top) - box.top}px`;
      window.scrollTo({ left: 0, top: Math.ceil(box.top), behavior: "instant" });
    });
    const box = await svg.boundingBox(); // viewport coordinates, as the clip wants them
    const size = await svg.evaluate((e) => [e.clientWidth, e.clientHeight]);
    const clip = { x: Math.round(box.x), y: Math.round(box.y), width: size[0], height: size[1] };
    const png = await page.screenshot({ clip });
    await page.evaluate(() => document.getElementById("pick-overlay").style.removeProperty("visibility"));
    await svg.evaluate((e) => ["position", "left", "top"].forEach((property) => e.style.removeProperty(property)));
    return png;
  };

  await step("page loads from covec serve with its assets", async () => {
    const response = await page.goto(base, { waitUntil: "load" });
    check(response.ok(), `GET / gave ${response.status()}`);
    check(/text\/html/.test(response.headers()["content-type"]), "page is not text/html");
    await page.waitForSelector("body[data-state=idle]", { timeout: 5000 });
    await page.waitForSelector("body[data-limits=loaded]", { timeout: 5000 });
    check((await page.title()).includes("covec"), "no title");
    await page.waitForFunction(() => document.querySelector("#intro img").complete);
    const picture = await page.evaluate(() => document.querySelector("#intro img").naturalWidth);
    check(picture > 0, "the picture of the layers did not load");
    check(await page.locator("#try-sample").isVisible(), "no sample to try");
    await screenshot("loaded");
  }, { later_steps_need_it: true });

  await step("the form's bounds, defaults and accepted types are the server's (GET /v1/limits)", async () => {
    const limits = JSON.parse(await apiBytes(base, "/v1/limits"));
    const form = await page.evaluate(() => {
      const attrs = (id) => {
        const e = document.getElementById(id);
        return { min: e.min, max: e.max, value: e.value };
      };
      return {
        paths: attrs("paths"),
        maxSize: attrs("max-size"),
        structure: attrs("it-structure"),
        polish: attrs("it-polish"),
        k: attrs("reference-k"),
        mode: document.getElementById("mode").value,
        accept: document.getElementById("image").accept,
        note: document.getElementById("accepted-types").textContent,
      };
    });
    const same = (field, expected) => check(JSON.stringify(field) === JSON.stringify(expected), `${JSON.stringify(field)} != ${JSON.stringify(expected)}`);
    same(form.paths, { min: `${limits.min_paths}`, max: `${limits.max_paths}`, value: `${limits.defaults.paths}` });
    same(form.maxSize, { min: `${limits.min_size}`, max: `${limits.max_size}`, value: `${limits.defaults.max_size}` });
    same(form.structure.value, `${limits.defaults.iterations.structure}`);
    same(form.polish.value, `${limits.defaults.iterations.polish}`);
    same(form.k.value, `${limits.reference_defaults.k}`);
    same(form.mode, limits.defaults.mode);
    same(form.accept, limits.media_types.join(","));
    // The server under test takes MAX_BODY_BYTES (976.6 KiB): the page says so.
    check(form.note.includes("976.6 KiB"), `limits note: ${form.note}`);
    facts.limits_shown = form;
  });

  await step("every control has a label and every action is a button", async () => {
    const unlabelled = await page.evaluate(() =>
      Array.from(document.querySelectorAll("input, select"))
        .filter((input) => input.labels.length === 0)
        .map((input) => input.id || input.outerHTML),
    );
    check(unlabelled.length === 0, `controls without labels: ${unlabelled.join(", ")}`);
    const clickableDivs = await page.evaluate(
      () => document.querySelectorAll("div[onclick], span[onclick], [role=button]:not(button)").length,
    );
    check(clickableDivs === 0, "clickable non-buttons found");
    // Tab from the top reaches the file input before the submit button.
    const order = [];
    await page.locator("body").focus();
    for (let i = 0; i < 12 && !order.includes("submit"); i++) {
      await page.keyboard.press("Tab");
      order.push(await page.evaluate(() => document.activeElement?.id || document.activeElement?.tagName));
    }
    check(order.includes("image") && order.includes("submit"), `tab order: ${order.join(" → ")}`);
    check(order.indexOf("image") < order.indexOf("submit"), `tab order: ${order.join(" → ")}`);
  });

  await step("a file of the wrong type is refused with a clear message", async () => {
    await page.setInputFiles("#image", { name: "notes.txt", mimeType: "text/plain", buffer: Buffer.from("hello") });
    await page.click("#submit");
    await page.waitForSelector(`${rowOf("notes.txt")} .error`);
    const row = await rowState("notes.txt");
    check(row.status === "refused" && !row.job, `row: ${JSON.stringify(row)}`);
    check(/not an image covec reads/.test(row.error), `message: ${row.error}`);
    await screenshot("wrong-type");
  });

  await step("an image the server rejects shows the server's problem details", async () => {
    await page.setInputFiles("#image", {
      name: "broken.png",
      mimeType: "image/png",
      buffer: Buffer.from("\x89PNG\r\n\x1a\n this is not really a PNG", "latin1"),
    });
    expectRejectedUpload = true;
    await page.click("#submit");
    await page.waitForSelector(`${rowOf("broken.png")} .error`, { timeout: 10_000 });
    expectRejectedUpload = false;
    const message = (await rowState("broken.png")).error;
    check(/refused “broken\.png”/.test(message) && message.length > 50, `message: ${message}`);
    facts.rejected_message = message;
    await screenshot("rejected-by-server");
  });

  if (args.covec) {
    await step("a file over the server's size limit is refused next to it, before any upload", async () => {
      const big = Buffer.alloc(MAX_BODY_BYTES + 100_000, 7);
      big.write("\x89PNG\r\n\x1a\n", 0, "latin1");
      await page.setInputFiles("#image", { name: "huge.png", mimeType: "image/png", buffer: big });
      let posted = false;
      const watch = (request) => (posted ||= request.method() === "POST");
      page.on("request", watch);
      await page.click("#submit");
      await page.waitForSelector(`${rowOf("huge.png")} .error`, { timeout: 10_000 });
      page.page.off("request", watch);
      check(!posted, "the page uploaded a file over the server's limit");
      facts.too_large_message = (await rowState("huge.png")).error;
      check(/too large/.test(facts.too_large_message) && facts.too_large_message.includes("976.6 KiB"), facts.too_large_message);
      await screenshot("too-large");
    });
  }

  let job;
  await step("uploads the bench image with a small budget", async () => {
    await page.setInputFiles("#image", FIXTURE);
    await fillForm();
    await screenshot("form-filled");
    const created = page.waitForResponse((r) => r.url().endsWith("/v1/jobs") && r.request().method() === "POST");
    await page.click("#submit");
    const response = await created;
    check(response.status() === 201, `POST /v1/jobs gave ${response.status()}: ${await response.text()}`);
    job = await response.json();
    facts.job_id = job.id;
    await page.waitForSelector("#progress:not([hidden])");
    await screenshot("progress-started");
  }, { later_steps_need_it: true });

  await step("the job completes and the result is shown beside the input", async () => {
    await page.waitForSelector("body[data-state=succeeded] #svg-host > svg", { timeout: JOB_TIMEOUT_MS });
    await page.waitForFunction(() => document.getElementById("input-image").complete);
    check(await page.locator("#input-image").isVisible(), "input not shown");
    check(await svg.isVisible(), "result not shown");
    await screenshot("result");
  }, { later_steps_need_it: true });

  const jobSvgUrl = `/v1/jobs/${job?.id}/svg`;
  let jobSvg;
  await step("the inlined SVG is the API's SVG, blend groups intact", async () => {
    jobSvg = await apiBytes(base, jobSvgUrl);
    const shown = await page.locator("#svg-host").getAttribute("data-sha256");
    check(shown === sha256(jobSvg), "the page shows different bytes than GET /svg");
    const groups = await page.evaluate(() => {
      const svg = document.querySelector("#svg-host > svg");
      const style = (id) => getComputedStyle(svg.querySelector(`g#${id}`)).mixBlendMode;
      return { isolation: getComputedStyle(svg).isolation, shade: style("shade"), light: style("light") };
    });
    check(groups.isolation === "isolate", `isolation: ${groups.isolation}`);
    check(groups.shade === "multiply" && groups.light === "plus-lighter", `blend modes: ${JSON.stringify(groups)}`);
  });

  await step("every stage preview the API lists is on the page", async () => {
    const list = JSON.parse(await apiBytes(base, `/v1/jobs/${job.id}/previews`));
    const items = Array.isArray(list) ? list : list.previews || list.items;
    const names = items.map((item) => (typeof item === "string" ? item : item.name));
    check(names.length > 0, "the API lists no previews");
    await page.waitForFunction(
      (count) => {
        const images = document.querySelectorAll("#previews img");
        return images.length === count && Array.from(images).every((img) => img.complete && img.naturalWidth > 0);
      },
      names.length,
      { timeout: 10_000 },
    );
    facts.previews = names;
  });

  let composite;
  await step(`${BROWSER_NAME}'s rendering matches covec's renderer (final composite preview)`, async () => {
    const name = facts.previews.filter((n) => /composite/.test(n)).at(-1);
    check(name, `no composite among previews ${facts.previews.join(", ")}`);
    const reference = await apiBytes(base, `/v1/jobs/${job.id}/previews/${encodeURIComponent(name)}.png`);
    const { width, height } = await pixels.size(reference);
    // Show the SVG at the renderer's pixel size so both rasterise the same grid.
    await page.evaluate(
      ({ width, height }) => {
        const svg = document.querySelector("#svg-host > svg");
        svg.style.width = `${width}px`;
        svg.style.height = `${height}px`;
      },
      { width, height },
    );
    const shown = await svgPixels();
    fs.writeFileSync(path.join(args.artifacts, `parity-${args.browser}.png`), shown);
    fs.writeFileSync(path.join(args.artifacts, "parity-covec.png"), reference);
    const diff = await pixels.diff(shown, reference);
    check(!diff.error, diff.error);
    facts.parity = { preview: name, width, height, mean: +diff.mean.toFixed(3), p99: diff.p99, max: diff.max };
    check(diff.mean <= PARITY_MEAN_MAX, `mean |Δ| ${diff.mean.toFixed(3)}/255 > ${PARITY_MEAN_MAX}`);
  });
  // The rest compares the page with itself at its normal size.
  await page.evaluate(() => {
    const svg = document.querySelector("#svg-host > svg");
    svg.style.removeProperty("width");
    svg.style.removeProperty("height");
  });
  composite = await svgPixels();

  await step("each layer toggle changes the displayed image", async () => {
    facts.layer_toggle_change = {};
    for (const layer of ["albedo", "shade", "light"]) {
      const paths = await page.locator(`#svg-host g#${layer} path`).count();
      await page.uncheck(`#show-${layer}`);
      const hidden = await svgPixels();
      await screenshot(`without-${layer}`);
      await page.check(`#show-${layer}`);
      const diff = await pixels.diff(composite, hidden);
      facts.layer_toggle_change[layer] = { paths, mean: +diff.mean.toFixed(2), max: diff.max, share: +diff.changed.toFixed(4) };
      check(visiblyChanged(diff), `hiding ${layer} (${paths} paths) hardly changed the image: ${JSON.stringify(facts.layer_toggle_change[layer])}`);
      const restored = await pixels.diff(composite, await svgPixels());
      check(restored.max === 0, `showing ${layer} again did not restore the image (max |Δ| ${restored.max})`);
    }
    for (const view of ["albedo", "shade", "light"]) {
      await page.click(`button[data-view=${view}]`);
      const alone = await svgPixels();
      await screenshot(`${view}-alone`);
      check(visiblyChanged(await pixels.diff(composite, alone)), `${view} alone looks like the composite`);
    }
    await page.click("button[data-view=all]");
    check((await pixels.diff(composite, await svgPixels())).max === 0, "'All layers' did not restore the composite");
  });

  await step("the compare slider shows the original over the vector", async () => {
    await page.locator("#compare").fill("50");
    check(await page.locator("#compare-overlay").isVisible(), "overlay not shown");
    await screenshot("compare-50");
    await page.locator("#compare").fill("0");
    check(!(await page.locator("#compare-overlay").isVisible()), "overlay still shown at 0");
  });

  const noEditsApi = job ? await missingEditsApi(base, job.id) : null;
  /**
   * An edit keeps the lighting: in the shade and light groups, every path the edit did not list
   * as changed is as it was, and a listed one (a reference edit refits an object's own shade and
   * light paths) differs in its fill only.
   */
  const checkLightingKept = async (original, edited, changed) => {
    const listed = changed.map((c) => c.path);
    const wrong = await scratch.evaluate(
      ({ a, b, listed }) => {
        const parse = (text) => new DOMParser().parseFromString(text, "image/svg+xml");
        const [x, y] = [parse(a), parse(b)];
        const wrong = [];
        for (const group of ["shade", "light"]) {
          const [gx, gy] = [x.querySelector(`g#${group}`), y.querySelector(`g#${group}`)];
          const attrs = (g) => [...g.attributes].map((at) => `${at.name}=${at.value}`).join(" ");
          if (attrs(gx) !== attrs(gy) || gx.children.length !== gy.children.length) wrong.push(group);
          for (const [i, px] of [...gx.children].entries()) {
            const py = gy.children[i];
            const same = listed.includes(px.id)
              ? py?.id === px.id && py.getAttribute("d") === px.getAttribute("d")
              : py?.outerHTML === px.outerHTML;
            if (!same) wrong.push(px.id);
          }
        }
        return wrong;
      },
      { a: original.toString("utf8"), b: edited.toString("utf8"), listed },
    );
    check(wrong.length === 0, `the edit changed lighting it did not list: ${JSON.stringify(wrong)}`);
  };
  let target;
  await step("clicking the result picks the albedo path under the cursor", async () => {
    // The non-base albedo path with the largest visible area, and the screen points it covers.
    target = await page.evaluate(() => {
      const svg = document.querySelector("#svg-host > svg");
      const box = svg.getBoundingClientRect();
      const hits = new Map();
      const step = 4;
      for (let y = box.top + 1; y < box.bottom - 1; y += step) {
        for (let x = box.left + 1; x < box.right - 1; x += step) {
          const hit = document.elementsFromPoint(x, y).find((e) => /^albedo-\d+$/.test(e.id));
          if (!hit || hit.id === "albedo-0") continue;
          if (!hits.has(hit.id)) hits.set(hit.id, []);
          hits.get(hit.id).push([x, y]);
        }
      }
      const [id, points] = [...hits.entries()].sort((a, b) => b[1].length - a[1].length)[0] ?? [];
      if (!id) return null;
      const [cx, cy] = points[Math.floor(points.length / 2)];
      const fill = svg.querySelector(`path#${id}`).getAttribute("fill");
      return { id, fill, click: { x: cx, y: cy }, points: points.map(([x, y]) => [Math.floor(x - box.left), Math.floor(y - box.top)]) };
    });
    check(target, "no albedo path besides the base is visible");
    await page.mouse.click(target.click.x, target.click.y);
    const picked = await page.locator("#path-select").inputValue();
    check(picked === target.id, `clicked ${target.id} but ${picked} is selected`);
    const outline = await page.locator("#pick-outline").getAttribute("d");
    const pathData = await page.locator(`#svg-host path#${target.id}`).getAttribute("d");
    check(outline === pathData, "the picked region is not outlined");
    const outlineScale = await page.locator("#pick-outline").getAttribute("transform");
    const layerScale = await page.locator("#svg-host g#albedo").getAttribute("transform");
    check(outlineScale === layerScale, `the outline is scaled by ${outlineScale}, its layer by ${layerScale}`);
    facts.recolour = { path: target.id, old_fill: target.fill, area_points: target.points.length };
    await screenshot("picked");
  });

  await step("recolouring changes the pixels under the path and keeps the lighting", async () => {
    const before = await svgPixels();
    // The colour furthest from the current fill, so the change cannot hide in the shading.
    const channels = (target.fill.match(/[0-9a-f]{2}/gi) || ["80", "80", "80"]).map((h) => parseInt(h, 16));
    const color = `#${channels.map((c) => (c < 128 ? 0xf0 : 0x10).toString(16).padStart(2, "0")).join("")}`;
    await page.fill("#color", color);
    const posted = page.waitForResponse((r) => /\/edits$/.test(r.url()) && r.request().method() === "POST");
    await page.click("#apply-colour");
    const response = await posted;
    check(response.status() === 201, `POST edits gave ${response.status()}: ${await response.text()}`);
    const edit = await response.json();
    await page.waitForSelector(`#svg-host[data-version="${edit.id}"]`, { timeout: 10_000 });
    await page.waitForFunction(() => document.querySelector("#svg-host").dataset.sha256);
    await screenshot("recoloured");
    const after = await svgPixels();
    const under = await pixels.diff(before, after, target.points);
    check(under.mean > 10, `pixels under ${target.id} changed by only ${under.mean.toFixed(2)}/255`);
    facts.recolour.new_fill = color;
    facts.recolour.mean_change_under_path = +under.mean.toFixed(1);

    const editSvgUrl = edit.urls?.svg || `/v1/jobs/${job.id}/edits/${edit.id}/svg`;
    const editSvg = await apiBytes(base, editSvgUrl);
    check((await page.locator("#svg-host").getAttribute("data-sha256")) === sha256(editSvg), "page shows other bytes than the edit's SVG");
    await checkLightingKept(jobSvg, editSvg, edit.changed);
  }, { skip_because: noEditsApi });

  await step("the recoloured picture downloads as flattened SVG, PDF and PNG, with the new colours", async () => {
    const version = await page.locator("#svg-host").getAttribute("data-version");
    check(version && version !== "original", `no edit shown (version ${version}): the recolour did not happen`);
    const editPath = `/v1/jobs/${job.id}/edits/${version}`;
    const files = {};
    for (const [kind, label, url, name] of [
      ["flat", "Flattened SVG (with your colours)", `${editPath}/svg?flatten=true`, `web_astronaut-${version}-flat.svg`],
      ["pdf", "PDF (with your colours)", `${editPath}/pdf`, `web_astronaut-${version}.pdf`],
      ["png", "PNG (with your colours)", `${editPath}/png`, `web_astronaut-${version}.png`],
    ]) {
      const link = page.locator(`#downloads a[data-kind=${kind}]`);
      check((await link.textContent()) === label, `the ${kind} link says "${await link.textContent()}"`);
      const saved = await downloadFrom(link);
      const api = await apiBytes(base, url);
      check(saved.bytes.equals(api), `${label}: downloaded ${saved.bytes.length} bytes differ from GET ${url} (${api.length} bytes)`);
      check(saved.name === name, `${label} was saved as ${saved.name}, not ${name}`);
      files[kind] = saved.bytes;
    }
    // The new colours, where the recoloured path is: the PNG and the flattened SVG (drawn by
    // this browser) at the page's size, against the job's own, under the path's points.
    const width = await svg.evaluate((e) => e.clientWidth);
    const jobPng = await apiBytes(base, `/v1/jobs/${job.id}/png?width=${width}`);
    const editPng = await apiBytes(base, `${editPath}/png?width=${width}`);
    const png = await pixels.diff(jobPng, editPng, target.points);
    check(!png.error && png.mean > 10, `the edit's PNG under ${target.id}: ${JSON.stringify(png)}`);
    const jobFlat = await pixels.svgToPng(await apiBytes(base, `/v1/jobs/${job.id}/svg?flatten=true`), width);
    const flat = await pixels.diff(jobFlat, await pixels.svgToPng(files.flat, width), target.points);
    check(!flat.error && flat.mean > 10, `the edit's flattened SVG under ${target.id}: ${JSON.stringify(flat)}`);
    // The PDF fills exactly the flattened SVG's colours (one flattening), which are not the job's.
    const pdfColours = pdfFills(files.pdf);
    const svgColours = new Set([...files.flat.toString("utf8").matchAll(/fill="#([0-9a-f]{6})"/g)].map((m) => m[1]));
    const off = [...pdfColours].filter((c) => !svgColours.has(c));
    check(pdfColours.size > 0 && off.length === 0, `the edit's PDF fills ${off.length} colours its flattened SVG has not: ${off.slice(0, 5)}`);
    const jobPdfColours = pdfFills(await apiBytes(base, `/v1/jobs/${job.id}/pdf`));
    check([...pdfColours].some((c) => !jobPdfColours.has(c)), "the edit's PDF has only the job's colours");
    facts.edit_downloads = {
      bytes: Object.fromEntries(Object.entries(files).map(([kind, bytes]) => [kind, bytes.length])),
      png_mean_change_under_path: +png.mean.toFixed(1),
      flat_svg_mean_change_under_path: +flat.mean.toFixed(1),
      pdf_colours: pdfColours.size,
    };
  }, { skip_because: noEditsApi });

  await step("undo brings the original back", async () => {
    check(await page.locator("#undo").isEnabled(), "nothing to undo: the recolour did not happen");
    await page.click("#undo");
    await page.waitForSelector('#svg-host[data-version="original"]');
    const restored = await pixels.diff(composite, await svgPixels());
    check(restored.max === 0, `after undo the image differs (max |Δ| ${restored.max})`);
    check(await page.locator("#undo").isDisabled(), "undo still enabled with nothing to undo");
    await screenshot("undone");
  }, { skip_because: noEditsApi });

  await step("downloads are the API's files byte for byte, named after the input file", async () => {
    const expected = [
      ["Layered SVG", jobSvgUrl, "web_astronaut.svg"],
      ["Scene JSON", `/v1/jobs/${job.id}/scene.json`, "web_astronaut.json"],
      ["Albedo layer SVG", `/v1/jobs/${job.id}/layers/albedo.svg`, "web_astronaut-albedo.svg"],
      ["Shade layer SVG", `/v1/jobs/${job.id}/layers/shade.svg`, "web_astronaut-shade.svg"],
      ["Light layer SVG", `/v1/jobs/${job.id}/layers/light.svg`, "web_astronaut-light.svg"],
      ["Flattened SVG", `/v1/jobs/${job.id}/svg?flatten=true`, "web_astronaut-flat.svg"],
      ["PDF", `/v1/jobs/${job.id}/pdf`, "web_astronaut.pdf"],
      ["PNG", `/v1/jobs/${job.id}/png`, "web_astronaut.png"],
    ];
    facts.downloads = {};
    for (const [label, url, name] of expected) {
      const saved = await downloadFrom(page.locator("#downloads a", { hasText: new RegExp(`^${label}$`) }));
      const api = await apiBytes(base, url);
      check(saved.bytes.equals(api), `${label}: downloaded ${saved.bytes.length} bytes differ from GET ${url} (${api.length} bytes)`);
      check(saved.name === name, `${label} was saved as ${saved.name}, not ${name}`);
      facts.downloads[saved.name] = saved.bytes.length;
    }
  });

  await step("the PNG download takes a width, and one over the server's pixel limit is refused next to the field", async () => {
    await page.fill("#png-width", "100");
    const saved = await downloadFrom(page.locator("#downloads a[data-kind=png]"));
    const { width, height } = await pixels.size(saved.bytes);
    check(width === 100 && height === 100, `the PNG is ${width}×${height}, not 100×100`);
    check(saved.name === "web_astronaut.png", `saved as ${saved.name}`);
    const limits = JSON.parse(await apiBytes(base, "/v1/limits"));
    await page.fill("#png-width", String(Math.ceil(Math.sqrt(limits.max_pixels)) + 1));
    await page.waitForSelector("#png-error");
    const message = await page.locator("#png-error").textContent();
    check(message.includes(String(limits.max_pixels)), `message: ${message}`);
    check((await page.locator("#downloads a[data-kind=png]").getAttribute("href")) === null, "the PNG link still points at a refused width");
    await screenshot("png-width-refused");
    // Cleared as a person would (puppeteer's fill("") leaves a number field as it was).
    await page.locator("#png-width").evaluate((input) => {
      input.value = "";
      input.dispatchEvent(new Event("input", { bubbles: true }));
    });
    check(await page.locator("#png-error").isHidden(), "the refusal stays after clearing the width");
    facts.png_width = { width, height, refused: message };
  });

  await step("recolouring by a reference image changes the colours and keeps the lighting", async () => {
    const before = await svgPixels();
    // The input with its left half painted a vivid green: the reference a person would make
    // in an image editor.
    await page.evaluate(async ({ b64 }) => {
      const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
      const bitmap = await createImageBitmap(new Blob([bytes], { type: "image/png" }));
      const canvas = new OffscreenCanvas(bitmap.width, bitmap.height);
      const context = canvas.getContext("2d");
      context.drawImage(bitmap, 0, 0);
      context.globalCompositeOperation = "color";
      context.fillStyle = "#10e020";
      context.fillRect(0, 0, bitmap.width / 2, bitmap.height);
      const blob = await canvas.convertToBlob({ type: "image/png" });
      const data = new DataTransfer();
      data.items.add(new File([blob], "web_astronaut-green.png", { type: "image/png" }));
      document.getElementById("reference").files = data.files;
    }, { b64: fs.readFileSync(FIXTURE).toString("base64") });
    await page.click("#by-reference > summary");
    const posted = page.waitForResponse((r) => /\/edits$/.test(r.url()) && r.request().method() === "POST");
    await page.click("#apply-reference");
    const response = await posted;
    check(response.status() === 201, `POST edits gave ${response.status()}: ${await response.text()}`);
    const edit = await response.json();
    check(edit.changed?.length > 0, `the reference changed no path: ${JSON.stringify(edit)}`);
    await page.waitForSelector(`#svg-host[data-version="${edit.id}"]`, { timeout: 10_000 });
    await screenshot("reference-recoloured");
    const change = await pixels.diff(before, await svgPixels());
    check(visiblyChanged(change), `the picture hardly changed: ${JSON.stringify(change)}`);
    const editSvg = await apiBytes(base, `/v1/jobs/${job.id}/edits/${edit.id}/svg`);
    check((await page.locator("#svg-host").getAttribute("data-sha256")) === sha256(editSvg), "page shows other bytes than the edit's SVG");
    await checkLightingKept(jobSvg, editSvg, edit.changed);
    const saved = await downloadFrom(page.locator("#downloads a[data-kind=svg]"));
    check(saved.bytes.equals(editSvg), "the recoloured SVG downloaded is not the edit's");
    check(saved.name === `web_astronaut-${edit.id}.svg`, `saved as ${saved.name}`);
    facts.reference_edit = { changed: edit.changed.length, mean_change: +change.mean.toFixed(2), saved_as: saved.name };
    await page.click("#undo");
    await page.waitForSelector('#svg-host[data-version="original"]');
  }, { skip_because: noEditsApi });

  await step("the job is in the page's address: a reload brings its result back", async () => {
    const hash = await page.evaluate(() => location.hash);
    check(hash.includes(`job=${job.id}`), `address: ${hash}`);
    await page.reload();
    await page.waitForSelector("body[data-state=succeeded] #svg-host > svg", { timeout: 30_000 });
    await page.waitForFunction(() => document.querySelector("#svg-host").dataset.sha256);
    check((await page.locator("#svg-host").getAttribute("data-sha256")) === sha256(jobSvg), "the reloaded page shows other bytes than GET /svg");
    const row = await rowState("web_astronaut.png");
    check(row?.job === job.id && row.status === "succeeded", `row after reload: ${JSON.stringify(row)}`);
    await page.waitForFunction(() => {
      const input = document.getElementById("input-image");
      return input.complete && input.naturalWidth > 0;
    });
    const saved = await downloadFrom(page.locator("#downloads a[data-kind=svg]"));
    check(saved.name === "web_astronaut.svg", `after a reload the SVG is saved as ${saved.name}`);
    facts.address = hash;
    await screenshot("reloaded-result");
  });

  await step("the page is usable on a phone-sized viewport", async () => {
    await page.setViewportSize({ width: 390, height: 844 });
    await page.waitForTimeout(100);
    const overflow = await page.evaluate(() => document.documentElement.scrollWidth - window.innerWidth);
    check(overflow <= 0, `the page is ${overflow}px wider than the phone`);
    const box = await svg.boundingBox();
    check(box && box.width >= 300, `result only ${box?.width}px wide on a phone`);
    await screenshot("phone");
    await page.setViewportSize({ width: 1280, height: 900 });
  });

  await step("a longer job shows live progress, previews and its draft, survives a reload, and can be canceled", async () => {
    // Long enough to be watched (and canceled) while it runs, even on an idle fast machine.
    await fillForm();
    await page.fill("#it-structure", String(LONG_JOB_STRUCTURE_ITERATIONS));
    await page.setInputFiles("#image", FIXTURE);
    await page.click("#submit");
    await page.waitForSelector("body[data-state=running]", { timeout: JOB_TIMEOUT_MS });
    await page.waitForFunction(
      () => {
        const bar = document.getElementById("bar").value;
        return (
          document.body.dataset.state === "running" &&
          bar > 0 &&
          bar < 1 &&
          document.getElementById("stage-name").textContent.startsWith("Stage: ") &&
          document.querySelector("#previews img")?.naturalWidth > 0
        );
      },
      null,
      { timeout: JOB_TIMEOUT_MS },
    );
    // The draft: the vector result so far, drawn while the job still runs.
    await page.waitForFunction(
      () =>
        document.body.dataset.state === "running" &&
        !document.getElementById("draft").hidden &&
        document.getElementById("draft").dataset.stage &&
        document.getElementById("draft-image").naturalWidth > 0,
      null,
      { timeout: JOB_TIMEOUT_MS },
    );
    facts.live = await page.evaluate(() => ({
      stage: document.getElementById("stage-name").textContent,
      bar: +document.getElementById("bar").value.toFixed(3),
      detail: document.getElementById("progress-detail").textContent,
      previews: document.querySelectorAll("#previews img").length,
      draft: document.getElementById("draft").dataset.stage,
      running: document.body.dataset.state === "running",
    }));
    check(facts.live.running, "the job ended before its draft was checked");
    await screenshot("progress-live");
    // Reloaded mid-job, the page follows the same job from its address.
    const running = await page.evaluate(() => new URLSearchParams(location.hash.slice(1)).get("show"));
    check(running && running !== job.id, `address: ${await page.evaluate(() => location.hash)}`);
    await page.reload();
    await page.waitForFunction(
      (id) =>
        document.body.dataset.state === "running" &&
        document.querySelector(`#jobs > li[data-job="${id}"][aria-current=true]`) &&
        document.getElementById("bar").value > 0 &&
        document.querySelector("#previews img")?.naturalWidth > 0,
      running,
      { timeout: JOB_TIMEOUT_MS },
    );
    check((await rowState("web_astronaut.png"))?.job === running, "the running job's row is not the newest of its name");
    await screenshot("reloaded-mid-job");
    facts.live.resumed = running;
    await page.click("#cancel");
    await page.waitForSelector("body[data-state=canceled]", { timeout: 30_000 });
    const message = await page.locator("#job-error").textContent();
    check(/canceled/i.test(message), `message: ${message}`);
    check(await page.locator("#result").isHidden(), "a canceled job shows a result");
    await screenshot("canceled");
  });

  await step("several files at once: a row each, with its own progress and errors", async () => {
    await fillForm();
    const names = ["first.png", "second.png", "notes.txt"];
    await page.evaluate(({ b64, names }) => {
      const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
      const data = new DataTransfer();
      data.items.add(new File([bytes], names[0], { type: "image/png" }));
      data.items.add(new File([bytes], names[1], { type: "image/png" }));
      data.items.add(new File(["not an image"], names[2], { type: "text/plain" }));
      document.getElementById("image").files = data.files;
    }, { b64: fs.readFileSync(FIXTURE).toString("base64"), names });
    await page.click("#submit");
    await page.waitForFunction(
      (names) => names.slice(0, 2).every((name) => document.querySelector(`#jobs > li[data-name="${name}"]`)?.dataset.status === "succeeded"),
      names,
      { timeout: JOB_TIMEOUT_MS },
    );
    const [first, second, notes] = await Promise.all(names.map(rowState));
    check(first.job && second.job && first.job !== second.job, `jobs: ${first.job}, ${second.job}`);
    check(first.bar === 1 && second.bar === 1 && !first.error && !second.error, `rows: ${JSON.stringify([first, second])}`);
    check(notes.status === "refused" && /not an image/.test(notes.error), `the text file's row: ${JSON.stringify(notes)}`);
    const hash = await page.evaluate(() => location.hash);
    check(hash.includes(`job=${first.job}`) && hash.includes(`job=${second.job}`), `address: ${hash}`);
    // The first is shown; "Show" on the second shows its result, downloads named after it.
    await page.waitForSelector(`#svg-host[data-svg-url*="${first.job}"] > svg`, { timeout: 10_000 });
    await screenshot("several-files");
    await page.click(`#jobs > li[data-job="${second.job}"] .job-show`);
    await page.waitForSelector(`body[data-state=succeeded] #svg-host[data-svg-url*="${second.job}"] > svg`, { timeout: 10_000 });
    const saved = await downloadFrom(page.locator("#downloads a[data-kind=svg]"));
    check(saved.name === "second.svg", `saved as ${saved.name}`);
    check(saved.bytes.equals(await apiBytes(base, `/v1/jobs/${second.job}/svg`)), "the second file's SVG differs from its job's");
    check((await page.evaluate(() => new URLSearchParams(location.hash.slice(1)).get("show"))) === second.job, "the address does not say which is shown");
    facts.several = { first: first.job, second: second.job, refused: notes.error };
    await screenshot("several-files-second");
  });

  await step("the sample photo runs without a file of one's own", async () => {
    await fillForm();
    const created = page.waitForResponse((r) => r.url().endsWith("/v1/jobs") && r.request().method() === "POST");
    await page.click("#try-sample");
    const response = await created;
    check(response.status() === 201, `POST /v1/jobs gave ${response.status()}: ${await response.text()}`);
    const sample = await response.json();
    check(sample.input_name === "sample.jpg", `input name: ${sample.input_name}`);
    await page.waitForSelector(`body[data-state=succeeded] #svg-host[data-svg-url*="${sample.id}"] > svg`, { timeout: JOB_TIMEOUT_MS });
    const saved = await downloadFrom(page.locator("#downloads a[data-kind=pdf]"));
    check(saved.name === "sample.pdf" && saved.bytes.subarray(0, 5).toString() === "%PDF-", `saved ${saved.name}`);
    facts.sample = sample.id;
    await screenshot("sample");
  });

  await step("a dropped image with an albedo map and masks is sent and vectorised", async () => {
    await fillForm();
    const png = fs.readFileSync(FIXTURE);
    const size = { width: png.readUInt32BE(16), height: png.readUInt32BE(20) };
    // Drop the image on the drop zone, as a person dragging a file would.
    await page.evaluate(({ b64 }) => {
      const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
      const data = new DataTransfer();
      data.items.add(new File([bytes], "dropped.png", { type: "image/png" }));
      const zone = document.getElementById("drop");
      for (const type of ["dragenter", "dragover", "drop"]) {
        zone.dispatchEvent(new DragEvent(type, { dataTransfer: data, bubbles: true, cancelable: true }));
      }
    }, { b64: png.toString("base64") });
    check((await page.evaluate(() => document.getElementById("image").files[0]?.name)) === "dropped.png", "the drop did not choose the file");
    await page.waitForFunction(() => {
      const chosen = document.getElementById("chosen");
      return !chosen.hidden && chosen.complete && chosen.naturalWidth > 0;
    });
    // The image itself as the albedo map, and two binary masks (left and right halves).
    await page.setInputFiles("#albedo", FIXTURE);
    await page.evaluate(async ({ width, height }) => {
      const data = new DataTransfer();
      for (const [index, x] of [[0, 0], [1, Math.floor(width / 2)]]) {
        const canvas = new OffscreenCanvas(width, height);
        const context = canvas.getContext("2d");
        context.fillStyle = "#000";
        context.fillRect(0, 0, width, height);
        context.fillStyle = "#fff";
        context.fillRect(x, 0, Math.ceil(width / 2), height);
        const blob = await canvas.convertToBlob({ type: "image/png" });
        data.items.add(new File([blob], `mask-${index}.png`, { type: "image/png" }));
      }
      document.getElementById("masks").files = data.files;
    }, size);
    // What the page hands to fetch (a multipart body's files are not visible on the wire here).
    await page.evaluate(() => {
      const original = window.fetch;
      window.fetch = (url, options) => {
        if (options?.body instanceof FormData) {
          window.sentFields = Array.from(options.body.entries(), ([name, value]) => [name, value.name ?? "", value.size ?? 0]);
        }
        return original(url, options);
      };
    });
    const created = page.waitForResponse((r) => r.url().endsWith("/v1/jobs") && r.request().method() === "POST");
    await page.click("#submit");
    const sentFields = await page.evaluate(() => window.sentFields ?? []);
    const fields = (name) => sentFields.filter(([field]) => field === name);
    check(
      fields("image").length === 1 && fields("albedo").length === 1 && fields("mask").length === 2,
      `sent ${JSON.stringify(sentFields)}`,
    );
    check(fields("image")[0][1] === "dropped.png", `the image sent was ${fields("image")[0][1]}`);
    const response = await created;
    check(response.status() === 201, `POST /v1/jobs gave ${response.status()}: ${await response.text()}`);
    const dropped = await response.json();
    await page.waitForSelector(`body[data-state=succeeded] #svg-host[data-svg-url*="${dropped.id}"] > svg`, { timeout: JOB_TIMEOUT_MS });
    facts.dropped_with_masks = { job: dropped.id, mask_size: size };
    await screenshot("dropped-with-masks");
  });

  await step("no script errors or blocked resources", async () => {
    check(problems.length === 0, problems.join("\n"));
  });

  if (args.covec) {
    await step("the page works against a server started with --api-keys", async () => {
      const key = "browser-test-key";
      const keyed = await startServer(path.resolve(args.covec), ["--api-keys", key]);
      const other = await context.newPage();
      const errors = [];
      other.on("pageerror", (error) => errors.push(`page error: ${error.message}`));
      try {
        await other.goto(keyed.url, { waitUntil: "load" });
        const fill = async () => {
          await other.setInputFiles("#image", FIXTURE);
          await fillForm(other);
        };
        // Without the key the server's refusal is shown, next to the file.
        await fill();
        await other.click("#submit");
        await other.waitForSelector("#jobs > li[data-status=refused] .error", { timeout: 10_000 });
        const refusal = await other.locator("#jobs > li[data-status=refused] .error").textContent();
        check(/Authorization|key/i.test(refusal), `message without a key: ${refusal}`);
        // With it: the stream, previews, result and downloads all carry it.
        await other.fill("#api-key", key);
        await other.click("#submit");
        await other.waitForSelector("body[data-state=succeeded] #svg-host > svg", { timeout: JOB_TIMEOUT_MS });
        await other.waitForFunction(() => {
          const images = Array.from(document.querySelectorAll("#previews img"));
          return images.length > 0 && images.every((img) => img.complete && img.naturalWidth > 0 && img.src.startsWith("blob:"));
        }, null, { timeout: 10_000 });
        const stage = await other.locator("#stage-name").textContent();
        check(stage === "Done", `stage line: ${stage}`);
        const url = await other.locator("#svg-host").getAttribute("data-svg-url");
        const { bytes } = await downloadFrom(other.locator("#downloads a", { hasText: /^Layered SVG$/ }), other);
        const served = await apiBytes(keyed.url, url, { authorization: `Bearer ${key}` });
        check(bytes.equals(served), `keyed download: ${bytes.length} bytes, the API serves ${served.length}`);
        // The key stays for the tab (sessionStorage), not in the page's URL or cookies.
        await other.reload({ waitUntil: "load" });
        check((await other.inputValue("#api-key")) === key, "the key was not kept for the tab");
        facts.keyed = { session_storage_items: await other.evaluate(() => sessionStorage.length), download_bytes: bytes.length };
        check(errors.length === 0, errors.join("\n"));
      } finally {
        await other.close();
        await keyed.stop();
      }
    });
  }
}

await main();
