//! The shared backend (issue 14) over real processes: API replicas (`covec serve
//! --database-url … --workers 0`) and `covec worker`s around one throwaway PostgreSQL
//! (tests/service_support/postgres.rs; scripts/setup-postgres.sh installs it), sharing one
//! directory for the job files.

use crate::service_support;

use std::path::Path;
use std::time::Duration;

use hyper::StatusCode;
use serde_json::Value;
use service_support::postgres::{Postgres, Worker};
use service_support::{DataDir, LONG_PARAMS, Server, problem, test_png};

/// Parameters of a quick job with this seed.
fn quick_params(seed: u32) -> String {
    format!(
        r#"{{"paths": 8, "max_size": 40, "seed": {seed},
           "iterations": {{"structure": 3, "reconstruction": 3, "refine_rounds": 1, "refine": 3, "polish": 3}}}}"#
    )
}

/// A job (image, parameters) long enough to be caught running and short enough to run again,
/// with this seed: about 3.3 s at 128² and 64 paths on two idle cores (measured 2026-11-27).
/// The stages stop early once their loss plateaus, so the iteration counts are only a ceiling:
/// at 48² and 16 paths the job took 0.45 s and once ended before the test could kill its worker.
fn seconds_job(seed: u32) -> (Vec<u8>, String) {
    let params = format!(
        r#"{{"paths": 64, "max_size": 128, "seed": {seed},
           "iterations": {{"structure": 1500, "reconstruction": 1500, "refine_rounds": 1, "refine": 1500, "polish": 1500}}}}"#
    );
    (test_png(128), params)
}

/// Room for [`LONG_PARAMS`].
const MAX_ITERATIONS: &str = "1000000";

/// A lease short enough for a test to wait out.
const LEASE: &str = "2";

fn api(files: &DataDir, name: &str, postgres: &Postgres) -> Server {
    api_at(files, name, &postgres.url)
}

fn api_at(files: &DataDir, name: &str, database_url: &str) -> Server {
    Server::start_logged(
        &files.0,
        &files.0.with_extension(format!("{name}.log")),
        &[
            "--database-url",
            database_url,
            "--workers",
            "0",
            "--max-iterations",
            MAX_ITERATIONS,
        ],
        &[],
    )
}

fn worker(files: &DataDir, name: &str, postgres: &Postgres) -> Worker {
    worker_at(files, name, &postgres.url)
}

fn worker_at(files: &DataDir, name: &str, database_url: &str) -> Worker {
    Worker::start(
        &files.0,
        &files.0.with_extension(format!("{name}.log")),
        &[
            "--database-url",
            database_url,
            "--threads",
            "1",
            "--lease-seconds",
            LEASE,
            "--max-iterations",
            MAX_ITERATIONS,
        ],
    )
}

async fn submit(server: &Server, image: &[u8], params: &str) -> String {
    let created = server
        .submit(&[("image", image), ("params", params.as_bytes())], &[])
        .await;
    assert_eq!(created.status, StatusCode::CREATED, "{}", created.text());
    created.json()["id"].as_str().unwrap().to_owned()
}

async fn ended(server: &Server, id: &str, timeout: Duration) -> Value {
    server
        .wait_for(id, timeout, |job| {
            job["status"] != "queued" && job["status"] != "running"
        })
        .await
}

/// Lines of a log that say a job finished.
fn finishes(log: &Path, id: &str) -> usize {
    std::fs::read_to_string(log)
        .unwrap_or_default()
        .lines()
        .filter(|line| line.contains(id) && line.contains("finished"))
        .count()
}

