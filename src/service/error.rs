//! RFC 9457 problem details: the body of every error response, and of a failed job's `error`.
//!
//! Each [`ApiError`] variant has a stable `code` (also the last part of `type`), so clients branch
//! on the code, never on the human-readable `detail`.

use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};

use super::derived::DerivedError;
use super::inputs::InputError;
use super::job::JobFailure;
use super::model::Problem;
use super::queue::Refusal;
use super::rate::RateRefusal;
use super::store::StoreError;
use super::webhooks::WebhookRefusal;
use crate::imageio;
use crate::output::RasterError;

/// A response in the API document.
type DocResponse = utoipa::openapi::RefOr<utoipa::openapi::Response>;

/// Media type of every error body.
pub const PROBLEM_JSON: &str = "application/problem+json";

/// The response of every error status in the API document.
impl<'r> utoipa::ToResponse<'r> for Problem {
    fn response() -> (&'r str, DocResponse) {
        ("Problem", problem_response("An RFC 9457 problem.", false))
    }
}

/// 429 in the API document: a per-key limit, with `Retry-After`.
pub struct TooManyRequests;

impl<'r> utoipa::ToResponse<'r> for TooManyRequests {
    fn response() -> (&'r str, DocResponse) {
        let description = "The key has as many jobs queued as its limit allows (`key-queue-full`, \
            with `limit` and `actual`), or submitted faster than its rate (`rate-limited`, `limit` \
            in submissions per minute); other keys are unaffected. Retry after `Retry-After` seconds.";
        ("TooManyRequests", problem_response(description, true))
    }
}

/// 503 in the API document: retry later, with `Retry-After`.
pub struct Unavailable;

impl<'r> utoipa::ToResponse<'r> for Unavailable {
    fn response() -> (&'r str, DocResponse) {
        let description = "The queue is full (`queue-full`), every decode slot stayed busy \
            (`decode-busy`), the server is shutting down (`shutting-down`) or the job storage \
            (database, object store or disk) cannot be reached or is full for now \
            (`storage-unavailable`); retry after `Retry-After` seconds.";
        ("Unavailable", problem_response(description, true))
    }
}

/// The problems of every operation on one job (`/v1/jobs/{id}…`) in the API document: a
/// malformed id (400), no key (401), no such job (404), an expired one (410), and the job
/// storage out of reach (503 `storage-unavailable`).
pub struct JobProblems;

impl utoipa::IntoResponses for JobProblems {
    fn responses() -> std::collections::BTreeMap<String, DocResponse> {
        with_unavailable(problem_statuses(&[400, 401, 404, 410]))
    }
}

/// [`JobProblems`] and 409 `job-not-succeeded`: what every read of a job's results answers.
pub struct ResultProblems;

impl utoipa::IntoResponses for ResultProblems {
    fn responses() -> std::collections::BTreeMap<String, DocResponse> {
        with_unavailable(problem_statuses(&[400, 401, 404, 409, 410]))
    }
}

/// [`ResultProblems`] and 403 for a signed URL's token that is not this job's
/// (`token-invalid`) or has expired (`token-expired`): what every file of a job answers.
pub struct FileProblems;

impl utoipa::IntoResponses for FileProblems {
    fn responses() -> std::collections::BTreeMap<String, DocResponse> {
        with_unavailable(problem_statuses(&[400, 401, 403, 404, 409, 410]))
    }
}

/// `responses` and 503 ([`Unavailable`]).
fn with_unavailable(
    mut responses: std::collections::BTreeMap<String, DocResponse>,
) -> std::collections::BTreeMap<String, DocResponse> {
    let unavailable = utoipa::openapi::Ref::from_response_name("Unavailable");
    responses.insert("503".to_owned(), unavailable.into());
    responses
}

/// The [`Problem`] response under each of `statuses`.
fn problem_statuses(statuses: &[u16]) -> std::collections::BTreeMap<String, DocResponse> {
    statuses
        .iter()
        .map(|status| {
            let problem = utoipa::openapi::Ref::from_response_name("Problem");
            (status.to_string(), problem.into())
        })
        .collect()
}

