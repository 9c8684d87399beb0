//! A job's results: the layered or flattened SVG, the per-layer SVGs, the JSON scene, a PNG of
//! any width, the PDF, the stage previews and the draft.
//!
//! Previews and the draft are served while the job runs; the other results once it has
//! succeeded.

use axum::extract::rejection::QueryRejection;
use axum::extract::{Path, Query, State};
use axum::http::{HeaderMap, Method};
use axum::response::{IntoResponse, Response};
use axum::{Extension, Json};

use super::auth::Owner;
use utoipa::openapi::schema::{KnownFormat, SchemaFormat};
use utoipa::openapi::{ObjectBuilder, RefOr, Schema, Type};

use super::derived::{self, Derived};
use super::download::{Download, etag_of, filename};
use super::error::{ApiError, FileProblems, JobProblems, off_async};
use super::jobs::find;
use super::model::{DRAFT_FILE, JobId, JobRecord, Problem, Status};
use super::queue::Queue;
use super::state::{AppState, Endpoint, endpoint};
use crate::output::FileKind;
use crate::scene::{LayerKind, Scene};

pub fn endpoints() -> Vec<Endpoint> {
    vec![
        endpoint(Method::GET, "/v1/jobs/{id}/svg", svg),
        endpoint(Method::GET, "/v1/jobs/{id}/layers/{file}", layer),
        endpoint(Method::GET, "/v1/jobs/{id}/scene.json", scene),
        endpoint(Method::GET, "/v1/jobs/{id}/png", png),
        endpoint(Method::GET, "/v1/jobs/{id}/pdf", pdf),
        endpoint(Method::GET, "/v1/jobs/{id}/previews", previews),
        endpoint(Method::GET, "/v1/jobs/{id}/previews/{file}", preview),
        endpoint(Method::GET, "/v1/jobs/{id}/draft.svg", draft),
    ]
}

/// `GET /v1/jobs/{id}/previews`.
#[derive(serde::Serialize, utoipa::ToSchema)]
struct PreviewList {
    items: Vec<PreviewLink>,
}

#[derive(serde::Serialize, utoipa::ToSchema)]
struct PreviewLink {
    name: String,
    url: String,
}

/// The `{file}` of `GET /v1/jobs/{id}/layers/{file}` in the API document: one per layer.
struct LayerFile;

impl utoipa::PartialSchema for LayerFile {
    fn schema() -> RefOr<Schema> {
        ObjectBuilder::new()
            .schema_type(Type::String)
            .enum_values(Some(
                LayerKind::ALL.map(|kind| format!("{}.svg", kind.name())),
            ))
            .into()
    }
}

impl utoipa::ToSchema for LayerFile {}

/// A scene (`scene.json`) in the API document.
pub(super) struct SceneJson;

impl utoipa::PartialSchema for SceneJson {
    fn schema() -> RefOr<Schema> {
        ObjectBuilder::new()
            .schema_type(Type::Object)
            .description(Some("covec's scene model (see `src/scene.rs`)."))
            .into()
    }
}

impl utoipa::ToSchema for SceneJson {
    fn name() -> std::borrow::Cow<'static, str> {
        "Scene".into()
    }
}

/// A file body (SVG, PNG, PDF) in the API document: a string of bytes, so that client
/// generators give a file download.
pub(super) struct Binary;

impl utoipa::PartialSchema for Binary {
    fn schema() -> RefOr<Schema> {
        ObjectBuilder::new()
            .schema_type(Type::String)
            .format(Some(SchemaFormat::KnownFormat(KnownFormat::Binary)))
            .into()
    }
}

impl utoipa::ToSchema for Binary {}

pub(super) fn require_success(record: &JobRecord) -> Result<(), ApiError> {
    if record.data_removed {
        return Err(ApiError::DataRemoved(record.id.clone()));
    }
    if record.status != Status::Succeeded {
        return Err(ApiError::NotReady(record.id.clone(), record.status.name()));
    }
    Ok(())
}

/// A stored file to serve: its name in the job's folder, its media type, and the name it is
/// offered for download under.
pub(super) struct Stored {
    pub name: String,
    pub media_type: &'static str,
    pub filename: String,
}

/// Whose scene files are meant: a job's own (`prefix` empty) or an edit's (`edits/<id>/`), and
/// the stem their downloads are named with.
pub(super) struct SceneFiles {
    pub prefix: String,
    pub stem: String,
}

impl SceneFiles {
    /// The job's own result files.
    pub fn of_job(record: &JobRecord) -> Self {
        Self {
            prefix: String::new(),
            stem: record.download_stem(),
        }
    }

    pub fn stored(&self, kind: FileKind) -> Stored {
        Stored {
            name: format!("{}{}", self.prefix, kind.name()),
            media_type: kind.media_type(),
            filename: format!("{}{}", self.stem, kind.download_suffix()),
        }
    }
}

