//! The job resource: create, read, list, cancel, delete, and its event stream.

use std::convert::Infallible;
use std::sync::Arc;
use std::time::Duration;

use axum::extract::rejection::QueryRejection;
use axum::extract::{Path, Query, Request, State};
use axum::http::{HeaderMap, HeaderName, HeaderValue, Method, StatusCode, header};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::{Extension, Json};
use serde::Deserialize;

use super::auth::{Client, Owner};
use super::error::{ApiError, JobProblems, TooManyRequests, Unavailable};
use super::model::{
    Idempotency, JobId, JobRecord, Problem, Status, is_job_id, new_job_id, now_ms, rfc3339,
};
use super::queue::Admission;
use super::rate::RateState;
use super::runner::JobEntry;
use super::signed;
use super::submit::{self, JsonSubmission, MultipartSubmission, UploadQuery};
use super::view::{IdempotentReplayed, JobEvent, JobList, JobView, SignedUrls};
use super::{AppState, Endpoint, endpoint};

pub fn endpoints() -> Vec<Endpoint> {
    vec![
        endpoint(Method::POST, "/v1/jobs", create),
        endpoint(Method::GET, "/v1/jobs", list),
        endpoint(Method::GET, "/v1/jobs/{id}", get),
        endpoint(Method::DELETE, "/v1/jobs/{id}", delete),
        endpoint(Method::POST, "/v1/jobs/{id}/cancel", cancel),
        endpoint(Method::GET, "/v1/jobs/{id}/events", events),
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
    tokio::task::spawn_blocking(move || {
        match queue.find(&id)?.filter(|entry| entry.owner == owner) {
            Some(entry) => Ok(entry),
            None if queue.expired(&id, &owner)? => Err(ApiError::JobExpired(id)),
            None => Err(ApiError::JobNotFound(id)),
        }
    })
    .await
    .map_err(|error| ApiError::Internal(error.to_string()))?
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
fn with_signed(state: &AppState, mut view: JobView) -> JobView {
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
        let earlier =
            tokio::task::spawn_blocking(move || queue.find_idempotent(&owner, &key, &print))
                .await
                .map_err(|error| ApiError::Internal(error.to_string()))??;
        if let Some(earlier) = earlier {
            return Ok(with_rate(created(&state, &earlier, true), rate));
        }
        state.queue.check_capacity(&client)?;
    }
    // Decoding is CPU work: off the async workers, and a few requests at a time. The slot goes
    // with the decoding, which runs on even if the client leaves.
    let slot = state.decode_slot().await?;
    let limits = state.limits.clone();
    let submission = tokio::task::spawn_blocking(move || {
        let _slot = slot;
        submission
            .inputs
            .decode(&limits, options.accept_truncated)
            .map(|_| submission)
    })
    .await
    .map_err(|error| ApiError::Internal(error.to_string()))??;

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
    let admission = tokio::task::spawn_blocking(move || queue.admit(record, submission.inputs))
        .await
        .map_err(|error| ApiError::Internal(error.to_string()))??;
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
    let (page, more) = tokio::task::spawn_blocking(move || {
        queue.list(&owner.0, status, query.cursor.as_deref(), limit)
    })
    .await
    .map_err(|error| ApiError::Internal(error.to_string()))??;
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
    let stopping = tokio::task::spawn_blocking(move || queue.cancel(&cancel_entry))
        .await
        .map_err(|error| ApiError::Internal(error.to_string()))??;
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
    tokio::task::spawn_blocking(move || queue.delete(&entry))
        .await
        .map_err(|error| ApiError::Internal(error.to_string()))??;
    Ok(StatusCode::NO_CONTENT)
}

/// Shortest gap between two progress events; the latest state always gets through.
const EVENT_INTERVAL: Duration = Duration::from_millis(100);

/// Server-Sent Events: `progress` events while the job is queued or running, then one
/// `completed` event with the final job, then the stream ends. `X-Accel-Buffering: no` asks a
/// proxy in front (nginx, ingress-nginx) to pass events as they come rather than buffer the
/// stream until the job ends, and `Cache-Control: no-cache` keeps caches from storing it.
#[utoipa::path(get, path = "/v1/jobs/{id}/events", tag = "jobs", operation_id = "jobEvents",
    summary = "Server-Sent Events of the job's progress",
    description = "`event: progress` with the job (as in `GET /v1/jobs/{id}`) whenever it \
        changes (at most every 100 ms), then one `event: completed` with the final job, then the \
        stream ends. Every event carries the whole job, and its `id:` is `{sequence}.{digest}`. \
        Reconnecting with `Last-Event-ID` (as EventSource does) misses nothing and repeats \
        nothing: the first event is the current state unless the client has it already (then the \
        next change, or, for an ended job, an empty stream), numbered after the given id. A \
        malformed id is ignored. A keep-alive comment is sent every 15 s. The response carries \
        `X-Accel-Buffering: no` (nginx and ingress-nginx then pass events through unbuffered) \
        and `Cache-Control: no-cache`.",
    params(("id" = JobId, Path), ("Last-Event-ID" = Option<String>, Header)),
    responses(
        (status = 200, description = "The event stream.", body = JobEvent, content_type = "text/event-stream"),
        JobProblems,
    ),
)]
async fn events(
    State(state): State<AppState>,
    Extension(owner): Extension<Owner>,
    Path(id): Path<String>,
    headers: HeaderMap,
) -> Result<impl IntoResponse, ApiError> {
    let entry = find(&state, &owner, &id).await?;
    let receiver = entry.record.subscribe();
    let shutdown = state.shutdown.subscribe();
    let resumed = headers
        .get(LAST_EVENT_ID)
        .and_then(|value| value.to_str().ok())
        .and_then(EventId::parse);
    let start = Cursor {
        sequence: resumed.map_or(0, |id| id.sequence + 1),
        waiting: false,
        seen: resumed.map(|id| id.digest),
        done: false,
    };
    let stream = futures_util::stream::unfold(
        (receiver, shutdown, state, start),
        |(mut receiver, mut shutdown, state, mut cursor)| async move {
            if cursor.done {
                return None;
            }
            loop {
                if cursor.waiting {
                    tokio::time::sleep(EVENT_INTERVAL).await;
                    tokio::select! {
                        changed = receiver.changed() => changed.ok()?,
                        _ = shutdown.wait_for(|stopping| *stopping) => return None,
                    }
                }
                let record = receiver.borrow_and_update().clone();
                let placement = if record.status == Status::Queued {
                    state.queue.placement(&record.id)
                } else {
                    None
                };
                let terminal = record.status.is_terminal();
                let data =
                    serde_json::to_string(&with_signed(&state, JobView::new(&record, placement)))
                        .expect("views serialise");
                let digest = EventId::digest_of(&data);
                if cursor.seen.take() == Some(digest) {
                    // The client has this state already (it resumed with its id).
                    if terminal {
                        return None;
                    }
                    cursor.waiting = true;
                    continue;
                }
                let id = EventId {
                    sequence: cursor.sequence,
                    digest,
                };
                let event = Event::default()
                    .id(id.to_string())
                    .event(if terminal { "completed" } else { "progress" })
                    .data(data);
                let next = Cursor {
                    sequence: cursor.sequence + 1,
                    waiting: true,
                    seen: None,
                    done: terminal,
                };
                return Some((
                    Ok::<_, Infallible>(event),
                    (receiver, shutdown, state, next),
                ));
            }
        },
    );
    Ok((
        [
            (header::CACHE_CONTROL, "no-cache"),
            (HeaderName::from_static("x-accel-buffering"), "no"),
        ],
        Sse::new(stream).keep_alive(KeepAlive::new().interval(Duration::from_secs(15))),
    ))
}