/// A problem+json response, with the `Retry-After` header when `retry_after`.
fn problem_response(description: &str, retry_after: bool) -> DocResponse {
    use utoipa::openapi::{
        ContentBuilder, HeaderBuilder, ObjectBuilder, Ref, ResponseBuilder, Type,
    };
    let mut response = ResponseBuilder::new().description(description).content(
        PROBLEM_JSON,
        ContentBuilder::new()
            .schema(Some(Ref::from_schema_name("Problem")))
            .build(),
    );
    if retry_after {
        response = response.header(
            "Retry-After",
            HeaderBuilder::new()
                .schema(Some(
                    ObjectBuilder::new()
                        .schema_type(Type::Integer)
                        .minimum(Some(1)),
                ))
                .description(Some("Seconds to wait before retrying."))
                .build(),
        );
    }
    response.build().into()
}

/// Everything a request (or a job) can fail with.
#[derive(Debug, thiserror::Error)]
pub enum ApiError {
    #[error("this server needs `Authorization: Bearer <key>` with a configured API key")]
    Unauthorized,
    #[error("the URL's token is not one this server signed for this job's files")]
    TokenInvalid,
    #[error("the URL's token has expired; get a fresh one from the job resource")]
    TokenExpired,
    #[error("no job `{0}`")]
    JobNotFound(String),
    #[error("job `{0}` ended longer ago than this server keeps job records; its record is deleted")]
    JobExpired(String),
    #[error("`{0}` is not a job id (expected `job_` followed by 32 lowercase hex digits)")]
    MalformedJobId(String),
    #[error("no route for {0}")]
    RouteNotFound(String),
    #[error("method {0} is not allowed here")]
    MethodNotAllowed(String),
    #[error("no result `{0}` for this job")]
    ResultNotFound(String),
    #[error("content type `{0}` is not accepted: send multipart/form-data or application/json")]
    UnsupportedMediaType(String),
    #[error("the request body is larger than the limit of {limit} bytes")]
    BodyTooLarge { limit: u64 },
    #[error("the image has {actual} pixels, more than the limit of {limit}")]
    TooManyPixels { limit: u64, actual: u64 },
    #[error("{actual} masks were sent, more than the limit of {limit}")]
    TooManyMasks { limit: u64, actual: u64 },
    #[error(
        "the label map holds more than {limit} distinct values, each of which would be a mask; the limit is {limit}"
    )]
    TooManyLabels { limit: u64 },
    #[error(
        "the {0} is a JPEG cut short (it ends before its end-of-image marker); send `accept_truncated=true` to use it anyway, its missing part grey"
    )]
    TruncatedImage(&'static str),
    #[error("{actual} changes were sent, more than the limit of {limit} per edit")]
    TooManyChanges { limit: u64, actual: u64 },
    #[error("the decoded inputs reach {actual} bytes, more than the limit of {limit}")]
    InputsTooLarge { limit: u64, actual: u64 },
    #[error("malformed request: {0}")]
    BadRequest(String),
    #[error("invalid query: {0}")]
    BadQuery(String),
    #[error("the {0} could not be decoded: {1}")]
    UndecodableImage(&'static str, String),
    #[error("invalid parameters: {0}")]
    InvalidParams(String),
    #[error("invalid input: {0}")]
    InvalidInput(String),
    #[error("webhooks to `{0}` are not allowed by this server")]
    WebhookHostNotAllowed(String),
    #[error("this Idempotency-Key was used with a different request")]
    IdempotencyMismatch,
    #[error("the job queue is full ({0} jobs); retry later")]
    QueueFull(usize, u64),
    #[error("this key has {actual} jobs queued, its limit is {limit}; retry once one has started")]
    KeyQueueFull {
        limit: u64,
        actual: u64,
        retry_after: u64,
    },
    #[error("this key may submit {} jobs a minute; retry in {} s", .0.state.per_minute, .0.retry_after)]
    RateLimited(RateRefusal),
    #[error("every decoding slot stayed busy; retry in {0} s")]
    DecodeBusy(u64),
    #[error("the server is shutting down")]
    ShuttingDown,
    #[error("the job storage cannot be reached now ({0}); retry shortly")]
    StorageUnavailable(String),
    #[error("job `{0}` has status `{1}`; results exist once it has succeeded")]
    NotReady(String, &'static str),
    #[error("the results of job `{0}` were removed after the retention period")]
    DataRemoved(String),
    #[error("the job ran longer than the limit of {0} s and was stopped")]
    TimeLimit(u64),
    #[error("the pipeline failed unexpectedly: {0}")]
    PipelineCrashed(String),
    #[error(
        "the job's worker stopped without finishing it {0} times (each time its lease expired); it is not tried again"
    )]
    WorkersLost(u32),
    #[error(
        "the stored result `{0}` is damaged (it does not match the digest recorded when it was written)"
    )]
    CorruptResult(String),
    #[error("internal error: {0}")]
    Internal(String),
}

