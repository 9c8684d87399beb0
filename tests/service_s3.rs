//! Artefacts in an S3-compatible bucket (`covec serve --object-store s3://bucket/prefix`,
//! issue 14), against a real S3 server on loopback: moto's (`moto_server`, installed by
//! `scripts/setup-s3.sh`, which `scripts/test.sh` calls).

mod service_support;

use std::process::Command;
use std::time::Duration;

use hyper::{Method, StatusCode};
use service_support::s3::S3Server;
use service_support::{DataDir, Server};

const BUCKET: &str = "covec-test";
const PREFIX: &str = "team/covec";

/// A server with its artefacts in `s3`'s bucket; files with no job are orphans after 1 s.
fn start_covec(dir: &DataDir, s3: &S3Server) -> Server {
    let url = format!("s3://{BUCKET}/{PREFIX}");
    let env = s3.env();
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
    let svg = server.get(&format!("/v1/jobs/{id}/svg")).await;
    assert_eq!(
        svg.status,
        StatusCode::INTERNAL_SERVER_ERROR,
        "{}",
        svg.text()
    );
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
