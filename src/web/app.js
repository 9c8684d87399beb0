// covec's web page: submit an image to the /v1 jobs API, follow its progress over Server-Sent
// Events, show the layered SVG inline (so its layers can be toggled), recolour albedo paths
// through the edits API, undo, and download the results. No dependencies, no build step.
//
// With an API key (the key field, kept in sessionStorage), every request carries
// `Authorization: Bearer <key>`: the event stream is read with fetch (EventSource sends no
// headers) and images and downloads are fetched and shown through blob: URLs.
//
// State the browser test reads: <body data-state="idle|submitting|queued|running|succeeded|
// failed|canceled">, and on #svg-host data-svg-url / data-sha256 (SHA-256 of the exact bytes
// fetched and inlined) / data-version (the edit id shown, or "original").

const TERMINAL = new Set(["succeeded", "failed", "canceled"]);
const IMAGE_TYPES = new Set(["image/png", "image/jpeg", "image/webp"]);
const LAYERS = ["albedo", "shade", "light"];
const SVG_NS = "http://www.w3.org/2000/svg";
/** If the event stream drops, the job is polled this often instead. */
const POLL_MS = 1000;

const $ = (id) => document.getElementById(id);

const ui = {
  form: $("job-form"),
  drop: $("drop"),
  image: $("image"),
  chosen: $("chosen"),
  paths: $("paths"),
  mode: $("mode"),
  albedo: $("albedo"),
  masks: $("masks"),
  labels: $("labels"),
  maxSize: $("max-size"),
  seed: $("seed"),
  iterations: {
    structure: $("it-structure"),
    reconstruction: $("it-reconstruction"),
    refine_rounds: $("it-refine-rounds"),
    refine: $("it-refine"),
    polish: $("it-polish"),
  },
  submit: $("submit"),
  formError: $("form-error"),
  progress: $("progress"),
  stageName: $("stage-name"),
  stageCount: $("stage-count"),
  bar: $("bar"),
  progressDetail: $("progress-detail"),
  cancel: $("cancel"),
  jobError: $("job-error"),
  previews: $("previews"),
  result: $("result"),
  resultNote: $("result-note"),
  inputImage: $("input-image"),
  host: $("svg-host"),
  compare: $("compare"),
  compareValue: $("compare-value"),
  compareOverlay: $("compare-overlay"),
  compareImage: $("compare-image"),
  pickOverlay: $("pick-overlay"),
  pickOutline: $("pick-outline"),
  show: { albedo: $("show-albedo"), shade: $("show-shade"), light: $("show-light") },
  pathSelect: $("path-select"),
  color: $("color"),
  applyColour: $("apply-colour"),
  undo: $("undo"),
  editStatus: $("edit-status"),
  editError: $("edit-error"),
  downloads: $("downloads"),
  apiKey: $("api-key"),
};

// ---------------------------------------------------------------- the API, with the key

const KEY_STORAGE = "covec-api-key";

try {
  ui.apiKey.value = sessionStorage.getItem(KEY_STORAGE) ?? "";
} catch {
  // Storage may be disabled; the field still works for this page.
}
ui.apiKey.addEventListener("input", () => {
  try {
    const key = ui.apiKey.value.trim();
    if (key) sessionStorage.setItem(KEY_STORAGE, key);
    else sessionStorage.removeItem(KEY_STORAGE);
  } catch {
    // as above
  }
});

/** fetch() with the API key, when one is given. */
function api(url, options = {}) {
  const key = ui.apiKey.value.trim();
  const headers = new Headers(options.headers || {});
  if (key) headers.set("authorization", `Bearer ${key}`);
  return fetch(url, { ...options, headers });
}

/** A blob: URL of what `url` answers (fetched with the key), for <img> and downloads. */
async function blobUrl(url) {
  const response = await api(url, { cache: "no-store" });
  if (!response.ok) throw new Error(await problemMessage(response));
  return URL.createObjectURL(await response.blob());
}

