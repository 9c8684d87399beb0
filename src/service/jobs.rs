//! The job resource: create, read, list, cancel, delete (its event stream: `events.rs`).

use std::sync::Arc;
use std::time::Duration;

use axum::extract::rejection::QueryRejection;
use axum::extract::{Path, Query, Request, State};
use axum::http::{HeaderMap, HeaderValue, Method, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::{Extension, Json};
use serde::Deserialize;

use super::auth::{Client, Owner};
use super::error::{ApiError, JobProblems, TooManyRequests, Unavailable, off_async};
use super::job::JobEntry;
use super::model::{
    Idempotency, JobId, JobRecord, Problem, Status, is_job_id, new_job_id, now_ms, rfc3339,
};
use super::queue::Admission;
use super::rate::RateState;
use super::signed;
use super::state::{AppState, Endpoint, endpoint};
use super::submit::{self, JsonSubmission, MultipartSubmission, UploadQuery};
use super::view::{IdempotentReplayed, JobList, JobView, SignedUrls};

pub fn endpoints() -> Vec<Endpoint> {
    vec![
        endpoint(Method::POST, "/v1/jobs", create),
        endpoint(Method::GET, "/v1/jobs", list),
        endpoint(Method::GET, "/v1/jobs/{id}", get),
        endpoint(Method::DELETE, "/v1/jobs/{id}", delete),
        endpoint(Method::POST, "/v1/jobs/{id}/cancel", cancel),
    ]
}

/// The job `id` if it is well-formed, exists and belongs to `owner`; `410 Gone` when its
/// record expired. Looked up off the async threads (a job not in memory is read from the
/// store, so a slow or unreachable database holds up only the requests that need it), and a
/// failed lookup is an error, not a 404 (a client must not take a job for gone while the
/// database is down).
pub async fn find(state: &AppState, owner: &Owner, id: &str) -> Result<Arc<JobEntry>, ApiError> {
    if !is_job_id(id) {
        return Err(ApiError::MalformedJobId(id.to_owned()));
    }
    tracing::Span::current().record("job_id", id);
    let (queue, id, owner) = (Arc::clone(&state.queue), id.to_owned(), owner.0.clone());
    off_async(
        move || match queue.find(&id)?.filter(|entry| entry.owner == owner) {
            Some(entry) => Ok(entry),
            None if queue.expired(&id, &owner)? => Err(ApiError::JobExpired(id)),
            None => Err(ApiError::JobNotFound(id)),
        },
    )
    .await
}

fn view(state: &AppState, entry: &JobEntry) -> JobView {
    let record = entry.snapshot();
    let placement = if record.status == Status::Queued {
        state.queue.placement(&record.id)
    } else {
        None
    };
    with_signed(state, JobView::new(&record, placement))
}

/// `view` with its signed URLs, on a server with API keys (where only the job's owner sees
/// the job).
pub(super) fn with_signed(state: &AppState, mut view: JobView) -> JobView {
    if !state.key_ids.is_empty() {
        let (token, expires) = state.signer.token(&view.id, now_ms());
        view.signed = Some(SignedUrls {
            results: view
                .urls
                .results
                .as_ref()
                .map(|results| results.signed(|url| signed::with_token(url, &token))),
            expires_at: rfc3339(expires * 1000),
            token,
        });
    }
    view
}

const IDEMPOTENCY_KEY: &str = "idempotency-key";
const PREFER: &str = "prefer";

#[utoipa::path(post, path = "/v1/jobs", tag = "jobs", operation_id = "createJob",
    summary = "Submit an image for vectorisation",
    description = "Validates and stores the inputs, then queues the job: 201 with the job and \
        `Location`. With `Idempotency-Key`, the same key and the same request return the first \
        job again (`Idempotent-Replayed: true`); the same key with a different request is 422. \
        A key holds for `--idempotency-window` (24 h) after its job was created; then it makes \
        a new job. \
        With `Prefer: wait=N` (RFC 7240) the answer waits up to N seconds (capped by the \
        server's `--max-wait`, default 60; a bare `Prefer: wait` waits that long) for the job to \
        end: 200 with the ended job, else 202 with the job as it is (it goes on). Both carry `Preference-Applied: wait=N` with the \
        wait used. Other and malformed preferences are ignored. A JPEG that ends before its \
        end-of-image marker (cut short in transfer) is refused with 422 `truncated-image` \
        unless `accept_truncated=true` (its missing part then decodes as grey).",
    params(
        UploadQuery,
        ("Idempotency-Key" = Option<String>, Header, min_length = 1, max_length = 255),
        ("Prefer" = Option<String>, Header, example = "wait=30",
            description = "`wait=N`: seconds to wait for the job to end before answering; `wait` alone: \
                the server's `--max-wait`."),
        ("X-Client-Key" = Option<String>, Header, min_length = 1, max_length = 255,
            pattern = r"^[\x20-\x7e]*[\x21-\x7e][\x20-\x7e]*$",
            description = "Without API keys on the server: whose turn the job takes in the queue \
                and whose per-key limits it counts against (ignored when the server has API \
                keys: the key is the API key). Not a secret."),
    ),
    request_body(content(
        (MultipartSubmission = "multipart/form-data"),
        (JsonSubmission = "application/json"),
    )),
    responses(
        (status = 200, description = "With `Prefer: wait`, the job ended within the wait.", body = JobView,
            headers(("Location" = String, description = "The job's URL."),
                    ("Preference-Applied" = String, description = "`wait=N`, the wait used."))),
        (status = 201, description = "The job was created (or replayed for an Idempotency-Key).", body = JobView,
            headers(("Location" = String, description = "The job's URL."),
                    ("Idempotent-Replayed" = IdempotentReplayed,
                        description = "Present when an earlier job is returned for the same Idempotency-Key."))),
        (status = 202, description = "With `Prefer: wait`, the job had not ended within the wait; poll `Location`.",
            body = JobView,
            headers(("Location" = String, description = "The job's URL."),
                    ("Preference-Applied" = String, description = "`wait=N`, the wait used."))),
        (status = 400, response = Problem),
        (status = 401, response = Problem),
        (status = 413, response = Problem),
        (status = 415, response = Problem),
        (status = 422, response = Problem),
        (status = 429, response = TooManyRequests),
        (status = 503, response = Unavailable),
    ),
)]
async fn create(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Extension(Client(client)): Extension<Client>,
    headers: HeaderMap,
    request: Request,
) -> Result<Response, ApiError> {
    let rate = state.rates.check(&client).map_err(ApiError::RateLimited)?;
    let key = match headers.get(IDEMPOTENCY_KEY) {
        Some(value) => match value.to_str() {
            Ok(key) if !key.is_empty() && key.len() <= 255 => Some(key.to_owned()),
            _ => {
                return Err(ApiError::BadRequest(
                    "Idempotency-Key must be 1-255 visible ASCII characters".into(),
                ));
            }
        },
        None => None,
    };
    let options = UploadQuery::of(&request)?;
    // Without a key, a full queue refuses before the body is read. With one, a retry gets its
    // replay even when the queue is full: capacity is checked once the key is looked up.
    if key.is_none() {
        state.queue.check_capacity(&client)?;
    }
    let mut submission = submit::read(request, &state.limits).await?;
    let fingerprint = submission.fingerprint();
    let webhook = state
        .webhooks
        .target(std::mem::take(&mut submission.webhook))?;
    if let Some(key) = &key {
        let (queue, owner, key, print) = (
            state.queue.clone(),
            owner.0.clone(),
            key.clone(),
            fingerprint.clone(),
        );
        let earlier = off_async(move || queue.find_idempotent(&owner, &key, &print)).await?;
        if let Some(earlier) = earlier {
            return Ok(with_rate(created(&state, &earlier, true), rate));
        }
        state.queue.check_capacity(&client)?;
    }
    // Decoding is CPU work: off the async workers, and a few requests at a time. The slot goes
    // with the decoding, which runs on even if the client leaves.
    let slot = state.decode_slot().await?;
    let limits = state.limits.clone();
    let submission = off_async(move || {
        let _slot = slot;
        submission
            .inputs
            .decode(&limits, options.accept_truncated)
            .map(|_| submission)
    })
    .await?;

    let id = new_job_id();
    tracing::Span::current().record("job_id", id.as_str());
    let manifest = submission.inputs.manifest(options.accept_truncated);
    let record = JobRecord {
        owner: owner.0.clone(),
        idempotency: key.map(|key| Idempotency { key, fingerprint }),
        webhook,
        input_name: submission.input_name,
        ..JobRecord::queued(
            id,
            client,
            submission.priority.unwrap_or_default(),
            submission.params,
            manifest,
        )
    };
    let queue = state.queue.clone();
    let admission = off_async(move || queue.admit(record, submission.inputs)).await?;
    let (entry, replayed) = match admission {
        Admission::Created(entry) => {
            tracing::info!("job created");
            state.webhooks.follow(entry.clone());
            (entry, false)
        }
        Admission::Replayed(entry) => (entry, true),
    };
    let wait = preferred_wait(&headers).map(|wait| wait.min(state.max_wait));
    let response = match wait {
        Some(wait) if !wait.is_zero() => waited(&state, &entry, replayed, wait).await,
        _ => created(&state, &entry, replayed),
    };
    Ok(with_rate(response, rate))
}

