//! Edits of a finished job: recolour albedo paths while the shade and light layers keep the
//! lighting. An edit is cheap (no optimisation), so it runs within the request, on
//! the blocking pool, and is stored under the job: `edits/<edit id>/{edit.json, scene.json,
//! result.svg, preview.png}`, with its flattened SVG, PDF and PNGs drawn on first request
//! ([`super::derived`]). An edit may build on an earlier edit (`base`), which gives clients
//! an undo history for free.

mod bodies;

use std::collections::BTreeMap;

use super::auth::Owner;
use super::derived::Derived;
use super::error::{ApiError, FileProblems, ResultProblems, Unavailable, off_async};
use super::inputs::{InputError, InputKind};
use super::jobs::find;
use super::model::{JobId, JobRecord, Problem};
use super::results::{
    Binary, PngQuery, SceneFiles, SceneJson, Stored, SvgQuery, artefact, derived_file,
    require_success, stored_scene,
};
use super::state::{AppState, Endpoint, endpoint};
use super::store::digest;
use super::submit::{UploadQuery, read_body};
use crate::edit::{self, ColorChange, Edit, ReferenceParams, Target};
use crate::imageio;
use crate::output::{self, EDIT_FILES, FileKind};
use crate::scene::PathId;
use crate::svg;
use axum::extract::rejection::QueryRejection;
use axum::extract::{FromRequest, Multipart, Path, Query, Request, State};
use axum::http::{HeaderMap, HeaderValue, Method, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::{Extension, Json};
use bodies::{
    ChangedView, ColorEdit, EditId, EditKind, EditRecord, EditRequest, EditUrls,
    ReferenceEditRequest, check_edit_id, new_edit_id,
};

pub fn endpoints() -> Vec<Endpoint> {
    vec![
        endpoint(Method::POST, "/v1/jobs/{id}/edits", create),
        endpoint(Method::GET, "/v1/jobs/{id}/edits/{edit_id}", get),
        endpoint(Method::GET, "/v1/jobs/{id}/edits/{edit_id}/svg", edit_svg),
        endpoint(
            Method::GET,
            "/v1/jobs/{id}/edits/{edit_id}/scene.json",
            edit_scene,
        ),
        endpoint(
            Method::GET,
            "/v1/jobs/{id}/edits/{edit_id}/preview.png",
            edit_preview,
        ),
        endpoint(Method::GET, "/v1/jobs/{id}/edits/{edit_id}/pdf", edit_pdf),
        endpoint(Method::GET, "/v1/jobs/{id}/edits/{edit_id}/png", edit_png),
    ]
}

#[utoipa::path(post, path = "/v1/jobs/{id}/edits", tag = "edits", operation_id = "createEdit",
    summary = "Recolour albedo paths of a succeeded job, keeping shade and light (runs within the request)",
    description = "JSON: direct colour changes, by path id or by the albedo path under a point \
        (viewBox coordinates). Multipart: recolour by an edited reference image of the job's \
        image size (paper Appendix D): the top `k` albedo paths by area that overlap the edited \
        region and change colour get the reference colour divided by the mean shade under them, \
        and the shade and light paths lying (half or more) inside the recoloured region are refit \
        to the reference. \
        `base` applies the edit on top of an earlier edit of the same job. A JSON body is at most \
        1 MiB (413 `body-too-large`) with at most 4096 changes (413 `too-many-changes`); a \
        reference image over `--max-pixels` is 413 `too-many-pixels`, one cut short 422 \
        `truncated-image` (unless `accept_truncated=true`); a reference edit waits for a decode slot as a submission does (503 \
        `decode-busy`).",
    params(("id" = JobId, Path), UploadQuery),
    request_body(content(
        (ColorEdit = "application/json", example = json!({"changes": [{"at": {"x": 8, "y": 8}, "color": "#2060c0"}]})),
        (ReferenceEditRequest = "multipart/form-data"),
    )),
    responses(
        (status = 201, description = "The edit.", body = EditRecord,
            headers(("Location" = String, description = "The edit's URL."))),
        ResultProblems,
        (status = 413, response = Problem),
        (status = 415, response = Problem),
        (status = 422, response = Problem),
        (status = 503, response = Unavailable),
    ),
)]
async fn create(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path(id): Path<String>,
    request: Request,
) -> Result<Response, ApiError> {
    let entry = find(&state, &owner, &id).await?;
    require_success(&entry.snapshot())?;
    let upload = UploadQuery::of(&request)?;
    let content_type = request
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("")
        .to_owned();
    let media_type = content_type
        .split(';')
        .next()
        .unwrap_or("")
        .trim()
        .to_ascii_lowercase();
    let (base, edit_request) = match media_type.as_str() {
        "application/json" => read_color_edit(request).await?,
        "multipart/form-data" => read_reference_edit(request).await?,
        _ => return Err(ApiError::UnsupportedMediaType(content_type)),
    };
    if let Some(base) = &base {
        check_edit_id(base)?;
    }

    // A reference edit decodes two images: it takes a decode slot as a submission does.
    let slot = match edit_request {
        EditRequest::Reference { .. } => Some(state.decode_slot().await?),
        EditRequest::Colors(_) => None,
    };
    let queue = state.queue.clone();
    let max_pixels = state.limits.max_pixels;
    let job_id = id.clone();
    let record = off_async(move || {
        let _slot = slot;
        let store = queue.store();
        let read = |name: &str| store.read_artefact(&job_id, name).map_err(ApiError::from);
        let prefix = base
            .as_ref()
            .map(|base| format!("edits/{base}/"))
            .unwrap_or_default();
        let scene = stored_scene(&queue, &job_id, &prefix)?;
        let (kind, edit) = match edit_request {
            EditRequest::Colors(changes) => {
                (EditKind::Colors, edit::recolor_paths(&scene, &changes))
            }
            EditRequest::Reference { image, params } => {
                let limits = imageio::Limits {
                    max_pixels,
                    accept_truncated: upload.accept_truncated,
                    ..imageio::Limits::default()
                };
                // The job's input passed the submission's checks (a cut JPEG only if the
                // client accepted it).
                let original = imageio::decode_image(
                    &read(&InputKind::Image.name())?
                        .ok_or_else(|| ApiError::ResultNotFound(InputKind::Image.name()))?,
                    &imageio::Limits {
                        accept_truncated: true,
                        ..limits.clone()
                    },
                )
                .map_err(|e| ApiError::Internal(format!("stored input: {e}")))?;
                let reference = imageio::decode_image(&image, &limits)
                    .map_err(InputError::refused("reference image"))?;
                let edit =
                    edit::recolor_by_reference_images(&scene, &reference, Some(&original), &params);
                (EditKind::Reference, edit)
            }
        };
        let edit = edit.map_err(|e| ApiError::InvalidInput(e.to_string()))?;
        store_edit(&queue, &job_id, base, kind, &edit)
    })
    .await?;

    let mut response = (StatusCode::CREATED, Json(&record)).into_response();
    if let Ok(location) = HeaderValue::from_str(&record.urls.this) {
        response.headers_mut().insert(header::LOCATION, location);
    }
    Ok(response)
}