/**
 * Reads a Server-Sent Events stream with fetch (so the key goes along): calls `onEvent(type,
 * data)` per event and resolves when the stream ends; `lastEventId` resumes a stream. Returns
 * the last event id seen.
 */
async function readEvents(url, signal, lastEventId, onEvent) {
  const headers = { accept: "text/event-stream" };
  if (lastEventId) headers["last-event-id"] = lastEventId;
  const response = await api(url, { headers, signal, cache: "no-store" });
  if (!response.ok || !response.body) throw new Error(await problemMessage(response));
  const reader = response.body.pipeThrough(new TextDecoderStream()).getReader();
  let buffer = "";
  let event = { type: "message", data: [], id: null };
  for (;;) {
    const { value, done } = await reader.read();
    if (done) return lastEventId;
    buffer += value;
    const lines = buffer.split(/\r\n|\r|\n/);
    buffer = lines.pop();
    for (const line of lines) {
      if (line === "") {
        if (event.id !== null) lastEventId = event.id;
        if (event.data.length) onEvent(event.type, event.data.join("\n"));
        event = { type: "message", data: [], id: null };
        continue;
      }
      if (line.startsWith(":")) continue;
      const colon = line.indexOf(":");
      const field = colon < 0 ? line : line.slice(0, colon);
      const text = colon < 0 ? "" : line.slice(colon + 1).replace(/^ /, "");
      if (field === "event") event.type = text;
      else if (field === "data") event.data.push(text);
      else if (field === "id") event.id = text;
    }
  }
}

/** Everything about the job on screen. Replaced wholesale on each submit. */
let session = null;

function newSession(inputUrl) {
  return {
    job: null,
    inputUrl,
    events: null,
    pollTimer: null,
    shownPreviews: new Set(),
    /** Versions shown, oldest first: the job's SVG, then one per edit. Undo pops. */
    versions: [],
    /** Whether the person has picked a region yet (by click or from the list). */
    picked: false,
    /** A click that hit no visible albedo path: recolour by position instead. */
    pickedPoint: null,
    busy: false,
  };
}

function setState(state) {
  document.body.dataset.state = state;
}

function showError(element, message) {
  element.textContent = message;
  element.hidden = !message;
}

/** A readable message from a failed response: RFC 9457 problem details when the server sent them. */
async function problemMessage(response) {
  let problem = null;
  try {
    problem = await response.json();
  } catch {
    // Not JSON: fall back to the status line.
  }
  return describeProblem(problem, `${response.status} ${response.statusText}`.trim());
}

function describeProblem(problem, fallback) {
  if (!problem || typeof problem !== "object") return fallback || "Something went wrong.";
  const title = problem.title || fallback || "Error";
  const detail = problem.detail ? `: ${problem.detail}` : "";
  const errors = Array.isArray(problem.errors)
    ? problem.errors.map((e) => (typeof e === "string" ? e : e.detail || e.message || "")).filter(Boolean)
    : [];
  return `${title}${detail}${errors.length ? ` (${errors.join("; ")})` : ""}`;
}

function fileLabel(file) {
  return `“${file.name}”${file.type ? ` (${file.type})` : ""}`;
}

// ---------------------------------------------------------------- choosing and submitting

function chooseFile(file) {
  if (!file) return;
  showError(ui.formError, "");
  if (!IMAGE_TYPES.has(file.type)) {
    showError(ui.formError, `${fileLabel(file)} is not an image covec reads: choose a PNG, JPEG or WebP file.`);
    ui.chosen.hidden = true;
    return;
  }
  if (ui.chosen.src.startsWith("blob:")) URL.revokeObjectURL(ui.chosen.src);
  ui.chosen.src = URL.createObjectURL(file);
  ui.chosen.alt = `Chosen image: ${file.name}`;
  ui.chosen.hidden = false;
}