impl ApiError {
    pub fn status(&self) -> StatusCode {
        use ApiError::*;
        match self {
            Unauthorized => StatusCode::UNAUTHORIZED,
            TokenInvalid | TokenExpired => StatusCode::FORBIDDEN,
            JobNotFound(_) | RouteNotFound(_) | ResultNotFound(_) => StatusCode::NOT_FOUND,
            MalformedJobId(_) | BadRequest(_) | BadQuery(_) => StatusCode::BAD_REQUEST,
            MethodNotAllowed(_) => StatusCode::METHOD_NOT_ALLOWED,
            UnsupportedMediaType(_) => StatusCode::UNSUPPORTED_MEDIA_TYPE,
            BodyTooLarge { .. }
            | TooManyPixels { .. }
            | TooManyMasks { .. }
            | TooManyLabels { .. }
            | TooManyChanges { .. }
            | InputsTooLarge { .. } => StatusCode::PAYLOAD_TOO_LARGE,
            TruncatedImage(_)
            | UndecodableImage(..)
            | InvalidParams(_)
            | InvalidInput(_)
            | WebhookHostNotAllowed(_)
            | IdempotencyMismatch => StatusCode::UNPROCESSABLE_ENTITY,
            KeyQueueFull { .. } | RateLimited(_) => StatusCode::TOO_MANY_REQUESTS,
            QueueFull(..) | DecodeBusy(_) | ShuttingDown | StorageUnavailable(_) => {
                StatusCode::SERVICE_UNAVAILABLE
            }
            NotReady(..) => StatusCode::CONFLICT,
            DataRemoved(_) | JobExpired(_) => StatusCode::GONE,
            TimeLimit(_) => StatusCode::REQUEST_TIMEOUT,
            PipelineCrashed(_) | WorkersLost(_) | CorruptResult(_) | Internal(_) => {
                StatusCode::INTERNAL_SERVER_ERROR
            }
        }
    }

    /// The stable code; listed in api/openapi.yaml.
    pub fn code(&self) -> &'static str {
        use ApiError::*;
        match self {
            Unauthorized => "unauthorized",
            TokenInvalid => "token-invalid",
            TokenExpired => "token-expired",
            JobNotFound(_) => "job-not-found",
            JobExpired(_) => "job-expired",
            MalformedJobId(_) => "malformed-job-id",
            RouteNotFound(_) => "route-not-found",
            MethodNotAllowed(_) => "method-not-allowed",
            ResultNotFound(_) => "result-not-found",
            UnsupportedMediaType(_) => "unsupported-media-type",
            BodyTooLarge { .. } => "body-too-large",
            TooManyPixels { .. } => "too-many-pixels",
            TooManyMasks { .. } | TooManyLabels { .. } => "too-many-masks",
            TruncatedImage(_) => "truncated-image",
            InputsTooLarge { .. } => "inputs-too-large",
            TooManyChanges { .. } => "too-many-changes",
            BadRequest(_) => "bad-request",
            BadQuery(_) => "bad-query",
            UndecodableImage(..) => "undecodable-image",
            InvalidParams(_) => "invalid-params",
            InvalidInput(_) => "invalid-input",
            WebhookHostNotAllowed(_) => "webhook-host-not-allowed",
            IdempotencyMismatch => "idempotency-key-reused",
            QueueFull(..) => "queue-full",
            KeyQueueFull { .. } => "key-queue-full",
            RateLimited(_) => "rate-limited",
            DecodeBusy(_) => "decode-busy",
            ShuttingDown => "shutting-down",
            StorageUnavailable(_) => "storage-unavailable",
            NotReady(..) => "job-not-succeeded",
            DataRemoved(_) => "data-removed",
            TimeLimit(_) => "time-limit",
            PipelineCrashed(_) => "pipeline-crashed",
            WorkersLost(_) => "workers-lost",
            CorruptResult(_) => "result-corrupt",
            Internal(_) => "internal",
        }
    }

    fn retry_after(&self) -> Option<u64> {
        match self {
            ApiError::QueueFull(_, seconds)
            | ApiError::DecodeBusy(seconds)
            | ApiError::KeyQueueFull {
                retry_after: seconds,
                ..
            } => Some(*seconds),
            ApiError::RateLimited(refusal) => Some(refusal.retry_after),
            ApiError::ShuttingDown | ApiError::StorageUnavailable(_) => Some(5),
            _ => None,
        }
    }

    pub fn problem(&self) -> Problem {
        let status = self.status();
        let (limit, actual) = match self {
            ApiError::TooManyPixels { limit, actual }
            | ApiError::TooManyMasks { limit, actual }
            | ApiError::TooManyChanges { limit, actual }
            | ApiError::InputsTooLarge { limit, actual }
            | ApiError::KeyQueueFull { limit, actual, .. } => (Some(*limit), Some(*actual)),
            ApiError::BodyTooLarge { limit } | ApiError::TooManyLabels { limit } => {
                (Some(*limit), None)
            }
            ApiError::RateLimited(refusal) => (Some(u64::from(refusal.state.per_minute)), None),
            _ => (None, None),
        };
        Problem {
            kind: format!("urn:covec:problem:{}", self.code()),
            title: status.canonical_reason().unwrap_or("Error").to_owned(),
            status: status.as_u16(),
            detail: bounded(&self.to_string()),
            code: self.code().to_owned(),
            limit,
            actual,
            retry_after: self.retry_after(),
        }
    }
}

