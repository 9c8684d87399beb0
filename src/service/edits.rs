//! Edits of a finished job: recolour albedo paths while the shade and light layers keep the
//! lighting (issue 6). An edit is cheap (no optimisation), so it runs within the request, on
//! the blocking pool, and is stored under the job: `edits/<edit id>/{edit.json, scene.json,
//! result.svg, preview.png}`. An edit may build on an earlier edit (`base`), which gives clients
//! an undo history for free.

use std::collections::BTreeMap;

use axum::extract::{FromRequest, Multipart, Path, Request, State};
use axum::http::{HeaderValue, Method, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::{Extension, Json};
use serde::{Deserialize, Serialize};

use super::auth::Owner;
use super::error::ApiError;
use super::jobs::find;
use super::results::{artefact, require_success, scene_file, stored_scene};
use super::store::digest;
use super::submit::{input_error, read_body};
use super::{AppState, Endpoint, endpoint};
use crate::edit::{self, ColorChange, Edit, ReferenceParams, Target};
use crate::imageio::{self, resize_rgb};
use crate::output::{self, EDIT_FILES, FileKind};
use crate::scene::{PathId, Point};
use crate::svg;

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
    ]
}

/// Edit id: `edit_` + a UUIDv7 in hex.
fn new_edit_id() -> String {
    format!("edit_{}", uuid::Uuid::now_v7().simple())
}

fn check_edit_id(id: &str) -> Result<(), ApiError> {
    let valid = id.strip_prefix("edit_").is_some_and(|hex| {
        hex.len() == 32
            && hex
                .bytes()
                .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
    });
    if valid {
        Ok(())
    } else {
        Err(ApiError::BadRequest(format!(
            "`{id}` is not an edit id (expected `edit_` followed by 32 lowercase hex digits)"
        )))
    }
}

/// JSON form: direct colour changes.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ColorEdit {
    /// Apply on top of this earlier edit instead of the job's scene.
    #[serde(default)]
    base: Option<String>,
    changes: Vec<ChangeRequest>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ChangeRequest {
    /// A path id such as `albedo-3`; or give `at`.
    #[serde(default)]
    path: Option<String>,
    /// A point in viewBox coordinates: the albedo path under it is recoloured.
    #[serde(default)]
    at: Option<Point>,
    /// `#rrggbb`.
    color: String,
    #[serde(default)]
    opacity: Option<f32>,
}

/// What a stored edit says about itself.
#[derive(Serialize, Deserialize)]
struct EditRecord {
    id: String,
    job_id: String,
    base: Option<String>,
    kind: EditKind,
    changed: Vec<ChangedView>,
    created_at: String,
    urls: EditUrls,
}

#[derive(Serialize, Deserialize, Clone, Copy)]
#[serde(rename_all = "lowercase")]
enum EditKind {
    Colors,
    Reference,
}

#[derive(Serialize, Deserialize)]
struct ChangedView {
    path: String,
    old_color: String,
    new_color: String,
    old_opacity: f32,
    new_opacity: f32,
}

#[derive(Serialize, Deserialize)]
struct EditUrls {
    #[serde(rename = "self")]
    this: String,
    svg: String,
    scene: String,
    preview: String,
}

/// The request as read, before the scene is loaded.
enum EditRequest {
    Colors(Vec<ColorChange>),
    Reference {
        image: axum::body::Bytes,
        params: ReferenceParams,
    },
}

async fn create(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path(id): Path<String>,
    request: Request,
) -> Result<Response, ApiError> {
    let entry = find(&state, &owner, &id).await?;
    require_success(&entry.snapshot())?;
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
    let record = tokio::task::spawn_blocking(move || {
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
                    ..imageio::Limits::default()
                };
                // The job's input passed the submission's checks (a cut JPEG only if the
                // client accepted it).
                let original = imageio::decode_image(
                    &read("input/image")?
                        .ok_or_else(|| ApiError::ResultNotFound("input/image".into()))?,
                    &imageio::Limits {
                        accept_truncated: true,
                        ..limits.clone()
                    },
                )
                .map_err(|e| ApiError::Internal(format!("stored input: {e}")))?;
                let reference = imageio::decode_image(&image, &limits)
                    .map_err(input_error("reference image"))?;
                imageio::check_aspect(
                    "the reference image",
                    (reference.width(), reference.height()),
                    (original.width(), original.height()),
                )
                .map_err(|e| ApiError::InvalidInput(e.to_string()))?;
                let (w, h) = (scene.width, scene.height);
                let edit = edit::recolor_by_reference(
                    &scene,
                    &resize_rgb(&original, w, h),
                    &resize_rgb(&reference, w, h),
                    &params,
                );
                (EditKind::Reference, edit)
            }
        };
        let edit = edit.map_err(|e| ApiError::InvalidInput(e.to_string()))?;
        store_edit(&queue, &job_id, base, kind, &edit)
    })
    .await
    .map_err(|e| ApiError::Internal(e.to_string()))??;

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

/// Checks access to the job and the edit id; the edit exists once its record does.
async fn check_edit(
    state: &AppState,
    owner: &Owner,
    id: &str,
    edit_id: &str,
) -> Result<(), ApiError> {
    let entry = find(state, owner, id).await?;
    require_success(&entry.snapshot())?;
    check_edit_id(edit_id)?;
    Ok(())
}

/// One of an edit's scene files, once the edit exists.
async fn edit_file(
    state: &AppState,
    owner: &Owner,
    id: &str,
    edit_id: &str,
    kind: FileKind,
) -> Result<Response, ApiError> {
    check_edit(state, owner, id, edit_id).await?;
    // The record says the edit exists; only its size is looked at, never its changes.
    let queue = state.queue.clone();
    let (job, record) = (id.to_owned(), edit_record(edit_id));
    let exists = tokio::task::spawn_blocking(move || queue.store().has_artefact(&job, &record))
        .await
        .map_err(|error| ApiError::Internal(error.to_string()))??;
    if !exists {
        return Err(ApiError::ResultNotFound(edit_record(edit_id)));
    }
    scene_file(state, id, &format!("edits/{edit_id}/"), kind).await
}

/// Where an edit's record is stored.
fn edit_record(edit_id: &str) -> String {
    format!("edits/{edit_id}/{EDIT_RECORD}")
}

/// The file name of an edit's record.
const EDIT_RECORD: &str = "edit.json";

async fn get(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path((id, edit_id)): Path<(String, String)>,
) -> Result<Response, ApiError> {
    check_edit(&state, &owner, &id, &edit_id).await?;
    artefact(&state, &id, edit_record(&edit_id), "application/json").await
}

async fn edit_svg(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path((id, edit_id)): Path<(String, String)>,
) -> Result<Response, ApiError> {
    edit_file(&state, &owner, &id, &edit_id, FileKind::LayeredSvg).await
}

async fn edit_scene(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path((id, edit_id)): Path<(String, String)>,
) -> Result<Response, ApiError> {
    edit_file(&state, &owner, &id, &edit_id, FileKind::SceneJson).await
}

async fn edit_preview(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path((id, edit_id)): Path<(String, String)>,
) -> Result<Response, ApiError> {
    edit_file(&state, &owner, &id, &edit_id, FileKind::Preview).await
}