ui.image.addEventListener("change", () => chooseFile(ui.image.files[0]));
// A file that claims to be an image but is not decodable: no thumbnail (the server will say why).
ui.chosen.addEventListener("error", () => (ui.chosen.hidden = true));

for (const type of ["dragenter", "dragover"]) {
  ui.drop.addEventListener(type, (event) => {
    event.preventDefault();
    ui.drop.classList.add("dragging");
  });
}
for (const type of ["dragleave", "drop"]) {
  ui.drop.addEventListener(type, () => ui.drop.classList.remove("dragging"));
}
ui.drop.addEventListener("drop", (event) => {
  event.preventDefault();
  const files = event.dataTransfer?.files;
  if (!files || files.length === 0) return;
  ui.image.files = files;
  chooseFile(files[0]);
});

function integerField(input, name, min, max) {
  const text = input.value.trim();
  const value = Number(text);
  if (text === "" || !Number.isInteger(value) || value < min || (max !== undefined && value > max)) {
    const range = max === undefined ? `at least ${min}` : `from ${min} to ${max}`;
    throw new Error(`${name} must be a whole number ${range}.`);
  }
  return value;
}

/** The multipart body of POST /v1/jobs, or an Error saying what to fix. */
function buildJobRequest() {
  const image = ui.image.files[0];
  if (!image) throw new Error("Choose an image first.");
  if (!IMAGE_TYPES.has(image.type)) {
    throw new Error(`${fileLabel(image)} is not an image covec reads: choose a PNG, JPEG or WebP file.`);
  }
  const params = {
    paths: integerField(ui.paths, "Paths", 8, 1024),
    mode: ui.mode.value,
    max_size: integerField(ui.maxSize, "Working size", 16),
    seed: integerField(ui.seed, "Seed", 0),
    iterations: {},
  };
  for (const [key, input] of Object.entries(ui.iterations)) {
    params.iterations[key] = integerField(input, `Iterations (${key.replace("_", " ")})`, 0);
  }
  const body = new FormData();
  body.append("image", image, image.name);
  const albedo = ui.albedo.files[0];
  if (albedo) body.append("albedo", albedo, albedo.name);
  for (const mask of ui.masks.files) body.append("mask", mask, mask.name);
  const labels = ui.labels.files[0];
  if (labels) body.append("labels", labels, labels.name);
  if (ui.masks.files.length > 0 && labels) throw new Error("Give either masks or a label map, not both.");
  body.append("params", JSON.stringify(params));
  return { body, image };
}

ui.form.addEventListener("submit", async (event) => {
  event.preventDefault();
  showError(ui.formError, "");
  let request;
  try {
    request = buildJobRequest();
  } catch (error) {
    showError(ui.formError, error.message);
    return;
  }
  stopFollowing();
  session = newSession(URL.createObjectURL(request.image));
  resetJobView();
  setState("submitting");
  ui.submit.disabled = true;
  try {
    const response = await api("/v1/jobs", { method: "POST", body: request.body });
    if (!response.ok) {
      showError(ui.formError, `The server rejected the image. ${await problemMessage(response)}`);
      setState("idle");
      return;
    }
    const job = await response.json();
    session.job = job;
    ui.progress.hidden = false;
    showJob(job);
    follow(job);
  } catch (error) {
    showError(ui.formError, `Could not reach the server: ${error.message}`);
    setState("idle");
  } finally {
    ui.submit.disabled = false;
  }
});

function resetJobView() {
  ui.progress.hidden = true;
  ui.result.hidden = true;
  ui.previews.replaceChildren();
  ui.bar.value = 0;
  ui.stageName.textContent = "Queued";
  ui.stageCount.textContent = "";
  ui.progressDetail.textContent = "";
  ui.cancel.hidden = false;
  ui.cancel.disabled = false;
  showError(ui.jobError, "");
  showError(ui.editError, "");
  ui.editStatus.textContent = "";
  ui.host.replaceChildren();
  ui.downloads.replaceChildren();
}

// ---------------------------------------------------------------- following a job