/// Reads a stored file of `record`'s job off the async workers (checked against its recorded
/// digest) and serves it with its validator, caching and download name ([`Download`]).
pub(super) async fn artefact(
    state: &AppState,
    request: &HeaderMap,
    record: &JobRecord,
    file: Stored,
) -> Result<Response, ApiError> {
    let queue = state.queue.clone();
    let (job, name) = (record.id.clone(), file.name);
    let (name, bytes) =
        off_async(move || queue.read_result(&job, &name).map(|bytes| (name, bytes))).await?;
    let bytes = bytes.ok_or(ApiError::ResultNotFound(name))?;
    let download = Download::of(record, etag_of(&[&bytes]), file.filename, file.media_type);
    Ok(download.respond(request, || bytes))
}

/// The query of `GET /v1/jobs/{id}/svg`.
#[derive(serde::Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub(super) struct SvgQuery {
    /// `true`: the same picture as plain opaque paths in painter's order (no blend modes,
    /// opacities, filters or images), for programs without `multiply` or `plus-lighter`; drawn
    /// from the stored scene on the first request, then stored. Anything but `true`/`false`:
    /// 400 `bad-query`.
    #[serde(default)]
    #[param(default = false)]
    pub flatten: bool,
}

#[utoipa::path(get, path = "/v1/jobs/{id}/svg", tag = "results", operation_id = "getSvg",
    summary = "The layered SVG, or with `flatten=true` the flattened one",
    params(("id" = JobId, Path), SvgQuery),
    responses(
        (status = 200, description = "The SVG (layered - albedo, shade with \
            `mix-blend-mode:multiply`, light with `plus-lighter` - or flattened).",
            body = Binary, content_type = "image/svg+xml"),
        FileProblems,
    ),
)]
async fn svg(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path(id): Path<String>,
    headers: HeaderMap,
    query: Result<Query<SvgQuery>, QueryRejection>,
) -> Result<Response, ApiError> {
    let Query(query) = query.map_err(|rejection| ApiError::BadQuery(rejection.body_text()))?;
    let record = succeeded(&state, &owner, &id).await?;
    let files = SceneFiles::of_job(&record);
    if query.flatten {
        derived_file(
            &state,
            &headers,
            &record,
            &files,
            Derived::Flat(FileKind::FlatSvg),
        )
        .await
    } else {
        artefact(
            &state,
            &headers,
            &record,
            files.stored(FileKind::LayeredSvg),
        )
        .await
    }
}

/// The record of `id` once its job has succeeded (and its results are still there).
async fn succeeded(state: &AppState, owner: &Owner, id: &str) -> Result<JobRecord, ApiError> {
    let record = find(state, owner, id).await?.snapshot();
    require_success(&record)?;
    Ok(record)
}

#[utoipa::path(get, path = "/v1/jobs/{id}/pdf", tag = "results", operation_id = "getPdf",
    summary = "The result as a vector PDF of the flattened picture",
    description = "One page the original image's size (96 px per inch), the flattened SVG's \
        opaque regions as filled paths (no blend modes needed). Drawn from the stored scene on \
        the first request, then stored and served as a file.",
    params(("id" = JobId, Path)),
    responses(
        (status = 200, description = "The PDF.", body = Binary, content_type = "application/pdf"),
        FileProblems,
        (status = 500, response = Problem),
    ),
)]
async fn pdf(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path(id): Path<String>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let record = succeeded(&state, &owner, &id).await?;
    let files = SceneFiles::of_job(&record);
    derived_file(
        &state,
        &headers,
        &record,
        &files,
        Derived::Flat(FileKind::Pdf),
    )
    .await
}

/// A file derived from a stored scene (a job's or an edit's, `files`): served from storage once
/// drawn ([`derived`]), else drawn off the async workers, on the render pool and one at a time
/// with the other renders, and stored. Its validator comes from the scene's bytes and the
/// file's key, so a client holding the file gets a 304 before anything is read or drawn.
pub(super) async fn derived_file(
    state: &AppState,
    request: &HeaderMap,
    record: &JobRecord,
    files: &SceneFiles,
    file: Derived,
) -> Result<Response, ApiError> {
    let (queue, id, prefix) = (state.queue.clone(), record.id.clone(), files.prefix.clone());
    let scene = blocking(move || {
        derived::scene_bytes(&queue, &id, &prefix)?
            .ok_or_else(|| ApiError::ResultNotFound(format!("{prefix}scene.json")))
    })
    .await?;
    let etag = etag_of(&[&scene, file.key().as_bytes()]);
    let filename = format!("{}{}", files.stem, file.download_suffix());
    let download = Download::of(record, etag, filename, file.media_type());
    if download.is_cached_by(request) {
        return Ok(download.respond(request, Vec::new));
    }
    if let Some(bytes) = stored_copy(state, record, files, file).await? {
        return Ok(download.respond(request, || bytes));
    }
    let _turn = state
        .renders
        .acquire()
        .await
        .map_err(|error| ApiError::Internal(error.to_string()))?;
    // Drawn and stored by another request while this one waited for its turn?
    if let Some(bytes) = stored_copy(state, record, files, file).await? {
        return Ok(download.respond(request, || bytes));
    }
    let (queue, id, prefix) = (state.queue.clone(), record.id.clone(), files.prefix.clone());
    let (pool, max_pixels) = (state.render_pool.clone(), state.limits.max_pixels);
    let bytes = blocking(move || {
        Ok(pool.install(|| derived::render(&queue, &id, &prefix, &scene, file, max_pixels))?)
    })
    .await?;
    Ok(download.respond(request, || bytes))
}

