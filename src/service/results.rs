//! A job's results: the layered or flattened SVG, the per-layer SVGs, the JSON scene, a PNG of
//! any width, the PDF and the stage previews.
//!
//! Previews are served while the job runs; the other results once it has succeeded.

use axum::extract::rejection::QueryRejection;
use axum::extract::{Path, Query, State};
use axum::http::{HeaderMap, Method};
use axum::response::{IntoResponse, Response};
use axum::{Extension, Json};

use super::auth::Owner;
use utoipa::openapi::schema::{KnownFormat, SchemaFormat};
use utoipa::openapi::{ObjectBuilder, RefOr, Schema, Type};

use super::download::{Download, etag_of, filename};
use super::error::{ApiError, JobProblems, ResultProblems};
use super::jobs::find;
use super::model::{JobId, JobRecord, Problem, Status};
use super::queue::Queue;
use super::{AppState, Endpoint, endpoint};
use crate::output::{self, FileKind, RasterError};
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
    let (name, bytes) = tokio::task::spawn_blocking(move || {
        queue.read_result(&job, &name).map(|bytes| (name, bytes))
    })
    .await
    .map_err(|error| ApiError::Internal(error.to_string()))??;
    let bytes = bytes.ok_or(ApiError::ResultNotFound(name))?;
    let download = Download::of(record, etag_of(&[&bytes]), file.filename, file.media_type);
    Ok(download.respond(request, || bytes))
}

/// The query of `GET /v1/jobs/{id}/svg`.
#[derive(serde::Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
struct SvgQuery {
    /// `true`: the same picture as plain opaque paths in painter's order (no blend modes,
    /// opacities, filters or images), for programs without `multiply` or `plus-lighter`; made
    /// on request from the stored scene. Anything but `true`/`false`: 400 `bad-query`.
    #[serde(default)]
    #[param(default = false)]
    flatten: bool,
}