/// Largest JSON edit body. A change takes about 60 bytes, so this is room for some 16 000,
/// far more than the 1024 paths a scene may have; it bounds what an edit holds in memory.
const MAX_EDIT_JSON_BYTES: u64 = 1 << 20;

/// Most changes in one edit, and so in its stored record (which a client reads whole).
const MAX_EDIT_CHANGES: usize = 4096;

async fn read_color_edit(request: Request) -> Result<(Option<String>, EditRequest), ApiError> {
    let body = read_body(request, MAX_EDIT_JSON_BYTES).await?;
    let body: ColorEdit = serde_json::from_slice(&body)
        .map_err(|error| ApiError::BadRequest(format!("JSON body: {error}")))?;
    if body.changes.is_empty() {
        return Err(ApiError::BadRequest("`changes` is empty".into()));
    }
    if body.changes.len() > MAX_EDIT_CHANGES {
        return Err(ApiError::TooManyChanges {
            limit: MAX_EDIT_CHANGES as u64,
            actual: body.changes.len() as u64,
        });
    }
    let changes = body
        .changes
        .into_iter()
        .map(|change| {
            let color = svg::parse_hex_colour(&change.color).ok_or_else(|| {
                ApiError::InvalidInput(format!(
                    "`{}` is not a colour (expected #rrggbb)",
                    change.color
                ))
            })?;
            let target = match (change.path, change.at) {
                (Some(path), None) => Target::Path(path.parse::<PathId>().map_err(|()| {
                    ApiError::InvalidInput(format!("`{path}` is not a path id (e.g. albedo-3)"))
                })?),
                (None, Some(point)) => Target::AlbedoAt(point),
                _ => {
                    return Err(ApiError::BadRequest(
                        "each change needs exactly one of `path` and `at`".into(),
                    ));
                }
            };
            Ok(ColorChange {
                target,
                color,
                opacity: change.opacity,
            })
        })
        .collect::<Result<_, ApiError>>()?;
    Ok((body.base, EditRequest::Colors(changes)))
}

