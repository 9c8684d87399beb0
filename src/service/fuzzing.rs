//! Entry points for the fuzz targets (`fuzz/`): the service's own parsing code, reachable
//! without a data directory, a queue or a socket. Not part of the API.

use axum::extract::Request;
use axum::http::StatusCode;

use super::error::ApiError;
use super::inputs::InputLimits;
use super::submit;

/// `POST /v1/jobs` up to the job record: reads the body (multipart or JSON with base64), checks
/// the parameters and decodes the inputs, as [`super::jobs`] does. `Err` is the status the
/// request would have been refused with; `accept_truncated` is the query parameter.
pub async fn submission(
    request: Request,
    limits: &InputLimits,
    accept_truncated: bool,
) -> Result<(), StatusCode> {
    let submission = submit::read(request, limits)
        .await
        .map_err(|error| error.status())?;
    submission
        .inputs
        .decode(limits, accept_truncated)
        .map_err(|error| ApiError::from(error).status())?;
    Ok(())
}
