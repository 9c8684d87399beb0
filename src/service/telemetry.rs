//! The service's metrics, recorded by the queue, the job runners and the HTTP layer alike.
//!
//! They go through the `metrics` facade into a Prometheus recorder of this service's own (not
//! the process-wide one: each [`Metrics`] is one server's), which renders the text that
//! [`super::ops`] serves on `/metrics`.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use metrics_exporter_prometheus::{Matcher, PrometheusBuilder, PrometheusRecorder};

/// What an API process's queue shows on `/metrics`.
pub struct QueueGauges {
    pub queued: usize,
    pub running: usize,
    /// Jobs whose state is held in memory: the live ones and ended ones in use (the rest are
    /// read from the store when asked for).
    pub in_memory: usize,
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
    pub fn http_request(
        &self,
        method: &'static str,
        route: String,
        status: u16,
        elapsed: Duration,
    ) {
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

    /// The Prometheus text, with the gauges read at scrape time set first: the number of job
    /// workers, and the queue's where known (API processes).
    pub fn text(&self, queue: Option<QueueGauges>, workers: usize) -> String {
        let mut gauges = vec![(WORKERS, workers as f64)];
        if let Some(queue) = queue {
            gauges.extend([
                (JOBS_QUEUED, queue.queued as f64),
                (JOBS_RUNNING, queue.running as f64),
                (JOBS_IN_MEMORY, queue.in_memory as f64),
            ]);
        }
        metrics::with_local_recorder(&self.recorder, || {
            for (name, value) in gauges {
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
