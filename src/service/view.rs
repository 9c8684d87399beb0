//! The job resource's public JSON: the job as `GET /v1/jobs/{id}` shows it, listings, events
//! and webhook bodies, made from the [`JobRecord`].

use serde::Serialize;
use utoipa::ToSchema;
use utoipa::openapi::{ObjectBuilder, Ref, RefOr, Schema, Type};

use super::model::{
    CancelReason, DRAFT_FILE, DeliveryStatus, JobId, JobRecord, Placement, Priority, Problem,
    ProgressView, Status, Webhook, WebhookEvent, now_ms, rfc3339,
};
use crate::pipeline::{Mode, Params};

/// The job resource as clients see it.
#[derive(Debug, Serialize, ToSchema)]
#[schema(as = Job)]
pub struct JobView {
    #[schema(value_type = JobId)]
    pub id: String,
    pub status: Status,
    pub priority: Priority,
    /// Jobs that start before this one by the fair rule if no other arrives, 0 = next (only
    /// while queued).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = u64)]
    pub queue_position: Option<usize>,
    /// Only while queued, once a job has succeeded since the server started: when this job
    /// should start if each job ahead takes the mean run time of the last 20 that succeeded, on
    /// as many workers as are busy now, the running jobs taken as half done.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = String, format = DateTime)]
    pub estimated_start_at: Option<String>,
    #[schema(format = DateTime)]
    pub created_at: String,
    #[schema(format = DateTime, required)]
    pub started_at: Option<String>,
    #[schema(format = DateTime, required)]
    pub completed_at: Option<String>,
    /// When the results will be removed.
    #[schema(format = DateTime, required)]
    pub expires_at: Option<String>,
    #[schema(required)]
    pub progress: Option<ProgressView>,
    pub params: Params,
    /// The mode actually run, once known.
    #[schema(required)]
    pub mode: Option<Mode>,
    /// Why that mode, once known: the request, or what `auto` saw in the image (flat artwork;
    /// smooth shading or photographic texture).
    #[schema(required)]
    pub mode_reason: Option<String>,
    /// A stop was asked for; a running job stops within one iteration.
    pub cancel_requested: bool,
    #[schema(required)]
    pub cancel_reason: Option<CancelReason>,
    /// Why the job failed.
    #[schema(required)]
    pub error: Option<Problem>,
    /// The results were removed after the retention period.
    pub data_removed: bool,
    pub previews: Vec<String>,
    /// The newest draft, once the first stages have made one.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = DraftView, required = false)]
    pub draft: Option<DraftView>,
    /// Present when the job was submitted with a webhook.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = WebhookView)]
    pub webhook: Option<WebhookView>,
    /// PostgreSQL backend only: runs started by workers (a run whose worker vanished counts;
    /// one stopped by shutdown does not).
    #[serde(skip_serializing_if = "is_zero")]
    #[schema(required = false, minimum = 1)]
    pub attempts: u32,
    /// The uploaded image's file name (the multipart part's `filename`, or the JSON
    /// submission's `filename`), when one was sent; downloads of the results are named after
    /// it (`Content-Disposition`).
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = String, required = false)]
    pub input_name: Option<String>,
    pub urls: Urls,
    /// Present on a server with API keys, to the key that owns the job: a token that opens
    /// this job's files without the `Authorization` header, for a browser's `<img>`, `<a
    /// download>` and other requests that cannot send it.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = SignedUrls, required = false)]
    pub signed: Option<SignedUrls>,
}

/// A running job's result so far: the whole layered SVG (albedo, shade, light) as the run has
/// it after `stage`, made as soon as the initialisation ends and again as the structure,
/// reconstruction and refinement stages end (then the result itself follows). Coarse at first,
/// improving with each stage.
#[derive(Debug, Serialize, ToSchema)]
pub struct DraftView {
    /// The stage after which it was made (`init`, `structure`, …).
    pub stage: String,
    /// The draft's SVG; each new draft replaces it at this URL (`ETag` changes, `no-cache`
    /// while the job runs).
    pub url: String,
}