const LAST_EVENT_ID: &str = "last-event-id";

/// Where an event stream stands.
#[derive(Clone, Copy)]
struct Cursor {
    sequence: u64,
    /// Wait for a change before the next event (not before the first).
    waiting: bool,
    /// The digest of the state a resuming client has: not sent again.
    seen: Option<u64>,
    done: bool,
}

/// An event's id, `{sequence}.{digest}`. Every event carries the job's whole state, so a
/// client that reconnects with `Last-Event-ID` misses nothing: it gets the current state, unless
/// the digest says it has that one already (then the next change, or, for an ended job,
/// nothing), and sequences go on from its id.
#[derive(Clone, Copy, Debug, PartialEq)]
struct EventId {
    sequence: u64,
    digest: u64,
}

impl EventId {
    fn parse(text: &str) -> Option<Self> {
        let (sequence, digest) = text.trim().split_once('.')?;
        Some(Self {
            sequence: sequence.parse().ok()?,
            digest: u64::from_str_radix(digest, 16).ok()?,
        })
    }

    /// FNV-1a of the event's data: the same in every process, unlike std's hasher.
    fn digest_of(data: &str) -> u64 {
        data.bytes().fold(0xcbf2_9ce4_8422_2325, |hash, byte| {
            (hash ^ u64::from(byte)).wrapping_mul(0x0000_0100_0000_01b3)
        })
    }
}

impl std::fmt::Display for EventId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}.{:016x}", self.sequence, self.digest)
    }
}
