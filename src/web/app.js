// covec's web page: submit images to the /v1 jobs API (one job each, or the sample photo),
// follow each job's progress over Server-Sent Events in its own row, show one job's layered
// SVG inline (so its layers can be toggled), recolour albedo paths (by colour or by a reference
// image) through the edits API, undo, and download the results named after the input file. The
// job ids are kept in the page's address (`#job=ID&job=ID2&show=ID`), so a reload or a shared
// link resumes them. Every limit and default comes from `GET /v1/limits`. No dependencies, no
// build step.
//
// With an API key (the key field, kept in sessionStorage), every request carries
// `Authorization: Bearer <key>`: the event stream is read with fetch (EventSource sends no
// headers) and images and downloads are fetched and shown through blob: URLs.
//
// State the browser test reads: <body data-state="idle|submitting|queued|running|succeeded|
// failed|canceled"> (the shown job's) and data-limits="loaded|failed"; each row of #jobs has
// data-name, data-job and data-status (a job status, "uploading" or "refused"); on #svg-host
// data-svg-url / data-sha256 (SHA-256 of the exact bytes fetched and inlined) / data-version
// (the edit id shown, or "original").

const TERMINAL = new Set(["succeeded", "failed", "canceled"]);
const LAYERS = ["albedo", "shade", "light"];
const SVG_NS = "http://www.w3.org/2000/svg";
/** If the event stream drops, the job is polled this often instead. */
const POLL_MS = 1000;
/** What a job id in the address may look like (anything else is ignored). */
const JOB_ID = /^[A-Za-z0-9_-]{1,128}$/;

const $ = (id) => document.getElementById(id);

