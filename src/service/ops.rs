//! Operations endpoints: `/healthz`, `/readyz`, `/metrics` (Prometheus text format).
//!
//! Metrics go through the `metrics` facade into a Prometheus recorder of this service's own
//! (not the process-wide one: each [`Metrics`] is one server's), which renders the text.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use axum::extract::{MatchedPath, Request, State};
use axum::http::{Method, StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use metrics_exporter_prometheus::{Matcher, PrometheusBuilder, PrometheusRecorder};

use super::store::StoreError;
use super::{AppState, Endpoint, endpoint};

/// The liveness probe's path, on the API port and on a worker's `--ops-addr`.
pub const LIVENESS_PATH: &str = "/healthz";

pub fn endpoints() -> Vec<Endpoint> {
    vec![
        endpoint(Method::GET, LIVENESS_PATH, healthz),
        endpoint(Method::GET, "/readyz", readyz),
        endpoint(Method::GET, "/metrics", metrics),
    ]
}

/// Liveness: the process answers.
#[utoipa::path(get, path = "/healthz", tag = "operations", operation_id = "healthz",
    summary = "Liveness", security(()),
    responses((status = 200, description = "The process answers.", body = Liveness)),
)]
pub async fn healthz() -> impl IntoResponse {
    axum::Json(Liveness {
        status: LivenessStatus::Ok,
    })
}

/// The answer of `/healthz`.
#[derive(serde::Serialize, utoipa::ToSchema)]
pub struct Liveness {
    status: LivenessStatus,
}

#[derive(serde::Serialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
enum LivenessStatus {
    Ok,
}

/// The answer of `/readyz` (and a worker's ready probe).
#[derive(serde::Serialize, utoipa::ToSchema)]
pub struct Readiness {
    status: ReadinessStatus,
    /// `ok`, or why storage is not writable.
    storage: String,
    /// `ok`, or why not every worker is alive.
    workers: String,
}

#[derive(serde::Serialize, utoipa::ToSchema)]
enum ReadinessStatus {
    #[serde(rename = "ready")]
    Ready,
    #[serde(rename = "not ready")]
    NotReady,
}

/// Readiness: storage writable, every worker alive, not shutting down.
#[utoipa::path(get, path = "/readyz", tag = "operations", operation_id = "readyz",
    summary = "Readiness (storage writable, every worker alive, not shutting down)", security(()),
    responses(
        (status = 200, description = "Ready for work.", body = Readiness),
        (status = 503, description = "Not ready.", body = Readiness),
    ),
)]
async fn readyz(State(state): State<AppState>) -> Response {
    let queue = state.queue.clone();
    readiness(move || queue.store().check(), state.queue.is_ready()).await
}

/// The readiness answer (API and worker): 200 when `check_storage` passes (run off the async
/// threads) and `workers` are alive, else 503 saying which is not.
pub async fn readiness(
    check_storage: impl FnOnce() -> Result<(), StoreError> + Send + 'static,
    workers: bool,
) -> Response {
    let storage =
        tokio::task::spawn_blocking(move || check_storage().map_err(|error| error.public_detail()))
            .await
            .unwrap_or_else(|error| Err(error.to_string()));
    let ready = storage.is_ok() && workers;
    let body = Readiness {
        status: if ready {
            ReadinessStatus::Ready
        } else {
            ReadinessStatus::NotReady
        },
        storage: storage.err().unwrap_or_else(|| "ok".into()),
        workers: if workers {
            "ok"
        } else {
            "draining or a worker stopped"
        }
        .into(),
    };
    let status = if ready {
        StatusCode::OK
    } else {
        StatusCode::SERVICE_UNAVAILABLE
    };
    (status, axum::Json(body)).into_response()
}

