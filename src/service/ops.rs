//! Operations endpoints: `/healthz`, `/readyz`, `/metrics` (Prometheus text format).
//!
//! The metrics are a handful of hand-kept counters and histograms; a metrics crate would add
//! a registry and a dependency tree for the same few lines of text.

use std::collections::BTreeMap;
use std::fmt::Write;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use axum::extract::{MatchedPath, Request, State};
use axum::http::{Method, StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use super::{AppState, Endpoint, endpoint};

pub fn endpoints() -> Vec<Endpoint> {
    vec![
        endpoint(Method::GET, "/healthz", healthz),
        endpoint(Method::GET, "/readyz", readyz),
        endpoint(Method::GET, "/metrics", metrics),
    ]
}

/// Liveness: the process answers.
async fn healthz() -> impl IntoResponse {
    axum::Json(serde_json::json!({ "status": "ok" }))
}

/// Readiness: storage writable, every worker alive, not shutting down.
async fn readyz(State(state): State<AppState>) -> Response {
    let queue = state.queue.clone();
    let storage = tokio::task::spawn_blocking(move || {
        queue.store().check().map_err(|error| error.public_detail())
    })
    .await
    .unwrap_or_else(|error| Err(error.to_string()));
    let workers = state.queue.is_ready();
    let ready = storage.is_ok() && workers;
    let body = serde_json::json!({
        "status": if ready { "ready" } else { "not ready" },
        "storage": storage.err().unwrap_or_else(|| "ok".into()),
        "workers": if workers { "ok" } else { "draining or a worker stopped" },
    });
    let status = if ready {
        StatusCode::OK
    } else {
        StatusCode::SERVICE_UNAVAILABLE
    };
    (status, axum::Json(body)).into_response()
}

async fn metrics(State(state): State<AppState>) -> Response {
    let (queued, running) = state.queue.depth();
    let mut text = String::new();
    let _ = writeln!(
        text,
        "# HELP covec_jobs_queued Jobs waiting for a worker.\n# TYPE covec_jobs_queued gauge"
    );
    let _ = writeln!(text, "covec_jobs_queued {queued}");
    let _ = writeln!(
        text,
        "# HELP covec_jobs_running Jobs being run.\n# TYPE covec_jobs_running gauge"
    );
    let _ = writeln!(text, "covec_jobs_running {running}");
    let _ = writeln!(
        text,
        "# HELP covec_workers Configured job workers.\n# TYPE covec_workers gauge"
    );
    let _ = writeln!(text, "covec_workers {}", state.queue.workers());
    state.metrics.write(&mut text);
    (
        [(
            header::CONTENT_TYPE,
            "text/plain; version=0.0.4; charset=utf-8",
        )],
        text,
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
    state.metrics.http_request(
        method,
        &route,
        response.status().as_u16(),
        started.elapsed(),
    );
    response
}

/// The `method` label: clients may send any token as a method, and one series per token would
/// grow `/metrics` without bound (issue 13), so unknown methods share the label `other`.
fn method_label(method: &Method) -> &'static str {
    const KNOWN: [&str; 7] = ["GET", "POST", "PUT", "DELETE", "PATCH", "HEAD", "OPTIONS"];
    KNOWN
        .into_iter()
        .find(|known| *known == method.as_str())
        .unwrap_or("other")
}

const HTTP_BUCKETS: &[f64] = &[
    0.001, 0.0025, 0.005, 0.01, 0.02, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 10.0,
];
const JOB_BUCKETS: &[f64] = &[
    0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0, 120.0, 300.0, 600.0, 1800.0,
];

#[derive(Default)]
struct Histogram {
    /// Cumulative counts per bucket bound.
    buckets: Vec<u64>,
    sum: f64,
    count: u64,
}

impl Histogram {
    fn observe(&mut self, bounds: &[f64], value: f64) {
        self.buckets.resize(bounds.len(), 0);
        for (bucket, bound) in self.buckets.iter_mut().zip(bounds) {
            if value <= *bound {
                *bucket += 1;
            }
        }
        self.sum += value;
        self.count += 1;
    }

    fn write(&self, text: &mut String, name: &str, labels: &str, bounds: &[f64]) {
        let separator = if labels.is_empty() { "" } else { "," };
        for (bound, count) in bounds.iter().zip(&self.buckets) {
            let _ = writeln!(
                text,
                "{name}_bucket{{{labels}{separator}le=\"{bound}\"}} {count}"
            );
        }
        let _ = writeln!(
            text,
            "{name}_bucket{{{labels}{separator}le=\"+Inf\"}} {}",
            self.count
        );
        let _ = writeln!(text, "{name}_sum{{{labels}}} {}", self.sum);
        let _ = writeln!(text, "{name}_count{{{labels}}} {}", self.count);
    }
}

#[derive(Default)]
struct HttpStats {
    /// (method, route) → latency.
    latency: BTreeMap<(String, String), Histogram>,
    /// (method, route, status) → requests.
    requests: BTreeMap<(String, String, u16), u64>,
}

#[derive(Default)]
pub struct Metrics {
    http: Mutex<HttpStats>,
    /// Outcome → run duration.
    jobs: Mutex<BTreeMap<&'static str, Histogram>>,
    /// Unreadable job records moved to quarantine at start.
    quarantined: AtomicU64,
    /// Orphaned job directories removed since start.
    orphans_swept: AtomicU64,
}

impl Metrics {
    fn http_request(&self, method: &str, route: &str, status: u16, elapsed: Duration) {
        let mut http = self.http.lock().unwrap_or_else(|p| p.into_inner());
        let key = (method.to_owned(), route.to_owned());
        http.latency
            .entry(key.clone())
            .or_default()
            .observe(HTTP_BUCKETS, elapsed.as_secs_f64());
        *http.requests.entry((key.0, key.1, status)).or_default() += 1;
    }

    pub fn job_finished(&self, outcome: &'static str, elapsed: Duration) {
        let mut jobs = self.jobs.lock().unwrap_or_else(|p| p.into_inner());
        jobs.entry(outcome)
            .or_default()
            .observe(JOB_BUCKETS, elapsed.as_secs_f64());
    }

    pub fn set_quarantined(&self, count: usize) {
        self.quarantined.store(count as u64, Ordering::Relaxed);
    }

    pub fn orphans_swept(&self, count: usize) {
        self.orphans_swept
            .fetch_add(count as u64, Ordering::Relaxed);
    }

    /// Mean run time of succeeded jobs, for `Retry-After` estimates.
    pub fn mean_job_seconds(&self) -> Option<f64> {
        let jobs = self.jobs.lock().unwrap_or_else(|p| p.into_inner());
        jobs.get("succeeded")
            .filter(|h| h.count > 0)
            .map(|h| h.sum / h.count as f64)
    }

    fn write(&self, text: &mut String) {
        let _ = writeln!(
            text,
            "# HELP covec_jobs_quarantined Unreadable job records moved to quarantine at start.\n# TYPE covec_jobs_quarantined gauge\ncovec_jobs_quarantined {}",
            self.quarantined.load(Ordering::Relaxed)
        );
        let _ = writeln!(
            text,
            "# HELP covec_orphans_swept_total Job directories without a job removed.\n# TYPE covec_orphans_swept_total counter\ncovec_orphans_swept_total {}",
            self.orphans_swept.load(Ordering::Relaxed)
        );
        let jobs = self.jobs.lock().unwrap_or_else(|p| p.into_inner());
        let _ = writeln!(
            text,
            "# HELP covec_job_duration_seconds Run time of finished jobs by outcome.\n# TYPE covec_job_duration_seconds histogram"
        );
        for (outcome, histogram) in jobs.iter() {
            histogram.write(
                text,
                "covec_job_duration_seconds",
                &format!("outcome=\"{outcome}\""),
                JOB_BUCKETS,
            );
        }
        drop(jobs);
        let http = self.http.lock().unwrap_or_else(|p| p.into_inner());
        let _ = writeln!(
            text,
            "# HELP covec_http_requests_total HTTP requests by route and status.\n# TYPE covec_http_requests_total counter"
        );
        for ((method, route, status), count) in &http.requests {
            let _ = writeln!(
                text,
                "covec_http_requests_total{{method=\"{method}\",route=\"{route}\",status=\"{status}\"}} {count}"
            );
        }
        let _ = writeln!(
            text,
            "# HELP covec_http_request_duration_seconds HTTP latency by route.\n# TYPE covec_http_request_duration_seconds histogram"
        );
        for ((method, route), histogram) in &http.latency {
            let labels = format!("method=\"{method}\",route=\"{route}\"");
            histogram.write(
                text,
                "covec_http_request_duration_seconds",
                &labels,
                HTTP_BUCKETS,
            );
        }
    }
}
