//! Cheap attacks on a real `covec serve` over loopback (issue 13): requests that must not grow
//! the server's state without bound, connections that must not lock clients out or hold up a
//! shutdown.
#![cfg(all(feature = "cli", feature = "service"))]

use crate::service_support;

use std::sync::Arc;
use std::time::{Duration, Instant};

use hyper::{Method, StatusCode};
use service_support::{DataDir, Server};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

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

/// Opens `count` connections that each send half a request's headers and then nothing.
async fn half_open(server: &Server, count: usize) -> Vec<TcpStream> {
    let addr = server.base.strip_prefix("http://").unwrap();
    let mut connections = Vec::with_capacity(count);
    for _ in 0..count {
        let mut stream = TcpStream::connect(addr).await.unwrap();
        stream
            .write_all(b"GET /healthz HTTP/1.1\r\nHost: covec\r\n")
            .await
            .unwrap();
        connections.push(stream);
    }
    connections
}

/// How many of `connections` the server has closed (end of stream or reset) within `wait`.
async fn closed_within(connections: &mut [TcpStream], wait: Duration) -> usize {
    let deadline = tokio::time::Instant::now() + wait;
    let mut closed = 0;
    for stream in connections {
        let mut byte = [0_u8; 1];
        let read = tokio::time::timeout_at(deadline, stream.read(&mut byte)).await;
        if matches!(read, Ok(Ok(0) | Err(_))) {
            closed += 1;
        }
    }
    closed
}

/// Slowloris: connections holding half-sent headers neither lock new clients out (the oldest
/// idle ones make room) nor stay open past the header read timeout; a stalled body ends at the
/// body read timeout.
#[tokio::test(flavor = "multi_thread")]
async fn half_open_connections_neither_lock_clients_out_nor_stay_open() {
    let dir = DataDir::new("slowloris");
    let server = Server::start(
        &dir.0,
        &[
            "--max-connections",
            "100",
            "--header-read-timeout",
            "1",
            "--body-read-timeout",
            "1",
        ],
    );
    let mut idle = half_open(&server, 300).await;
    let started = Instant::now();
    let reply = server.get("/healthz").await;
    let waited = started.elapsed();
    assert_eq!(reply.status, StatusCode::OK);
    println!("a new client with 300 half-open connections waited {waited:?}");
    assert!(waited < Duration::from_millis(900), "waited {waited:?}");
    // Evicted at once or closed by the 1 s header timeout.
    let closed = closed_within(&mut idle, Duration::from_secs(3)).await;
    assert_eq!(closed, idle.len(), "half-open connections left open");

    // A body that stops halfway fails after the 1 s body read timeout.
    let addr = server.base.strip_prefix("http://").unwrap();
    let mut upload = TcpStream::connect(addr).await.unwrap();
    upload
        .write_all(
            b"POST /v1/jobs HTTP/1.1\r\nHost: covec\r\nContent-Type: application/json\r\n\
              Content-Length: 1000\r\n\r\n{\"image\": \"",
        )
        .await
        .unwrap();
    let started = Instant::now();
    let mut answer = Vec::new();
    tokio::time::timeout(Duration::from_secs(3), upload.read_to_end(&mut answer))
        .await
        .expect("the stalled upload ends within 3 s")
        .unwrap();
    let answer = String::from_utf8_lossy(&answer);
    assert!(answer.starts_with("HTTP/1.1 400"), "{answer}");
    assert!(started.elapsed() >= Duration::from_millis(900));
}

/// SIGTERM with a half-open connection, an idle one and a running job: the process exits
/// within the grace period (the job is stopped and re-queued for the next start).
#[tokio::test(flavor = "multi_thread")]
async fn shutdown_completes_within_the_grace_period_despite_half_open_connections() {
    let dir = DataDir::new("shutdown-half-open");
    let server = Server::start(
        &dir.0,
        &[
            "--header-read-timeout",
            "60",
            "--shutdown-grace",
            "1",
            "--max-iterations",
            "10000000",
        ],
    );
    let created = server
        .submit(
            &[
                ("image", &service_support::test_png(64)),
                ("params", service_support::LONG_PARAMS.as_bytes()),
            ],
            &[],
        )
        .await;
    assert_eq!(created.status, StatusCode::CREATED, "{}", created.text());
    let id = created.json()["id"].as_str().unwrap().to_owned();
    server
        .wait_for(&id, Duration::from_secs(10), |job| {
            job["status"] == "running"
        })
        .await;
    let _half_open = half_open(&server, 1).await;
    let addr = server.base.strip_prefix("http://").unwrap();
    let _idle = TcpStream::connect(addr).await.unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    let started = Instant::now();
    server.stop();
    let took = started.elapsed();
    println!("stopped in {took:?} with a half-open connection and a running job");
    assert!(took < Duration::from_secs(3), "stopping took {took:?}");
}