/// The stored copy of `file` derived from `files`' scene, if a whole one is there.
async fn stored_copy(
    state: &AppState,
    record: &JobRecord,
    files: &SceneFiles,
    file: Derived,
) -> Result<Option<Vec<u8>>, ApiError> {
    let (queue, id, prefix) = (state.queue.clone(), record.id.clone(), files.prefix.clone());
    blocking(move || Ok(derived::stored(&queue, &id, &prefix, file)?)).await
}

/// Runs blocking `work` off the async workers.
async fn blocking<T: Send + 'static>(
    work: impl FnOnce() -> Result<T, ApiError> + Send + 'static,
) -> Result<T, ApiError> {
    off_async(work).await
}

#[utoipa::path(get, path = "/v1/jobs/{id}/layers/{file}", tag = "results",
    operation_id = "getLayerSvg", summary = "One layer as a standalone SVG",
    params(("id" = JobId, Path), ("file" = inline(LayerFile), Path)),
    responses(
        (status = 200, description = "The layer's SVG.", body = Binary, content_type = "image/svg+xml"),
        FileProblems,
    ),
)]
async fn layer(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path((id, file)): Path<(String, String)>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let entry = find(&state, &owner, &id).await?;
    let Some(kind) = LayerKind::ALL
        .into_iter()
        .find(|kind| file.strip_suffix(".svg") == Some(kind.name()))
    else {
        return Err(ApiError::ResultNotFound(format!(
            "layers/{file} (layers are albedo.svg, shade.svg, light.svg)"
        )));
    };
    let record = entry.snapshot();
    require_success(&record)?;
    let file = SceneFiles::of_job(&record).stored(FileKind::Layer(kind));
    artefact(&state, &headers, &record, file).await
}

#[utoipa::path(get, path = "/v1/jobs/{id}/scene.json", tag = "results", operation_id = "getScene",
    summary = "The scene as JSON (layers → paths → points, colour, opacity), loadable losslessly",
    params(("id" = JobId, Path)),
    responses(
        (status = 200, description = "The scene.", body = SceneJson),
        FileProblems,
    ),
)]
async fn scene(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path(id): Path<String>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let record = succeeded(&state, &owner, &id).await?;
    let file = SceneFiles::of_job(&record).stored(FileKind::SceneJson);
    artefact(&state, &headers, &record, file).await
}

/// The query of `GET /v1/jobs/{id}/png`; `width` is read as text so that a bad value is a 422
/// problem naming it.
#[derive(serde::Deserialize)]
pub(super) struct PngQuery {
    width: Option<String>,
}

impl PngQuery {
    /// The width asked for, if any.
    pub fn width(&self) -> Result<Option<u32>, ApiError> {
        self.width.as_deref().map(parse_width).transpose()
    }
}

#[utoipa::path(get, path = "/v1/jobs/{id}/png", tag = "results", operation_id = "getPng",
    summary = "The result as a PNG of any width, drawn by covec's own renderer",
    description = "The picture covec optimised (albedo × shade + light), drawn with the \
        geometry scaled to `width`; no viewer's blend modes involved. Equal to \
        `covec render scene.json --width N` byte for byte. Drawn on the first request for a \
        width (one render at a time per server), then stored and served as a file.",
    params(("id" = JobId, Path), ("width" = Option<u64>, Query, minimum = 1, maximum = 4294967295.0,
        description = "Width in pixels (default: the original image's width); the height keeps \
            the aspect ratio. 0, negative or non-numeric: 422 `invalid-params`; width × height \
            over `--max-pixels`: 413 `too-many-pixels`.")),
    responses(
        (status = 200, description = "The PNG.", body = Binary, content_type = "image/png"),
        FileProblems,
        (status = 413, response = Problem),
        (status = 422, response = Problem),
        (status = 500, response = Problem),
    ),
)]
async fn png(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path(id): Path<String>,
    headers: HeaderMap,
    query: Result<Query<PngQuery>, QueryRejection>,
) -> Result<Response, ApiError> {
    let Query(query) = query.map_err(|rejection| ApiError::BadQuery(rejection.body_text()))?;
    let width = query.width()?;
    let record = succeeded(&state, &owner, &id).await?;
    let files = SceneFiles::of_job(&record);
    derived_file(&state, &headers, &record, &files, Derived::Png(width)).await
}