#[utoipa::path(get, path = "/v1/jobs/{id}/svg", tag = "results", operation_id = "getSvg",
    summary = "The layered SVG, or with `flatten=true` the flattened one",
    params(("id" = JobId, Path), SvgQuery),
    responses(
        (status = 200, description = "The SVG (layered - albedo, shade with \
            `mix-blend-mode:multiply`, light with `plus-lighter` - or flattened).",
            body = Binary, content_type = "image/svg+xml"),
        ResultProblems,
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
    if query.flatten {
        derived(&state, &headers, &record, Derived::Flat(FileKind::FlatSvg)).await
    } else {
        let file = SceneFiles::of_job(&record).stored(FileKind::LayeredSvg);
        artefact(&state, &headers, &record, file).await
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
        opaque regions as filled paths (no blend modes needed). Made on request from the stored \
        scene.",
    params(("id" = JobId, Path)),
    responses(
        (status = 200, description = "The PDF.", body = Binary, content_type = "application/pdf"),
        ResultProblems,
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
    derived(&state, &headers, &record, Derived::Flat(FileKind::Pdf)).await
}

/// A file made from the stored scene on request.
#[derive(Clone, Copy)]
enum Derived {
    /// The flattened SVG or the PDF.
    Flat(FileKind),
    /// A PNG this wide (default: the original width).
    Png(Option<u32>),
}

impl Derived {
    /// What the file's bytes depend on besides the scene: its kind, its width, and the covec
    /// version that draws it.
    fn key(self) -> String {
        let kind = match self {
            Derived::Flat(kind) => kind.name(),
            Derived::Png(width) => format!("png:{width:?}"),
        };
        format!("{kind}/{}", env!("CARGO_PKG_VERSION"))
    }
}

/// A file made from the stored scene on request, off the async workers and one at a time with
/// the other renders (a flattening's boolean operations, or a large PNG, take a CPU for a
/// while). Its validator comes from the scene's bytes, so a client holding the file gets a 304
/// before anything is drawn.
async fn derived(
    state: &AppState,
    request: &HeaderMap,
    record: &JobRecord,
    file: Derived,
) -> Result<Response, ApiError> {
    let queue = state.queue.clone();
    let id = record.id.clone();
    let scene = tokio::task::spawn_blocking(move || {
        let name = FileKind::SceneJson.name();
        queue
            .read_result(&id, &name)?
            .ok_or(ApiError::ResultNotFound(name))
    })
    .await
    .map_err(|error| ApiError::Internal(error.to_string()))??;
    let (media_type, suffix) = match file {
        Derived::Flat(kind) => (kind.media_type(), kind.download_suffix()),
        Derived::Png(_) => ("image/png", ".png".to_owned()),
    };
    let etag = etag_of(&[&scene, file.key().as_bytes()]);
    let download = Download::of(record, etag, filename(record, &suffix), media_type);
    if download.is_cached_by(request) {
        return Ok(download.respond(request, Vec::new));
    }
    let _slot = state
        .png_renders
        .acquire()
        .await
        .map_err(|error| ApiError::Internal(error.to_string()))?;
    let max_pixels = state.limits.max_pixels;
    let bytes = tokio::task::spawn_blocking(move || {
        let scene: Scene = serde_json::from_slice(&scene)
            .map_err(|e| ApiError::Internal(format!("stored scene: {e}")))?;
        match file {
            Derived::Flat(kind) => Ok(output::artefacts(&scene, &[kind])
                .pop()
                .expect("one file asked for")
                .bytes),
            Derived::Png(width) => {
                output::png(&scene, width, max_pixels).map_err(|error| match error {
                    RasterError::ZeroWidth => ApiError::InvalidParams(error.to_string()),
                    RasterError::TooManyPixels { actual, limit, .. } => {
                        ApiError::TooManyPixels { limit, actual }
                    }
                    RasterError::EmptyCanvas => {
                        ApiError::Internal(format!("stored scene: {error}"))
                    }
                })
            }
        }
    })
    .await
    .map_err(|error| ApiError::Internal(error.to_string()))??;
    Ok(download.respond(request, || bytes))
}

#[utoipa::path(get, path = "/v1/jobs/{id}/layers/{file}", tag = "results",
    operation_id = "getLayerSvg", summary = "One layer as a standalone SVG",
    params(("id" = JobId, Path), ("file" = inline(LayerFile), Path)),
    responses(
        (status = 200, description = "The layer's SVG.", body = Binary, content_type = "image/svg+xml"),
        ResultProblems,
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
        ResultProblems,
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

/// PNG renders at once: one at the pixel limit holds four f32 RGB images (12 bytes a pixel
/// each, 768 MB at the default 16 Mpx), so concurrent requests wait rather than add up.
pub(super) const PNG_RENDERS: usize = 1;

/// The query of `GET /v1/jobs/{id}/png`; `width` is read as text so that a bad value is a 422
/// problem naming it.
#[derive(serde::Deserialize)]
struct PngQuery {
    width: Option<String>,
}

#[utoipa::path(get, path = "/v1/jobs/{id}/png", tag = "results", operation_id = "getPng",
    summary = "The result as a PNG of any width, drawn by covec's own renderer",
    description = "The picture covec optimised (albedo × shade + light), rendered on request \
        with the geometry scaled to `width`; no viewer's blend modes involved. Equal to \
        `covec render scene.json --width N` byte for byte. One render runs at a time.",
    params(("id" = JobId, Path), ("width" = Option<u64>, Query, minimum = 1, maximum = 4294967295.0,
        description = "Width in pixels (default: the original image's width); the height keeps \
            the aspect ratio. 0, negative or non-numeric: 422 `invalid-params`; width × height \
            over `--max-pixels`: 413 `too-many-pixels`.")),
    responses(
        (status = 200, description = "The PNG.", body = Binary, content_type = "image/png"),
        ResultProblems,
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
    let width = query.width.as_deref().map(parse_width).transpose()?;
    let record = succeeded(&state, &owner, &id).await?;
    derived(&state, &headers, &record, Derived::Png(width)).await
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
    let entry = find(&state, &owner, &id).await?;
    let record = entry.snapshot();
    if record.data_removed {
        return Err(ApiError::DataRemoved(id));
    }
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
    ),
)]
async fn preview(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path((id, file)): Path<(String, String)>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let entry = find(&state, &owner, &id).await?;
    let record = entry.snapshot();
    if record.data_removed {
        return Err(ApiError::DataRemoved(id));
    }
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