/// Thirty jobs submitted round-robin to two API replicas run on three workers: each succeeds
/// exactly once (one attempt, one `finished` in all the workers' logs), every replica serves
/// every job, its events and its result, and the results are byte-identical to a
/// single-process embedded run of the same inputs and seeds.
#[tokio::test(flavor = "multi_thread")]
async fn jobs_spread_over_replicas_and_workers_run_once_with_the_embedded_results() {
    let postgres = Postgres::start();
    let files = DataDir::plain("pg-files");
    let apis = [
        api(&files, "api-0", &postgres),
        api(&files, "api-1", &postgres),
    ];
    const WORKERS: [&str; 3] = ["worker-0", "worker-1", "worker-2"];
    let _workers = WORKERS.map(|name| worker(&files, name, &postgres));
    let inputs: Vec<(Vec<u8>, String)> = (0..30)
        .map(|index| (test_png(32 + 8 * (index % 3)), quick_params(index)))
        .collect();
    let mut ids = Vec::new();
    for (index, (image, params)) in inputs.iter().enumerate() {
        ids.push(submit(&apis[index % 2], image, params).await);
    }
    // Events on the replica that did not take the job follow it to its end.
    let events = apis[1]
        .events(
            &format!("/v1/jobs/{}/events", ids[0]),
            Duration::from_secs(60),
        )
        .await;
    assert_eq!(events.last().unwrap().0, "completed", "{events:?}");
    let mut results = Vec::new();
    for (index, id) in ids.iter().enumerate() {
        let other = &apis[(index + 1) % 2];
        let job = ended(other, id, Duration::from_secs(120)).await;
        assert_eq!(job["status"], "succeeded", "{job}");
        assert_eq!(job["attempts"], 1, "{job}");
        let svg = other.get(&format!("/v1/jobs/{id}/svg")).await;
        assert_eq!(svg.status, StatusCode::OK);
        results.push(svg.body);
    }
    for id in &ids {
        let runs: usize = WORKERS
            .iter()
            .map(|name| finishes(&files.0.with_extension(format!("{name}.log")), id))
            .sum();
        assert_eq!(runs, 1, "job {id} finished {runs} times");
    }
    // Both replicas list all thirty, and the queue is empty.
    for api in &apis {
        let listed = api.get("/v1/jobs?limit=50").await.json();
        assert_eq!(listed["items"].as_array().unwrap().len(), 30, "{listed}");
    }
    assert_eq!(
        postgres.query("SELECT count(*) FROM jobs WHERE status <> 'succeeded'"),
        "0\n"
    );

    let single = DataDir::plain("pg-reference");
    let reference = Server::start(&single.0, &["--workers", "1", "--threads", "1"]);
    for ((image, params), expected) in inputs.iter().zip(&results) {
        let id = submit(&reference, image, params).await;
        let job = ended(&reference, &id, Duration::from_secs(60)).await;
        assert_eq!(job["status"], "succeeded", "{job}");
        let svg = reference.get(&format!("/v1/jobs/{id}/svg")).await;
        assert!(svg.body == *expected, "job {id}: results differ");
    }
}

/// A worker killed with SIGKILL mid-job: its lease expires, the other worker runs the job
/// again, and it succeeds on the second attempt.
#[tokio::test(flavor = "multi_thread")]
async fn a_job_whose_worker_is_killed_succeeds_on_another() {
    let postgres = Postgres::start();
    let files = DataDir::plain("pg-kill");
    let server = api(&files, "api", &postgres);
    let doomed = worker(&files, "doomed", &postgres);
    let (image, params) = seconds_job(3);
    let id = submit(&server, &image, &params).await;
    server
        .wait_for(&id, Duration::from_secs(60), |job| {
            job["status"] == "running" && !job["progress"].is_null()
        })
        .await;
    doomed.kill();
    let _survivor = worker(&files, "survivor", &postgres);
    let job = ended(&server, &id, Duration::from_secs(120)).await;
    assert_eq!(job["status"], "succeeded", "{job}");
    assert_eq!(job["attempts"], 2, "{job}");
}

