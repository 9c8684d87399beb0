// The browsers the page test runs in, behind the few page operations it uses: Debian's Chromium
// (over the DevTools protocol) and Debian's Firefox ESR (over WebDriver BiDi), both driven by
// puppeteer-core, so that one test body runs unchanged in both. Playwright cannot drive Debian's
// Firefox (its own Firefox build is not reachable, and its BiDi client needs commands Firefox ESR
// lacks); puppeteer's BiDi client works with it.
//
// The operations are named and shaped as Playwright's (page.fill, page.locator(..).textContent,
// page.waitForEvent("download"), ...), which the test was first written against.

import fs from "node:fs";
import os from "node:os";
import path from "node:path";

import puppeteer from "puppeteer-core";

/** The browsers the test knows, with their Debian executables. */
export const BROWSERS = {
  chromium: { puppeteer: "chrome", executable: "/usr/bin/chromium" },
  firefox: { puppeteer: "firefox", executable: "/usr/bin/firefox-esr" },
};

/** How long an action waits for its element, as Playwright's default action timeout. */
const ACTION_TIMEOUT_MS = 30_000;

/**
 * Starts `name` headless with a fresh profile, background networking off, a light colour
 * scheme, reduced motion and downloads saved into `downloads`. Returns a context with
 * `pages()`, `newPage()` and `close()`.
 */
export async function launch(name, { executable, profile, downloads, viewport }) {
  const browser = BROWSERS[name];
  if (!browser) throw new Error(`unknown browser ${name}; known: ${Object.keys(BROWSERS).join(", ")}`);
  const session = { downloads, scratch: fs.mkdtempSync(path.join(os.tmpdir(), "covec-web-test-files-")) };
  const handle = await puppeteer.launch({
    browser: browser.puppeteer,
    executablePath: executable || browser.executable,
    headless: true,
    userDataDir: profile,
    defaultViewport: { ...viewport, deviceScaleFactor: 1 },
    downloadBehavior: { policy: "allow", downloadPath: downloads },
    args:
      name === "chromium"
        ? [
            "--no-sandbox",
            "--disable-gpu",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--no-first-run",
            "--disable-quic",
            "--hide-scrollbars",
            "--force-color-profile=srgb",
          ]
        : [],
    // On top of puppeteer's own Firefox preferences, which already point updates, remote
    // settings, safe browsing and telemetry at unreachable addresses.
    extraPrefsFirefox: {
      "network.captive-portal-service.enabled": false,
      "network.connectivity-service.enabled": false,
      "browser.download.dir": downloads,
      "browser.download.folderList": 2,
      "browser.download.useDownloadDir": true,
      "browser.download.always_ask_before_handling_new_types": false,
      "ui.prefersReducedMotion": 1,
      "layout.css.prefers-color-scheme.content-override": 1,
    },
  });
  const wrap = async (page) => {
    if (name === "chromium") {
      await page.emulateMediaFeatures([
        { name: "prefers-color-scheme", value: "light" },
        { name: "prefers-reduced-motion", value: "reduce" },
      ]);
    }
    return new Page(page, session);
  };
  const first = (await handle.pages())[0];
  const opened = first ? [await wrap(first)] : [];
  return {
    version: await handle.version(),
    pages: () => opened,
    // Each page in a window of its own, so that none is a hidden background tab (whose timers
    // and animation frames the browser throttles).
    newPage: async () => wrap(await handle.newPage({ type: "window" })),
    async close() {
      await handle.close();
      fs.rmSync(session.scratch, { recursive: true, force: true });
    },
  };
}

/** One page (tab or window) with the operations the test uses. */
class Page {
  constructor(page, session) {
    this.page = page;
    this.session = session;
    this.keyboard = page.keyboard;
    this.mouse = page.mouse;
  }

  on(event, handler) {
    this.page.on(event, handler);
  }

  goto(url) {
    return this.page.goto(url, { waitUntil: "load" });
  }

  reload() {
    return this.page.reload({ waitUntil: "load" });
  }

  title() {
    return this.page.title();
  }

  close() {
    return this.page.close();
  }

  evaluate(fn, arg) {
    return this.page.evaluate(fn, arg);
  }

  /** Waits until `selector` matches a visible element (Playwright's default state). */
  waitForSelector(selector, { timeout = ACTION_TIMEOUT_MS } = {}) {
    return this.page.waitForSelector(selector, { visible: true, timeout });
  }

  /** Polls by time, not animation frames, so that a page in the background still answers. */
  waitForFunction(fn, arg, { timeout = ACTION_TIMEOUT_MS } = {}) {
    return this.page.waitForFunction(fn, { timeout, polling: 50 }, arg);
  }

  waitForResponse(predicate, { timeout = ACTION_TIMEOUT_MS } = {}) {
    return this.page.waitForResponse(predicate, { timeout });
  }

  waitForTimeout(ms) {
    return new Promise((resolve) => setTimeout(resolve, ms));
  }