/// `response` with the key's `RateLimit-Policy` and `RateLimit` fields, when a rate applies.
fn with_rate(mut response: Response, rate: Option<RateState>) -> Response {
    for (name, value) in rate.iter().flat_map(RateState::fields) {
        let value = HeaderValue::from_str(&value).expect("ASCII");
        response.headers_mut().insert(name, value);
    }
    response
}

/// The `wait` preference of RFC 7240 (`Prefer: wait=N`, seconds), if sent and well formed; a
/// bare `wait` (as other APIs document it) asks for as long as the server allows. Other
/// preferences, and malformed ones, are ignored as the RFC asks.
fn preferred_wait(headers: &HeaderMap) -> Option<Duration> {
    headers
        .get_all(PREFER)
        .iter()
        .filter_map(|value| value.to_str().ok())
        .flat_map(|value| value.split(','))
        .find_map(|preference| {
            let preference = preference.split(';').next()?;
            let (name, value) = preference.split_once('=').unwrap_or((preference, ""));
            if !name.trim().eq_ignore_ascii_case("wait") {
                return None;
            }
            match value.trim().trim_matches('"') {
                "" => Some(Duration::MAX),
                seconds => seconds.parse::<u64>().ok().map(Duration::from_secs),
            }
        })
}

/// Waits up to `wait` for the job to end: 200 with the ended job, else 202 with it as it is
/// (the job goes on; poll `Location`). Both carry `Preference-Applied`. A server shutdown
/// ends the wait early.
async fn waited(state: &AppState, entry: &JobEntry, replayed: bool, wait: Duration) -> Response {
    let mut record = entry.record.subscribe();
    let mut shutdown = state.shutdown.subscribe();
    let ended = tokio::select! {
        result = tokio::time::timeout(wait, record.wait_for(|r| r.status.is_terminal())) => {
            matches!(result, Ok(Ok(_)))
        }
        _ = shutdown.wait_for(|&stopping| stopping) => false,
    };
    let mut response = created(state, entry, replayed);
    *response.status_mut() = if ended {
        StatusCode::OK
    } else {
        StatusCode::ACCEPTED
    };
    let applied = HeaderValue::from_str(&format!("wait={}", wait.as_secs()))
        .expect("digits are a header value");
    response.headers_mut().insert("preference-applied", applied);
    response
}