/// Signed URLs of a job's files: each opens that file, and nothing else, without a key until
/// `expires_at` (then 403 `token-expired`; another job's file: 403 `token-invalid`).
#[derive(Debug, Serialize, ToSchema)]
pub struct SignedUrls {
    /// Add it as `token=<token>` to the query of any of this job's file URLs: the results,
    /// layers, stage previews (`/previews/<name>.png`) and an edit's files (`svg`, `pdf`, `png`,
    /// `scene.json`, `preview.png`). Not the job resource, its events or an edit's record.
    pub token: String,
    /// When the token stops working (15 minutes or more after it was handed out, by
    /// `--signed-url-ttl`); ask for the job again for a fresh one.
    #[schema(format = DateTime)]
    pub expires_at: String,
    /// The result URLs with the token, once the job has succeeded.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = ResultUrls)]
    pub results: Option<ResultUrls>,
}

/// One page of `GET /v1/jobs`.
#[derive(Debug, Serialize, ToSchema)]
pub struct JobList {
    pub items: Vec<JobView>,
    /// Pass as `cursor` for the next page; null on the last page.
    #[schema(value_type = Option<JobId>, required)]
    pub next_cursor: Option<String>,
}

/// One event of `GET /v1/jobs/{id}/events` in the API document; the stream itself is written
/// by axum's [`Sse`](axum::response::sse::Sse).
pub struct JobEvent;

impl utoipa::PartialSchema for JobEvent {
    fn schema() -> RefOr<Schema> {
        let job = Ref::from_schema_name(JobView::name());
        ObjectBuilder::new()
            .description(Some("One event (keep-alive comments are not events)."))
            .property("id", ObjectBuilder::new().schema_type(Type::String))
            .property(
                "event",
                ObjectBuilder::new()
                    .schema_type(Type::String)
                    .enum_values(Some(["progress", "draft", "completed"])),
            )
            .property(
                "data",
                ObjectBuilder::new()
                    .schema_type(Type::String)
                    .content_media_type("application/json")
                    .content_schema(Some(job)),
            )
            .required("event")
            .required("data")
            .into()
    }
}

impl ToSchema for JobEvent {}

/// The `Idempotent-Replayed` header in the API document: `true` when present.
pub struct IdempotentReplayed;

impl utoipa::PartialSchema for IdempotentReplayed {
    fn schema() -> RefOr<Schema> {
        ObjectBuilder::new()
            .schema_type(Type::String)
            .enum_values(Some(["true"]))
            .into()
    }
}

impl ToSchema for IdempotentReplayed {}

/// A job's webhook as served: deliveries with their attempts, times in RFC 3339.
#[derive(Debug, Serialize, ToSchema)]
#[schema(as = Webhook)]
pub struct WebhookView {
    pub url: String,
    pub events: Vec<WebhookEvent>,
    /// One per event that has happened; every attempt of one uses the same `webhook-id` (`id`).
    pub deliveries: Vec<DeliveryView>,
}

#[derive(Debug, Serialize, ToSchema)]
#[schema(as = Delivery)]
pub struct DeliveryView {
    /// The `webhook-id` header.
    pub id: String,
    pub event: WebhookEvent,
    pub status: DeliveryStatus,
    pub attempts: Vec<AttemptView>,
    #[schema(format = DateTime, required)]
    pub next_attempt_at: Option<String>,
}

#[derive(Debug, Serialize, ToSchema)]
#[schema(as = DeliveryAttempt)]
pub struct AttemptView {
    #[schema(format = DateTime)]
    pub at: String,
    /// The receiver's HTTP status.
    #[schema(required)]
    pub status_code: Option<u16>,
    /// Why there was no answer.
    #[schema(required)]
    pub error: Option<String>,
}

impl From<&Webhook> for WebhookView {
    fn from(webhook: &Webhook) -> Self {
        Self {
            url: webhook.url.clone(),
            events: webhook.events.clone(),
            deliveries: webhook
                .deliveries
                .iter()
                .map(|delivery| DeliveryView {
                    id: delivery.id.clone(),
                    event: delivery.event,
                    status: delivery.status,
                    attempts: delivery
                        .attempts
                        .iter()
                        .map(|attempt| AttemptView {
                            at: rfc3339(attempt.at),
                            status_code: attempt.status_code,
                            error: attempt.error.clone(),
                        })
                        .collect(),
                    next_attempt_at: delivery.next_attempt_at.map(rfc3339),
                })
                .collect(),
        }
    }
}

/// The body of a webhook delivery: the event and the job as `GET /v1/jobs/{id}` shows it,
/// without its webhook deliveries (those change with every attempt; the body stays the same).
#[derive(Debug, Serialize, ToSchema)]
pub struct WebhookMessage {
    /// `job.started` or `job.completed`.
    #[serde(rename = "type")]
    #[schema(pattern = "^job\\.(started|completed)$", example = "job.completed")]
    pub kind: String,
    /// When the event happened (the job's `started_at` or `completed_at`).
    #[schema(format = DateTime)]
    pub timestamp: String,
    pub data: JobView,
}

