//! Artefacts in an S3-compatible bucket (`covec serve --object-store s3://bucket/prefix`,
//! issue 14), against a real S3 server on loopback: moto's (`moto_server`, installed by
//! `scripts/setup-s3.sh`, which `scripts/test.sh` calls).

mod service_support;

use std::net::TcpStream;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use hyper::{Method, StatusCode};
use service_support::{DataDir, Server};

const BUCKET: &str = "covec-test";
const PREFIX: &str = "team/covec";

/// `moto_server` on a free loopback port, killed on drop.
struct S3Server {
    child: Child,
    endpoint: String,
}

impl S3Server {
    fn start() -> Self {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let child = Command::new("moto_server")
            .args(["-H", "127.0.0.1", "-p", &port.to_string()])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("moto_server (scripts/setup-s3.sh installs it)");
        let started = Instant::now();
        while TcpStream::connect(("127.0.0.1", port)).is_err() {
            assert!(
                started.elapsed() < Duration::from_secs(30),
                "moto_server did not start"
            );
            std::thread::sleep(Duration::from_millis(100));
        }
        Self {
            child,
            endpoint: format!("http://127.0.0.1:{port}"),
        }
    }

    /// What `covec serve` needs to reach this server.
    fn env(&self) -> Vec<(&str, &str)> {
        vec![
            ("AWS_ENDPOINT", self.endpoint.as_str()),
            ("AWS_ALLOW_HTTP", "true"),
            ("AWS_ACCESS_KEY_ID", "test"),
            ("AWS_SECRET_ACCESS_KEY", "test"),
            ("AWS_REGION", "us-east-1"),
        ]
    }

    /// An unsigned request (moto accepts them) with curl, for setting up and looking.
    fn curl(&self, method: &str, path: &str) -> String {
        let output = Command::new("curl")
            .args(["-sf", "-X", method, &format!("{}{path}", self.endpoint)])
            .output()
            .unwrap();
        assert!(output.status.success(), "{method} {path}");
        String::from_utf8(output.stdout).unwrap()
    }

    /// Keys in the bucket under `prefix`.
    fn keys(&self, prefix: &str) -> Vec<String> {
        let listing = self.curl("GET", &format!("/{BUCKET}?list-type=2&prefix={prefix}"));
        listing
            .split("<Key>")
            .skip(1)
            .map(|rest| rest.split("</Key>").next().unwrap().to_owned())
            .collect()
    }
}

impl Drop for S3Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn start_covec(dir: &DataDir, s3: &S3Server) -> Server {
    let url = format!("s3://{BUCKET}/{PREFIX}");
    Server::start_with_env(
        &dir.0,
        &["--workers", "1", "--object-store", &url],
        &s3.env(),
    )
}

#[tokio::test]
async fn results_live_in_the_bucket_survive_a_restart_and_go_with_delete() {
    let s3 = S3Server::start();
    s3.curl("PUT", &format!("/{BUCKET}"));
    // An upload whose record never came (a crash between the two): swept at start.
    let orphan = format!("{PREFIX}/jobs/job_0000000000000000000000000000dead/input.png");
    s3.curl("PUT", &format!("/{BUCKET}/{orphan}"));
    let dir = DataDir::new("s3");
    let server = start_covec(&dir, &s3);
    assert!(
        !s3.keys(PREFIX).contains(&orphan),
        "the orphaned upload was not swept"
    );
    let id = server.finished_job().await;
    let svg = server.get(&format!("/v1/jobs/{id}/svg")).await;
    assert_eq!(svg.status, StatusCode::OK);
    assert!(svg.text().contains("<svg"));
    let keys = s3.keys(&format!("{PREFIX}/jobs/{id}/"));
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
        s3.keys(&format!("{PREFIX}/jobs/{id}/")),
        Vec::<String>::new()
    );
    server.stop();
}

#[tokio::test]
async fn an_unreachable_bucket_is_not_ready_and_fails_results_with_a_problem() {
    let s3 = S3Server::start();
    s3.curl("PUT", &format!("/{BUCKET}"));
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
