//! Artefacts in an S3-compatible bucket (`covec serve --object-store s3://bucket/prefix`,
//! issue 14), against a real S3 server on loopback: moto's (`moto_server`, installed by
//! `scripts/setup-s3.sh`, which `scripts/test.sh` calls).

use crate::service_support;

use std::process::Command;
use std::time::Duration;

use hyper::{Method, StatusCode};
use service_support::s3::{Relay, S3Server};
use service_support::{DataDir, LONG_PARAMS, QUICK_PARAMS, Server, problem, test_png};

const BUCKET: &str = "covec-test";
const PREFIX: &str = "team/covec";

/// A server with its artefacts in `s3`'s bucket; files with no job are orphans after 1 s, and
/// jobs may run long ([`LONG_PARAMS`]).
fn start_covec(dir: &DataDir, s3: &S3Server) -> Server {
    start_covec_at(dir, s3, &s3.endpoint)
}

/// [`start_covec`] reaching the bucket through `endpoint` (a [`Relay`]'s).
fn start_covec_at(dir: &DataDir, s3: &S3Server, endpoint: &str) -> Server {
    let url = format!("s3://{BUCKET}/{PREFIX}");
    let mut env = s3.env();
    env.retain(|(name, _)| name != "AWS_ENDPOINT");
    env.push(("AWS_ENDPOINT".to_owned(), endpoint.to_owned()));
    let env: Vec<_> = env
        .iter()
        .map(|(name, value)| (name.as_str(), value.as_str()))
        .collect();
    Server::start_with_env(
        &dir.0,
        &[
            "--workers",
            "1",
            "--object-store",
            &url,
            "--orphan-age",
            "1",
            "--max-iterations",
            "10000000",
        ],
        &env,
    )
}

/// Creates the test's bucket.
fn make_bucket(s3: &S3Server) {
    s3.curl("PUT", &format!("/{BUCKET}"), None)
        .expect("creating the bucket");
}

#[tokio::test]
async fn results_live_in_the_bucket_survive_a_restart_and_go_with_delete() {
    let s3 = S3Server::start();
    make_bucket(&s3);
    // An upload whose record never came (a crash between the two): swept at start (on the
    // shared backend once older than --orphan-age).
    let orphan = format!("{PREFIX}/jobs/job_0000000000000000000000000000dead/input.png");
    s3.curl("PUT", &format!("/{BUCKET}/{orphan}"), Some(b"png"))
        .unwrap();
    std::thread::sleep(Duration::from_millis(2100));
    let dir = DataDir::new("s3");
    let server = start_covec(&dir, &s3);
    assert!(
        !s3.keys(BUCKET, PREFIX).contains(&orphan),
        "the orphaned upload was not swept"
    );
    let id = server.finished_job().await;
    let svg = server.get(&format!("/v1/jobs/{id}/svg")).await;
    assert_eq!(svg.status, StatusCode::OK);
    assert!(svg.text().contains("<svg"));
    let keys = s3.keys(BUCKET, &format!("{PREFIX}/jobs/{id}/"));
    for name in ["result.svg", "scene.json", "layers/albedo.svg"] {
        assert!(
            keys.contains(&format!("{PREFIX}/jobs/{id}/{name}")),
            "{name} not in the bucket: {keys:?}"
        );
    }
    assert!(
        keys.iter().any(|key| key.contains("/previews/")),
        "no previews in the bucket: {keys:?}"
    );
    // Nothing but the database stays on the local disk.
    assert!(!dir.0.join("jobs").join(&id).exists());
    let ready = server.get("/readyz").await;
    assert_eq!(ready.status, StatusCode::OK, "{}", ready.text());

    // A restart on the same database and bucket serves the same result.
    server.stop();
    let server = start_covec(&dir, &s3);
    let again = server.get(&format!("/v1/jobs/{id}/svg")).await;
    assert_eq!(
        (again.status, again.body.clone()),
        (StatusCode::OK, svg.body)
    );

    let deleted = server
        .request(Method::DELETE, &format!("/v1/jobs/{id}"), &[], Vec::new())
        .await;
    assert_eq!(deleted.status, StatusCode::NO_CONTENT, "{}", deleted.text());
    assert_eq!(
        s3.keys(BUCKET, &format!("{PREFIX}/jobs/{id}/")),
        Vec::<String>::new()
    );
    server.stop();
}