/**
 * The job's link `key` as the server gave it (in `urls`, or `urls.results` once it succeeded),
 * else the documented path under the job.
 */
function jobUrl(job, key, suffix) {
  const url = job.urls?.[key] ?? job.urls?.results?.[key];
  return typeof url === "string" ? url : jobPath(job, suffix);
}

function jobPath(job, suffix) {
  return `/v1/jobs/${encodeURIComponent(job.id)}${suffix}`;
}

function follow(job) {
  if (TERMINAL.has(job.status)) {
    finish(job);
    return;
  }
  const current = session;
  const controller = new AbortController();
  current.events = controller;
  // The service sends `progress` events (the job) while it runs, then one `completed`.
  const onEvent = (type, text) => {
    if (type !== "progress" && type !== "completed") return;
    let data;
    try {
      data = JSON.parse(text);
    } catch {
      return; // non-JSON notes carry nothing to show
    }
    handleUpdate(data);
  };
  const url = jobUrl(job, "events", "/events");
  (async () => {
    // A dropped stream is resumed once from its last event id (no repeats); after that, or if
    // the stream cannot be opened, the job is polled.
    let lastEventId = null;
    for (let attempt = 0; attempt < 2; attempt++) {
      try {
        lastEventId = await readEvents(url, controller.signal, lastEventId, onEvent);
      } catch {
        break;
      }
      if (current !== session || current.events !== controller || TERMINAL.has(current.job.status)) return;
    }
    if (current === session && current.events === controller) {
      current.events = null;
      poll();
    }
  })();
}

function stopFollowing() {
  if (!session) return;
  session.events?.abort();
  session.events = null;
  clearTimeout(session.pollTimer);
}

async function poll() {
  const current = session;
  if (!current?.job) return;
  try {
    const response = await api(jobUrl(current.job, "self", ""), { cache: "no-store" });
    if (current !== session) return;
    if (response.ok) {
      handleUpdate(await response.json());
    } else if (response.status === 404 || response.status === 410) {
      showError(ui.jobError, `The job is gone. ${await problemMessage(response)}`);
      setState("failed");
      return;
    }
  } catch {
    // The server may be restarting; keep polling.
  }
  if (current === session && !TERMINAL.has(current.job.status)) {
    current.pollTimer = setTimeout(poll, POLL_MS);
  }
}

/**
 * One update of the job (from the event stream, a poll or a cancel reply): show it, add the
 * previews that are new, and on a terminal status end the stream and show the outcome.
 */
function handleUpdate(data) {
  const job = session?.job;
  if (!job || data?.id !== job.id) return;
  // A job that ended stays ended: a late reply (say, to a cancel request) must not revive it.
  if (TERMINAL.has(job.status)) return;
  Object.assign(job, data);
  showJob(job);
  showPreviews(job.previews ?? []);
  if (TERMINAL.has(job.status)) {
    stopFollowing();
    finish(job);
  }
}

function formatSeconds(seconds) {
  if (!Number.isFinite(seconds)) return "";
  if (seconds < 60) return `${Math.max(0, Math.round(seconds))} s`;
  const minutes = Math.floor(seconds / 60);
  return `${minutes} min ${Math.round(seconds - minutes * 60)} s`;
}