/// Cancel and delete from a replica other than the one that took the job, while a worker
/// elsewhere runs it: the job stops within a heartbeat and an iteration.
#[tokio::test(flavor = "multi_thread")]
async fn cancel_and_delete_work_from_any_replica() {
    let postgres = Postgres::start();
    let files = DataDir::plain("pg-cancel");
    let apis = [
        api(&files, "api-0", &postgres),
        api(&files, "api-1", &postgres),
    ];
    let _worker = worker(&files, "worker", &postgres);
    let id = submit(&apis[0], &test_png(48), LONG_PARAMS).await;
    apis[1]
        .wait_for(&id, Duration::from_secs(60), |job| {
            job["status"] == "running"
        })
        .await;
    let canceled = apis[1].cancel(&id).await;
    assert_eq!(canceled.status, StatusCode::ACCEPTED, "{}", canceled.text());
    let job = ended(&apis[0], &id, Duration::from_secs(10)).await;
    assert_eq!(job["status"], "canceled", "{job}");

    // A second long job, deleted through the other replica while it runs: gone everywhere.
    let id = submit(&apis[1], &test_png(48), LONG_PARAMS).await;
    apis[0]
        .wait_for(&id, Duration::from_secs(60), |job| {
            job["status"] == "running"
        })
        .await;
    let deleted = apis[0]
        .request(
            hyper::Method::DELETE,
            &format!("/v1/jobs/{id}"),
            &[],
            Vec::new(),
        )
        .await;
    assert_eq!(deleted.status, StatusCode::NO_CONTENT);
    let started = std::time::Instant::now();
    while apis[1].get(&format!("/v1/jobs/{id}")).await.status != StatusCode::NOT_FOUND {
        assert!(started.elapsed() < Duration::from_secs(5), "still served");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    // The worker is free again: a quick job runs.
    let id = submit(&apis[1], &test_png(32), &quick_params(1)).await;
    let job = ended(&apis[0], &id, Duration::from_secs(60)).await;
    assert_eq!(job["status"], "succeeded", "{job}");
}

/// With no worker running, jobs submitted to one replica wait in the database's queue: every
/// replica reports the queue's depth (`covec_jobs_queued`, what an autoscaler reads) and each
/// job's place in it, and a replayed Idempotency-Key on the other replica finds the first job.
#[tokio::test(flavor = "multi_thread")]
async fn every_replica_sees_the_whole_queue() {
    let postgres = Postgres::start();
    let files = DataDir::plain("pg-depth");
    let apis = [
        api(&files, "api-0", &postgres),
        api(&files, "api-1", &postgres),
    ];
    let image = test_png(32);
    let mut ids = Vec::new();
    for seed in 0..3 {
        ids.push(submit(&apis[0], &image, &quick_params(seed)).await);
    }
    let started = std::time::Instant::now();
    loop {
        let metrics = apis[1].get("/metrics").await.text();
        if metrics.lines().any(|line| line == "covec_jobs_queued 3") {
            break;
        }
        assert!(started.elapsed() < Duration::from_secs(5), "{metrics}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    for (position, id) in ids.iter().enumerate() {
        let job = apis[1].get(&format!("/v1/jobs/{id}")).await.json();
        assert_eq!(job["queue_position"], position, "{job}");
    }
    let params = quick_params(7);
    let parts = [("image", image.as_slice()), ("params", params.as_bytes())];
    let key = [("idempotency-key", "batch-7")];
    let first = apis[0].submit(&parts, &key).await;
    assert_eq!(first.status, StatusCode::CREATED, "{}", first.text());
    let replayed = apis[1].submit(&parts, &key).await;
    assert_eq!(replayed.header("idempotent-replayed"), Some("true"));
    assert_eq!(replayed.json()["id"], first.json()["id"]);
}

/// A job whose worker vanishes on every attempt fails after the last one with
/// `workers-lost`, instead of going round the queue for ever.
#[tokio::test(flavor = "multi_thread")]
async fn a_job_is_failed_after_its_last_attempt() {
    let postgres = Postgres::start();
    let files = DataDir::plain("pg-attempts");
    let server = api(&files, "api", &postgres);
    let id = submit(&server, &test_png(48), LONG_PARAMS).await;
    for attempt in 1..=3 {
        let doomed = worker(&files, &format!("worker-{attempt}"), &postgres);
        server
            .wait_for(&id, Duration::from_secs(30), |job| {
                job["status"] == "running" && job["attempts"] == attempt
            })
            .await;
        doomed.kill();
    }
    // No worker left: the API replica's follower takes back the expired lease.
    let job = ended(&server, &id, Duration::from_secs(20)).await;
    assert_eq!(job["status"], "failed", "{job}");
    assert_eq!(job["error"]["code"], "workers-lost", "{job}");
    assert_eq!(job["attempts"], 3, "{job}");
}

/// PostgreSQL stopped and started again while a job runs: meanwhile the replica answers for
/// the job it knows and an error (not 404) for one it cannot look up; then the worker and the
/// replica reconnect, the job still succeeds, and the replica takes new jobs.
#[tokio::test(flavor = "multi_thread")]
async fn a_database_restart_loses_no_job() {
    let mut postgres = Postgres::start();
    let files = DataDir::plain("pg-restart");
    let server = api(&files, "api", &postgres);
    let _worker = worker(&files, "worker", &postgres);
    let (image, params) = seconds_job(5);
    let id = submit(&server, &image, &params).await;
    server
        .wait_for(&id, Duration::from_secs(60), |job| {
            job["status"] == "running"
        })
        .await;
    postgres.stop();
    // The replica's copy still answers for the job; one it has never seen cannot be looked
    // up, which is an error, not a 404 (the job may well exist): 503 `storage-unavailable`
    // with Retry-After, so a client retries.
    let known = server.get(&format!("/v1/jobs/{id}")).await;
    assert_eq!(known.status, StatusCode::OK, "{}", known.text());
    let unknown = server
        .get(&format!("/v1/jobs/job_{}", "0".repeat(32)))
        .await;
    assert_eq!(unknown.status, StatusCode::SERVICE_UNAVAILABLE);
    assert_eq!(
        problem(&unknown)["code"],
        "storage-unavailable",
        "{}",
        unknown.text()
    );
    assert_eq!(unknown.header("retry-after"), Some("5"));
    postgres.start_again();
    let job = ended(&server, &id, Duration::from_secs(120)).await;
    assert_eq!(job["status"], "succeeded", "{job}");
    let id = submit(&server, &test_png(32), &quick_params(2)).await;
    let job = ended(&server, &id, Duration::from_secs(60)).await;
    assert_eq!(job["status"], "succeeded", "{job}");
}

/// An API replica killed with SIGKILL while a client streams a job's events from it: the
/// client reconnects to the other replica and sees the job complete there.
#[tokio::test(flavor = "multi_thread")]
async fn sse_clients_of_a_killed_replica_see_completion_on_the_other() {
    use http_body_util::{BodyExt, Full};
    use hyper::body::Bytes;
    use hyper_util::client::legacy::Client;
    use hyper_util::rt::TokioExecutor;

    let postgres = Postgres::start();
    let files = DataDir::plain("pg-sse");
    let apis = [
        api(&files, "api-0", &postgres),
        api(&files, "api-1", &postgres),
    ];
    let _worker = worker(&files, "worker", &postgres);
    let (image, params) = seconds_job(9);
    let id = submit(&apis[0], &image, &params).await;
    let path = format!("/v1/jobs/{id}/events");
    let client = Client::builder(TokioExecutor::new()).build_http::<Full<Bytes>>();
    let request = hyper::Request::builder()
        .uri(format!("{}{path}", apis[0].base))
        .body(Full::new(Bytes::new()))
        .unwrap();
    let mut stream = client.request(request).await.unwrap().into_body();
    // The first event (the job queued or running), then the replica dies mid-stream.
    let first = stream.frame().await.unwrap().unwrap();
    assert!(String::from_utf8_lossy(first.data_ref().unwrap()).contains("event: progress"));
    apis[0].sigkill();
    let mut seen = String::new();
    while let Ok(Some(Ok(frame))) =
        tokio::time::timeout(Duration::from_secs(10), stream.frame()).await
    {
        if let Some(data) = frame.data_ref() {
            seen.push_str(&String::from_utf8_lossy(data));
        }
    }
    assert!(!seen.contains("event: completed"), "{seen}");
    let events = apis[1].events(&path, Duration::from_secs(120)).await;
    let (name, data) = events.last().unwrap();
    assert_eq!(name, "completed", "{events:?}");
    assert!(data.contains("\"succeeded\""), "{data}");
}

/// A database that takes TLS only: an API replica and a worker that verify its certificate
/// (`sslmode=verify-full` with the CA as `sslrootcert`) run a job; a worker asking for no
/// TLS, one connecting by an address the certificate does not name, and one trusting
/// another CA each stop at start with a one-line error saying why.
#[tokio::test(flavor = "multi_thread")]
async fn tls_to_the_database_with_libpq_sslmodes() {
    let (postgres, ca) = Postgres::start_tls_only();
    let files = DataDir::plain("pg-tls");
    let by_name = postgres.url.replace("127.0.0.1", "localhost");
    let verified = format!("{by_name}?sslmode=verify-full&sslrootcert={}", ca.display());
    let server = api_at(&files, "api", &verified);
    let _worker = worker_at(&files, "worker", &verified);
    let id = submit(&server, &test_png(32), &quick_params(1)).await;
    let job = ended(&server, &id, Duration::from_secs(60)).await;
    assert_eq!(job["status"], "succeeded", "{job}");
    // Encrypted without checking the certificate, as libpq's `require`.
    let required = format!("{}?sslmode=require", postgres.url);
    let unchecked = api_at(&files, "unchecked", &required);
    let job = unchecked.get(&format!("/v1/jobs/{id}")).await.json();
    assert_eq!(job["status"], "succeeded", "{job}");

    let other_ca = files.0.join("other-ca.pem");
    let self_signed = rcgen::generate_simple_self_signed(vec!["localhost".to_owned()]).unwrap();
    std::fs::write(&other_ca, self_signed.cert.pem()).unwrap();
    let refused = [
        (format!("{}?sslmode=disable", postgres.url), "no encryption"),
        (
            format!(
                "{}?sslmode=verify-full&sslrootcert={}",
                postgres.url,
                ca.display()
            ),
            "certificate",
        ),
        (
            format!(
                "{by_name}?sslmode=verify-ca&sslrootcert={}",
                other_ca.display()
            ),
            "certificate",
        ),
        (
            format!("{by_name}?sslmode=verify-ca&sslrootcert=/nonexistent/ca.pem"),
            "/nonexistent/ca.pem",
        ),
    ];
    for (url, reason) in refused {
        let error = worker_start_error(&files, &url);
        assert!(error.contains(reason), "{url}: {error}");
        assert_eq!(error.trim_end().lines().count(), 1, "{error}");
    }
}

/// What `covec worker` printed when it stopped at start (within 30 s).
fn worker_start_error(files: &DataDir, database_url: &str) -> String {
    use std::process::{Command, Stdio};
    let mut child = Command::new(env!("CARGO_BIN_EXE_covec"))
        .args(["worker", "--data-dir"])
        .arg(&files.0)
        .args(["--database-url", database_url])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let started = std::time::Instant::now();
    while child.try_wait().unwrap().is_none() {
        if started.elapsed() > Duration::from_secs(30) {
            child.kill().unwrap();
            panic!("covec worker --database-url {database_url} did not stop");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let output = child.wait_with_output().unwrap();
    assert!(!output.status.success());
    String::from_utf8(output.stderr).unwrap()
}

/// `covec worker --ops-addr`: liveness, readiness (not ready while the database is down) and
/// the job metrics of that worker.
#[tokio::test(flavor = "multi_thread")]
async fn a_worker_serves_probes_and_metrics() {
    let mut postgres = Postgres::start();
    let files = DataDir::plain("pg-ops");
    let server = api(&files, "api", &postgres);
    let worker = Worker::start(
        &files.0,
        &files.0.with_extension("worker.log"),
        &[
            "--database-url",
            &postgres.url,
            "--threads",
            "1",
            "--ops-addr",
            "127.0.0.1:0",
        ],
    );
    let ops = worker.ops_url.clone().unwrap();
    assert_eq!(http_get(&ops, "/healthz").0, 200);
    assert_eq!(http_get(&ops, "/readyz").0, 200);
    // What a container's health check runs (the image has no curl).
    assert!(healthcheck(&format!("{ops}/healthz")).status.success());
    let id = submit(&server, &test_png(32), &quick_params(3)).await;
    let job = ended(&server, &id, Duration::from_secs(60)).await;
    assert_eq!(job["status"], "succeeded", "{job}");
    let (status, metrics) = http_get(&ops, "/metrics");
    assert_eq!(status, 200);
    assert!(metrics.contains("covec_workers 1"), "{metrics}");
    assert!(
        metrics.contains("covec_job_duration_seconds_count{outcome=\"succeeded\"} 1"),
        "{metrics}"
    );
    postgres.stop();
    let (status, body) = http_get(&ops, "/readyz");
    assert_eq!(status, 503, "{body}");
    assert!(body.contains("job database"), "{body}");
    let not_ready = healthcheck(&format!("{ops}/readyz"));
    assert!(!not_ready.status.success());
    assert!(
        String::from_utf8_lossy(&not_ready.stderr).contains("answered 503"),
        "{not_ready:?}"
    );
    postgres.start_again();
}

/// `covec healthcheck --url URL`.
fn healthcheck(url: &str) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_covec"))
        .args(["healthcheck", "--url", url])
        .output()
        .expect("covec healthcheck runs")
}

/// (status, body) of `GET url+path`, over a plain blocking connection.
fn http_get(url: &str, path: &str) -> (u16, String) {
    use std::io::{Read, Write};
    let mut stream = std::net::TcpStream::connect(url.trim_start_matches("http://")).unwrap();
    stream
        .set_read_timeout(Some(Duration::from_secs(30)))
        .unwrap();
    write!(
        stream,
        "GET {path} HTTP/1.1\r\nHost: covec\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut reply = String::new();
    stream.read_to_string(&mut reply).unwrap();
    let status = reply[9..12].parse().unwrap();
    let body = reply.split_once("\r\n\r\n").map_or("", |(_, body)| body);
    (status, body.to_owned())
}