impl WebhookMessage {
    pub fn new(record: &JobRecord, event: WebhookEvent) -> Self {
        let mut job = record.clone();
        job.webhook = None;
        let at = match event {
            WebhookEvent::Started => job.started_at,
            WebhookEvent::Completed => job.completed_at,
        };
        Self {
            kind: format!("job.{}", event.name()),
            timestamp: rfc3339(at.unwrap_or_else(now_ms)),
            data: JobView::new(&job, None),
        }
    }
}

/// Where the job's resources are.
#[derive(Debug, Serialize, ToSchema)]
#[schema(as = JobUrls)]
pub struct Urls {
    #[serde(rename = "self")]
    pub job: String,
    pub events: String,
    pub cancel: String,
    pub previews: String,
    /// Result links, present once the job has succeeded.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schema(value_type = ResultUrls)]
    pub results: Option<ResultUrls>,
}

/// Every format of a succeeded job's result.
#[derive(Debug, Serialize, ToSchema)]
pub struct ResultUrls {
    /// The layered SVG (albedo, shade with `multiply`, light with `plus-lighter`).
    pub svg: String,
    /// The same picture as plain opaque paths, for programs without those blend modes.
    pub flat_svg: String,
    /// A vector PDF of the flattened picture.
    pub pdf: String,
    /// A PNG drawn by covec's renderer at the original width (add `?width=N` for another).
    pub png: String,
    /// The JSON scene, which `covec render` and `covec edit` load losslessly.
    pub scene: String,
    /// The albedo layer alone.
    pub albedo: String,
    /// The shade layer alone.
    pub shade: String,
    /// The light layer alone.
    pub light: String,
}

impl ResultUrls {
    fn of(base: &str) -> Self {
        Self {
            svg: format!("{base}/svg"),
            flat_svg: format!("{base}/svg?flatten=true"),
            pdf: format!("{base}/pdf"),
            png: format!("{base}/png"),
            scene: format!("{base}/scene.json"),
            albedo: format!("{base}/layers/albedo.svg"),
            shade: format!("{base}/layers/shade.svg"),
            light: format!("{base}/layers/light.svg"),
        }
    }

    /// Each URL through `sign`.
    pub fn signed(&self, sign: impl Fn(&str) -> String) -> Self {
        Self {
            svg: sign(&self.svg),
            flat_svg: sign(&self.flat_svg),
            pdf: sign(&self.pdf),
            png: sign(&self.png),
            scene: sign(&self.scene),
            albedo: sign(&self.albedo),
            shade: sign(&self.shade),
            light: sign(&self.light),
        }
    }
}

impl JobView {
    pub fn new(record: &JobRecord, placement: Option<Placement>) -> Self {
        let base = format!("/v1/jobs/{}", record.id);
        let results = (record.status == Status::Succeeded && !record.data_removed)
            .then(|| ResultUrls::of(&base));
        Self {
            id: record.id.clone(),
            status: record.status,
            priority: record.priority,
            queue_position: placement.map(|placement| placement.position),
            estimated_start_at: placement
                .and_then(|placement| placement.estimated_start_at)
                .map(rfc3339),
            created_at: rfc3339(record.created_at),
            started_at: record.started_at.map(rfc3339),
            completed_at: record.completed_at.map(rfc3339),
            expires_at: record.expires_at.map(rfc3339),
            progress: record.progress.clone(),
            params: record.params.clone(),
            mode: record.mode,
            mode_reason: record.mode_reason.clone(),
            cancel_requested: record.cancel_requested,
            cancel_reason: record.cancel_reason,
            error: record.error.clone(),
            data_removed: record.data_removed,
            previews: record.previews.clone(),
            draft: (!record.data_removed)
                .then_some(record.draft.as_ref())
                .flatten()
                .map(|stage| DraftView {
                    stage: stage.clone(),
                    url: format!("{base}/{DRAFT_FILE}"),
                }),
            webhook: record.webhook.as_ref().map(WebhookView::from),
            attempts: record.attempts,
            input_name: record.input_name.clone(),
            urls: Urls {
                events: format!("{base}/events"),
                cancel: format!("{base}/cancel"),
                previews: format!("{base}/previews"),
                results,
                job: base,
            },
            signed: None,
        }
    }
}

fn is_zero(count: &u32) -> bool {
    *count == 0
}
