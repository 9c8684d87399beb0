//! Optional API keys: with keys configured, every `/v1` request needs `Authorization: Bearer <key>`
//! (the scheme in any case, RFC 9110 section 11.1), or for a job's files a signed URL's token
//! ([`super::signed`]), and each job is visible only to the key that created it. The key is also
//! whose turn a job takes in the queue and whose limits it counts against ([`Client`]).

use axum::extract::{Request, State};
use axum::http::{Method, header};
use axum::middleware::Next;
use axum::response::Response;

use super::error::{ApiError, off_async};
use super::model::{key_id, now_ms};
use super::signed;
use super::state::AppState;

/// Who is asking: a hash of their API key, or `None` when the server has no keys.
/// Only the hash is stored with jobs and logged.
#[derive(Clone, Debug)]
pub struct Owner(pub Option<String>);

/// Whose turn a request's job takes in the queue, and whose per-key limits it counts against
/// ([`super::fair`]): with API keys, the key's identity (as [`Owner`]); without, the identity of
/// the `X-Client-Key` header's value if sent (a client's own label, not a secret: the server
/// has no keys to check it against); else empty, every anonymous request one key together.
#[derive(Clone, Debug)]
pub struct Client(pub String);

/// `/v1` routes that need no key: nothing in them belongs to a key.
const PUBLIC: [&str; 1] = ["/v1/limits"];

/// The header naming a client when the server has no API keys.
const CLIENT_KEY: &str = "x-client-key";

/// An `X-Client-Key` value: 1-255 visible ASCII characters or spaces, not all spaces (the
/// pattern the API document gives); surrounding spaces are not part of the label.
fn client_label(value: &[u8]) -> Result<&str, ApiError> {
    let visible = value.iter().all(|byte| (0x20..=0x7e).contains(byte));
    match std::str::from_utf8(value) {
        Ok(label) if visible && value.len() <= 255 && !label.trim().is_empty() => Ok(label.trim()),
        _ => Err(ApiError::BadRequest(
            "X-Client-Key must be 1-255 visible ASCII characters".into(),
        )),
    }
}

/// The credentials of an `Authorization` value: what follows the `Bearer` scheme, whose name
/// is case-insensitive (RFC 9110 section 11.1).
fn bearer(value: &str) -> Option<&str> {
    let (scheme, credentials) = value.trim_start().split_once(' ')?;
    scheme
        .eq_ignore_ascii_case("bearer")
        .then(|| credentials.trim())
}

pub async fn require_key(
    State(state): State<AppState>,
    mut request: Request,
    next: Next,
) -> Result<Response, ApiError> {
    let path = request.uri().path();
    let open = !path.starts_with("/v1/") || PUBLIC.contains(&path);
    let owner = if state.key_ids.is_empty() || open {
        None
    } else {
        let presented = request
            .headers()
            .get(header::AUTHORIZATION)
            .and_then(|value| value.to_str().ok())
            .and_then(bearer)
            .map(key_id);
        match presented {
            Some(id) if state.key_ids.contains(&id) => Some(id),
            Some(_) => return Err(ApiError::Unauthorized),
            None => {
                let job = signed_job(&state, &request)?;
                owner_of(&state, job).await?
            }
        }
    };
    // Checked whether or not it counts (with API keys the key decides), so a request is valid
    // or not by the same rule on every server.
    let label = match request.headers().get(CLIENT_KEY) {
        Some(value) => Some(client_label(value.as_bytes())?),
        None => None,
    };
    let client = match (&owner, label) {
        (Some(id), _) => id.clone(),
        (None, Some(label)) => key_id(label),
        (None, None) => String::new(),
    };
    request.extensions_mut().insert(Owner(owner));
    request.extensions_mut().insert(Client(client));
    Ok(next.run(request).await)
}

/// The job whose file a request without a key asks for, when its query holds a token signed
/// for that job ([`signed`]); else 401 (or 403 for a token that is not that job's, or expired).
fn signed_job(state: &AppState, request: &Request) -> Result<String, ApiError> {
    let readable = matches!(*request.method(), Method::GET | Method::HEAD);
    let job = signed::file_route_job(request.uri().path()).filter(|_| readable);
    let token = signed::query_token(request.uri().query());
    let (Some(job), Some(token)) = (job, token) else {
        return Err(ApiError::Unauthorized);
    };
    state.signer.check(job, token, now_ms())?;
    Ok(job.to_owned())
}

/// The owner of `job`, looked up so that the handler then finds the job as its owner would (a
/// job that does not exist is the handler's 404).
async fn owner_of(state: &AppState, job: String) -> Result<Option<String>, ApiError> {
    let queue = state.queue.clone();
    let entry = off_async(move || queue.find(&job)).await?;
    Ok(entry.and_then(|entry| entry.owner.clone()))
}
