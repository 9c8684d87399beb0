//! Cheap attacks on a real `covec serve` over loopback (issue 13): requests that must not grow
//! the server's state without bound, connections that must not lock clients out or hold up a
//! shutdown.
#![cfg(all(feature = "cli", feature = "service"))]

mod service_support;

use std::sync::Arc;

use hyper::{Method, StatusCode};
use service_support::{DataDir, Server};

/// Made-up methods and raw paths must not become label values: `/metrics` stays the same few
/// series however many distinct ones clients send.
#[tokio::test(flavor = "multi_thread")]
async fn metrics_labels_stay_bounded_under_made_up_methods_and_paths() {
    let dir = DataDir::new("metrics-labels");
    let server = Arc::new(Server::start(&dir.0, &[]));
    let requests = 4000;
    let tasks: Vec<_> = (0..8)
        .map(|task| {
            let server = Arc::clone(&server);
            tokio::spawn(async move {
                for i in (task..requests).step_by(8) {
                    let method = Method::from_bytes(format!("MADEUP{i}").as_bytes()).unwrap();
                    let path = if i % 2 == 0 {
                        "/healthz".to_owned()
                    } else {
                        format!("/no-such-route-{i}")
                    };
                    let reply = server.request(method, &path, &[], Vec::new()).await;
                    assert!(reply.status.is_client_error(), "{}", reply.status);
                }
            })
        })
        .collect();
    for task in tasks {
        task.await.unwrap();
    }
    let metrics = server.get("/metrics").await;
    assert_eq!(metrics.status, StatusCode::OK);
    let text = metrics.text();
    assert!(!text.contains("MADEUP"), "a made-up method is a label");
    assert!(!text.contains("no-such-route"), "a raw path is a label");
    // Every request is counted, under the shared labels.
    for (route, status) in [("/healthz", 405), ("unmatched", 404)] {
        let series = format!(
            "covec_http_requests_total{{method=\"other\",route=\"{route}\",status=\"{status}\"}} {}",
            requests / 2
        );
        assert!(text.contains(&series), "no `{series}` in {text}");
    }
    // Before the fix these requests made it about 5.5 MB.
    assert!(text.len() < 16 * 1024, "/metrics is {} bytes", text.len());
}