/// Longest client-sent value a `detail` echoes (between backticks): a 30 MB `mode` must not
/// come back whole.
const ECHO_CHARS: usize = 64;
/// Longest `detail`, for values echoed without backticks (paths, methods).
const DETAIL_CHARS: usize = 512;

/// `detail` with each backticked span cut to [`ECHO_CHARS`] and the whole to [`DETAIL_CHARS`].
fn bounded(detail: &str) -> String {
    let mut spans = String::with_capacity(detail.len().min(4 * DETAIL_CHARS));
    for (i, span) in detail.split('`').enumerate() {
        if i > 0 {
            spans.push('`');
        }
        // Odd spans are the quoted ones.
        spans.push_str(&clip(
            span,
            if i % 2 == 1 { ECHO_CHARS } else { DETAIL_CHARS },
        ));
    }
    clip(&spans, DETAIL_CHARS)
}

/// `text` cut to `max` characters, marked with `…` when cut.
fn clip(text: &str, max: usize) -> String {
    match text.char_indices().nth(max) {
        Some((end, _)) => format!("{}…", &text[..end]),
        None => text.to_owned(),
    }
}

/// A failure of the moment (the database or the store out of reach, a full disk) is 503
/// `storage-unavailable` with `Retry-After`: the same request may well succeed shortly.
impl From<StoreError> for ApiError {
    fn from(error: StoreError) -> Self {
        tracing::error!(%error, "storage error");
        if error.is_transient() {
            ApiError::StorageUnavailable(error.public_detail())
        } else {
            ApiError::Internal(error.public_detail())
        }
    }
}

/// Limits are 413, the rest 422.
impl From<InputError> for ApiError {
    fn from(error: InputError) -> Self {
        let (what, source) = match error {
            InputError::Refused { what, source } => (what, source),
            InputError::TooLarge { limit, actual } => {
                return ApiError::InputsTooLarge { limit, actual };
            }
            InputError::MasksAndLabels => return ApiError::InvalidInput(error.to_string()),
        };
        match source {
            imageio::InputError::Undecodable(detail) => ApiError::UndecodableImage(what, detail),
            imageio::InputError::TooManyPixels { pixels, max, .. } => ApiError::TooManyPixels {
                limit: max,
                actual: pixels,
            },
            imageio::InputError::TooManyMasks { count, max } => ApiError::TooManyMasks {
                limit: max as u64,
                actual: count as u64,
            },
            imageio::InputError::TooManyLabels { max } => {
                ApiError::TooManyLabels { limit: max as u64 }
            }
            imageio::InputError::Truncated => ApiError::TruncatedImage(what),
            aspect @ imageio::InputError::AspectRatio { .. } => {
                ApiError::InvalidInput(aspect.to_string())
            }
            // The last three come from pixels in memory, which the service never takes.
            other @ (imageio::InputError::Empty { .. }
            | imageio::InputError::NonBinaryMask { .. }
            | imageio::InputError::Channels(_)
            | imageio::InputError::SampleCount { .. }
            | imageio::InputError::FloatRange(_)) => {
                ApiError::InvalidInput(format!("{what}: {other}"))
            }
        }
    }
}

/// The problem a failed job's record keeps.
impl From<JobFailure> for Problem {
    fn from(failure: JobFailure) -> Self {
        ApiError::from(failure).problem()
    }
}