async fn read_reference_edit(request: Request) -> Result<(Option<String>, EditRequest), ApiError> {
    let mut multipart = Multipart::from_request(request, &())
        .await
        .map_err(|rejection| ApiError::BadRequest(rejection.body_text()))?;
    let (mut reference, mut params, mut k, mut base) = (None, None, None, None);
    while let Some(field) = multipart
        .next_field()
        .await
        .map_err(|e| ApiError::BadRequest(e.body_text()))?
    {
        let name = field.name().unwrap_or("").to_owned();
        let bytes = field
            .bytes()
            .await
            .map_err(|e| ApiError::BadRequest(e.body_text()))?;
        let text = || String::from_utf8_lossy(&bytes).trim().to_owned();
        match name.as_str() {
            "reference" => reference = Some(bytes.clone()),
            "params" => {
                params = Some(
                    serde_json::from_slice::<ReferenceParams>(&bytes).map_err(|e| {
                        ApiError::InvalidParams(format!(
                            "`params` (k, tau, gamma, delta, epsilon): {e}"
                        ))
                    })?,
                )
            }
            "k" => {
                k = Some(text().parse::<usize>().map_err(|_| {
                    ApiError::InvalidParams(format!(
                        "`k` must be a positive integer, not `{}`",
                        text()
                    ))
                })?)
            }
            "base" => base = Some(text()),
            other => {
                return Err(ApiError::BadRequest(format!(
                    "unknown form field `{other}`"
                )));
            }
        }
    }
    let image = reference
        .ok_or_else(|| ApiError::BadRequest("the form field `reference` is required".into()))?;
    let mut params = params.unwrap_or_default();
    if let Some(k) = k {
        params.k = k;
    }
    if params.k == 0 {
        return Err(ApiError::InvalidParams("`k` must be at least 1".into()));
    }
    Ok((base, EditRequest::Reference { image, params }))
}

/// Writes the edit's scene, SVG and preview, then its record last (the record is what makes
/// an edit visible, so a crash never exposes a half-written edit).
fn store_edit(
    queue: &super::queue::Queue,
    job_id: &str,
    base: Option<String>,
    kind: EditKind,
    edit: &Edit,
) -> Result<EditRecord, ApiError> {
    let id = new_edit_id();
    let prefix = format!("/v1/jobs/{job_id}/edits/{id}");
    let record = EditRecord {
        id: id.clone(),
        job_id: job_id.to_owned(),
        base,
        kind,
        changed: edit
            .changed
            .iter()
            .map(|c| ChangedView {
                path: c.path.to_string(),
                old_color: svg::hex_colour(c.old_color),
                new_color: svg::hex_colour(c.new_color),
                old_opacity: c.old_opacity,
                new_opacity: c.new_opacity,
            })
            .collect(),
        created_at: super::model::rfc3339(super::model::now_ms()),
        urls: EditUrls {
            this: prefix.clone(),
            svg: format!("{prefix}/svg"),
            flat_svg: format!("{prefix}/svg?flatten=true"),
            pdf: format!("{prefix}/pdf"),
            png: format!("{prefix}/png"),
            scene: format!("{prefix}/scene.json"),
            preview: format!("{prefix}/preview.png"),
        },
    };
    let store = queue.store();
    let write = |name: &str, bytes: &[u8]| {
        store
            .write_artefact(job_id, name, bytes)
            .map_err(ApiError::from)
    };
    let json = serde_json::to_vec_pretty(&record).expect("a record serialises");
    let files = output::artefacts(&edit.scene, EDIT_FILES);
    // Every file's digest, the record's too, is stored before the record.
    let mut digests: BTreeMap<String, String> = files
        .iter()
        .map(|artefact| (artefact.kind.name(), digest(&artefact.bytes)))
        .collect();
    digests.insert(EDIT_RECORD.to_owned(), digest(&json));
    let folder = format!("edits/{id}");
    for artefact in &files {
        write(
            &format!("{folder}/{}", artefact.kind.name()),
            &artefact.bytes,
        )?;
    }
    store
        .write_folder_digests(job_id, &folder, &digests)
        .map_err(ApiError::from)?;
    write(&edit_record(&id), &json)?;
    Ok(record)
}

