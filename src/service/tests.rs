//! The router's own tests: routes, limits and headers on an app without a socket.

use std::sync::Arc;

use axum::body::Body;
use axum::http::{Request, StatusCode};
use tower::ServiceExt;

use super::*;

fn state(name: &str) -> (AppState, PathBuf) {
    state_with(name, InputLimits::default())
}

fn state_with(name: &str, limits: InputLimits) -> (AppState, PathBuf) {
    let data_dir = std::env::temp_dir().join(format!("covec-unit-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&data_dir);
    let config = Config {
        data_dir: data_dir.clone(),
        limits,
        ..Config::default()
    };
    (AppState::open(&config).unwrap(), data_dir)
}

async fn call(app: Router, method: &str, uri: &str) -> (StatusCode, String, serde_json::Value) {
    let request = Request::builder()
        .method(method)
        .uri(uri)
        .body(Body::empty())
        .unwrap();
    let response = app.oneshot(request).await.unwrap();
    let status = response.status();
    let content_type = response.headers()["content-type"]
        .to_str()
        .unwrap()
        .to_owned();
    let body = axum::body::to_bytes(response.into_body(), 1 << 20)
        .await
        .unwrap();
    (status, content_type, serde_json::from_slice(&body).unwrap())
}

#[tokio::test(flavor = "multi_thread")]
async fn routes_answer_in_process() {
    let (state, data_dir) = state("routes");
    let app = app(state);
    let (status, _, body) = call(app.clone(), "GET", "/healthz").await;
    assert_eq!(
        (status, body["status"].as_str()),
        (StatusCode::OK, Some("ok"))
    );
    let (status, _, body) = call(app.clone(), "GET", "/readyz").await;
    assert_eq!(
        (status, body["status"].as_str()),
        (StatusCode::OK, Some("ready"))
    );
    let (status, content_type, body) = call(app.clone(), "GET", "/v1/jobs/nope").await;
    assert_eq!(
        (status, content_type.as_str()),
        (StatusCode::BAD_REQUEST, error::PROBLEM_JSON)
    );
    assert_eq!(body["code"], "malformed-job-id");
    // `/` is the web page; other unknown paths are problems.
    let (status, _, body) = call(app.clone(), "GET", "/no-such-page").await;
    assert_eq!(
        (status, body["code"].as_str()),
        (StatusCode::NOT_FOUND, Some("route-not-found"))
    );
    let (status, _, body) = call(app, "DELETE", "/v1/jobs").await;
    assert_eq!(
        (status, body["code"].as_str()),
        (StatusCode::METHOD_NOT_ALLOWED, Some("method-not-allowed"))
    );
    let _ = std::fs::remove_dir_all(data_dir);
}

/// A `POST /v1/jobs` of a 32² image, 8 paths and a few iterations.
fn submission() -> Request<Body> {
    let png = crate::imageio::encode_png(&crate::render::Image::filled(32, 32, [0.2, 0.5, 0.8]));
    let params = r#"{"paths": 8, "max_size": 32, "iterations": {"structure": 2,
        "reconstruction": 2, "refine_rounds": 1, "refine": 2, "polish": 2}}"#;
    let mut body = Vec::new();
    for (name, content_type, bytes) in [
        ("image", "image/png", png.as_slice()),
        ("params", "application/json", params.as_bytes()),
    ] {
        body.extend_from_slice(
            format!(
                "--b\r\ncontent-disposition: form-data; name=\"{name}\"; filename=\"{name}\"\r\n\
                 content-type: {content_type}\r\n\r\n"
            )
            .as_bytes(),
        );
        body.extend_from_slice(bytes);
        body.extend_from_slice(b"\r\n");
    }
    body.extend_from_slice(b"--b--\r\n");
    Request::builder()
        .method("POST")
        .uri("/v1/jobs")
        .header("content-type", "multipart/form-data; boundary=b")
        .body(Body::from(body))
        .unwrap()
}

/// Decoding beyond the slots answers 503 `decode-busy` with `Retry-After`. The test holds
/// every slot itself, so the outcome does not hang on timing; once they are free again the
/// same request is accepted.
#[tokio::test(flavor = "multi_thread")]
async fn submissions_beyond_the_decode_slots_answer_decode_busy() {
    let limits = InputLimits {
        decode_slots: 2,
        decode_wait: Duration::from_millis(50),
        ..InputLimits::default()
    };
    let (state, data_dir) = state_with("decode-busy", limits);
    let held = state
        .queue
        .decode_slots()
        .acquire_many_owned(2)
        .await
        .unwrap();
    let app = app(state.clone());
    let busy = app.clone().oneshot(submission()).await.unwrap();
    let (status, retry_after) = (busy.status(), busy.headers().get("retry-after").cloned());
    let body = axum::body::to_bytes(busy.into_body(), 1 << 20)
        .await
        .unwrap();
    let problem: serde_json::Value = serde_json::from_slice(&body).unwrap();
    assert_eq!(status, StatusCode::SERVICE_UNAVAILABLE, "{problem}");
    assert_eq!(retry_after.unwrap(), "1");
    assert_eq!(problem["code"], "decode-busy");
    drop(held);
    let created = app.oneshot(submission()).await.unwrap();
    assert_eq!(created.status(), StatusCode::CREATED);
    let queue = Arc::clone(&state.queue);
    tokio::task::spawn_blocking(move || queue.drain(Duration::ZERO))
        .await
        .unwrap();
    let _ = std::fs::remove_dir_all(data_dir);
}