/// Problem details echo client strings cut short, and never show the data directory's path.
#[tokio::test(flavor = "multi_thread")]
async fn problem_details_stay_short_and_hide_server_paths() {
    let dir = DataDir::new("details");
    let server = Server::start(&dir.0, &[]);
    let image = service_support::test_png(32);
    let params = format!(r#"{{"mode": "{}"}}"#, "m".repeat(100_000));
    let refused = server
        .submit(&[("image", &image), ("params", params.as_bytes())], &[])
        .await;
    let detail = service_support::problem(&refused)["detail"]
        .as_str()
        .unwrap()
        .to_owned();
    assert_eq!(refused.status, StatusCode::UNPROCESSABLE_ENTITY, "{detail}");
    assert!(detail.len() < 600, "a detail of {} bytes", detail.len());
    assert!(
        detail.contains(&format!("`{}…`", "m".repeat(64))),
        "{detail}"
    );

    dir.break_storage();
    let failed = server
        .submit(
            &[
                ("image", &image),
                ("params", service_support::QUICK_PARAMS.as_bytes()),
            ],
            &[],
        )
        .await;
    let problem = service_support::problem(&failed);
    assert_eq!(
        failed.status,
        StatusCode::INTERNAL_SERVER_ERROR,
        "{problem}"
    );
    let detail = problem["detail"].as_str().unwrap();
    if dir.keeps_files_locally() {
        assert!(detail.contains("Not a directory"), "{detail}");
    }
    assert!(
        !detail.contains("127.0.0.1"),
        "the store's endpoint in {detail}"
    );
    let root = dir.0.to_str().unwrap();
    assert!(!detail.contains(root), "the data directory in {detail}");
    assert!(!detail.contains("/tmp"), "a server path in {detail}");
}

/// Many small masks decode to far more than they weigh: the decoded total is capped per job.
#[tokio::test]
async fn decoded_inputs_are_capped_per_job() {
    let dir = DataDir::new("decoded-cap");
    // A 64² image is 12 288 bytes decoded, each 64² mask 4 096: two masks fit, three do not.
    let server = Server::start(&dir.0, &["--max-decoded-bytes", "20480"]);
    let image = service_support::test_png(64);
    let mut square = image::GrayImage::new(64, 64);
    for y in 16..48 {
        for x in 16..48 {
            square.put_pixel(x, y, image::Luma([255]));
        }
    }
    let mask = service_support::png(&image::DynamicImage::ImageLuma8(square));
    let params = br#"{"paths": 8, "max_size": 64}"#.as_slice();
    let two = [
        ("image", image.as_slice()),
        ("mask", mask.as_slice()),
        ("mask", mask.as_slice()),
        ("params", params),
    ];
    let accepted = server.submit(&two, &[]).await;
    assert_eq!(accepted.status, StatusCode::CREATED, "{}", accepted.text());

    let three = [
        ("image", image.as_slice()),
        ("mask", mask.as_slice()),
        ("mask", mask.as_slice()),
        ("mask", mask.as_slice()),
        ("params", params),
    ];
    let refused = server.submit(&three, &[]).await;
    assert_eq!(
        refused.status,
        StatusCode::PAYLOAD_TOO_LARGE,
        "{}",
        refused.text()
    );
    let problem = service_support::problem(&refused);
    assert_eq!(problem["code"], "inputs-too-large");
    assert_eq!(problem["limit"], 20480);
    assert_eq!(problem["actual"], 24576);
}

/// `POST /v1/jobs{query}` with `image` and quick parameters.
async fn submit_to(server: &Server, image: &[u8], query: &str) -> service_support::Reply {
    let params = service_support::QUICK_PARAMS.as_bytes();
    let (content_type, body) = service_support::multipart(&[("image", image), ("params", params)]);
    server
        .request(
            Method::POST,
            &format!("/v1/jobs{query}"),
            &[("content-type", &content_type)],
            body,
        )
        .await
}

/// A JPEG cut in half is refused (422 `truncated-image`) rather than vectorised on grey fill,
/// unless the client opts in with `accept_truncated=true`; a label map with too many values
/// says so (not "257 masks were sent").
#[tokio::test]
async fn truncated_jpegs_and_crowded_label_maps_are_refused_clearly() {
    let dir = DataDir::new("truncated");
    let server = Server::start(&dir.0, &["--max-masks", "8"]);
    // Large enough that half the file is well into the scan data.
    let photo = image::load_from_memory(&service_support::test_png(192)).unwrap();
    let mut jpeg = Vec::new();
    photo
        .write_to(
            &mut std::io::Cursor::new(&mut jpeg),
            image::ImageFormat::Jpeg,
        )
        .unwrap();
    let half = &jpeg[..jpeg.len() / 2];
    let params = service_support::QUICK_PARAMS.as_bytes();
    let refused = submit_to(&server, half, "").await;
    assert_eq!(
        refused.status,
        StatusCode::UNPROCESSABLE_ENTITY,
        "{}",
        refused.text()
    );
    assert_eq!(
        service_support::problem(&refused)["code"],
        "truncated-image"
    );
    let accepted = submit_to(&server, half, "?accept_truncated=true").await;
    assert_eq!(accepted.status, StatusCode::CREATED, "{}", accepted.text());
    let id = accepted.json()["id"].as_str().unwrap().to_owned();
    let job = server
        .wait_for(&id, Duration::from_secs(60), |job| {
            job["status"] != "queued" && job["status"] != "running"
        })
        .await;
    assert_eq!(job["status"], "succeeded", "{job}");
    let whole = submit_to(&server, &jpeg, "").await;
    assert_eq!(whole.status, StatusCode::CREATED, "{}", whole.text());
    let bad_query = submit_to(&server, &jpeg, "?accept_truncated=maybe").await;
    assert_eq!(
        bad_query.status,
        StatusCode::BAD_REQUEST,
        "{}",
        bad_query.text()
    );

    // 10 grey levels with a limit of 8 masks.
    let labels = image::GrayImage::from_fn(48, 48, |x, _| image::Luma([(x / 5) as u8 * 20]));
    let labels = service_support::png(&image::DynamicImage::ImageLuma8(labels));
    let image = service_support::test_png(48);
    let (content_type, body) =
        service_support::multipart(&[("image", &image), ("labels", &labels), ("params", params)]);
    let refused = server
        .request(
            Method::POST,
            "/v1/jobs",
            &[("content-type", &content_type)],
            body,
        )
        .await;
    assert_eq!(
        refused.status,
        StatusCode::PAYLOAD_TOO_LARGE,
        "{}",
        refused.text()
    );
    let problem = service_support::problem(&refused);
    assert_eq!(
        (problem["code"].as_str(), problem["limit"].as_u64()),
        (Some("too-many-masks"), Some(8))
    );
    let detail = problem["detail"].as_str().unwrap();
    assert!(
        detail.contains("label map holds more than 8 distinct values"),
        "{detail}"
    );
    assert!(!detail.contains("masks were sent"), "{detail}");
}

/// The issue's memory attacks with default settings, the server's peak RSS (`VmHWM`) held under
/// 1 GiB: a flat 4000² image with 256 all-zero 4000² masks (4.5 GiB before the decode cap),
/// concurrent 4000² RGBA16 PNGs (3.2 GiB for 16 before the decode slots), then made-up
/// methods and scrapes of `/metrics`.
#[tokio::test(flavor = "multi_thread")]
async fn peak_memory_stays_under_1_gib_under_decode_and_metrics_attacks() {
    let dir = DataDir::new("memory-ceiling");
    let server = Arc::new(Server::start(&dir.0, &["--max-queued", "64"]));
    let side = 4000;
    let flat = service_support::png(&image::DynamicImage::ImageRgb8(
        image::RgbImage::from_pixel(side, side, image::Rgb([128, 128, 128])),
    ));
    let zero_mask = service_support::png(&image::DynamicImage::ImageLuma8(image::GrayImage::new(
        side, side,
    )));
    let rgba16 = service_support::png(&image::DynamicImage::ImageRgba16(
        image::ImageBuffer::from_fn(side, side, |x, y| {
            image::Rgba([(x * 16) as u16, (y * 16) as u16, 30_000, 65_535])
        }),
    ));
    let params = service_support::QUICK_PARAMS.as_bytes();
    let mut masked: Vec<(&str, &[u8])> = vec![("image", &flat), ("params", params)];
    masked.extend(std::iter::repeat_n(("mask", zero_mask.as_slice()), 256));
    let (masked_type, masked_body) = service_support::multipart(&masked);
    let (rgba_type, rgba_body) =
        service_support::multipart(&[("image", &rgba16), ("params", params)]);
    let attacks: Vec<_> = (0..10)
        .map(|i| {
            let server = Arc::clone(&server);
            let (content_type, body) = if i < 2 {
                (masked_type.clone(), masked_body.clone())
            } else {
                (rgba_type.clone(), rgba_body.clone())
            };
            tokio::spawn(async move {
                server
                    .request(
                        Method::POST,
                        "/v1/jobs",
                        &[("content-type", &content_type)],
                        body,
                    )
                    .await
            })
        })
        .collect();
    let mut statuses = Vec::new();
    for attack in attacks {
        let reply = attack.await.unwrap();
        assert!(
            [
                StatusCode::CREATED,
                StatusCode::PAYLOAD_TOO_LARGE,
                StatusCode::SERVICE_UNAVAILABLE
            ]
            .contains(&reply.status),
            "{} {}",
            reply.status,
            reply.text()
        );
        statuses.push(reply.status.as_u16());
    }
    for i in 0..2000 {
        let method = Method::from_bytes(format!("M{i}").as_bytes()).unwrap();
        server.request(method, "/healthz", &[], Vec::new()).await;
        if i % 100 == 0 {
            assert_eq!(server.get("/metrics").await.status, StatusCode::OK);
        }
    }
    let peak = server.peak_rss_kib().expect("VmHWM in /proc");
    println!(
        "decode attacks answered {statuses:?}; peak RSS {} MiB",
        peak / 1024
    );
    assert!(peak < 1 << 20, "peak RSS {} MiB", peak / 1024);
}