function showJob(job) {
  setState(job.status || "queued");
  const progress = job.progress || {};
  const stage = progress.stage;
  if (job.status === "queued") {
    const position = job.queue_position;
    ui.stageName.textContent = Number.isInteger(position) ? `Queued (position ${position + 1})` : "Queued";
  } else if (job.status === "running" || (stage && !TERMINAL.has(job.status))) {
    ui.stageName.textContent = stage ? `Stage: ${stage.name}` : "Running";
  } else if (job.status === "succeeded") {
    ui.stageName.textContent = "Done";
  } else if (job.status === "failed") {
    ui.stageName.textContent = "Failed";
  } else if (job.status === "canceled") {
    ui.stageName.textContent = "Canceled";
  }
  ui.stageCount.textContent =
    stage && Number.isInteger(stage.index) && Number.isInteger(stage.count) && !TERMINAL.has(job.status)
      ? `(${stage.index + 1} of ${stage.count})`
      : "";
  const fraction = job.status === "succeeded" ? 1 : Number(progress.fraction);
  if (Number.isFinite(fraction)) ui.bar.value = Math.min(1, Math.max(0, fraction));
  const details = [];
  if (Number.isFinite(fraction)) details.push(`${Math.round(ui.bar.value * 100)}%`);
  const live = !TERMINAL.has(job.status);
  if (live && Number.isInteger(progress.iteration) && Number.isInteger(progress.iterations) && progress.iterations > 0) {
    details.push(`iteration ${progress.iteration} of ${progress.iterations}`);
  }
  if (Number.isFinite(progress.loss)) details.push(`loss ${progress.loss.toPrecision(3)}`);
  if (live && Number.isFinite(progress.eta_seconds)) {
    details.push(`about ${formatSeconds(progress.eta_seconds)} left`);
  }
  ui.progressDetail.textContent = details.join(" · ");
  ui.cancel.hidden = TERMINAL.has(job.status);
}

ui.cancel.addEventListener("click", async () => {
  if (!session?.job) return;
  ui.cancel.disabled = true;
  try {
    const response = await api(jobUrl(session.job, "cancel", "/cancel"), { method: "POST" });
    if (!response.ok) showError(ui.jobError, `Could not cancel. ${await problemMessage(response)}`);
    else handleUpdate(await response.json().catch(() => null));
  } catch (error) {
    showError(ui.jobError, `Could not cancel: ${error.message}`);
  } finally {
    ui.cancel.disabled = false;
  }
});

/** Adds the stage previews (names, in the order the stages made them) not on the page yet. */
function showPreviews(names) {
  for (const name of names) {
    if (session.shownPreviews.has(name)) continue;
    session.shownPreviews.add(name);
    const url = `${jobUrl(session.job, "previews", "/previews")}/${encodeURIComponent(name)}.png`;
    const entry = document.createElement("li");
    const figure = document.createElement("figure");
    const img = document.createElement("img");
    blobUrl(url)
      .then((blob) => (img.src = blob))
      .catch((error) => showError(ui.jobError, `A preview could not be loaded. ${error.message}`));
    img.alt = `Preview after stage ${name}`;
    img.decoding = "async";
    const caption = document.createElement("figcaption");
    caption.textContent = name;
    figure.append(img, caption);
    entry.append(figure);
    ui.previews.append(entry);
  }
}

async function finish(job) {
  const status = job.status;
  setState(status);
  showJob(job);
  if (status === "failed") {
    showError(ui.jobError, `The job failed. ${describeProblem(job.error, "No reason was given.")}`);
    return;
  }
  if (status === "canceled") {
    showError(ui.jobError, "The job was canceled.");
    return;
  }
  await showResult(job);
}

// ---------------------------------------------------------------- the result

async function fetchText(url) {
  const response = await api(url, { cache: "no-store" });
  if (!response.ok) throw new Error(await problemMessage(response));
  return response.text();
}

async function sha256Hex(text) {
  if (!crypto.subtle) return "";
  const digest = await crypto.subtle.digest("SHA-256", new TextEncoder().encode(text));
  return Array.from(new Uint8Array(digest), (b) => b.toString(16).padStart(2, "0")).join("");
}

