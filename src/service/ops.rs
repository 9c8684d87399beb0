//! Operations endpoints: `/healthz`, `/readyz`, `/metrics` (Prometheus text format, what
//! [`Metrics`] recorded), and the middleware that records every request.

use std::sync::Arc;
use std::time::Instant;

use axum::Router;
use axum::extract::{MatchedPath, Request, State};
use axum::http::{Method, StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::routing::get;

use super::backend::Workers;
use super::error::ApiError;
use super::model::Problem;
use super::state::{AppState, Endpoint, endpoint};
use super::store::StoreError;
use super::telemetry::{Metrics, QueueGauges};

/// The liveness probe's path, on the API port and on a worker's `--ops-addr`.
pub const LIVENESS_PATH: &str = "/healthz";

pub fn endpoints() -> Vec<Endpoint> {
    vec![
        endpoint(Method::GET, LIVENESS_PATH, healthz),
        endpoint(Method::GET, "/readyz", readyz),
        endpoint(Method::GET, "/metrics", metrics),
    ]
}

/// The worker's own HTTP port (`covec worker --ops-addr`), for probes and scraping:
/// `/healthz`, `/readyz` (storage reachable, every slot alive, not draining) and `/metrics`
/// (job durations and outcomes, `covec_workers`; the queue's depth is on the API replicas').
pub fn worker_app(workers: &Arc<Workers>) -> Router {
    async fn ready(State(workers): State<Arc<Workers>>) -> Response {
        let runner = Arc::clone(workers.runner());
        readiness(move || runner.store.check(), workers.is_ready()).await
    }
    async fn metrics(State(workers): State<Arc<Workers>>) -> Response {
        metrics_text(&workers.runner().metrics, None, workers.slots())
    }
    Router::new()
        .route(LIVENESS_PATH, get(healthz))
        .route("/readyz", get(ready))
        .route("/metrics", get(metrics))
        .with_state(Arc::clone(workers))
}

/// `covec serve --ops-addr`: the same `/healthz`, `/readyz` and `/metrics` as on the API port,
/// on a port of their own for probes and scraping, which then serves `/metrics` alone (an
/// Ingress or load balancer in front of the API port does not expose it).
pub fn serve_app(state: AppState) -> Router {
    async fn metrics(State(state): State<AppState>) -> Response {
        queue_metrics(&state)
    }
    Router::new()
        .route(LIVENESS_PATH, get(healthz))
        .route("/readyz", get(readyz))
        .route("/metrics", get(metrics))
        .with_state(state)
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
        `covec_http_request_duration_seconds{method,route}` (histogram). With `--ops-addr` \
        it is served on that port instead, and this one answers 404 `route-not-found`.",
    security(()),
    responses((status = 200, description = "Text exposition format 0.0.4.", body = String,
        content_type = "text/plain"),
        (status = 404, response = Problem)),
)]
async fn metrics(State(state): State<AppState>) -> Result<Response, ApiError> {
    if state.metrics_elsewhere {
        return Err(ApiError::RouteNotFound(
            "/metrics (served on the --ops-addr port)".into(),
        ));
    }
    Ok(queue_metrics(&state))
}

/// The API process's metrics, with the queue's gauges.
fn queue_metrics(state: &AppState) -> Response {
    metrics_text(
        &state.metrics,
        Some(state.queue.gauges()),
        state.queue.workers(),
    )
}

/// The `/metrics` answer: what `metrics` recorded, with the queue's gauges where known (API
/// processes) and the number of job workers.
pub fn metrics_text(metrics: &Metrics, queue: Option<QueueGauges>, workers: usize) -> Response {
    (
        [(
            header::CONTENT_TYPE,
            "text/plain; version=0.0.4; charset=utf-8",
        )],
        metrics.text(queue, workers),
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
