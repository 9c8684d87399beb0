//! A job's event stream (`GET /v1/jobs/{id}/events`): Server-Sent Events of its progress.

use std::convert::Infallible;
use std::time::Duration;

use axum::Extension;
use axum::extract::{Path, State};
use axum::http::{HeaderMap, HeaderName, Method, header};
use axum::response::IntoResponse;
use axum::response::sse::{Event, KeepAlive, Sse};

use super::auth::Owner;
use super::error::{ApiError, JobProblems};
use super::jobs::{find, with_signed};
use super::model::{JobId, Status};
use super::state::{AppState, Endpoint, endpoint};
use super::view::{JobEvent, JobView};

pub fn endpoints() -> Vec<Endpoint> {
    vec![endpoint(Method::GET, "/v1/jobs/{id}/events", events)]
}

/// Shortest gap between two progress events; the latest state always gets through.
const EVENT_INTERVAL: Duration = Duration::from_millis(100);

/// How often a stream looks for a new draft within [`EVENT_INTERVAL`]: a draft goes out at most
/// this late, and a stream wakes at most 100 times a second, however fast the job reports.
const DRAFT_LOOK: Duration = Duration::from_millis(10);

/// Server-Sent Events: `progress` events while the job is queued or running (`draft` instead
/// when the job has a draft newer than the last event's, sent without waiting out the
/// interval), then one `completed` event with the final job, then the stream ends. `X-Accel-Buffering: no` asks a
/// proxy in front (nginx, ingress-nginx) to pass events as they come rather than buffer the
/// stream until the job ends, and `Cache-Control: no-cache` keeps caches from storing it.
#[utoipa::path(get, path = "/v1/jobs/{id}/events", tag = "jobs", operation_id = "jobEvents",
    summary = "Server-Sent Events of the job's progress",
    description = "`event: progress` with the job (as in `GET /v1/jobs/{id}`) whenever it \
        changes (at most every 100 ms), then one `event: completed` with the final job, then the \
        stream ends. When the job's `draft` is new (not in the stream's previous event), the \
        event is `event: draft` instead of `progress`, sent at once: fetch `draft.url` to show \
        the result so far. Every event carries the whole job, and its `id:` is \
        `{sequence}.{digest}`. \
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
        draft: None,
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
                    // The interval, cut short by a new draft: looked for every DRAFT_LOOK
                    // rather than woken by every change, which comes at each iteration.
                    let interval_ends = tokio::time::Instant::now() + EVENT_INTERVAL;
                    let mut new_draft = false;
                    while !new_draft && tokio::time::Instant::now() < interval_ends {
                        let now = tokio::time::Instant::now();
                        tokio::time::sleep_until(interval_ends.min(now + DRAFT_LOOK)).await;
                        new_draft = receiver.borrow().draft != cursor.draft;
                    }
                    if !new_draft {
                        tokio::select! {
                            changed = receiver.changed() => changed.ok()?,
                            _ = shutdown.wait_for(|stopping| *stopping) => return None,
                        }
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
                    cursor.draft = record.draft;
                    continue;
                }
                let id = EventId {
                    sequence: cursor.sequence,
                    digest,
                };
                let kind = if terminal {
                    "completed"
                } else if record.draft.is_some() && record.draft != cursor.draft {
                    "draft"
                } else {
                    "progress"
                };
                let event = Event::default().id(id.to_string()).event(kind).data(data);
                let next = Cursor {
                    sequence: cursor.sequence + 1,
                    waiting: true,
                    seen: None,
                    draft: record.draft,
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
struct Cursor {
    sequence: u64,
    /// Wait for a change before the next event (not before the first).
    waiting: bool,
    /// The digest of the state a resuming client has: not sent again.
    seen: Option<u64>,
    /// The draft (its stage) in the last event sent.
    draft: Option<String>,
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