const ui = {
  form: $("job-form"),
  drop: $("drop"),
  image: $("image"),
  chosen: $("chosen"),
  acceptedTypes: $("accepted-types"),
  trySample: $("try-sample"),
  paths: $("paths"),
  mode: $("mode"),
  albedo: $("albedo"),
  masks: $("masks"),
  masksHint: $("masks-hint"),
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
  limitsNote: $("limits-note"),
  formError: $("form-error"),
  progress: $("progress"),
  jobs: $("jobs"),
  selectedHeading: $("selected-heading"),
  stageName: $("stage-name"),
  stageCount: $("stage-count"),
  bar: $("bar"),
  progressDetail: $("progress-detail"),
  cancel: $("cancel"),
  jobError: $("job-error"),
  previews: $("previews"),
  draft: $("draft"),
  draftImage: $("draft-image"),
  draftCaption: $("draft-caption"),
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
  reference: $("reference"),
  referenceK: $("reference-k"),
  applyReference: $("apply-reference"),
  undo: $("undo"),
  editStatus: $("edit-status"),
  editError: $("edit-error"),
  downloads: $("downloads"),
  pngWidth: $("png-width"),
  pngError: $("png-error"),
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

function formatBytes(bytes) {
  if (bytes >= 1 << 20) return `${+(bytes / (1 << 20)).toFixed(1)} MiB`;
  if (bytes >= 1 << 10) return `${+(bytes / (1 << 10)).toFixed(1)} KiB`;
  return `${bytes} bytes`;
}

/** "PNG, JPEG or WebP" from media types. */
function typeNames(types) {
  const names = types.map((type) => {
    const name = type.replace(/^image\//, "");
    return name === "webp" ? "WebP" : name.toUpperCase();
  });
  return names.length > 1 ? `${names.slice(0, -1).join(", ")} or ${names.at(-1)}` : names.join("");
}

// ---------------------------------------------------------------- the server's limits

/** GET /v1/limits: bounds, accepted media types and defaults; null until read. */
let limits = null;

/** Reads the limits and sets the form's bounds and (empty fields') defaults from them. */
async function loadLimits() {
  try {
    const response = await api("/v1/limits", { cache: "no-store" });
    if (!response.ok) throw new Error(await problemMessage(response));
    limits = await response.json();
  } catch (error) {
    document.body.dataset.limits = "failed";
    showError(ui.formError, `The server's limits could not be read (${error.message}); it will check each image itself.`);
    return;
  }
  const first = document.body.dataset.limits !== "loaded";
  document.body.dataset.limits = "loaded";
  if (ui.formError.textContent.startsWith("The server's limits")) showError(ui.formError, "");
  const { defaults } = limits;
  const bound = (input, min, max, value) => {
    if (min !== undefined) input.min = String(min);
    if (max !== undefined) input.max = String(max);
    if (input.value.trim() === "" && value !== undefined) input.value = String(value);
  };
  bound(ui.paths, limits.min_paths, limits.max_paths, defaults.paths);
  bound(ui.maxSize, limits.min_size, limits.max_size, defaults.max_size);
  bound(ui.seed, 0, undefined, defaults.seed);
  for (const [key, input] of Object.entries(ui.iterations)) bound(input, 0, limits.max_iterations, defaults.iterations[key]);
  bound(ui.referenceK, 1, undefined, limits.reference_defaults?.k);
  if (first) ui.mode.value = defaults.mode;
  const accept = limits.media_types.join(",");
  for (const input of [ui.image, ui.albedo, ui.reference]) input.accept = accept;
  ui.masks.accept = ui.labels.accept = "image/png";
  ui.acceptedTypes.textContent = `${typeNames(limits.media_types)}, up to ${formatBytes(limits.max_body_bytes)} and ${+(limits.max_pixels / 1e6).toFixed(1)} megapixels each`;
  ui.masksHint.textContent = `(binary, one file each, at most ${limits.max_masks})`;
  ui.limitsNote.textContent = `This server allows ${limits.min_paths}–${limits.max_paths} paths and a working size of ${limits.min_size}–${limits.max_size} px.`;
}

/** Why this file cannot be sent, or null (the server checks the rest). */
function fileProblem(file) {
  if (limits && !limits.media_types.includes(file.type)) {
    return `${fileLabel(file)} is not an image covec reads: choose a ${typeNames(limits.media_types)} file.`;
  }
  if (limits && file.size > limits.max_body_bytes) {
    return `${fileLabel(file)} is too large: ${formatBytes(file.size)}, and this server takes at most ${formatBytes(limits.max_body_bytes)} a request.`;
  }
  return null;
}

// ---------------------------------------------------------------- the jobs on the page

/** Every image on the page, in the order given (or listed in the address). */
const items = [];
/** The item whose progress, previews and result are shown below the rows. */
let session = null;

/** A new row for an image (its job comes once the server accepts it). */
function newItem(name) {
  const item = {
    name,
    job: null,
    /** The input image to show (a blob: URL), once known. */
    inputUrl: null,
    events: null,
    pollTimer: null,
    shownPreviews: new Set(),
    /** The stage of the draft shown (or being fetched). */
    shownDraft: null,
    /** Versions of the result, oldest first: the job's SVG, then one per edit. Undo pops. */
    versions: [],
    /** Whether the person has picked a region yet (by click or from the list). */
    picked: false,
    /** A click that hit no visible albedo path: recolour by position instead. */
    pickedPoint: null,
    busy: false,
  };
  const element = document.createElement("li");
  element.className = "job-row";
  element.dataset.name = name;
  const title = document.createElement("span");
  title.className = "job-name";
  title.textContent = name;
  const progress = document.createElement("div");
  progress.className = "job-progress";
  const status = document.createElement("span");
  status.className = "job-status";
  status.setAttribute("aria-live", "polite");
  const bar = document.createElement("progress");
  bar.max = 1;
  bar.value = 0;
  bar.setAttribute("aria-label", `Progress of ${name}`);
  progress.append(status, bar);
  const actions = document.createElement("div");
  actions.className = "job-actions";
  const button = (name, label, action) => {
    const element = document.createElement("button");
    element.type = "button";
    element.className = `job-${name}`;
    element.textContent = label;
    element.addEventListener("click", action);
    return element;
  };
  const show = button("show", "Show", () => select(item));
  show.disabled = true;
  const cancel = button("cancel", "Cancel", () => cancelJob(item));
  cancel.hidden = true;
  actions.append(show, cancel);
  const error = document.createElement("p");
  error.className = "error";
  error.setAttribute("role", "alert");
  error.hidden = true;
  element.append(title, progress, actions, error);
  item.row = { element, title, status, bar, show, cancel, error };
  items.push(item);
  ui.jobs.append(element);
  ui.progress.hidden = false;
  return item;
}

/** What a job's stage line says: the queue position, the stage, or the outcome. */
function stageText(job) {
  const stage = job.progress?.stage;
  if (job.status === "queued") {
    const position = job.queue_position;
    return Number.isInteger(position) ? `Queued (position ${position + 1})` : "Queued";
  }
  if (job.status === "running" || (stage && !TERMINAL.has(job.status))) return stage ? `Stage: ${stage.name}` : "Running";
  return { succeeded: "Done", failed: "Failed", canceled: "Canceled" }[job.status] ?? job.status;
}

function jobFraction(job) {
  return job.status === "succeeded" ? 1 : Number(job.progress?.fraction);
}

function updateRow(item, status = item.job?.status) {
  const { row, job } = item;
  row.element.dataset.status = status;
  if (job) {
    row.element.dataset.job = job.id;
    row.title.textContent = item.name;
    row.element.dataset.name = item.name;
    row.status.textContent = stageText(job);
    const fraction = jobFraction(job);
    if (Number.isFinite(fraction)) row.bar.value = Math.min(1, Math.max(0, fraction));
    row.cancel.hidden = TERMINAL.has(job.status);
    row.show.disabled = item === session;
    if (job.status === "failed") showError(row.error, `The job failed. ${describeProblem(job.error, "No reason was given.")}`);
  }
}

/** A file that was not turned into a job: the reason goes next to it. */
function refuse(item, message) {
  item.row.status.textContent = "Not sent";
  item.row.bar.hidden = true;
  showError(item.row.error, message);
  updateRow(item, "refused");
}

/** The address lists the page's jobs and the one shown, so a reload or a shared link resumes them. */
function updateAddress() {
  const params = new URLSearchParams();
  for (const item of items) if (item.job) params.append("job", item.job.id);
  if (session?.job && items.filter((item) => item.job).length > 1) params.set("show", session.job.id);
  const hash = params.toString();
  history.replaceState(null, "", hash ? `#${hash}` : `${location.pathname}${location.search}`);
}

/** Shows one item's progress, previews and result below the rows. */
function select(item) {
  if (session === item || !item.job) return;
  session = item;
  for (const other of items) {
    other.row.element.setAttribute("aria-current", other === item ? "true" : "false");
    if (other.job) other.row.show.disabled = other === item;
  }
  resetJobView();
  ui.selectedHeading.textContent = item.name;
  updateAddress();
  item.shownPreviews = new Set();
  item.shownDraft = null;
  showJob(item);
  showPreviews(item, item.job.previews ?? []);
  showDraft(item);
  if (TERMINAL.has(item.job.status)) finish(item);
}

function resetJobView() {
  ui.result.hidden = true;
  ui.previews.replaceChildren();
  hideDraft();
  ui.bar.value = 0;
  ui.stageName.textContent = "Queued";
  ui.stageCount.textContent = "";
  ui.progressDetail.textContent = "";
  ui.cancel.hidden = false;
  ui.cancel.disabled = false;
  showError(ui.jobError, "");
  showError(ui.editError, "");
  showError(ui.pngError, "");
  ui.editStatus.textContent = "";
  ui.host.replaceChildren();
  ui.downloads.replaceChildren();
}

// ---------------------------------------------------------------- choosing and submitting

function chooseFiles(files) {
  const first = Array.from(files).find((file) => file.type.startsWith("image/"));
  if (ui.chosen.src.startsWith("blob:")) URL.revokeObjectURL(ui.chosen.src);
  ui.chosen.hidden = !first;
  if (!first) return;
  ui.chosen.src = URL.createObjectURL(first);
  ui.chosen.alt = files.length > 1 ? `${files.length} images chosen, the first: ${first.name}` : `Chosen image: ${first.name}`;
}

ui.image.addEventListener("change", () => chooseFiles(ui.image.files));
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
  chooseFiles(files);
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

/** A number field left empty: the server's default applies (undefined is left out of JSON). */
function optionalInteger(input, name, min, max) {
  return input.value.trim() === "" ? undefined : integerField(input, name, min, max);
}

/** The job parameters the form asks for, or an Error saying what to fix. */
function formParams() {
  const params = {
    paths: optionalInteger(ui.paths, "Paths", limits?.min_paths ?? 1, limits?.max_paths),
    mode: ui.mode.value || undefined,
    max_size: optionalInteger(ui.maxSize, "Working size", limits?.min_size ?? 1, limits?.max_size),
    seed: optionalInteger(ui.seed, "Seed", 0),
    iterations: {},
  };
  for (const [key, input] of Object.entries(ui.iterations)) {
    params.iterations[key] = optionalInteger(input, `Iterations (${key.replace("_", " ")})`, 0, limits?.max_iterations);
  }
  const extras = ui.albedo.files.length + ui.masks.files.length + ui.labels.files.length;
  if (ui.masks.files.length > 0 && ui.labels.files.length > 0) throw new Error("Give either masks or a label map, not both.");
  if (limits && ui.masks.files.length > limits.max_masks) {
    throw new Error(`This server takes at most ${limits.max_masks} masks; ${ui.masks.files.length} were chosen.`);
  }
  return { params, extras };
}

/** The multipart body of POST /v1/jobs for one image. */
function jobBody(image, params) {
  const body = new FormData();
  body.append("image", image, image.name);
  const albedo = ui.albedo.files[0];
  if (albedo) body.append("albedo", albedo, albedo.name);
  for (const mask of ui.masks.files) body.append("mask", mask, mask.name);
  const labels = ui.labels.files[0];
  if (labels) body.append("labels", labels, labels.name);
  body.append("params", JSON.stringify(params));
  return body;
}

/** One job per image, each in its own row; the first accepted is shown. */
async function submitFiles(files) {
  showError(ui.formError, "");
  if (!limits) await loadLimits();
  let request;
  try {
    if (files.length === 0) throw new Error("Choose an image first.");
    request = formParams();
    if (request.extras > 0 && files.length > 1) {
      throw new Error("An albedo map, masks or a label map go with one image: choose one image, or clear them under Advanced.");
    }
  } catch (error) {
    showError(ui.formError, error.message);
    return;
  }
  ui.submit.disabled = ui.trySample.disabled = true;
  let shown = false;
  const previous = document.body.dataset.state;
  setState("submitting");
  try {
    for (const file of files) {
      const item = newItem(file.name);
      const problem = fileProblem(file);
      if (problem) {
        refuse(item, problem);
        continue;
      }
      item.inputUrl = URL.createObjectURL(file);
      item.row.status.textContent = "Uploading…";
      updateRow(item, "uploading");
      try {
        const response = await api("/v1/jobs", { method: "POST", body: jobBody(file, request.params) });
        if (!response.ok) {
          refuse(item, `The server refused ${fileLabel(file)}. ${await problemMessage(response)}`);
          continue;
        }
        item.job = await response.json();
      } catch (error) {
        refuse(item, `Could not reach the server: ${error.message}`);
        continue;
      }
      updateRow(item);
      updateAddress();
      if (!shown) {
        shown = true;
        select(item);
      }
      follow(item);
    }
  } finally {
    ui.submit.disabled = ui.trySample.disabled = false;
    if (!shown) setState(session?.job?.status ?? (previous === "submitting" ? "idle" : previous));
  }
}

ui.form.addEventListener("submit", (event) => {
  event.preventDefault();
  submitFiles(Array.from(ui.image.files));
});

ui.trySample.addEventListener("click", async () => {
  showError(ui.formError, "");
  try {
    const response = await fetch("/sample.jpg");
    if (!response.ok) throw new Error(`${response.status} ${response.statusText}`);
    const blob = await response.blob();
    await submitFiles([new File([blob], "sample.jpg", { type: blob.type || "image/jpeg" })]);
  } catch (error) {
    showError(ui.formError, `The sample could not be loaded: ${error.message}`);
  }
});

// A new key may open the limits (and jobs) the server refused without one.
ui.apiKey.addEventListener("change", () => loadLimits());

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

function previewUrl(job, name) {
  return `${jobUrl(job, "previews", "/previews")}/${encodeURIComponent(name)}.png`;
}

function follow(item) {
  // An ended job has nothing to follow (select shows its outcome).
  if (TERMINAL.has(item.job.status)) return;
  const controller = new AbortController();
  item.events = controller;
  // The service sends `progress` events (the job) while it runs, `draft` when it has a new
  // draft, then one `completed`.
  const onEvent = (type, text) => {
    if (type !== "progress" && type !== "draft" && type !== "completed") return;
    let data;
    try {
      data = JSON.parse(text);
    } catch {
      return; // non-JSON notes carry nothing to show
    }
    handleUpdate(item, data);
  };
  const url = jobUrl(item.job, "events", "/events");
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
      if (item.events !== controller || TERMINAL.has(item.job.status)) return;
    }
    if (item.events === controller) {
      item.events = null;
      poll(item);
    }
  })();
}

