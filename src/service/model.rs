//! The job resource: the persisted record and its public JSON view.

use std::collections::BTreeMap;
use std::time::Duration;

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;
use utoipa::openapi::{ObjectBuilder, RefOr, Schema, Type};

use crate::pipeline::{Mode, Params, Progress};

/// A problem details object (RFC 9457) with covec's extensions.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Problem {
    /// `urn:covec:problem:<code>`.
    #[serde(rename = "type")]
    pub kind: String,
    pub title: String,
    pub status: u16,
    /// For people, not for branching on. At most 512 characters (then cut, ending in `…`); a
    /// value the client sent appears cut to 64 the same way; server paths never appear.
    pub detail: String,
    /// Stable machine-readable code.
    pub code: String,
    /// The configured limit that was exceeded, when one was.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = u64)]
    pub limit: Option<u64>,
    /// The measured value that exceeded `limit`.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = u64)]
    pub actual: Option<u64>,
    /// Seconds to wait before retrying (also sent as `Retry-After`).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = u64)]
    pub retry_after: Option<u64>,
}

/// The job id's schema in the API document: what [`is_job_id`] accepts.
pub struct JobId;

impl utoipa::PartialSchema for JobId {
    fn schema() -> RefOr<Schema> {
        ObjectBuilder::new()
            .schema_type(Type::String)
            .pattern(Some("^job_[0-9a-f]{32}$"))
            .description(Some("`job_` + a UUIDv7 in hex; ids sort by creation time."))
            .into()
    }
}

impl ToSchema for JobId {}

/// Bytes in lowercase hex: digests, fingerprints and key ids.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|byte| format!("{byte:02x}")).collect()
}

/// The identity stored for an API key (the key itself never is).
pub fn key_id(key: &str) -> String {
    use sha2::Digest;
    hex(&sha2::Sha256::digest(key.as_bytes())[..12])
}

/// Job id: `job_` + a UUIDv7 in hex, so ids sort by creation time.
pub fn new_job_id() -> String {
    format!("job_{}", uuid::Uuid::now_v7().simple())
}

/// True for ids [`new_job_id`] could have made.
pub fn is_job_id(id: &str) -> bool {
    id.strip_prefix("job_").is_some_and(|hex| {
        hex.len() == 32
            && hex
                .bytes()
                .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
    })
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    Queued,
    Running,
    Succeeded,
    Failed,
    Canceled,
}

impl Status {
    pub fn name(self) -> &'static str {
        match self {
            Status::Queued => "queued",
            Status::Running => "running",
            Status::Succeeded => "succeeded",
            Status::Failed => "failed",
            Status::Canceled => "canceled",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        [
            Status::Queued,
            Status::Running,
            Status::Succeeded,
            Status::Failed,
            Status::Canceled,
        ]
        .into_iter()
        .find(|status| status.name() == name)
    }

    pub fn is_terminal(self) -> bool {
        matches!(self, Status::Succeeded | Status::Failed | Status::Canceled)
    }
}

/// How soon a job is wanted: `interactive` (someone is waiting: a web page) goes before `batch`
/// (bulk work that fills the rest); see [`super::fair`] for the rule and its ageing.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[schema(
    default = "interactive",
    description = "`interactive` (someone waits: a web page) runs before `batch` (bulk work \
        fills the rest); a batch job that has waited `--batch-age` counts as interactive."
)]
#[serde(rename_all = "lowercase")]
pub enum Priority {
    #[default]
    Interactive,
    Batch,
}

impl Priority {
    pub fn name(self) -> &'static str {
        match self {
            Priority::Interactive => "interactive",
            Priority::Batch => "batch",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        [Priority::Interactive, Priority::Batch]
            .into_iter()
            .find(|priority| priority.name() == name)
    }
}

/// Why a job was asked to stop.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum CancelReason {
    /// `POST /v1/jobs/{id}/cancel`.
    User,
    /// The per-job time limit passed.
    Deadline,
    /// The server stopped; the job is re-queued on the next start.
    Shutdown,
}

/// Which inputs were uploaded (the bytes are files in the job directory).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct InputManifest {
    pub albedo: bool,
    /// Number of binary masks (`input/mask-<n>`).
    pub masks: usize,
    pub labels: bool,
    /// The client accepted JPEGs cut short (`accept_truncated`).
    #[serde(default)]
    pub accept_truncated: bool,
}

/// Job progress as served (`progress` in the job resource and in events).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
#[schema(as = Progress)]
pub struct ProgressView {
    /// Fraction of the whole run done, 0-1.
    #[schema(minimum = 0, maximum = 1)]
    pub fraction: f32,
    pub stage: StageView,
    pub iteration: u32,
    pub iterations: u32,
    #[schema(required)]
    pub loss: Option<f32>,
    pub elapsed_seconds: f32,
    /// Estimated seconds to completion, from the elapsed time and `fraction`.
    #[schema(required)]
    pub eta_seconds: Option<f32>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, ToSchema)]
