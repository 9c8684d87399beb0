//! The service's HTTP contract without running the pipeline to the end: bad requests, auth and
//! visibility, listing, operations endpoints.
#![cfg(all(feature = "cli", feature = "service"))]

use crate::service_support;

use hyper::{Method, StatusCode};
use serde_json::json;
use service_support::{DataDir, LONG_PARAMS, QUICK_PARAMS, Server, png, problem, test_png};

const UNKNOWN_ID: &str = "job_0192f0c4a1b27c3d8e9f0a1b2c3d4e5f";

#[tokio::test]
async fn bad_requests_get_the_right_4xx_problem() {
    let dir = DataDir::new("bad-requests");
    // Tiny limits so each one is easy to cross; 32×32 = 1024 pixels is within them.
    let server = Server::start(
        &dir.0,
        &[
            "--max-pixels",
            "2000",
            "--max-body-bytes",
            "100000",
            "--workers",
            "1",
        ],
    );
    let image = test_png(32);
    // Masks may be scaled copies of the image's grid, not of another aspect ratio.
    let wide_mask = png(&image::DynamicImage::ImageLuma8(image::GrayImage::new(
        32, 16,
    )));
    let big_image = test_png(64);
    let noise: Vec<u8> = (0..150_000u32)
        .map(|i| (i.wrapping_mul(2_654_435_761) >> 24) as u8)
        .collect();

    let cases: Vec<(&str, service_support::Reply, StatusCode, &str)> = vec![
        (
            "corrupt image",
            server
                .submit(&[("image", b"this is not a PNG file at all")], &[])
                .await,
            StatusCode::UNPROCESSABLE_ENTITY,
            "undecodable-image",
        ),
        (
            "wrong content type",
            server
                .request(
                    Method::POST,
                    "/v1/jobs",
                    &[("content-type", "text/plain")],
                    b"hello".to_vec(),
                )
                .await,
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            "unsupported-media-type",
        ),
        (
            "oversized body",
            server.submit(&[("image", &noise)], &[]).await,
            StatusCode::PAYLOAD_TOO_LARGE,
            "body-too-large",
        ),
        (
            "too many pixels",
            server.submit(&[("image", &big_image)], &[]).await,
            StatusCode::PAYLOAD_TOO_LARGE,
            "too-many-pixels",
        ),
        (
            "bad params (out of range)",
            server
                .submit(&[("image", &image), ("params", br#"{"paths": 2}"#)], &[])
                .await,
            StatusCode::UNPROCESSABLE_ENTITY,
            "invalid-params",
        ),
        (
            "bad params (unknown field)",
            server
                .submit(&[("image", &image), ("params", br#"{"colours": 3}"#)], &[])
                .await,
            StatusCode::UNPROCESSABLE_ENTITY,
            "invalid-params",
        ),
        (
            "bad params (not JSON)",
            server
                .submit(&[("image", &image), ("params", b"paths=8")], &[])
                .await,
            StatusCode::UNPROCESSABLE_ENTITY,
            "invalid-params",
        ),
        (
            "mask of another aspect ratio",
            server
                .submit(&[("image", &image), ("mask", &wide_mask)], &[])
                .await,
            StatusCode::UNPROCESSABLE_ENTITY,
            "invalid-input",
        ),
        (
            "missing image",
            server
                .submit(&[("params", QUICK_PARAMS.as_bytes())], &[])
                .await,
            StatusCode::BAD_REQUEST,
            "bad-request",
        ),
        (
            "unknown form field",
            server
                .submit(&[("image", &image), ("picture", &image)], &[])
                .await,
            StatusCode::BAD_REQUEST,
            "bad-request",
        ),
        (
            "JSON body with invalid base64",
            server
                .post_json("/v1/jobs", &json!({ "image": "%%%not base64%%%" }))
                .await,
            StatusCode::BAD_REQUEST,
            "bad-request",
        ),
        (
            "unknown job id",
            server.get(&format!("/v1/jobs/{UNKNOWN_ID}")).await,
            StatusCode::NOT_FOUND,
            "job-not-found",
        ),
        (
            "malformed job id",
            server.get("/v1/jobs/12345").await,
            StatusCode::BAD_REQUEST,
            "malformed-job-id",
        ),
        (
            "malformed id on a result",
            server.get("/v1/jobs/job_..%2F..%2Fetc/svg").await,
            StatusCode::BAD_REQUEST,
            "malformed-job-id",
        ),
        (
            "results of an unknown job",
            server
                .get(&format!("/v1/jobs/{UNKNOWN_ID}/scene.json"))
                .await,
            StatusCode::NOT_FOUND,
            "job-not-found",
        ),
        (
            "bad list limit",
            server.get("/v1/jobs?limit=100000").await,
            StatusCode::BAD_REQUEST,
            "bad-query",
        ),
        (
            "bad list status",
            server.get("/v1/jobs?status=done").await,
            StatusCode::BAD_REQUEST,
            "bad-query",
        ),
        (
            "unknown route",
            server.get("/v2/things").await,
            StatusCode::NOT_FOUND,
            "route-not-found",
        ),
        (
            "wrong method",
            server
                .request(Method::PUT, "/v1/jobs", &[], Vec::new())
                .await,
            StatusCode::METHOD_NOT_ALLOWED,
            "method-not-allowed",
        ),
    ];
    for (name, reply, status, code) in cases {
        assert_eq!(reply.status, status, "{name}: {}", reply.text());
        assert_eq!(problem(&reply)["code"], code, "{name}");
    }
    let too_many = problem(&server.submit(&[("image", &big_image)], &[]).await);
    assert_eq!(
        (too_many["limit"].as_u64(), too_many["actual"].as_u64()),
        (Some(2000), Some(4096))
    );
    // Nothing above created a job.
    assert_eq!(server.get("/v1/jobs").await.json()["items"], json!([]));
}

#[tokio::test]
async fn api_keys_guard_v1_and_jobs_are_private_to_their_key() {
    let dir = DataDir::new("auth");
    let server = Server::start(
        &dir.0,
        &["--api-keys", "alpha-key,beta-key", "--workers", "1"],
    );
    let alpha = [("authorization", "Bearer alpha-key")];
    let beta = [("authorization", "Bearer beta-key")];

    let anonymous = server.get("/v1/jobs").await;
    assert_eq!(anonymous.status, StatusCode::UNAUTHORIZED);
    assert_eq!(problem(&anonymous)["code"], "unauthorized");
    let wrong = server
        .request(
            Method::GET,
            "/v1/jobs",
            &[("authorization", "Bearer nope")],
            Vec::new(),
        )
        .await;
    assert_eq!(wrong.status, StatusCode::UNAUTHORIZED);
    // The scheme is case-insensitive (RFC 9110 section 11.1); the key is not.
    for authorization in ["bearer alpha-key", "BEARER alpha-key", "Bearer  alpha-key"] {
        let listed = server
            .get_with("/v1/jobs", &[("authorization", authorization)])
            .await;
        assert_eq!(listed.status, StatusCode::OK, "{authorization}");
    }
    for authorization in ["Bearer ALPHA-KEY", "Basic alpha-key", "alpha-key"] {
        let listed = server
            .get_with("/v1/jobs", &[("authorization", authorization)])
            .await;
        assert_eq!(listed.status, StatusCode::UNAUTHORIZED, "{authorization}");
    }
    assert_eq!(
        server.get("/healthz").await.status,
        StatusCode::OK,
        "operations endpoints need no key"
    );

    let created = server
        .submit(
            &[("image", &test_png(32)), ("params", LONG_PARAMS.as_bytes())],
            &alpha,
        )
        .await;
    // LONG_PARAMS is over the default iteration budget: refused, with the key accepted.
    assert_eq!(
        created.status,
        StatusCode::UNPROCESSABLE_ENTITY,
        "{}",
        created.text()
    );
    let created = server
        .submit(
            &[
                ("image", &test_png(32)),
                ("params", QUICK_PARAMS.as_bytes()),
            ],
            &alpha,
        )
        .await;
    assert_eq!(created.status, StatusCode::CREATED, "{}", created.text());
    let id = created.json()["id"].as_str().unwrap().to_owned();

    let own = server.get_with(&format!("/v1/jobs/{id}"), &alpha).await;
    assert_eq!(own.status, StatusCode::OK);
    let other = server.get_with(&format!("/v1/jobs/{id}"), &beta).await;
    assert_eq!(other.status, StatusCode::NOT_FOUND);
    assert_eq!(problem(&other)["code"], "job-not-found");
    let other_cancel = server
        .request(
            Method::POST,
            &format!("/v1/jobs/{id}/cancel"),
            &beta,
            Vec::new(),
        )
        .await;
    assert_eq!(other_cancel.status, StatusCode::NOT_FOUND);
    let other_list = server.get_with("/v1/jobs", &beta).await.json();
    assert_eq!(other_list["items"], json!([]));
    let own_list = server.get_with("/v1/jobs", &alpha).await.json();
    assert_eq!(own_list["items"][0]["id"], id.as_str());
}

#[tokio::test]
async fn operations_endpoints_answer() {
    let dir = DataDir::new("ops");
    let server = Server::start(&dir.0, &["--workers", "1"]);
    let health = server.get("/healthz").await;
    assert_eq!(
        (health.status, health.json()["status"].clone()),
        (StatusCode::OK, json!("ok"))
    );
    let ready = server.get("/readyz").await;
    assert_eq!(ready.status, StatusCode::OK, "{}", ready.text());
    assert!(
        ready.header("x-request-id").is_some(),
        "every response carries a request id"
    );
    let metrics = server.get("/metrics").await;
    assert_eq!(metrics.status, StatusCode::OK);
    let text = metrics.text();
    for line in [
        "covec_jobs_queued 0",
        "covec_jobs_running 0",
        "covec_workers 1",
    ] {
        assert!(
            text.lines().any(|l| l == line),
            "missing `{line}` in\n{text}"
        );
    }
    assert!(
        text.contains(
            "covec_http_request_duration_seconds_bucket{method=\"GET\",route=\"/readyz\""
        ),
        "{text}"
    );
    server.stop();
}

#[tokio::test]
async fn listing_pages_through_jobs_newest_first() {
    let dir = DataDir::new("list");
    let server = Server::start(&dir.0, &["--workers", "1"]);
    let mut ids = Vec::new();
    for _ in 0..3 {
        let created = server
            .submit(
                &[
                    ("image", &test_png(32)),
                    ("params", QUICK_PARAMS.as_bytes()),
                ],
                &[],
            )
            .await;
        assert_eq!(created.status, StatusCode::CREATED, "{}", created.text());
        assert_eq!(
            created.header("location").unwrap(),
            format!("/v1/jobs/{}", created.json()["id"].as_str().unwrap())
        );
        ids.push(created.json()["id"].as_str().unwrap().to_owned());
    }
    let first = server.get("/v1/jobs?limit=2").await.json();
    let cursor = first["next_cursor"]
        .as_str()
        .expect("a second page")
        .to_owned();
    let second = server
        .get(&format!("/v1/jobs?limit=2&cursor={cursor}"))
        .await
        .json();
    assert!(second["next_cursor"].is_null(), "{second}");
    let listed: Vec<_> = first["items"]
        .as_array()
        .unwrap()
        .iter()
        .chain(second["items"].as_array().unwrap())
        .map(|job| job["id"].as_str().unwrap().to_owned())
        .collect();
    ids.reverse();
    assert_eq!(listed, ids);
}

#[tokio::test]
async fn cors_allows_configured_origins_only() {
    let dir = DataDir::new("cors");
    let server = Server::start(
        &dir.0,
        &["--cors-origins", "https://app.example", "--workers", "1"],
    );
    let preflight = [
        ("origin", "https://app.example"),
        ("access-control-request-method", "POST"),
        ("access-control-request-headers", "authorization, prefer"),
    ];
    let allowed = server
        .request(Method::OPTIONS, "/v1/jobs", &preflight, Vec::new())
        .await;
    assert_eq!(
        allowed.header("access-control-allow-origin"),
        Some("https://app.example")
    );
    // Named, not `*`: the Fetch standard's wildcard does not cover Authorization.
    assert_eq!(
        allowed.header("access-control-allow-headers"),
        Some("authorization, prefer")
    );
    let other = server
        .request(
            Method::GET,
            "/v1/jobs",
            &[("origin", "https://evil.example")],
            Vec::new(),
        )
        .await;
    assert_eq!(other.header("access-control-allow-origin"), None);
}

/// `covec serve` on `addr` with `args` and `env` (and no API keys or anonymity from the
/// caller's environment): `None` once it prints that it listens (then it is killed), else its
/// exit status and standard error.
fn serve_outcome(
    addr: &str,
    args: &[&str],
    env: &[(&str, &str)],
) -> Option<(std::process::ExitStatus, String)> {
    use std::io::{BufRead, BufReader, Read};
    let data = DataDir::plain("anonymous");
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_covec"))
        .args(["serve", "--addr", addr, "--data-dir"])
        .arg(&data.0)
        .args(args)
        .env_remove("COVEC_API_KEYS")
        .env_remove("COVEC_ALLOW_ANONYMOUS")
        .envs(env.iter().copied())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    if line.starts_with("covec serve: listening on ") {
        child.kill().unwrap();
        child.wait().unwrap();
        return None;
    }
    let status = child.wait().unwrap();
    let mut stderr = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut stderr)
        .unwrap();
    Some((status, stderr))
}

#[test]
fn serving_other_hosts_without_keys_needs_allow_anonymous() {
    // Reachable from other hosts, no keys: a one-line reason and a failed exit.
    for env in [&[][..], &[("COVEC_ALLOW_ANONYMOUS", "false")][..]] {
        let (status, stderr) =
            serve_outcome("0.0.0.0:0", &[], env).expect("covec serve started open");
        assert!(!status.success());
        assert_eq!(stderr.lines().count(), 1, "{stderr}");
        assert!(
            stderr.starts_with("covec serve: refusing to serve 0.0.0.0:0 without API keys")
                && stderr.contains("--allow-anonymous"),
            "{stderr}"
        );
    }
    // Told so, by flag or variable; or with keys; or on loopback: it starts.
    assert!(serve_outcome("0.0.0.0:0", &["--allow-anonymous"], &[]).is_none());
    assert!(serve_outcome("0.0.0.0:0", &[], &[("COVEC_ALLOW_ANONYMOUS", "true")]).is_none());
    assert!(serve_outcome("0.0.0.0:0", &["--api-keys", "k"], &[]).is_none());
    assert!(serve_outcome("127.0.0.1:0", &[], &[]).is_none());
    if ipv6_loopback() {
        assert!(serve_outcome("[::1]:0", &[], &[]).is_none());
    }
}

/// Whether this machine has an IPv6 loopback address to listen on.
fn ipv6_loopback() -> bool {
    std::net::TcpListener::bind("[::1]:0").is_ok()
}

/// A plain `GET` over HTTP/1.0: the status code and body.
fn get_plain(addr: &str, path: &str) -> (u16, String) {
    use std::io::{Read, Write};
    let mut stream = std::net::TcpStream::connect(addr).unwrap();
    write!(stream, "GET {path} HTTP/1.0\r\nHost: {addr}\r\n\r\n").unwrap();
    let mut answer = String::new();
    stream.read_to_string(&mut answer).unwrap();
    let status = answer[9..12].parse().unwrap();
    let body = answer.split_once("\r\n\r\n").map_or("", |(_, body)| body);
    (status, body.to_owned())
}

#[tokio::test]
async fn ops_addr_serves_probes_and_keeps_metrics_off_the_api_port() {
    let dir = DataDir::new("ops-addr");
    let ops = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .to_string();
    let server = Server::start(&dir.0, &["--ops-addr", &ops]);
    let api = server.get("/metrics").await;
    assert_eq!(api.status, StatusCode::NOT_FOUND);
    assert_eq!(problem(&api)["code"], "route-not-found");
    assert_eq!(server.get("/healthz").await.status, StatusCode::OK);
    let ops = ops.clone();
    let (metrics, healthz, readyz) = tokio::task::spawn_blocking(move || {
        (
            get_plain(&ops, "/metrics"),
            get_plain(&ops, "/healthz"),
            get_plain(&ops, "/readyz"),
        )
    })
    .await
    .unwrap();
    assert_eq!(metrics.0, 200);
    assert!(metrics.1.contains("covec_jobs_queued"), "{}", metrics.1);
    assert_eq!(healthz.0, 200);
    assert_eq!(readyz.0, 200, "{}", readyz.1);
    server.stop();
}
