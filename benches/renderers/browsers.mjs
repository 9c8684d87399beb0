// Renders SVG files in headless Debian Chromium and Firefox ESR, as a user opening the file
// would see it: each file is loaded as its own document in a viewport of its size (device scale
// 1) and screenshotted. Reuses the page test's browser launcher (tests/browser/driver.mjs;
// scripts/setup-browser.sh installs both browsers and puppeteer-core).
//
//     node benches/renderers/browsers.mjs BROWSER OUT_DIR W H FILE.svg...
//
// writes OUT_DIR/<file name without .svg>.png for each file.

import fs from "node:fs";
import os from "node:os";
import path from "node:path";
import { pathToFileURL } from "node:url";

import { launch } from "../../tests/browser/driver.mjs";

const [name, outDir, width, height, ...files] = process.argv.slice(2);
if (!name || !outDir || !files.length) {
  console.error("usage: browsers.mjs BROWSER OUT_DIR W H FILE.svg...");
  process.exit(2);
}
const scratch = fs.mkdtempSync(path.join(os.tmpdir(), "covec-renderers-"));
const viewport = { width: Number(width), height: Number(height) };
const browser = await launch(name, {
  profile: path.join(scratch, "profile"),
  downloads: path.join(scratch, "downloads"),
  viewport,
});
try {
  const page = (await browser.pages())[0] ?? (await browser.newPage());
  await page.setViewportSize(viewport);
  for (const file of files) {
    await page.goto(pathToFileURL(path.resolve(file)).href);
    const out = path.join(outDir, `${path.basename(file, ".svg")}.png`);
    await page.page.screenshot({ path: out, clip: { x: 0, y: 0, ...viewport } });
  }
  console.error(`${name}: ${browser.version}, ${files.length} files`);
} finally {
  await browser.close();
  fs.rmSync(scratch, { recursive: true, force: true });
}