#[tokio::test]
async fn an_unreachable_bucket_is_not_ready_and_fails_results_with_a_problem() {
    let s3 = S3Server::start();
    make_bucket(&s3);
    let dir = DataDir::new("s3-down");
    let server = start_covec(&dir, &s3);
    let id = server.finished_job().await;
    drop(s3);
    let ready = server.get("/readyz").await;
    assert_eq!(
        ready.status,
        StatusCode::SERVICE_UNAVAILABLE,
        "{}",
        ready.text()
    );
    // The store out of reach is a failure of the moment: 503 with Retry-After, not 500.
    let svg = server.get(&format!("/v1/jobs/{id}/svg")).await;
    assert_eq!(
        svg.status,
        StatusCode::SERVICE_UNAVAILABLE,
        "{}",
        svg.text()
    );
    assert_eq!(problem(&svg)["code"], "storage-unavailable");
    assert_eq!(svg.header("retry-after"), Some("5"));
    assert_eq!(
        svg.header("content-type"),
        Some("application/problem+json"),
        "{}",
        svg.text()
    );
    assert!(!svg.text().contains("127.0.0.1"), "{}", svg.text());
    server.stop();
}

#[test]
fn a_bad_object_store_url_stops_the_server_with_one_line() {
    let dir = DataDir::new("s3-bad-url");
    let output = Command::new(env!("CARGO_BIN_EXE_covec"))
        .args(["serve", "--addr", "127.0.0.1:0", "--data-dir"])
        .arg(&dir.0)
        .args(["--object-store", "gs://somewhere"])
        .output()
        .unwrap();
    assert!(!output.status.success());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(stderr.contains("only s3://bucket/prefix"), "{stderr}");
}

/// The object store down for longer than object_store's own retries of one request (10 s)
/// while a job is about to read its inputs: the job waits for the store and succeeds instead
/// of failing with `internal`, and meanwhile a request that needs the store is refused with
/// 503 `storage-unavailable` and `Retry-After` (not 500), so clients know to retry.
#[tokio::test(flavor = "multi_thread")]
async fn a_job_waits_out_an_object_store_outage_and_requests_get_503() {
    let s3 = S3Server::start();
    make_bucket(&s3);
    let relay = Relay::start(&s3.endpoint);
    let dir = DataDir::new("s3-outage");
    let server = start_covec_at(&dir, &s3, &relay.endpoint);
    let image = test_png(32);
    let submit = |params: &'static str| {
        let server = &server;
        let image = image.clone();
        async move {
            let reply = server
                .submit(&[("image", &image), ("params", params.as_bytes())], &[])
                .await;
            assert_eq!(reply.status, StatusCode::CREATED, "{}", reply.text());
            reply.json()["id"].as_str().unwrap().to_owned()
        }
    };
    // The long job holds the one worker, so the quick one starts only once the store is down.
    let long = submit(LONG_PARAMS).await;
    let quick = submit(QUICK_PARAMS).await;
    server
        .wait_for(&long, Duration::from_secs(60), |job| {
            job["status"] == "running"
        })
        .await;
    relay.down();
    assert_eq!(server.cancel(&long).await.status, StatusCode::ACCEPTED);
    let refused = server
        .submit(
            &[("image", &image), ("params", QUICK_PARAMS.as_bytes())],
            &[],
        )
        .await;
    assert_eq!(
        refused.status,
        StatusCode::SERVICE_UNAVAILABLE,
        "{}",
        refused.text()
    );
    assert_eq!(problem(&refused)["code"], "storage-unavailable");
    assert_eq!(refused.header("retry-after"), Some("5"));
    tokio::time::sleep(Duration::from_secs(15)).await;
    relay.up();
    let job = server
        .wait_for(&quick, Duration::from_secs(120), |job| {
            job["status"] != "queued" && job["status"] != "running"
        })
        .await;
    assert_eq!(job["status"], "succeeded", "{job}");
    let svg = server.get(&format!("/v1/jobs/{quick}/svg")).await;
    assert_eq!(svg.status, StatusCode::OK, "{}", svg.text());
    server.stop();
}