/// 201 + `Location` + the job (also for an idempotent replay, marked `Idempotent-Replayed`).
fn created(state: &AppState, entry: &JobEntry, replayed: bool) -> Response {
    let view = view(state, entry);
    let location = HeaderValue::from_str(&view.urls.job).expect("job urls are ASCII");
    let mut response = (
        StatusCode::CREATED,
        [(header::LOCATION, location)],
        Json(view),
    )
        .into_response();
    if replayed {
        response
            .headers_mut()
            .insert("idempotent-replayed", HeaderValue::from_static("true"));
    }
    response
}

#[utoipa::path(get, path = "/v1/jobs/{id}", tag = "jobs", operation_id = "getJob",
    summary = "A job's status, progress and links",
    params(("id" = JobId, Path)),
    responses(
        (status = 200, description = "The job.", body = JobView),
        JobProblems,
    ),
)]
async fn get(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path(id): Path<String>,
) -> Result<Json<JobView>, ApiError> {
    let entry = find(&state, &owner, &id).await?;
    Ok(Json(view(&state, &entry)))
}

#[derive(Deserialize)]
struct ListQuery {
    status: Option<String>,
    limit: Option<String>,
    cursor: Option<String>,
}

const DEFAULT_PAGE: usize = 20;
const MAX_PAGE: usize = 100;