impl From<JobFailure> for ApiError {
    fn from(failure: JobFailure) -> Self {
        match failure {
            JobFailure::Input(error) => error.into(),
            JobFailure::Storage(error) => error.into(),
            JobFailure::MissingInputs => ApiError::Internal(failure.to_string()),
            JobFailure::TimeLimit(seconds) => ApiError::TimeLimit(seconds),
            JobFailure::InvalidParams(message) => ApiError::InvalidParams(message),
            JobFailure::Internal(message) => ApiError::Internal(message),
            JobFailure::Crashed(message) => ApiError::PipelineCrashed(message),
            JobFailure::WorkersLost(attempts) => ApiError::WorkersLost(attempts),
        }
    }
}

impl From<DerivedError> for ApiError {
    fn from(error: DerivedError) -> Self {
        match error {
            DerivedError::Refused(refusal) => refusal.into(),
            DerivedError::Raster(error) => match error {
                RasterError::ZeroWidth => ApiError::InvalidParams(error.to_string()),
                RasterError::TooManyPixels { actual, limit, .. } => {
                    ApiError::TooManyPixels { limit, actual }
                }
                RasterError::EmptyCanvas => ApiError::Internal(format!("stored scene: {error}")),
            },
            DerivedError::Scene(_) => ApiError::Internal(error.to_string()),
        }
    }
}

impl From<WebhookRefusal> for ApiError {
    fn from(refusal: WebhookRefusal) -> Self {
        match refusal {
            WebhookRefusal::Invalid(detail) => ApiError::InvalidParams(detail),
            WebhookRefusal::HostNotAllowed(host) => ApiError::WebhookHostNotAllowed(host),
        }
    }
}

impl From<Refusal> for ApiError {
    fn from(refusal: Refusal) -> Self {
        match refusal {
            Refusal::ShuttingDown => ApiError::ShuttingDown,
            Refusal::QueueFull {
                queued,
                retry_after,
            } => ApiError::QueueFull(queued, retry_after),
            Refusal::KeyQueueFull {
                limit,
                actual,
                retry_after,
            } => ApiError::KeyQueueFull {
                limit,
                actual,
                retry_after,
            },
            Refusal::IdempotencyMismatch => ApiError::IdempotencyMismatch,
            Refusal::CorruptResult(name) => ApiError::CorruptResult(name),
            Refusal::Storage(error) => error.into(),
        }
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let problem = self.problem();
        if self.status().is_server_error() {
            tracing::error!(code = self.code(), "{}", problem.detail);
        } else {
            tracing::debug!(code = self.code(), "{}", problem.detail);
        }
        let body = serde_json::to_vec(&problem).expect("a problem always serialises");
        let mut response = (self.status(), body).into_response();
        let headers = response.headers_mut();
        headers.insert(header::CONTENT_TYPE, HeaderValue::from_static(PROBLEM_JSON));
        if let Some(seconds) = problem.retry_after {
            headers.insert(header::RETRY_AFTER, HeaderValue::from(seconds));
        }
        if let ApiError::RateLimited(refusal) = &self {
            for (name, value) in refusal.state.fields() {
                headers.insert(name, HeaderValue::from_str(&value).expect("ASCII"));
            }
        }
        response
    }
}

/// Runs blocking work (the store, the database, decoding) on tokio's blocking threads, off the
/// async workers; its error, or a panic in it, becomes the answer's problem.
pub async fn off_async<T, E>(
    work: impl FnOnce() -> Result<T, E> + Send + 'static,
) -> Result<T, ApiError>
where
    T: Send + 'static,
    E: Send + 'static,
    ApiError: From<E>,
{
    match tokio::task::spawn_blocking(work).await {
        Ok(result) => result.map_err(ApiError::from),
        Err(error) => Err(ApiError::Internal(error.to_string())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn details_echo_client_strings_cut_short() {
        let mode = "x".repeat(100_000);
        let error = ApiError::InvalidParams(format!(
            "unknown variant `{mode}`, expected `photo` or `simple`"
        ));
        let detail = error.problem().detail;
        let cut = format!("`{}…`", "x".repeat(ECHO_CHARS));
        assert_eq!(
            detail,
            format!("invalid parameters: unknown variant {cut}, expected `photo` or `simple`")
        );
        let path = "/é".repeat(10_000);
        let detail = ApiError::RouteNotFound(path).problem().detail;
        assert_eq!(detail.chars().count(), DETAIL_CHARS + 1);
        assert!(detail.ends_with('…'));
        let short = ApiError::MalformedJobId("job_1".into()).problem().detail;
        assert!(short.starts_with("`job_1` is not a job id"), "{short}");
    }
}