/// Checks access to the job and the edit id (the edit exists once its record does); the job's
/// record.
async fn check_edit(
    state: &AppState,
    owner: &Owner,
    id: &str,
    edit_id: &str,
) -> Result<JobRecord, ApiError> {
    let record = find(state, owner, id).await?.snapshot();
    require_success(&record)?;
    check_edit_id(edit_id)?;
    Ok(record)
}

/// Which edit a request names: the job and edit ids of its path.
type EditPath = Path<(String, String)>;

/// The job's record and an edit's scene files, once the edit exists, named after the job's
/// input and the edit (`hopper-edit_….svg`).
async fn edit_files(
    state: &AppState,
    owner: &Owner,
    Path((id, edit_id)): EditPath,
) -> Result<(JobRecord, SceneFiles), ApiError> {
    let record = check_edit(state, owner, &id, &edit_id).await?;
    // The record says the edit exists; only its size is looked at, never its changes.
    let queue = state.queue.clone();
    let (job, edit) = (id.clone(), edit_record(&edit_id));
    let exists = off_async(move || queue.store().has_artefact(&job, &edit)).await?;
    if !exists {
        return Err(ApiError::ResultNotFound(edit_record(&edit_id)));
    }
    let files = SceneFiles {
        prefix: format!("edits/{edit_id}/"),
        stem: format!("{}-{edit_id}", record.download_stem()),
    };
    Ok((record, files))
}

/// One of an edit's stored scene files ([`edit_files`]).
async fn edit_file(
    state: &AppState,
    request: &HeaderMap,
    owner: &Owner,
    path: EditPath,
    kind: FileKind,
) -> Result<Response, ApiError> {
    let (record, files) = edit_files(state, owner, path).await?;
    artefact(state, request, &record, files.stored(kind)).await
}

/// A file derived from an edit's scene ([`derived_file`]).
async fn edit_derived(
    state: &AppState,
    request: &HeaderMap,
    owner: &Owner,
    path: EditPath,
    file: Derived,
) -> Result<Response, ApiError> {
    let (record, files) = edit_files(state, owner, path).await?;
    derived_file(state, request, &record, &files, file).await
}

/// Where an edit's record is stored.
fn edit_record(edit_id: &str) -> String {
    format!("edits/{edit_id}/{EDIT_RECORD}")
}

/// The file name of an edit's record.
const EDIT_RECORD: &str = "edit.json";

#[utoipa::path(get, path = "/v1/jobs/{id}/edits/{edit_id}", tag = "edits", operation_id = "getEdit",
    summary = "One edit",
    params(("id" = JobId, Path), ("edit_id" = EditId, Path)),
    responses(
        (status = 200, description = "The edit.", body = EditRecord),
        ResultProblems,
    ),
)]
async fn get(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path((id, edit_id)): EditPath,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let record = check_edit(&state, &owner, &id, &edit_id).await?;
    let stored = Stored {
        name: edit_record(&edit_id),
        media_type: "application/json",
        filename: format!("{}-{edit_id}-edit.json", record.download_stem()),
    };
    artefact(&state, &headers, &record, stored).await
}

