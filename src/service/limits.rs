//! `GET /v1/limits`: what this server accepts (its configured limits) and the parameters a job
//! gets by default, so clients such as the web page read them instead of hard-coding them.

use axum::Json;
use axum::extract::State;
use axum::http::Method;

use super::state::{AppState, Endpoint, endpoint};
use crate::edit::ReferenceParams;
use crate::imageio::ACCEPTED_MEDIA_TYPES;
use crate::pipeline::{MIN_PATHS, MIN_SIZE, Params};

pub fn endpoints() -> Vec<Endpoint> {
    vec![endpoint(Method::GET, "/v1/limits", limits)]
}

/// This server's limits on a submission, and the default parameters.
#[derive(serde::Serialize, utoipa::ToSchema)]
pub struct Limits {
    /// Largest request body, in bytes (`--max-body-bytes`); beyond it 413 `body-too-large`.
    max_body_bytes: u64,
    /// Largest image (and albedo map, mask, label map, PNG download), in pixels
    /// (`--max-pixels`); beyond it 413 `too-many-pixels`.
    max_pixels: u64,
    /// Most masks in one job (`--max-masks`).
    max_masks: u64,
    /// Smallest `params.paths`: the albedo base and room for structure and refinement.
    min_paths: u32,
    /// Largest `params.paths` (`--max-paths`).
    max_paths: u32,
    /// Smallest `params.max_size`.
    min_size: u32,
    /// Largest `params.max_size`, the working size's long side (`--max-size`).
    max_size: u32,
    /// Largest total of a job's `params.iterations` (`--max-iterations`).
    max_iterations: u64,
    /// Longest `Prefer: wait` honoured on `POST /v1/jobs`, in seconds (`--max-wait`).
    max_wait_seconds: u64,
    /// The image formats `image` (and `albedo`, `mask`, `labels`, an edit's `reference`) may
    /// have.
    media_types: Vec<&'static str>,
    /// The parameters of a job that sends none (each member applies when left out).
    defaults: Params,
    /// The parameters of a reference edit (`POST /v1/jobs/{id}/edits` with a `reference`
    /// image) that sends none.
    reference_defaults: ReferenceParams,
}

#[utoipa::path(get, path = "/v1/limits", tag = "operations", operation_id = "getLimits",
    summary = "This server's limits on a submission, and the default parameters",
    description = "Needs no API key. Limits are the server's settings: a client (the web page, \
        a script) reads them here rather than assuming them.",
    security(()),
    responses((status = 200, description = "The limits.", body = Limits)),
)]
async fn limits(State(state): State<AppState>) -> Json<Limits> {
    let limits = &state.limits;
    Json(Limits {
        max_body_bytes: limits.max_body_bytes,
        max_pixels: limits.max_pixels,
        max_masks: limits.max_masks as u64,
        min_paths: MIN_PATHS,
        max_paths: limits.max_paths,
        min_size: MIN_SIZE,
        max_size: limits.max_size,
        max_iterations: limits.max_iterations,
        max_wait_seconds: state.max_wait.as_secs(),
        media_types: ACCEPTED_MEDIA_TYPES.to_vec(),
        defaults: Params::default(),
        reference_defaults: ReferenceParams::default(),
    })
}