#[utoipa::path(get, path = "/metrics", tag = "operations", operation_id = "metrics",
    summary = "Prometheus metrics",
    description = "`covec_jobs_queued`, `covec_jobs_running`, `covec_workers` (gauges), \
        `covec_job_duration_seconds{outcome}` (histogram), \
        `covec_http_requests_total{method,route,status}` (counter), \
        `covec_http_request_duration_seconds{method,route}` (histogram).",
    security(()),
    responses((status = 200, description = "Text exposition format 0.0.4.", body = String,
        content_type = "text/plain")),
)]
async fn metrics(State(state): State<AppState>) -> Response {
    let (queued, running) = state.queue.depth();
    let queue = QueueGauges {
        queued,
        running,
        in_memory: state.queue.in_memory(),
    };
    metrics_text(&state.metrics, Some(queue), state.queue.workers())
}

/// What an API process's queue shows on `/metrics`.
pub struct QueueGauges {
    pub queued: usize,
    pub running: usize,
    /// Jobs whose state is held in memory: the live ones and ended ones in use (the rest are
    /// read from the store when asked for).
    pub in_memory: usize,
}

/// The `/metrics` answer: what `metrics` recorded, with the queue's gauges where known (API
/// processes) and the number of job workers.
pub fn metrics_text(metrics: &Metrics, queue: Option<QueueGauges>, workers: usize) -> Response {
    let mut gauges = vec![(WORKERS, workers as f64)];
    if let Some(queue) = queue {
        gauges.extend([
            (JOBS_QUEUED, queue.queued as f64),
            (JOBS_RUNNING, queue.running as f64),
            (JOBS_IN_MEMORY, queue.in_memory as f64),
        ]);
    }
    (
        [(
            header::CONTENT_TYPE,
            "text/plain; version=0.0.4; charset=utf-8",
        )],
        metrics.render(&gauges),
    )
        .into_response()
}

/// Records every request's route, status and latency.
pub async fn record_http(State(state): State<AppState>, request: Request, next: Next) -> Response {
    let method = method_label(request.method());
    // The matched template (`/v1/jobs/{id}`), never the raw path: one series per route.
    let route = request
        .extensions()
        .get::<MatchedPath>()
        .map_or_else(|| "unmatched".to_owned(), |path| path.as_str().to_owned());
    let started = Instant::now();
    let response = next.run(request).await;
    state
        .metrics
        .http_request(method, route, response.status().as_u16(), started.elapsed());
    response
}

/// The `method` label: clients may send any token as a method, and one series per token would
/// grow `/metrics` without bound, so unknown methods share the label `other`.
fn method_label(method: &Method) -> &'static str {
    const KNOWN: [&str; 7] = ["GET", "POST", "PUT", "DELETE", "PATCH", "HEAD", "OPTIONS"];
    KNOWN
        .into_iter()
        .find(|known| *known == method.as_str())
        .unwrap_or("other")
}

const JOBS_QUEUED: &str = "covec_jobs_queued";
const JOBS_RUNNING: &str = "covec_jobs_running";
const JOBS_IN_MEMORY: &str = "covec_jobs_in_memory";
const WORKERS: &str = "covec_workers";
const JOBS_QUARANTINED: &str = "covec_jobs_quarantined";
const ORPHANS_SWEPT: &str = "covec_orphans_swept_total";
const JOB_DURATION: &str = "covec_job_duration_seconds";
const HTTP_REQUESTS: &str = "covec_http_requests_total";
const HTTP_DURATION: &str = "covec_http_request_duration_seconds";

const HTTP_BUCKETS: &[f64] = &[
    0.001, 0.0025, 0.005, 0.01, 0.02, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 10.0,
];
const JOB_BUCKETS: &[f64] = &[
    0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0, 120.0, 300.0, 600.0, 1800.0,
];

/// How often recorded histogram samples are folded into their buckets. The recorder keeps them
/// until a scrape or this: without it, a server nobody scrapes would hold every request's.
const UPKEEP_PERIOD: Duration = Duration::from_secs(5);

/// One server's metrics: what the service records, rendered on `/metrics`.
pub struct Metrics {
    recorder: PrometheusRecorder,
    /// Sum of seconds and count of succeeded jobs, for `Retry-After` estimates (the recorder
    /// renders its histograms but does not read them back).
    succeeded: Mutex<(f64, u64)>,
}