async function showResult(job) {
  const current = session;
  let svgText;
  const svgUrl = jobUrl(job, "svg", "/svg");
  try {
    svgText = await fetchText(svgUrl);
  } catch (error) {
    showError(ui.jobError, `The job finished but its SVG could not be read. ${error.message}`);
    return;
  }
  if (current !== session) return;
  current.versions = [
    {
      id: null,
      svgUrl,
      svgText,
      sceneUrl: jobUrl(job, "scene", "/scene.json"),
      layerUrls: Object.fromEntries(LAYERS.map((layer) => [layer, jobUrl(job, layer, `/layers/${layer}.svg`)])),
      changed: [],
    },
  ];
  ui.inputImage.src = current.inputUrl;
  ui.compareImage.src = current.inputUrl;
  ui.result.hidden = false;
  await showVersion();
  setState("succeeded");
  ui.result.scrollIntoView({ behavior: "smooth", block: "start" });
}

/** Inlines the newest version's SVG (keeping its `isolation:isolate`) and refreshes the controls. */
async function showVersion() {
  const version = session.versions.at(-1);
  const doc = new DOMParser().parseFromString(version.svgText, "image/svg+xml");
  const root = doc.documentElement;
  if (root.localName !== "svg" || doc.querySelector("parsererror")) {
    showError(ui.jobError, "The server's SVG could not be parsed.");
    return;
  }
  const svg = document.importNode(root, true);
  // The blend modes must composite within the SVG, never with the page behind it.
  if (!/isolation\s*:\s*isolate/.test(svg.getAttribute("style") || "")) svg.style.isolation = "isolate";
  svg.setAttribute("focusable", "false");
  svg.setAttribute("aria-hidden", "true");
  ui.host.replaceChildren(svg);
  ui.host.dataset.svgUrl = version.svgUrl;
  ui.host.dataset.version = version.id ?? "original";
  ui.host.dataset.sha256 = await sha256Hex(version.svgText);

  const viewBox = svg.getAttribute("viewBox");
  if (viewBox) ui.pickOverlay.setAttribute("viewBox", viewBox);
  const [, , width, height] = (viewBox || "").split(/[\s,]+/).map(Number);
  ui.resultNote.textContent =
    Number.isFinite(width) && Number.isFinite(height)
      ? `(${svg.querySelectorAll("path").length} paths, ${width}×${height} working size)`
      : "";
  applyLayerView();
  fillPathSelect(svg);
  showPicked();
  fillDownloads();
  ui.undo.disabled = session.versions.length < 2;
}

function svgRoot() {
  return ui.host.querySelector("svg");
}

function layerGroup(svg, name) {
  return svg.querySelector(`g#${name}`);
}

/**
 * Shows the checked layers. With the albedo hidden the shade multiplies onto white (the view of
 * the shading alone), and the light alone adds onto black: the neutral colours of each blend.
 */
function applyLayerView() {
  const svg = svgRoot();
  if (!svg) return;
  for (const name of LAYERS) {
    const group = layerGroup(svg, name);
    if (group) group.style.display = ui.show[name].checked ? "" : "none";
  }
  svg.querySelector("rect[data-covec-backdrop]")?.remove();
  if (!ui.show.albedo.checked) {
    const [x, y, w, h] = (svg.getAttribute("viewBox") || "0 0 100% 100%").split(/[\s,]+/);
    const backdrop = document.createElementNS(SVG_NS, "rect");
    backdrop.dataset.covecBackdrop = "";
    backdrop.setAttribute("x", x);
    backdrop.setAttribute("y", y);
    backdrop.setAttribute("width", w);
    backdrop.setAttribute("height", h);
    backdrop.setAttribute("fill", ui.show.shade.checked ? "#ffffff" : "#000000");
    svg.prepend(backdrop);
  }
}

for (const name of LAYERS) ui.show[name].addEventListener("change", applyLayerView);

for (const button of document.querySelectorAll("button[data-view]")) {
  button.addEventListener("click", () => {
    const view = button.dataset.view;
    for (const name of LAYERS) ui.show[name].checked = view === "all" || view === name;
    applyLayerView();
  });
}

ui.compare.addEventListener("input", () => {
  const percent = Number(ui.compare.value);
  ui.compareValue.textContent = `${percent}%`;
  ui.compareOverlay.style.clipPath = `inset(0 ${100 - percent}% 0 0)`;
  ui.compareOverlay.hidden = percent === 0;
});
ui.compareOverlay.hidden = true;