function stopFollowing(item) {
  item.events?.abort();
  item.events = null;
  clearTimeout(item.pollTimer);
}

async function poll(item) {
  try {
    const response = await api(jobUrl(item.job, "self", ""), { cache: "no-store" });
    if (response.ok) {
      handleUpdate(item, await response.json());
    } else if (response.status === 404 || response.status === 410) {
      const message = `The job is gone. ${await problemMessage(response)}`;
      showError(item.row.error, message);
      if (item === session) {
        showError(ui.jobError, message);
        setState("failed");
      }
      return;
    }
  } catch {
    // The server may be restarting; keep polling.
  }
  if (!TERMINAL.has(item.job.status)) item.pollTimer = setTimeout(() => poll(item), POLL_MS);
}

/**
 * One update of a job (from the event stream, a poll or a cancel reply): show it, add the
 * previews that are new, and on a terminal status end the stream and show the outcome.
 */
function handleUpdate(item, data) {
  const job = item.job;
  if (!job || data?.id !== job.id) return;
  // A job that ended stays ended: a late reply (say, to a cancel request) must not revive it.
  if (TERMINAL.has(job.status)) return;
  Object.assign(job, data);
  updateRow(item);
  if (item === session) {
    showJob(item);
    showPreviews(item, job.previews ?? []);
    showDraft(item);
  }
  if (TERMINAL.has(job.status)) {
    stopFollowing(item);
    finish(item);
  }
}

