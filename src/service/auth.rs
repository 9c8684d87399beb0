//! Optional API keys: with keys configured, every `/v1` request needs `Authorization: Bearer <key>`,
//! and each job is visible only to the key that created it.

use axum::extract::{Request, State};
use axum::http::header;
use axum::middleware::Next;
use axum::response::Response;
use sha2::{Digest, Sha256};

use super::AppState;
use super::error::ApiError;
use super::submit::hex;

/// Who is asking: a hash of their API key, or `None` when the server has no keys.
/// Only the hash is stored with jobs and logged.
#[derive(Clone, Debug)]
pub struct Owner(pub Option<String>);

/// The identity stored for a key.
pub fn key_id(key: &str) -> String {
    hex(&Sha256::digest(key.as_bytes())[..12])
}

pub async fn require_key(
    State(state): State<AppState>,
    mut request: Request,
    next: Next,
) -> Result<Response, ApiError> {
    let owner = if state.key_ids.is_empty() || !request.uri().path().starts_with("/v1/") {
        None
    } else {
        let presented = request
            .headers()
            .get(header::AUTHORIZATION)
            .and_then(|value| value.to_str().ok())
            .and_then(|value| value.strip_prefix("Bearer "))
            .map(|key| key_id(key.trim()));
        match presented {
            Some(id) if state.key_ids.contains(&id) => Some(id),
            _ => return Err(ApiError::Unauthorized),
        }
    };
    request.extensions_mut().insert(Owner(owner));
    Ok(next.run(request).await)
}