/// A `width` query value: a whole number of pixels (0 is refused with the raster's own rule).
fn parse_width(text: &str) -> Result<u32, ApiError> {
    text.parse::<u32>().map_err(|_| {
        ApiError::InvalidParams(format!(
            "`width` must be a whole number of pixels, not `{text}`"
        ))
    })
}

/// The stored JSON scene of a job (under `prefix`, e.g. `edits/<id>/`). Blocking: call it off
/// the async workers.
pub(super) fn stored_scene(queue: &Queue, job: &str, prefix: &str) -> Result<Scene, ApiError> {
    let name = format!("{prefix}{}", FileKind::SceneJson.name());
    let bytes = queue
        .read_result(job, &name)?
        .ok_or(ApiError::ResultNotFound(name))?;
    serde_json::from_slice(&bytes).map_err(|e| ApiError::Internal(format!("stored scene: {e}")))
}

/// The record of a job whose files are served while it runs (previews, the draft), unless they
/// were removed.
async fn files_of(state: &AppState, owner: &Owner, id: &str) -> Result<JobRecord, ApiError> {
    let record = find(state, owner, id).await?.snapshot();
    if record.data_removed {
        return Err(ApiError::DataRemoved(id.to_owned()));
    }
    Ok(record)
}

#[utoipa::path(get, path = "/v1/jobs/{id}/previews", tag = "results", operation_id = "listPreviews",
    summary = "The stage previews so far (each appears as soon as its stage ends)",
    params(("id" = JobId, Path)),
    responses(
        (status = 200, description = "The previews, in stage order.", body = PreviewList),
        JobProblems,
    ),
)]
async fn previews(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let record = files_of(&state, &owner, &id).await?;
    let items = record
        .previews
        .iter()
        .map(|name| PreviewLink {
            url: format!("/v1/jobs/{id}/previews/{name}.png"),
            name: name.clone(),
        })
        .collect();
    Ok(Json(PreviewList { items }).into_response())
}

#[utoipa::path(get, path = "/v1/jobs/{id}/previews/{file}", tag = "results", operation_id = "getPreview",
    summary = "One stage preview",
    params(("id" = JobId, Path), ("file" = String, Path, pattern = r"^[A-Za-z0-9_-]+\.png$",
        example = "00-input.png", description = "`<name>.png` for a name listed by `/previews`.")),
    responses(
        (status = 200, description = "The preview image.", body = Binary, content_type = "image/png"),
        JobProblems,
        (status = 403, response = Problem),
    ),
)]
async fn preview(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path((id, file)): Path<(String, String)>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let record = files_of(&state, &owner, &id).await?;
    // Only names the pipeline reported, which also keeps paths inside the job directory.
    let known = file
        .strip_suffix(".png")
        .is_some_and(|name| record.previews.iter().any(|p| p == name));
    if !known {
        return Err(ApiError::ResultNotFound(format!("previews/{file}")));
    }
    let stored = Stored {
        name: format!("previews/{file}"),
        media_type: "image/png",
        filename: filename(&record, &format!("-{file}")),
    };
    artefact(&state, &headers, &record, stored).await
}

#[utoipa::path(get, path = "/v1/jobs/{id}/draft.svg", tag = "results", operation_id = "getDraft",
    summary = "The job's result so far: a complete layered SVG, improving as stages end",
    description = "Made as soon as the initialisation ends (well before the job does) and \
        replaced as the structure, reconstruction and refinement stages end (the split's picture \
        is the refinement's draft, and the polish's is the result); the job's `draft` names the \
        stage, and the \
        event stream sends `event: draft` when a new one is stored. After the job ends the last \
        draft stays until the results go. 404 `result-not-found` before the first draft.",
    params(("id" = JobId, Path)),
    responses(
        (status = 200, description = "The draft: a layered SVG like the result's.", body = Binary,
            content_type = "image/svg+xml"),
        JobProblems,
        (status = 403, response = Problem),
    ),
)]
async fn draft(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path(id): Path<String>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let record = files_of(&state, &owner, &id).await?;
    if record.draft.is_none() {
        return Err(ApiError::ResultNotFound(DRAFT_FILE.to_owned()));
    }
    let stored = Stored {
        name: DRAFT_FILE.to_owned(),
        media_type: "image/svg+xml",
        filename: filename(&record, "-draft.svg"),
    };
    artefact(&state, &headers, &record, stored).await
}
