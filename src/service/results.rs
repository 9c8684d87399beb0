//! A job's results: the layered SVG, the per-layer SVGs, the JSON scene and the stage previews.
//!
//! Previews are served while the job runs; the other results once it has succeeded.

use axum::extract::{Path, State};
use axum::http::{Method, header};
use axum::response::{IntoResponse, Response};
use axum::{Extension, Json};

use super::auth::Owner;
use super::error::ApiError;
use super::jobs::find;
use super::model::{JobRecord, Status};
use super::{AppState, Endpoint, endpoint};
use crate::output::FileKind;
use crate::scene::LayerKind;

pub fn endpoints() -> Vec<Endpoint> {
    vec![
        endpoint(Method::GET, "/v1/jobs/{id}/svg", svg),
        endpoint(Method::GET, "/v1/jobs/{id}/layers/{file}", layer),
        endpoint(Method::GET, "/v1/jobs/{id}/scene.json", scene),
        endpoint(Method::GET, "/v1/jobs/{id}/previews", previews),
        endpoint(Method::GET, "/v1/jobs/{id}/previews/{file}", preview),
    ]
}

pub(super) fn require_success(record: &JobRecord) -> Result<(), ApiError> {
    if record.data_removed {
        return Err(ApiError::DataRemoved(record.id.clone()));
    }
    if record.status != Status::Succeeded {
        return Err(ApiError::NotReady(record.id.clone(), record.status.name()));
    }
    Ok(())
}

/// Reads a stored file of a scene (under `prefix`, e.g. `edits/<id>/`) off the async workers.
pub(super) async fn scene_file(
    state: &AppState,
    id: &str,
    prefix: &str,
    kind: FileKind,
) -> Result<Response, ApiError> {
    artefact(
        state,
        id,
        format!("{prefix}{}", kind.name()),
        kind.media_type(),
    )
    .await
}

/// Reads a stored artefact off the async workers.
pub(super) async fn artefact(
    state: &AppState,
    id: &str,
    name: String,
    media_type: &'static str,
) -> Result<Response, ApiError> {
    let queue = state.queue.clone();
    let job = id.to_owned();
    let bytes = tokio::task::spawn_blocking(move || {
        queue
            .store()
            .read_artefact(&job, &name)
            .map(|bytes| (name, bytes))
    })
    .await
    .map_err(|error| ApiError::Internal(error.to_string()))?
    .map_err(ApiError::from)?;
    match bytes {
        (_, Some(bytes)) => Ok(([(header::CONTENT_TYPE, media_type)], bytes).into_response()),
        (name, None) => Err(ApiError::ResultNotFound(name)),
    }
}

async fn svg(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let entry = find(&state, &owner, &id)?;
    require_success(&entry.snapshot())?;
    scene_file(&state, &id, "", FileKind::LayeredSvg).await
}

async fn layer(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path((id, file)): Path<(String, String)>,
) -> Result<Response, ApiError> {
    let entry = find(&state, &owner, &id)?;
    let Some(kind) = LayerKind::ALL
        .into_iter()
        .find(|kind| file.strip_suffix(".svg") == Some(kind.name()))
    else {
        return Err(ApiError::ResultNotFound(format!(
            "layers/{file} (layers are albedo.svg, shade.svg, light.svg)"
        )));
    };
    require_success(&entry.snapshot())?;
    scene_file(&state, &id, "", FileKind::Layer(kind)).await
}

async fn scene(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let entry = find(&state, &owner, &id)?;
    require_success(&entry.snapshot())?;
    scene_file(&state, &id, "", FileKind::SceneJson).await
}

async fn previews(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let entry = find(&state, &owner, &id)?;
    let record = entry.snapshot();
    if record.data_removed {
        return Err(ApiError::DataRemoved(id));
    }
    let items: Vec<_> = record
        .previews
        .iter()
        .map(|name| serde_json::json!({ "name": name, "url": format!("/v1/jobs/{id}/previews/{name}.png") }))
        .collect();
    Ok(Json(serde_json::json!({ "items": items })).into_response())
}

async fn preview(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path((id, file)): Path<(String, String)>,
) -> Result<Response, ApiError> {
    let entry = find(&state, &owner, &id)?;
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
    artefact(&state, &id, format!("previews/{file}"), "image/png").await
}