#[schema(as = Stage)]
pub struct StageView {
    pub name: String,
    /// 0-based.
    pub index: u32,
    pub count: u32,
}

impl From<&Progress> for ProgressView {
    fn from(progress: &Progress) -> Self {
        let fraction = progress.fraction();
        let elapsed = progress.elapsed.as_secs_f32();
        let eta_seconds = (fraction > 0.01).then(|| elapsed * (1.0 - fraction) / fraction);
        Self {
            fraction,
            stage: StageView {
                name: progress.stage.to_owned(),
                index: progress.stage_index,
                count: progress.stage_count,
            },
            iteration: progress.iteration,
            iterations: progress.iterations,
            loss: progress.loss.filter(|loss| loss.is_finite()),
            elapsed_seconds: elapsed,
            eta_seconds,
        }
    }
}

/// Everything known about a job; persisted as JSON in the job table.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JobRecord {
    pub id: String,
    /// Hash of the API key that created the job (`None` without keys).
    pub owner: Option<String>,
    /// Whose turn the job takes in the queue ([`super::auth::Client`]): the owner with API
    /// keys, else a hash of `X-Client-Key`; empty for anonymous requests (one key together).
    #[serde(default)]
    pub client: String,
    #[serde(default)]
    pub priority: Priority,
    pub status: Status,
    /// Unix milliseconds.
    pub created_at: u64,
    pub started_at: Option<u64>,
    pub completed_at: Option<u64>,
    /// When the results will be removed (set on completion).
    pub expires_at: Option<u64>,
    pub params: Params,
    pub inputs: InputManifest,
    /// The mode actually run, once known.
    pub mode: Option<Mode>,
    /// Why that mode (the request, or what `auto` saw in the image), once known.
    #[serde(default)]
    pub mode_reason: Option<String>,
    pub progress: Option<ProgressView>,
    /// Preview names (`<name>.png` under `previews/`), in the order the stages produced them.
    pub previews: Vec<String>,
    /// The stage after which the stored draft was made, once there is one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub draft: Option<String>,
    pub cancel_reason: Option<CancelReason>,
    /// A stop was asked for (by a user, the time limit or shutdown).
    #[serde(default)]
    pub cancel_requested: bool,
    pub error: Option<Problem>,
    pub idempotency: Option<Idempotency>,
    /// Results deleted after the retention period.
    pub data_removed: bool,
    /// SHA-256 (hex) of each result file by name, checked when it is served.
    #[serde(default)]
    pub checksums: BTreeMap<String, String>,
    /// Where to announce the job's events, and the deliveries so far.
    #[serde(default)]
    pub webhook: Option<Webhook>,
    /// Runs started by PostgreSQL workers (a run whose worker vanished counts; one stopped by
    /// shutdown does not). Always 0 on the embedded backend.
    #[serde(default)]
    pub attempts: u32,
    /// The uploaded image's file name as the client sent it ([`input_name`]), if any: results
    /// are offered for download under its stem.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub input_name: Option<String>,
}

/// A job's newest draft (the layered SVG after its latest stage that made one), replaced as
/// stages end.
pub const DRAFT_FILE: &str = "draft.svg";

/// The longest input file name kept, in characters.
const INPUT_NAME_CHARS: usize = 255;

/// A client's file name made safe to keep and show: its last path component (`/` or `\`), with
/// control characters dropped, at most [`INPUT_NAME_CHARS`] characters; `None` when nothing is
/// left.
pub fn input_name(sent: &str) -> Option<String> {
    let last = sent.rsplit(['/', '\\']).next().unwrap_or(sent);
    let name: String = last
        .chars()
        .filter(|c| !c.is_control())
        .take(INPUT_NAME_CHARS)
        .collect();
    let name = name.trim();
    (!name.is_empty() && name != "." && name != "..").then(|| name.to_owned())
}

impl JobRecord {
    /// A job just submitted, waiting in the queue; the submission's other details (owner,
    /// idempotency, webhook) are set on the result.
    pub fn queued(
        id: String,
        client: String,
        priority: Priority,
        params: Params,
        inputs: InputManifest,
    ) -> Self {
        Self {
            id,
            owner: None,
            client,
            priority,
            status: Status::Queued,
            created_at: now_ms(),
            started_at: None,
            completed_at: None,
            expires_at: None,
            params,
            inputs,
            mode: None,
            mode_reason: None,
            progress: None,
            previews: Vec::new(),
            draft: None,
            cancel_reason: None,
            cancel_requested: false,
            error: None,
            idempotency: None,
            data_removed: false,
            checksums: Default::default(),
            webhook: None,
            attempts: 0,
            input_name: None,
        }
    }