#[utoipa::path(get, path = "/v1/jobs/{id}/edits/{edit_id}/svg", tag = "edits", operation_id = "getEditSvg",
    summary = "The edited layered SVG, or with `flatten=true` the flattened one",
    params(("id" = JobId, Path), ("edit_id" = EditId, Path), SvgQuery),
    responses(
        (status = 200, description = "The SVG (layered, or flattened: plain opaque paths).",
            body = Binary, content_type = "image/svg+xml"),
        FileProblems,
    ),
)]
async fn edit_svg(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    path: EditPath,
    headers: HeaderMap,
    query: Result<Query<SvgQuery>, QueryRejection>,
) -> Result<Response, ApiError> {
    let Query(query) = query.map_err(|rejection| ApiError::BadQuery(rejection.body_text()))?;
    if query.flatten {
        let file = Derived::Flat(FileKind::FlatSvg);
        edit_derived(&state, &headers, &owner, path, file).await
    } else {
        edit_file(&state, &headers, &owner, path, FileKind::LayeredSvg).await
    }
}

#[utoipa::path(get, path = "/v1/jobs/{id}/edits/{edit_id}/pdf", tag = "edits", operation_id = "getEditPdf",
    summary = "The edited picture as a vector PDF of its flattened SVG",
    description = "As `GET /v1/jobs/{id}/pdf`, of the edit's scene: drawn on the first request, \
        then stored and served as a file.",
    params(("id" = JobId, Path), ("edit_id" = EditId, Path)),
    responses(
        (status = 200, description = "The PDF.", body = Binary, content_type = "application/pdf"),
        FileProblems,
        (status = 500, response = Problem),
    ),
)]
async fn edit_pdf(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    path: EditPath,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    edit_derived(&state, &headers, &owner, path, Derived::Flat(FileKind::Pdf)).await
}

#[utoipa::path(get, path = "/v1/jobs/{id}/edits/{edit_id}/png", tag = "edits", operation_id = "getEditPng",
    summary = "The edited picture as a PNG of any width, drawn by covec's own renderer",
    description = "As `GET /v1/jobs/{id}/png`, of the edit's scene: drawn on the first request \
        for a width, then stored and served as a file.",
    params(("id" = JobId, Path), ("edit_id" = EditId, Path),
        ("width" = Option<u64>, Query, minimum = 1, maximum = 4294967295.0,
        description = "Width in pixels (default: the original image's width); as for the job's PNG.")),
    responses(
        (status = 200, description = "The PNG.", body = Binary, content_type = "image/png"),
        FileProblems,
        (status = 413, response = Problem),
        (status = 422, response = Problem),
        (status = 500, response = Problem),
    ),
)]
async fn edit_png(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    path: EditPath,
    headers: HeaderMap,
    query: Result<Query<PngQuery>, QueryRejection>,
) -> Result<Response, ApiError> {
    let Query(query) = query.map_err(|rejection| ApiError::BadQuery(rejection.body_text()))?;
    let width = query.width()?;
    edit_derived(&state, &headers, &owner, path, Derived::Png(width)).await
}

#[utoipa::path(get, path = "/v1/jobs/{id}/edits/{edit_id}/scene.json", tag = "edits", operation_id = "getEditScene",
    summary = "The edited scene as JSON",
    params(("id" = JobId, Path), ("edit_id" = EditId, Path)),
    responses(
        (status = 200, description = "The scene.", body = SceneJson),
        FileProblems,
    ),
)]
async fn edit_scene(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    path: EditPath,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    edit_file(&state, &headers, &owner, path, FileKind::SceneJson).await
}

#[utoipa::path(get, path = "/v1/jobs/{id}/edits/{edit_id}/preview.png", tag = "edits", operation_id = "getEditPreview",
    summary = "The edited scene as covec's renderer draws it",
    params(("id" = JobId, Path), ("edit_id" = EditId, Path)),
    responses(
        (status = 200, description = "The preview image.", body = Binary, content_type = "image/png"),
        FileProblems,
    ),
)]
async fn edit_preview(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    path: EditPath,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    edit_file(&state, &headers, &owner, path, FileKind::Preview).await
}