impl Default for Metrics {
    fn default() -> Self {
        let recorder = PrometheusBuilder::new()
            .set_buckets_for_metric(Matcher::Full(HTTP_DURATION.into()), HTTP_BUCKETS)
            .and_then(|builder| {
                builder.set_buckets_for_metric(Matcher::Full(JOB_DURATION.into()), JOB_BUCKETS)
            })
            .expect("bucket lists are not empty")
            .build_recorder();
        metrics::with_local_recorder(&recorder, || {
            metrics::describe_gauge!(JOBS_QUEUED, "Jobs waiting for a worker.");
            metrics::describe_gauge!(JOBS_RUNNING, "Jobs being run.");
            metrics::describe_gauge!(
                JOBS_IN_MEMORY,
                "Jobs held in memory: queued, running, and ended ones in use."
            );
            metrics::describe_gauge!(WORKERS, "Configured job workers.");
            metrics::describe_gauge!(
                JOBS_QUARANTINED,
                "Unreadable job records moved to quarantine since start."
            );
            metrics::describe_counter!(ORPHANS_SWEPT, "Job directories without a job removed.");
            metrics::describe_histogram!(JOB_DURATION, "Run time of finished jobs by outcome.");
            metrics::describe_counter!(HTTP_REQUESTS, "HTTP requests by route and status.");
            metrics::describe_histogram!(HTTP_DURATION, "HTTP latency by route.");
            // Present from the start, so a dashboard sees 0 rather than no series.
            metrics::gauge!(JOBS_QUARANTINED).set(0.0);
            metrics::counter!(ORPHANS_SWEPT).increment(0);
        });
        Self {
            recorder,
            succeeded: Mutex::new((0.0, 0)),
        }
    }
}

impl Metrics {
    fn http_request(&self, method: &'static str, route: String, status: u16, elapsed: Duration) {
        metrics::with_local_recorder(&self.recorder, || {
            metrics::counter!(HTTP_REQUESTS, "method" => method, "route" => route.clone(), "status" => status.to_string())
                .increment(1);
            metrics::histogram!(HTTP_DURATION, "method" => method, "route" => route)
                .record(elapsed.as_secs_f64());
        });
    }

    pub fn job_finished(&self, outcome: &'static str, elapsed: Duration) {
        let seconds = elapsed.as_secs_f64();
        metrics::with_local_recorder(&self.recorder, || {
            metrics::histogram!(JOB_DURATION, "outcome" => outcome).record(seconds);
        });
        if outcome == "succeeded" {
            let mut succeeded = self.succeeded.lock().unwrap_or_else(|p| p.into_inner());
            succeeded.0 += seconds;
            succeeded.1 += 1;
        }
    }

    /// Counts records moved to quarantine: at start, or when an ended one is first read.
    pub fn quarantined(&self, count: usize) {
        metrics::with_local_recorder(&self.recorder, || {
            metrics::gauge!(JOBS_QUARANTINED).increment(count as f64);
        });
    }

    pub fn orphans_swept(&self, count: usize) {
        metrics::with_local_recorder(&self.recorder, || {
            metrics::counter!(ORPHANS_SWEPT).increment(count as u64);
        });
    }

    /// Mean run time of succeeded jobs, for `Retry-After` estimates.
    pub fn mean_job_seconds(&self) -> Option<f64> {
        let (sum, count) = *self.succeeded.lock().unwrap_or_else(|p| p.into_inner());
        (count > 0).then(|| sum / count as f64)
    }

    /// The Prometheus text, with `gauges` (name, value) read at scrape time set first.
    fn render(&self, gauges: &[(&'static str, f64)]) -> String {
        metrics::with_local_recorder(&self.recorder, || {
            for &(name, value) in gauges {
                metrics::gauge!(name).set(value);
            }
        });
        self.recorder.handle().render()
    }
}

/// Runs the recorder's upkeep every [`UPKEEP_PERIOD`], for as long as the server runs.
pub async fn upkeep(metrics: Arc<Metrics>) {
    let handle = metrics.recorder.handle();
    let mut ticks = tokio::time::interval(UPKEEP_PERIOD);
    loop {
        ticks.tick().await;
        handle.run_upkeep();
    }
}