function formatSeconds(seconds) {
  if (!Number.isFinite(seconds)) return "";
  if (seconds < 60) return `${Math.max(0, Math.round(seconds))} s`;
  const minutes = Math.floor(seconds / 60);
  return `${minutes} min ${Math.round(seconds - minutes * 60)} s`;
}

/** The shown job's stage line, bar and details. */
function showJob(item) {
  const job = item.job;
  setState(job.status || "queued");
  const progress = job.progress || {};
  const stage = progress.stage;
  ui.stageName.textContent = stageText(job);
  ui.stageCount.textContent =
    stage && Number.isInteger(stage.index) && Number.isInteger(stage.count) && !TERMINAL.has(job.status)
      ? `(${stage.index + 1} of ${stage.count})`
      : "";
  const fraction = jobFraction(job);
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

async function cancelJob(item) {
  if (!item?.job) return;
  const buttons = [item.row.cancel, ...(item === session ? [ui.cancel] : [])];
  for (const button of buttons) button.disabled = true;
  const fail = (message) => {
    showError(item.row.error, message);
    if (item === session) showError(ui.jobError, message);
  };
  try {
    const response = await api(jobUrl(item.job, "cancel", "/cancel"), { method: "POST" });
    if (!response.ok) fail(`Could not cancel. ${await problemMessage(response)}`);
    else handleUpdate(item, await response.json().catch(() => null));
  } catch (error) {
    fail(`Could not cancel: ${error.message}`);
  } finally {
    for (const button of buttons) button.disabled = false;
  }
}

ui.cancel.addEventListener("click", () => cancelJob(session));

/** Adds the shown job's stage previews (in the order the stages made them) not on the page yet. */
function showPreviews(item, names) {
  for (const name of names) {
    if (item.shownPreviews.has(name)) continue;
    item.shownPreviews.add(name);
    const entry = document.createElement("li");
    const figure = document.createElement("figure");
    const img = document.createElement("img");
    blobUrl(previewUrl(item.job, name))
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

/**
 * The shown job's draft while it runs: the vector result so far (the service's layered SVG after
 * its latest stage), replaced as stages end; the result takes its place.
 */
function showDraft(item) {
  const draft = item.job.draft;
  if (item !== session || TERMINAL.has(item.job.status) || !draft?.url || draft.stage === item.shownDraft) return;
  item.shownDraft = draft.stage;
  blobUrl(draft.url)
    .then((url) => {
      // A newer draft, another job or the end may have come meanwhile.
      if (item !== session || item.shownDraft !== draft.stage || TERMINAL.has(item.job.status)) {
        URL.revokeObjectURL(url);
        return;
      }
      if (ui.draftImage.src.startsWith("blob:")) URL.revokeObjectURL(ui.draftImage.src);
      ui.draftImage.src = url;
      ui.draftCaption.textContent = `The result so far, after stage ${draft.stage}: it improves as the stages end.`;
      ui.draft.dataset.stage = draft.stage;
      ui.draft.hidden = false;
    })
    // A draft is a courtesy: the progress and the result go on without it, and the next
    // stage's draft is tried again.
    .catch(() => {});
}

function hideDraft() {
  ui.draft.hidden = true;
  delete ui.draft.dataset.stage;
  if (ui.draftImage.src.startsWith("blob:")) URL.revokeObjectURL(ui.draftImage.src);
  ui.draftImage.removeAttribute("src");
  ui.draftCaption.textContent = "";
}

/** A job that ended: its row says so; if it is the one shown, so does the view (and its result). */
async function finish(item) {
  const { job } = item;
  updateRow(item);
  if (job.status === "succeeded") item.row.show.disabled = item === session;
  if (item !== session) return;
  hideDraft();
  setState(job.status);
  showJob(item);
  if (job.status === "failed") {
    showError(ui.jobError, `The job failed. ${describeProblem(job.error, "No reason was given.")}`);
    return;
  }
  if (job.status === "canceled") {
    showError(ui.jobError, "The job was canceled.");
    return;
  }
  await showResult(item);
}

// ---------------------------------------------------------------- resuming from the address

/** The jobs the address names: each gets its row back, and is followed or shown. */
async function resumeFromAddress() {
  const params = new URLSearchParams(location.hash.slice(1));
  const ids = [...new Set(params.getAll("job"))].filter((id) => JOB_ID.test(id));
  if (ids.length === 0) return;
  const wanted = params.get("show");
  const resumed = await Promise.all(
    ids.map(async (id) => {
      const item = newItem(id);
      item.row.status.textContent = "Loading…";
      try {
        const response = await api(`/v1/jobs/${encodeURIComponent(id)}`, { cache: "no-store" });
        if (!response.ok) throw new Error(await problemMessage(response));
        item.job = await response.json();
        item.name = item.job.input_name || id;
      } catch (error) {
        refuse(item, `The job ${id} could not be loaded. ${error.message}`);
      }
      return item;
    }),
  );
  const live = resumed.filter((item) => item.job);
  for (const item of live) updateRow(item);
  const shown = live.find((item) => item.job.id === wanted) ?? live[0];
  if (shown) select(shown);
  for (const item of live) follow(item);
  updateAddress();
}

// Another job pasted into the address of this tab: start over from it.
window.addEventListener("hashchange", () => location.reload());

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

/** The shown job's result: its SVG (fetched once per item), the input beside it. */
async function showResult(item) {
  const { job } = item;
  if (item.versions.length === 0) {
    const svgUrl = jobUrl(job, "svg", "/svg");
    let svgText;
    try {
      svgText = await fetchText(svgUrl);
    } catch (error) {
      if (item === session) showError(ui.jobError, `The job finished but its SVG could not be read. ${error.message}`);
      return;
    }
    if (item.versions.length === 0) {
      item.versions.push({
        id: null,
        svgUrl,
        svgText,
        sceneUrl: jobUrl(job, "scene", "/scene.json"),
        flatUrl: jobUrl(job, "flat_svg", "/svg?flatten=true"),
        pdfUrl: jobUrl(job, "pdf", "/pdf"),
        pngUrl: jobUrl(job, "png", "/png"),
        layerUrls: Object.fromEntries(LAYERS.map((layer) => [layer, jobUrl(job, layer, `/layers/${layer}.svg`)])),
        changed: [],
      });
    }
  }
  // A resumed job's input is its first preview (the image as the pipeline read it).
  if (!item.inputUrl && job.previews?.includes("00-input")) {
    item.inputUrl = await blobUrl(previewUrl(job, "00-input")).catch(() => null);
  }
  if (item !== session) return;
  ui.inputImage.src = item.inputUrl ?? "";
  ui.compareImage.src = item.inputUrl ?? "";
  ui.result.hidden = false;
  await showVersion();
  setState("succeeded");
  // Smooth scrolling only for those who have not asked for reduced motion.
  const reduced = window.matchMedia("(prefers-reduced-motion: reduce)").matches;
  ui.result.scrollIntoView({ behavior: reduced ? "auto" : "smooth", block: "start" });
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
  // Path data is in the layer group's grid units; its transform brings them to the viewBox.
  ui.pickOutline.setAttribute("transform", path?.parentNode.getAttribute("transform") || "");
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

/**
 * Posts an edit on top of the version shown (`body` is JSON changes or a reference form) and
 * shows its result as the newest version.
 */
async function applyEdit(makeBody) {
  if (!session?.job || session.busy || session.versions.length === 0) return;
  const current = session;
  const base = current.versions.at(-1);
  let request;
  try {
    request = makeBody(current, base.id);
  } catch (error) {
    showError(ui.editError, error.message);
    return;
  }
  current.busy = true;
  ui.applyColour.disabled = ui.applyReference.disabled = true;
  showError(ui.editError, "");
  ui.editStatus.textContent = "Recolouring…";
  try {
    const response = await api(jobUrl(current.job, "edits", "/edits"), { method: "POST", ...request });
    if (!response.ok) throw new Error(await problemMessage(response));
    const edit = await response.json();
    const editPath = `/edits/${encodeURIComponent(edit.id)}`;
    const svgUrl = edit.urls?.svg || jobPath(current.job, `${editPath}/svg`);
    const svgText = await fetchText(svgUrl);
    current.versions.push({
      id: edit.id,
      svgUrl,
      svgText,
      sceneUrl: edit.urls?.scene || jobPath(current.job, `${editPath}/scene.json`),
      flatUrl: edit.urls?.flat_svg || jobPath(current.job, `${editPath}/svg?flatten=true`),
      pdfUrl: edit.urls?.pdf || jobPath(current.job, `${editPath}/pdf`),
      pngUrl: edit.urls?.png || jobPath(current.job, `${editPath}/png`),
      layerUrls: edit.urls?.layers || null,
      changed: edit.changed || [],
    });
    current.pickedPoint = null;
    if (current !== session) return;
    const changed = current.versions.at(-1).changed;
    if (changed.length === 1) ui.pathSelect.value = changed[0].path;
    await showVersion();
    ui.editStatus.textContent = changed.length
      ? `Recoloured ${changed.map((c) => `${c.path} ${c.old_color} → ${c.new_color}`).join(", ")}.`
      : "Nothing changed.";
  } catch (error) {
    if (current === session) {
      showError(ui.editError, `The colour could not be applied. ${error.message}`);
      ui.editStatus.textContent = "";
    }
  } finally {
    current.busy = false;
    ui.applyColour.disabled = ui.applyReference.disabled = false;
  }
}

ui.applyColour.addEventListener("click", () =>
  applyEdit((current, base) => {
    const color = ui.color.value.toLowerCase();
    const change = current.pickedPoint ? { at: current.pickedPoint, color } : { path: ui.pathSelect.value, color };
    if (!change.at && !change.path) throw new Error("Pick a region first: click the vector image or choose one from the list.");
    const body = { changes: [change] };
    if (base) body.base = base;
    return { headers: { "content-type": "application/json" }, body: JSON.stringify(body) };
  }),
);

ui.applyReference.addEventListener("click", () =>
  applyEdit((current, base) => {
    const reference = ui.reference.files[0];
    if (!reference) throw new Error("Choose the edited copy of the photo first.");
    const problem = fileProblem(reference);
    if (problem) throw new Error(problem);
    const body = new FormData();
    body.append("reference", reference, reference.name);
    body.append("k", String(integerField(ui.referenceK, "Surfaces to recolour", 1)));
    if (base) body.append("base", base);
    return { body };
  }),
);

ui.undo.addEventListener("click", async () => {
  if (!session || session.versions.length < 2 || session.busy) return;
  const undone = session.versions.pop();
  await showVersion();
  ui.editStatus.textContent = `Undid ${undone.changed.map((c) => c.path).join(", ") || "the last edit"}.`;
  if (ui.undo.disabled) ui.applyColour.focus();
});

// ---------------------------------------------------------------- downloads

/** What downloads are named after, as the server names them: the input's stem, else the job id. */
function downloadStem(item) {
  const name = item.job.input_name;
  if (!name) return item.job.id;
  const dot = name.lastIndexOf(".");
  return dot > 0 ? name.slice(0, dot) : name;
}

/** The PNG's width from its field: null for the original width, or an Error saying what to fix. */
function pngWidth() {
  const text = ui.pngWidth.value.trim();
  if (text === "") return null;
  const width = integerField(ui.pngWidth, "The PNG width", 1);
  const svg = svgRoot();
  const aspect = svg ? Number(svg.getAttribute("height")) / Number(svg.getAttribute("width")) : NaN;
  if (limits && Number.isFinite(aspect) && aspect > 0) {
    const pixels = width * Math.max(1, Math.round(width * aspect));
    const widest = Math.floor(Math.sqrt(limits.max_pixels / aspect));
    if (pixels > limits.max_pixels) {
      throw new Error(`A PNG ${width} px wide has ${pixels} pixels; this server draws at most ${limits.max_pixels} (up to ${widest} px wide for this image).`);
    }
  }
  return width;
}

/** Points the PNG link at the width asked for, or says why it cannot be drawn. */
function updatePngLink() {
  const link = ui.downloads.querySelector("a[data-kind=png]");
  if (!link || !session?.job) return;
  try {
    const width = pngWidth();
    showError(ui.pngError, "");
    const url = session.versions.at(-1).pngUrl;
    link.href = width ? `${url}${url.includes("?") ? "&" : "?"}width=${width}` : url;
    link.removeAttribute("aria-disabled");
  } catch (error) {
    showError(ui.pngError, error.message);
    link.removeAttribute("href");
    link.setAttribute("aria-disabled", "true");
  }
}

ui.pngWidth.addEventListener("input", updatePngLink);

function fillDownloads() {
  const version = session.versions.at(-1);
  const original = session.versions[0];
  const stem = downloadStem(session);
  const versionStem = version.id ? `${stem}-${version.id}` : stem;
  const links = [
    ["svg", version.svgUrl, `${versionStem}.svg`, version.id ? "Layered SVG (with your colours)" : "Layered SVG"],
    ["scene", version.sceneUrl, `${versionStem}.json`, "Scene JSON"],
  ];
  // The picture shown (with its recolouring) for programs without the SVG's blend modes, and
  // at a fixed size.
  const yours = version.id ? " (with your colours)" : "";
  links.push(
    ["flat", version.flatUrl, `${versionStem}-flat.svg`, `Flattened SVG${yours}`],
    ["pdf", version.pdfUrl, `${versionStem}.pdf`, `PDF${yours}`],
    ["png", version.pngUrl, `${versionStem}.png`, `PNG${yours}`],
  );
  // The job's layer files stay current for each layer no edit since the original changed (a
  // reference edit may recolour an object's own shade and light paths with its albedo).
  const layerUrls = version.layerUrls || original.layerUrls;
  const layerStem = version.layerUrls ? versionStem : stem;
  const edited = (name) =>
    session.versions.slice(1).some((v) => v.changed.some((c) => c.path.startsWith(`${name}-`)));
  for (const name of LAYERS) {
    const stale = !version.layerUrls && edited(name);
    const label = `${name[0].toUpperCase()}${name.slice(1)} layer SVG${stale ? " (before recolouring)" : ""}`;
    links.push([name, layerUrls[name], `${layerStem}-${name}.svg`, label]);
  }
  ui.downloads.replaceChildren(
    ...links.map(([kind, href, filename, label]) => {
      const item = document.createElement("li");
      const link = document.createElement("a");
      link.href = href;
      link.download = filename;
      link.dataset.kind = kind;
      link.textContent = label;
      link.addEventListener("click", (event) => download(event, link));
      item.append(link);
      return item;
    }),
  );
  const svg = svgRoot();
  ui.pngWidth.placeholder = svg?.getAttribute("width") ?? "";
  if (limits) ui.pngWidth.max = String(limits.max_pixels);
  updatePngLink();
}

/**
 * With a key, a plain link would be refused (it sends no header): fetch the file with the key
 * and save it through a blob: URL instead.
 */
async function download(event, link) {
  if (!link.hasAttribute("href")) {
    event.preventDefault();
    return;
  }
  if (!ui.apiKey.value.trim()) return;
  event.preventDefault();
  try {
    const url = await blobUrl(link.getAttribute("href"));
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
loadLimits();
resumeFromAddress();