#[utoipa::path(get, path = "/v1/jobs", tag = "jobs", operation_id = "listJobs",
    summary = "List jobs, newest first",
    params(
        ("status" = Option<Status>, Query),
        ("limit" = Option<u32>, Query, minimum = 1, maximum = 100),
        ("cursor" = Option<JobId>, Query, description = "`next_cursor` of the previous page."),
    ),
    responses(
        (status = 200, description = "One page of jobs.", body = JobList),
        (status = 400, response = Problem),
        (status = 401, response = Problem),
        (status = 500, response = Problem),
        (status = 503, response = Unavailable),
    ),
)]
async fn list(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    query: Result<Query<ListQuery>, QueryRejection>,
) -> Result<Response, ApiError> {
    let Query(query) = query.map_err(|rejection| ApiError::BadQuery(rejection.body_text()))?;
    let status = query
        .status
        .map(|name| {
            Status::from_name(&name).ok_or_else(|| {
                ApiError::BadQuery(format!(
                    "`status` must be queued, running, succeeded, failed or canceled, not `{name}`"
                ))
            })
        })
        .transpose()?;
    let limit = match query.limit {
        Some(text) => text
            .parse::<usize>()
            .ok()
            .filter(|limit| (1..=MAX_PAGE).contains(limit))
            .ok_or_else(|| {
                ApiError::BadQuery(format!(
                    "`limit` must be an integer in 1..={MAX_PAGE}, not `{text}`"
                ))
            })?,
        None => DEFAULT_PAGE,
    };
    if let Some(cursor) = &query.cursor
        && !is_job_id(cursor)
    {
        return Err(ApiError::BadQuery(format!(
            "`cursor` must be a `next_cursor` from an earlier page, not `{cursor}`"
        )));
    }
    let queue = state.queue.clone();
    let (page, more) =
        off_async(move || queue.list(&owner.0, status, query.cursor.as_deref(), limit)).await?;
    let next_cursor = if more {
        page.last().map(|(record, _)| record.id.clone())
    } else {
        None
    };
    let items: Vec<JobView> = page
        .iter()
        .map(|(record, placement)| with_signed(&state, JobView::new(record, *placement)))
        .collect();
    Ok(Json(JobList { items, next_cursor }).into_response())
}

/// 202 while a running job stops; 200 when the job is already terminal (or was queued and is
/// now canceled).
#[utoipa::path(post, path = "/v1/jobs/{id}/cancel", tag = "jobs", operation_id = "cancelJob",
    summary = "Cancel a job",
    description = "A queued job is canceled at once (200). A running job stops within one \
        iteration and frees its worker (202; poll until `canceled`). A finished job is left as \
        it is (200).",
    params(("id" = JobId, Path)),
    responses(
        (status = 200, description = "The job is terminal.", body = JobView),
        (status = 202, description = "The running job was asked to stop.", body = JobView),
        JobProblems,
        (status = 500, response = Problem),
    ),
)]
async fn cancel(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let entry = find(&state, &owner, &id).await?;
    let queue = state.queue.clone();
    let cancel_entry = entry.clone();
    let stopping = off_async(move || queue.cancel(&cancel_entry)).await?;
    let status = if stopping {
        StatusCode::ACCEPTED
    } else {
        StatusCode::OK
    };
    Ok((status, Json(view(&state, &entry))).into_response())
}

#[utoipa::path(delete, path = "/v1/jobs/{id}", tag = "jobs", operation_id = "deleteJob",
    summary = "Delete a job and its files (a running job is stopped first)",
    description = "The job's record is marked deleted first: once that is written (204) nothing \
        brings the job back, neither a cancel racing the delete, nor its runner finishing, nor a \
        restart. If it cannot be written (a full disk, a failing database) the answer is a 500 \
        problem and the job is left whole. Files that cannot be removed at once (a read-only \
        disk) are removed by the sweep of orphaned job directories later.",
    params(("id" = JobId, Path)),
    responses(
        (status = 204, description = "Deleted."),
        JobProblems,
        (status = 500, response = Problem),
    ),
)]
async fn delete(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path(id): Path<String>,
) -> Result<StatusCode, ApiError> {
    let entry = find(&state, &owner, &id).await?;
    let queue = state.queue.clone();
    off_async(move || queue.delete(&entry)).await?;
    Ok(StatusCode::NO_CONTENT)
}