    /// What downloads of this job's results are named after: the uploaded file's name without
    /// its extension, or the job id when the client sent no name.
    pub fn download_stem(&self) -> String {
        let stem = self
            .input_name
            .as_deref()
            .map(|name| match name.rsplit_once('.') {
                Some((stem, _)) if !stem.is_empty() => stem,
                _ => name,
            });
        stem.unwrap_or(&self.id).to_owned()
    }

    /// Puts the job back in the queue for a re-run: what the last run produced is forgotten.
    pub fn requeue(&mut self) {
        self.status = Status::Queued;
        self.started_at = None;
        self.progress = None;
        self.cancel_requested = false;
        self.previews.clear();
        self.draft = None;
    }

    /// Marks the job ended (`status` terminal): when, until when its results are kept, why.
    pub fn end(
        &mut self,
        status: Status,
        error: Option<Problem>,
        reason: Option<CancelReason>,
        retention: Duration,
    ) {
        let now = now_ms();
        self.status = status;
        self.completed_at = Some(now);
        self.expires_at = Some(now + retention.as_millis() as u64);
        self.error = error;
        self.cancel_reason = reason;
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Idempotency {
    pub key: String,
    /// SHA-256 of the parameters and inputs.
    pub fingerprint: String,
}

/// A job's webhook: the URL and events its owner asked for, and every delivery made so far
/// (persisted with the job, so deliveries go on after a restart).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Webhook {
    pub url: String,
    pub events: Vec<WebhookEvent>,
    #[serde(default)]
    pub deliveries: Vec<Delivery>,
}

impl Webhook {
    /// Whether an event asked for is not yet delivered or given up.
    pub fn unfinished(&self) -> bool {
        self.events.iter().any(|event| {
            self.deliveries
                .iter()
                .find(|delivery| delivery.event == *event)
                .is_none_or(|delivery| delivery.status == DeliveryStatus::Pending)
        })
    }
}

/// What a webhook can announce.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum WebhookEvent {
    /// A worker took the job.
    Started,
    /// The job ended: succeeded, failed or canceled.
    Completed,
}

impl WebhookEvent {
    pub const ALL: [WebhookEvent; 2] = [WebhookEvent::Started, WebhookEvent::Completed];

    pub fn name(self) -> &'static str {
        match self {
            WebhookEvent::Started => "started",
            WebhookEvent::Completed => "completed",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|event| event.name() == name)
    }
}

/// One event's delivery: every attempt uses the same `webhook-id`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Delivery {
    pub id: String,
    pub event: WebhookEvent,
    pub status: DeliveryStatus,
    pub attempts: Vec<Attempt>,
    /// Unix milliseconds of the next attempt, while pending.
    pub next_attempt_at: Option<u64>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum DeliveryStatus {
    Pending,
    /// A 2xx answer.
    Delivered,
    /// Every attempt failed.
    Failed,
}

/// One POST to the webhook URL.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Attempt {
    /// Unix milliseconds.
    pub at: u64,
    /// The receiver's HTTP status, when it answered.
    pub status_code: Option<u16>,
    /// Why there was no answer (connection, timeout).
    pub error: Option<String>,
}

pub fn now_ms() -> u64 {
    jiff::Timestamp::now().as_millisecond().max(0) as u64
}

/// RFC 3339 UTC with milliseconds, e.g. `2026-11-22T03:20:33.123Z`.
pub fn rfc3339(unix_ms: u64) -> String {
    // Beyond jiff's range (year 9999) only from a corrupt record: shown as the latest instant.
    let instant = i64::try_from(unix_ms)
        .ok()
        .and_then(|ms| jiff::Timestamp::from_millisecond(ms).ok())
        .unwrap_or(jiff::Timestamp::MAX);
    format!("{instant:.3}")
}

/// Where a queued job stands: how many jobs start before it, and when it should start (Unix
/// milliseconds; `None` before any job has succeeded to estimate from).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Placement {
    pub position: usize,
    pub estimated_start_at: Option<u64>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rfc3339_formats_known_instants() {
        assert_eq!(rfc3339(0), "1970-01-01T00:00:00.000Z");
        assert_eq!(rfc3339(951_782_400_000), "2000-02-29T00:00:00.000Z");
        assert_eq!(rfc3339(1_795_318_833_123), "2026-11-22T03:40:33.123Z");
        // A corrupt record far in the future shows as the latest instant rather than panicking.
        assert_eq!(rfc3339(u64::MAX), "9999-12-30T22:00:00.999Z");
    }

    #[test]
    fn job_ids_are_recognised() {
        let id = new_job_id();
        assert!(is_job_id(&id), "{id}");
        assert!(!is_job_id("job_123"));
        assert!(!is_job_id(&id.to_uppercase()));
        assert!(!is_job_id("../etc/passwd"));
    }
}