// ---------------------------------------------------------------- picking and recolouring

function albedoPaths(svg) {
  const group = layerGroup(svg, "albedo");
  return group ? Array.from(group.querySelectorAll("path[id]")) : [];
}

function fillPathSelect(svg) {
  const previous = ui.pathSelect.value;
  const options = albedoPaths(svg).map((path) => {
    const option = document.createElement("option");
    option.value = path.id;
    const fill = path.getAttribute("fill") || "";
    option.textContent = `${path.id}${fill ? ` (${fill})` : ""}`;
    return option;
  });
  ui.pathSelect.replaceChildren(...options);
  if (options.some((o) => o.value === previous)) ui.pathSelect.value = previous;
  else ui.pathSelect.selectedIndex = options.length > 1 ? 1 : 0; // skip the base path by default
  syncColourToSelection();
}

function syncColourToSelection() {
  const path = svgRoot()?.querySelector(`path#${CSS.escape(ui.pathSelect.value)}`);
  const fill = path?.getAttribute("fill");
  if (fill && /^#[0-9a-f]{6}$/i.test(fill)) ui.color.value = fill.toLowerCase();
}

/**
 * Outlines the picked path over the image (outside the blended SVG, so it changes no colour),
 * once the person has picked one.
 */
function showPicked() {
  const picking = session?.picked && !session.pickedPoint;
  const path = picking ? svgRoot()?.querySelector(`path#${CSS.escape(ui.pathSelect.value)}`) : null;
  ui.pickOutline.setAttribute("d", path?.getAttribute("d") || "");
}

ui.pathSelect.addEventListener("change", () => {
  session.picked = true;
  session.pickedPoint = null;
  syncColourToSelection();
  showPicked();
});

ui.host.addEventListener("click", (event) => {
  const svg = svgRoot();
  if (!svg || !session) return;
  session.picked = true;
  const hit = document
    .elementsFromPoint(event.clientX, event.clientY)
    .find((element) => /^albedo-\d+$/.test(element.id) && svg.contains(element));
  if (hit) {
    session.pickedPoint = null;
    ui.pathSelect.value = hit.id;
    syncColourToSelection();
    ui.editStatus.textContent = `Picked ${hit.id}. Choose a colour and apply it.`;
  } else {
    // The albedo is hidden: let the server find the path under this point.
    const matrix = svg.getScreenCTM();
    if (!matrix) return;
    const point = new DOMPoint(event.clientX, event.clientY).matrixTransform(matrix.inverse());
    session.pickedPoint = { x: Number(point.x.toFixed(2)), y: Number(point.y.toFixed(2)) };
    ui.editStatus.textContent = `Picked the albedo region at (${session.pickedPoint.x}, ${session.pickedPoint.y}).`;
  }
  showPicked();
});

ui.applyColour.addEventListener("click", async () => {
  if (!session?.job || session.busy || session.versions.length === 0) return;
  const current = session;
  const base = current.versions.at(-1);
  const color = ui.color.value.toLowerCase();
  const change = current.pickedPoint ? { at: current.pickedPoint, color } : { path: ui.pathSelect.value, color };
  if (!change.at && !change.path) {
    showError(ui.editError, "Pick a region first: click the vector image or choose one from the list.");
    return;
  }
  const body = { changes: [change] };
  if (base.id) body.base = base.id;
  current.busy = true;
  ui.applyColour.disabled = true;
  showError(ui.editError, "");
  ui.editStatus.textContent = "Recolouring…";
  try {
    const response = await api(jobUrl(current.job, "edits", "/edits"), {
      method: "POST",
      headers: { "content-type": "application/json" },
      body: JSON.stringify(body),
    });
    if (!response.ok) throw new Error(await problemMessage(response));
    const edit = await response.json();
    const editPath = `/edits/${encodeURIComponent(edit.id)}`;
    const svgUrl = edit.urls?.svg || jobPath(current.job, `${editPath}/svg`);
    const svgText = await fetchText(svgUrl);
    if (current !== session) return;
    current.versions.push({
      id: edit.id,
      svgUrl,
      svgText,
      sceneUrl: edit.urls?.scene || jobPath(current.job, `${editPath}/scene.json`),
      layerUrls: edit.urls?.layers || null,
      changed: edit.changed || [],
    });
    current.pickedPoint = null;
    const changed = current.versions.at(-1).changed;
    if (changed.length === 1) ui.pathSelect.value = changed[0].path;
    await showVersion();
    ui.editStatus.textContent = changed.length
      ? `Recoloured ${changed.map((c) => `${c.path} ${c.old_color} → ${c.new_color}`).join(", ")}.`
      : "Nothing changed.";
  } catch (error) {
    showError(ui.editError, `The colour could not be applied. ${error.message}`);
    ui.editStatus.textContent = "";
  } finally {
    current.busy = false;
    ui.applyColour.disabled = false;
  }
});

ui.undo.addEventListener("click", async () => {
  if (!session || session.versions.length < 2 || session.busy) return;
  const undone = session.versions.pop();
  await showVersion();
  ui.editStatus.textContent = `Undid ${undone.changed.map((c) => c.path).join(", ") || "the last edit"}.`;
  if (ui.undo.disabled) ui.applyColour.focus();
});

// ---------------------------------------------------------------- downloads

function fillDownloads() {
  const version = session.versions.at(-1);
  const original = session.versions[0];
  const stem = `covec-${session.job.id}${version.id ? `-${version.id}` : ""}`;
  const links = [
    [version.svgUrl, `${stem}.svg`, version.id ? "Layered SVG (with your colours)" : "Layered SVG"],
    [version.sceneUrl, `${stem}.scene.json`, "Scene JSON"],
  ];
  // The job's picture for programs without the SVG's blend modes, and at a fixed size; the
  // service makes these from the job's scene, not an edit's.
  const jobStem = `covec-${session.job.id}`;
  const before = version.id ? " (before recolouring)" : "";
  links.push(
    [jobPath(session.job, "/svg?flatten=true"), `${jobStem}-flat.svg`, `Flattened SVG${before}`],
    [jobPath(session.job, "/pdf"), `${jobStem}.pdf`, `PDF${before}`],
    [jobPath(session.job, "/png"), `${jobStem}.png`, `PNG${before}`],
  );
  // An edit recolours albedo paths only: the job's shade and light layers stay current.
  const layerUrls = version.layerUrls || original.layerUrls;
  for (const name of LAYERS) {
    const stale = name === "albedo" && version.id && !version.layerUrls;
    const label = `${name[0].toUpperCase()}${name.slice(1)} layer SVG${stale ? " (before recolouring)" : ""}`;
    links.push([layerUrls[name], `${stem}-${name}.svg`, label]);
  }
  ui.downloads.replaceChildren(
    ...links.map(([href, filename, label]) => {
      const item = document.createElement("li");
      const link = document.createElement("a");
      link.href = href;
      link.download = filename;
      link.textContent = label;
      link.addEventListener("click", (event) => download(event, link, href));
      item.append(link);
      return item;
    }),
  );
}

/**
 * With a key, a plain link would be refused (it sends no header): fetch the file with the key
 * and save it through a blob: URL instead.
 */
async function download(event, link, href) {
  if (!ui.apiKey.value.trim()) return;
  event.preventDefault();
  try {
    const url = await blobUrl(href);
    const save = document.createElement("a");
    save.href = url;
    save.download = link.download;
    document.body.append(save);
    save.click();
    save.remove();
    setTimeout(() => URL.revokeObjectURL(url), 60_000);
  } catch (error) {
    showError(ui.jobError, `The download failed. ${error.message}`);
  }
}

setState("idle");
