//! The body of `POST /v1/jobs` (multipart form or JSON with base64 images) through the
//! service's own reader and input decoding (`covec::service::fuzzing::submission`). The first
//! byte picks the content type and `accept_truncated`; a refusal must be a 4xx, never a panic or a 5xx.
#![no_main]

use std::sync::LazyLock;

use axum::body::Body;
use axum::extract::Request;
use covec::service::InputLimits;
use covec::service::fuzzing;
use libfuzzer_sys::fuzz_target;

/// The boundary the multipart seeds use.
const BOUNDARY: &str = "covecfuzz";

static RUNTIME: LazyLock<tokio::runtime::Runtime> = LazyLock::new(|| {
    tokio::runtime::Builder::new_current_thread()
        .build()
        .expect("runtime")
});

fuzz_target!(|data: &[u8]| {
    let Some((&which, body)) = data.split_first() else {
        return;
    };
    let content_type = match which % 3 {
        0 => format!("multipart/form-data; boundary={BOUNDARY}"),
        1 => "application/json".to_owned(),
        _ => "multipart/form-data; boundary=\"covec fuzz\"".to_owned(),
    };
    let request = Request::post("/v1/jobs")
        .header("content-type", content_type)
        .body(Body::from(body.to_vec()))
        .expect("request");
    // Service defaults, with pixel budgets small enough to fuzz quickly.
    let limits = InputLimits {
        max_pixels: 1 << 18,
        max_decoded_bytes: 8 << 20,
        ..InputLimits::default()
    };
    let accept_truncated = which & 0x80 != 0;
    if let Err(status) = RUNTIME.block_on(fuzzing::submission(request, &limits, accept_truncated)) {
        assert!(status.is_client_error(), "refused with {status}");
    }
});