  /**
   * The next file the browser saves into the downloads directory: resolves once it is there, no
   * download is still in progress and the directory (names and sizes) has not changed for
   * `SETTLE_MS`. Firefox may first write a download under a temporary name and rename it when
   * done (seen in CI: `P-T8Y7AL.json` gone when read), so a new name alone is not a finished file.
   * With `name`, only a file of that name counts: the directory is the whole browser's, and a
   * click that saved another file (one that landed on the next link while the page still
   * scrolled, seen in Chromium) then fails naming the files that did come. Only "download" is
   * supported.
   */
  async waitForEvent(event, { timeout = ACTION_TIMEOUT_MS, name } = {}) {
    if (event !== "download") throw new Error(`waitForEvent(${event}) is not supported`);
    const SETTLE_MS = 500;
    const dir = this.session.downloads;
    const before = new Set(fs.readdirSync(dir));
    const partial = (name) => /\.(part|crdownload)$/.test(name);
    const listing = () =>
      fs
        .readdirSync(dir)
        .map((name) => {
          try {
            return `${name}\t${fs.statSync(path.join(dir, name)).size}`;
          } catch {
            return `${name}\t?`; // renamed between readdir and stat: not settled
          }
        })
        .sort()
        .join("\n");
    const deadline = Date.now() + timeout;
    let last = null;
    let since = Date.now();
    while (Date.now() < deadline) {
      const now = listing();
      if (now !== last) {
        last = now;
        since = Date.now();
      } else if (Date.now() - since >= SETTLE_MS) {
        const names = fs.readdirSync(dir);
        const fresh = names.filter((file) => !before.has(file) && !partial(file) && (name === undefined || file === name));
        if (fresh.length > 0 && !names.some(partial) && !now.includes("\t?")) {
          const file = path.join(dir, fresh[0]);
          return { path: async () => file, suggestedFilename: () => fresh[0] };
        }
      }
      await this.waitForTimeout(50);
    }
    const seen = fs.readdirSync(dir).filter((file) => !before.has(file));
    throw new Error(`no download${name === undefined ? "" : ` named ${name}`} within ${timeout} ms (new files: ${seen.join(", ") || "none"})`);
  }

  /** `clip` is in viewport coordinates (as Playwright's); puppeteer wants the document's. */
  async screenshot({ path: file, fullPage = false, clip } = {}) {
    if (!clip) return Buffer.from(await this.page.screenshot({ path: file, fullPage }));
    const [left, top] = await this.page.evaluate(() => [window.visualViewport.pageLeft, window.visualViewport.pageTop]);
    const documentClip = { ...clip, x: clip.x + left, y: clip.y + top };
    return Buffer.from(await this.page.screenshot({ path: file, clip: documentClip, captureBeyondViewport: false }));
  }

  setViewportSize({ width, height }) {
    return this.page.setViewport({ width, height, deviceScaleFactor: 1 });
  }

  locator(selector, options) {
    return new Locator(this, selector, options);
  }

  click(selector) {
    return this.locator(selector).click();
  }

  fill(selector, value) {
    return this.locator(selector).fill(value);
  }

  inputValue(selector) {
    return this.locator(selector).inputValue();
  }

  selectOption(selector, value) {
    return this.locator(selector).fill(value);
  }

  check(selector) {
    return this.#setChecked(selector, true);
  }

  uncheck(selector) {
    return this.#setChecked(selector, false);
  }

  async #setChecked(selector, checked) {
    const element = await this.waitForSelector(selector);
    if ((await element.evaluate((e) => e.checked)) !== checked) await this.click(selector);
    if ((await element.evaluate((e) => e.checked)) !== checked) throw new Error(`${selector} did not become ${checked ? "checked" : "unchecked"}`);
  }

  /** A file path, or `{ name, buffer }` written to a scratch file of that name first. */
  async setInputFiles(selector, file) {
    let filePath = file;
    if (typeof file !== "string") {
      const dir = fs.mkdtempSync(path.join(this.session.scratch, "upload-"));
      filePath = path.join(dir, file.name);
      fs.writeFileSync(filePath, file.buffer);
    }
    const input = await this.page.waitForSelector(selector, { timeout: ACTION_TIMEOUT_MS });
    await input.uploadFile(filePath);
  }
}

/** The element(s) matching a selector (and optionally a text pattern), found when used. */
class Locator {
  constructor(tab, selector, { hasText = null } = {}) {
    this.tab = tab;
    this.selector = selector;
    this.hasText = hasText;
  }

  /** The first matching element, waited for (attached, not necessarily visible). */
  async #element() {
    const { page } = this.tab;
    const deadline = Date.now() + ACTION_TIMEOUT_MS;
    while (Date.now() < deadline) {
      for (const element of await page.$$(this.selector)) {
        if (!this.hasText) return element;
        const text = await element.evaluate((e) => e.textContent);
        if (this.hasText.test(text)) return element;
      }
      await this.tab.waitForTimeout(50);
    }
    throw new Error(`no element matches ${this.selector}${this.hasText ? ` with text ${this.hasText}` : ""}`);
  }

  async click() {
    if (!this.hasText) return this.tab.page.locator(this.selector).setTimeout(ACTION_TIMEOUT_MS).click();
    return (await this.#element()).click();
  }

  fill(value) {
    return this.tab.page.locator(this.selector).setTimeout(ACTION_TIMEOUT_MS).fill(value);
  }

  async focus() {
    return (await this.#element()).focus();
  }

  async count() {
    return (await this.tab.page.$$(this.selector)).length;
  }

  async evaluate(fn) {
    return (await this.#element()).evaluate(fn);
  }

  async boundingBox() {
    return (await this.#element()).boundingBox();
  }

  async textContent() {
    return this.evaluate((e) => e.textContent);
  }

  async inputValue() {
    return this.evaluate((e) => e.value);
  }

  async getAttribute(name) {
    return (await this.#element()).evaluate((e, name) => e.getAttribute(name), name);
  }

  /** Visible as Playwright means it: rendered with a non-empty box and not visibility:hidden. */
  async isVisible() {
    const [element] = await this.tab.page.$$(this.selector);
    return element
      ? element.evaluate((e) => {
          const box = e.getBoundingClientRect();
          return box.width > 0 && box.height > 0 && e.checkVisibility({ visibilityProperty: true });
        })
      : false;
  }

  async isHidden() {
    return !(await this.isVisible());
  }

  async isEnabled() {
    return this.evaluate((e) => !e.disabled);
  }

  async isDisabled() {
    return !(await this.isEnabled());
  }
}
