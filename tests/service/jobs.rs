//! Jobs end to end through the real pipeline: success and results, events, cancel, queue
//! limits, idempotency, restart recovery. Tiny images and iteration counts keep each job short.
#![cfg(all(feature = "cli", feature = "service"))]

use crate::service_support;

use std::time::Duration;

use base64::Engine;
use http_body_util::{BodyExt, Full};
use hyper::body::Bytes;
use hyper::{Method, Request, StatusCode};
use hyper_util::client::legacy::Client;
use hyper_util::rt::TokioExecutor;
use serde_json::json;
use service_support::{DataDir, LONG_PARAMS, QUICK_PARAMS, Server, problem, test_png};

const PATIENCE: Duration = Duration::from_secs(60);
/// Lets LONG_PARAMS through.
const BIG_BUDGET: &[&str] = &["--max-iterations", "10000000"];

fn terminal(job: &serde_json::Value) -> bool {
    ["succeeded", "failed", "canceled"].contains(&job["status"].as_str().unwrap())
}

async fn submit_quick(server: &Server) -> String {
    let created = server
        .submit(
            &[
                ("image", &test_png(48)),
                ("params", QUICK_PARAMS.as_bytes()),
            ],
            &[],
        )
        .await;
    assert_eq!(created.status, StatusCode::CREATED, "{}", created.text());
    created.json()["id"].as_str().unwrap().to_owned()
}

async fn submit_long(server: &Server) -> String {
    let created = server
        .submit(
            &[("image", &test_png(64)), ("params", LONG_PARAMS.as_bytes())],
            &[],
        )
        .await;
    assert_eq!(created.status, StatusCode::CREATED, "{}", created.text());
    created.json()["id"].as_str().unwrap().to_owned()
}

#[tokio::test]
async fn a_job_succeeds_and_serves_every_result() {
    let dir = DataDir::new("success");
    let server = Server::start(&dir.0, &["--workers", "1"]);
    let id = submit_quick(&server).await;
    let job = server.wait_for(&id, PATIENCE, terminal).await;
    assert_eq!(job["status"], "succeeded", "{job}");
    assert_eq!(
        job["progress"]["fraction"].as_f64().map(|f| f > 0.99),
        Some(true),
        "{job}"
    );
    assert!(
        job["completed_at"].is_string() && job["expires_at"].is_string(),
        "{job}"
    );

    let svg = server.get(&format!("/v1/jobs/{id}/svg")).await;
    assert_eq!(
        (svg.status, svg.header("content-type")),
        (StatusCode::OK, Some("image/svg+xml"))
    );
    let document = svg.text();
    let tree = roxmltree::Document::parse(&document).expect("well-formed SVG");
    let groups: Vec<_> = tree
        .descendants()
        .filter_map(|node| node.attribute("id"))
        .collect();
    for layer in ["albedo", "shade", "light"] {
        assert!(
            groups.contains(&layer),
            "no <g id=\"{layer}\"> in {document}"
        );
        let layer_svg = server
            .get(&format!("/v1/jobs/{id}/layers/{layer}.svg"))
            .await;
        assert_eq!(layer_svg.status, StatusCode::OK, "{layer}");
        roxmltree::Document::parse(&layer_svg.text()).expect("well-formed layer SVG");
    }
    let scene = server.get(&format!("/v1/jobs/{id}/scene.json")).await;
    assert_eq!(scene.status, StatusCode::OK);
    let scene: covec::scene::Scene =
        serde_json::from_slice(&scene.body).expect("the scene loads back");
    assert!(scene.path_count() <= 8, "the path budget holds");

    let previews = server.get(&format!("/v1/jobs/{id}/previews")).await.json();
    let items = previews["items"].as_array().unwrap();
    assert!(
        !items.is_empty(),
        "every stage leaves a preview: {previews}"
    );
    for item in items {
        let png = server.get(item["url"].as_str().unwrap()).await;
        assert_eq!(
            (png.status, png.header("content-type")),
            (StatusCode::OK, Some("image/png"))
        );
        assert!(png.body.starts_with(b"\x89PNG"));
    }
    let missing = server
        .get(&format!("/v1/jobs/{id}/layers/shadow.svg"))
        .await;
    assert_eq!(problem(&missing)["code"], "result-not-found");
    let missing = server
        .get(&format!("/v1/jobs/{id}/previews/nope.png"))
        .await;
    assert_eq!(problem(&missing)["code"], "result-not-found");

    assert_eq!(
        server
            .request(Method::DELETE, &format!("/v1/jobs/{id}"), &[], Vec::new())
            .await
            .status,
        StatusCode::NO_CONTENT
    );
    assert_eq!(
        server.get(&format!("/v1/jobs/{id}")).await.status,
        StatusCode::NOT_FOUND
    );
    assert!(!dir.job_files_exist(&id), "DELETE removes the job's files");
}

#[tokio::test]
async fn json_submission_with_base64_and_idempotency_key() {
    let dir = DataDir::new("json");
    let server = Server::start(&dir.0, &["--workers", "1"]);
    let image = base64::engine::general_purpose::STANDARD.encode(test_png(32));
    let params: serde_json::Value = serde_json::from_str(QUICK_PARAMS).unwrap();
    let body = json!({ "image": format!("data:image/png;base64,{image}"), "params": params });
    let key = [
        ("content-type", "application/json"),
        ("idempotency-key", "order-42"),
    ];
    let first = server
        .request(
            Method::POST,
            "/v1/jobs",
            &key,
            body.to_string().into_bytes(),
        )
        .await;
    assert_eq!(first.status, StatusCode::CREATED, "{}", first.text());
    let again = server
        .request(
            Method::POST,
            "/v1/jobs",
            &key,
            body.to_string().into_bytes(),
        )
        .await;
    assert_eq!(again.status, StatusCode::CREATED);
    assert_eq!(again.header("idempotent-replayed"), Some("true"));
    assert_eq!(
        again.json()["id"],
        first.json()["id"],
        "same key + same body → same job"
    );
    // The same bytes as schemathesis wrote them: a bit set among the padding bits, and (as
    // Python's and browsers' decoders allow) no `=`: decoded alike, so the same job again.
    let lenient = {
        let alphabet = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
        let data = image.trim_end_matches('=');
        assert!(
            data.len() < image.len(),
            "the test image's base64 ends in padding"
        );
        let last = alphabet.find(data.chars().last().unwrap()).unwrap();
        let flipped = alphabet.as_bytes()[last ^ 1] as char;
        format!("{}{flipped}", &data[..data.len() - 1])
    };
    let body_lenient = json!({ "image": lenient, "params": params });
    let replay = server
        .request(
            Method::POST,
            "/v1/jobs",
            &key,
            body_lenient.to_string().into_bytes(),
        )
        .await;
    assert_eq!(replay.status, StatusCode::CREATED, "{}", replay.text());
    assert_eq!(replay.json()["id"], first.json()["id"]);
    let changed = json!({ "image": image, "params": { "paths": 9 } });
    let conflict = server
        .request(
            Method::POST,
            "/v1/jobs",
            &key,
            changed.to_string().into_bytes(),
        )
        .await;
    assert_eq!(conflict.status, StatusCode::UNPROCESSABLE_ENTITY);
    assert_eq!(problem(&conflict)["code"], "idempotency-key-reused");
    let id = first.json()["id"].as_str().unwrap().to_owned();
    let job = server.wait_for(&id, PATIENCE, terminal).await;
    assert_eq!(job["status"], "succeeded", "{job}");
}

#[tokio::test]
async fn events_stream_progress_and_end_with_the_final_status() {
    let dir = DataDir::new("events");
    let server = Server::start(&dir.0, &["--workers", "1"]);
    let id = submit_quick(&server).await;
    let events = server
        .events(&format!("/v1/jobs/{id}/events"), PATIENCE)
        .await;
    let (last_name, last_data) = events.last().expect("some events");
    assert_eq!(last_name, "completed");
    let last: serde_json::Value = serde_json::from_str(last_data).unwrap();
    assert_eq!(last["status"], "succeeded", "{last}");
    assert!(
        events[..events.len() - 1]
            .iter()
            .all(|(name, _)| name == "progress" || name == "draft"),
        "{events:?}"
    );
    // A finished job's stream is just its final event.
    let replay = server
        .events(&format!("/v1/jobs/{id}/events"), PATIENCE)
        .await;
    assert_eq!(replay.len(), 1);
    assert_eq!(replay[0].0, "completed");
}

#[tokio::test]
async fn cancel_stops_a_running_job_and_frees_the_worker() {
    let dir = DataDir::new("cancel");
    let mut args = vec!["--workers", "1"];
    args.extend_from_slice(BIG_BUDGET);
    let server = Server::start(&dir.0, &args);
    let long = submit_long(&server).await;
    let quick = submit_quick(&server).await;
    server
        .wait_for(&long, PATIENCE, |job| {
            job["status"] == "running" && job["progress"].is_object()
        })
        .await;
    let queued = server.get(&format!("/v1/jobs/{quick}")).await.json();
    assert_eq!(
        (queued["status"].clone(), queued["queue_position"].clone()),
        (json!("queued"), json!(0))
    );

    let cancel = server.cancel(&long).await;
    assert_eq!(cancel.status, StatusCode::ACCEPTED, "{}", cancel.text());
    assert_eq!(cancel.json()["cancel_requested"], true);
    let canceled = server
        .wait_for(&long, Duration::from_secs(10), terminal)
        .await;
    assert_eq!(
        (
            canceled["status"].clone(),
            canceled["cancel_reason"].clone()
        ),
        (json!("canceled"), json!("user"))
    );
    let next = server.wait_for(&quick, PATIENCE, terminal).await;
    assert_eq!(
        next["status"], "succeeded",
        "the freed worker runs the next job: {next}"
    );
    let results = server.get(&format!("/v1/jobs/{long}/svg")).await;
    assert_eq!(
        (results.status, problem(&results)["code"].clone()),
        (StatusCode::CONFLICT, json!("job-not-succeeded"))
    );
    // Canceling a finished job changes nothing.
    let again = server.cancel(&long).await;
    assert_eq!(
        (again.status, again.json()["status"].clone()),
        (StatusCode::OK, json!("canceled"))
    );
}

#[tokio::test]
async fn a_full_queue_answers_503_with_retry_after() {
    let dir = DataDir::new("full");
    let mut args = vec!["--workers", "1", "--max-queued", "1"];
    args.extend_from_slice(BIG_BUDGET);
    let server = Server::start(&dir.0, &args);
    let running = submit_long(&server).await;
    server
        .wait_for(&running, PATIENCE, |job| job["status"] == "running")
        .await;
    let image = test_png(64);
    let long = [
        ("image", image.as_slice()),
        ("params", LONG_PARAMS.as_bytes()),
    ];
    let waiting = server.submit(&long, &[("idempotency-key", "wait-1")]).await;
    assert_eq!(waiting.status, StatusCode::CREATED, "{}", waiting.text());
    let waiting = waiting.json()["id"].as_str().unwrap().to_owned();
    let refused = server
        .submit(
            &[
                ("image", &test_png(32)),
                ("params", QUICK_PARAMS.as_bytes()),
            ],
            &[],
        )
        .await;
    assert_eq!(
        refused.status,
        StatusCode::SERVICE_UNAVAILABLE,
        "{}",
        refused.text()
    );
    let seconds: u64 = refused
        .header("retry-after")
        .expect("Retry-After")
        .parse()
        .unwrap();
    assert!(seconds >= 1);
    assert_eq!(problem(&refused)["code"], "queue-full");
    // A retry of the queued job gets its replay although the queue is full; a new key does not.
    let retry = server.submit(&long, &[("idempotency-key", "wait-1")]).await;
    assert_eq!(retry.status, StatusCode::CREATED, "{}", retry.text());
    assert_eq!(retry.header("idempotent-replayed"), Some("true"));
    assert_eq!(retry.json()["id"], json!(waiting));
    let new_key = server.submit(&long, &[("idempotency-key", "wait-2")]).await;
    assert_eq!(problem(&new_key)["code"], "queue-full");
    // Canceling the queued job makes room again.
    let cancel = server.cancel(&waiting).await;
    assert_eq!(
        (cancel.status, cancel.json()["status"].clone()),
        (StatusCode::OK, json!("canceled"))
    );
    let accepted = server
        .submit(
            &[
                ("image", &test_png(32)),
                ("params", QUICK_PARAMS.as_bytes()),
            ],
            &[],
        )
        .await;
    assert_eq!(accepted.status, StatusCode::CREATED, "{}", accepted.text());
    server.cancel(&running).await;
}

#[tokio::test]
async fn the_time_limit_fails_a_job_with_a_clear_reason() {
    let dir = DataDir::new("deadline");
    let mut args = vec!["--workers", "1", "--job-time-limit", "1"];
    args.extend_from_slice(BIG_BUDGET);
    let server = Server::start(&dir.0, &args);
    let id = submit_long(&server).await;
    let job = server
        .wait_for(&id, Duration::from_secs(30), terminal)
        .await;
    assert_eq!(job["status"], "failed", "{job}");
    assert_eq!(job["error"]["code"], "time-limit", "{job}");
    assert_eq!(job["cancel_reason"], "deadline", "{job}");
}

#[tokio::test]
async fn a_restarted_server_serves_finished_jobs_and_reruns_interrupted_ones() {
    let dir = DataDir::persistent("restart");
    let mut args = vec!["--workers", "1", "--shutdown-grace", "0"];
    args.extend_from_slice(BIG_BUDGET);
    let server = Server::start(&dir.0, &args);
    let done = submit_quick(&server).await;
    assert_eq!(
        server.wait_for(&done, PATIENCE, terminal).await["status"],
        "succeeded"
    );
    let svg = server.get(&format!("/v1/jobs/{done}/svg")).await.body;
    let scene = server
        .get(&format!("/v1/jobs/{done}/scene.json"))
        .await
        .body;
    let interrupted = submit_long(&server).await;
    server
        .wait_for(&interrupted, PATIENCE, |job| job["status"] == "running")
        .await;
    server.stop();

    let server = Server::start(&dir.0, &args);
    assert_eq!(
        server.get(&format!("/v1/jobs/{done}/svg")).await.body,
        svg,
        "the same SVG after a restart"
    );
    assert_eq!(
        server
            .get(&format!("/v1/jobs/{done}/scene.json"))
            .await
            .body,
        scene
    );
    let job = server.get(&format!("/v1/jobs/{interrupted}")).await.json();
    assert!(
        ["queued", "running"].contains(&job["status"].as_str().unwrap()),
        "re-queued: {job}"
    );
    server.cancel(&interrupted).await;
    server
        .wait_for(&interrupted, Duration::from_secs(10), terminal)
        .await;
}

#[tokio::test]
async fn results_expire_after_the_retention_period() {
    let dir = DataDir::new("retention");
    let server = Server::start(&dir.0, &["--workers", "1", "--retention", "1"]);
    let id = submit_quick(&server).await;
    assert_eq!(
        server.wait_for(&id, PATIENCE, terminal).await["status"],
        "succeeded"
    );
    let job = server
        .wait_for(&id, Duration::from_secs(10), |job| {
            job["data_removed"] == true
        })
        .await;
    assert!(job["urls"]["results"].is_null(), "{job}");
    let gone = server.get(&format!("/v1/jobs/{id}/svg")).await;
    assert_eq!(
        (gone.status, problem(&gone)["code"].clone()),
        (StatusCode::GONE, json!("data-removed"))
    );
    assert!(!dir.job_files_exist(&id), "the files are removed");
}

#[tokio::test]
async fn prefer_wait_answers_with_the_finished_job_or_202_in_time() {
    let dir = DataDir::new("prefer-wait");
    let mut args = vec!["--workers", "1", "--max-wait", "2"];
    args.extend_from_slice(BIG_BUDGET);
    let server = Server::start(&dir.0, &args);
    let quick = [
        ("image", test_png(48)),
        ("params", QUICK_PARAMS.as_bytes().to_vec()),
    ];
    let quick: Vec<(&str, &[u8])> = quick.iter().map(|(n, b)| (*n, b.as_slice())).collect();

    // A small job ends within the wait: 200 with the finished job.
    let done = server
        .submit(&quick, &[("prefer", "respond-async, wait=30")])
        .await;
    assert_eq!(done.status, StatusCode::OK, "{}", done.text());
    assert_eq!(done.json()["status"], "succeeded");
    assert!(done.header("location").is_some());
    // Asked 30 s, capped by --max-wait.
    assert_eq!(done.header("preference-applied"), Some("wait=2"));

    // A long one does not: 202 after the (capped) wait, the job still going.
    let started = std::time::Instant::now();
    let long = [
        ("image", test_png(64)),
        ("params", LONG_PARAMS.as_bytes().to_vec()),
    ];
    let long: Vec<(&str, &[u8])> = long.iter().map(|(n, b)| (*n, b.as_slice())).collect();
    let pending = server.submit(&long, &[("prefer", "wait=30")]).await;
    let waited = started.elapsed();
    assert_eq!(pending.status, StatusCode::ACCEPTED, "{}", pending.text());
    assert!(!terminal(&pending.json()), "{}", pending.text());
    assert!(
        waited >= Duration::from_secs(2) && waited < Duration::from_secs(10),
        "{waited:?}"
    );
    let id = pending.json()["id"].as_str().unwrap().to_owned();
    let cancel = server.cancel(&id).await;
    assert!(cancel.status.is_success(), "{}", cancel.text());

    // A bare `wait` (as other APIs write it): as long as the server allows.
    let bare = server.submit(&quick, &[("prefer", "wait")]).await;
    assert_eq!(bare.status, StatusCode::OK, "{}", bare.text());
    assert_eq!(bare.header("preference-applied"), Some("wait=2"));
    let pending = server.submit(&long, &[("prefer", "Wait")]).await;
    assert_eq!(pending.status, StatusCode::ACCEPTED, "{}", pending.text());
    assert_eq!(pending.header("preference-applied"), Some("wait=2"));
    let id = pending.json()["id"].as_str().unwrap().to_owned();
    assert!(server.cancel(&id).await.status.is_success());

    // Without the preference, or with a malformed one: 201 at once, as before.
    let plain = server.submit(&quick, &[("prefer", "wait=soon")]).await;
    assert_eq!(plain.status, StatusCode::CREATED, "{}", plain.text());
    assert!(plain.header("preference-applied").is_none());
}

/// (id, event name) of each event of a job's stream, read to its end, resuming after `last`.
async fn stream(server: &Server, path: &str, last: Option<&str>) -> Vec<(String, String)> {
    let headers: Vec<(&str, &str)> = last.map(|v| ("last-event-id", v)).into_iter().collect();
    let reply = server
        .request(Method::GET, path, &headers, Vec::new())
        .await;
    assert_eq!(reply.status, StatusCode::OK, "{}", reply.text());
    event_ids(&reply.text())
}

/// (id, event name) of each event in an SSE body.
fn event_ids(text: &str) -> Vec<(String, String)> {
    text.split("\n\n")
        .filter_map(parse_event)
        .map(|event| (event.id, event.name))
        .collect()
}

/// One Server-Sent Event of a job's stream.
#[derive(Debug)]
struct StreamEvent {
    id: String,
    name: String,
    data: serde_json::Value,
}

impl StreamEvent {
    /// The sequence number in the id (`sequence.digest`).
    fn sequence(&self) -> u64 {
        self.id.split_once('.').unwrap().0.parse().unwrap()
    }
}

/// One block of an SSE body as an event, or None for a keep-alive comment.
fn parse_event(block: &str) -> Option<StreamEvent> {
    let field = |name: &str| {
        block
            .lines()
            .find_map(|line| line.strip_prefix(name).map(|v| v.trim().to_owned()))
    };
    Some(StreamEvent {
        id: field("id:")?,
        name: field("event:")?,
        data: serde_json::from_str(&field("data:")?).unwrap(),
    })
}

/// Reads a job's event stream as it comes (resuming after `last`), until `enough` holds for
/// what arrived or the stream ends; then drops the connection, as a client losing it would.
async fn read_stream(
    server: &Server,
    path: &str,
    last: Option<&str>,
    enough: impl Fn(&[StreamEvent]) -> bool,
) -> Vec<StreamEvent> {
    let client = Client::builder(TokioExecutor::new()).build_http::<Full<Bytes>>();
    let mut request = Request::get(format!("{}{path}", server.base));
    if let Some(last) = last {
        request = request.header("last-event-id", last);
    }
    let response = client
        .request(request.body(Full::new(Bytes::new())).unwrap())
        .await
        .unwrap();
    assert_eq!(response.status(), StatusCode::OK);
    let mut body = response.into_body();
    let (mut text, mut events) = (String::new(), Vec::new());
    while !enough(&events) {
        let Some(frame) = tokio::time::timeout(PATIENCE, body.frame())
            .await
            .expect("an event or the stream's end in time")
        else {
            break;
        };
        if let Ok(data) = frame.unwrap().into_data() {
            text.push_str(std::str::from_utf8(&data).unwrap());
        }
        while let Some(end) = text.find("\n\n") {
            let block: String = text.drain(..end + 2).collect();
            events.extend(parse_event(&block));
        }
    }
    events
}

#[tokio::test]
async fn a_resumed_event_stream_repeats_nothing_and_misses_nothing() {
    let dir = DataDir::new("resume");
    let server = Server::start(&dir.0, &["--workers", "1"]);
    let id = submit_quick(&server).await;
    server.wait_for(&id, PATIENCE, terminal).await;
    let path = format!("/v1/jobs/{id}/events");
    let first = stream(&server, &path, None).await;
    assert_eq!(first.len(), 1, "{first:?}");
    let (last_id, name) = &first[0];
    assert_eq!(name, "completed");
    let digest = last_id.strip_prefix("0.").expect("ids are sequence.digest");

    // Resuming with the id of the ended state: nothing more to send.
    assert!(stream(&server, &path, Some(last_id)).await.is_empty());
    // With an id of an older state: the current one, numbered after it.
    let resumed = stream(&server, &path, Some("4.0000000000000000")).await;
    assert_eq!(
        resumed,
        vec![(format!("5.{digest}"), "completed".to_owned())]
    );
    // A malformed id is ignored.
    assert_eq!(stream(&server, &path, Some("soon")).await, first);
}

#[tokio::test]
async fn a_stream_dropped_while_the_job_runs_resumes_without_repeats_or_gaps() {
    let dir = DataDir::new("resume-running");
    let mut args = vec!["--workers", "1"];
    args.extend_from_slice(BIG_BUDGET);
    let server = Server::start(&dir.0, &args);
    let id = submit_long(&server).await;
    let path = format!("/v1/jobs/{id}/events");
    let running = |events: &[StreamEvent]| {
        events
            .iter()
            .filter(|event| event.data["status"] == "running")
            .count()
    };
    // The connection drops after two events of the running job; the job goes on meanwhile.
    let before = read_stream(&server, &path, None, |events| running(events) >= 2).await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    let last = before.last().unwrap();
    // Resumed from the last id received; the job is canceled a second later, which ends it.
    let (after, ()) = tokio::join!(
        read_stream(&server, &path, Some(&last.id), |_| false),
        async {
            tokio::time::sleep(Duration::from_secs(1)).await;
            let canceled = server.cancel(&id).await;
            assert!(canceled.status.is_success(), "{}", canceled.text());
        }
    );
    assert!(
        running(&after) >= 1,
        "no progress after resuming: {after:?}"
    );

    let all: Vec<_> = before.iter().chain(&after).collect();
    // No gap in the numbering: the resumed stream goes on from the id it was given.
    let sequences: Vec<_> = all.iter().map(|event| event.sequence()).collect();
    assert_eq!(sequences, (0..all.len() as u64).collect::<Vec<_>>());
    // Nothing repeated: the first resumed event is a state the client did not have yet, and
    // progress only moves forward.
    assert_ne!(
        last.data, after[0].data,
        "the resumed stream repeated the last state"
    );
    for pair in all.windows(2) {
        let elapsed = |event: &StreamEvent| event.data["progress"]["elapsed_seconds"].as_f64();
        assert!(elapsed(pair[0]) <= elapsed(pair[1]), "{pair:?}");
    }
    // Nothing missed: the stream ends with the job's final state, once.
    let names: Vec<_> = all.iter().map(|event| event.name.as_str()).collect();
    assert_eq!(names.iter().filter(|name| **name == "completed").count(), 1);
    assert_eq!(names.last(), Some(&"completed"));
    let final_state = server.get(&format!("/v1/jobs/{id}")).await.json();
    assert_eq!(final_state["status"], "canceled");
    assert_eq!(all.last().unwrap().data, final_state);
}

#[tokio::test]
async fn a_running_job_has_a_layered_draft_and_its_stream_says_so() {
    let dir = DataDir::new("draft");
    let mut args = vec!["--workers", "1"];
    args.extend_from_slice(BIG_BUDGET);
    let server = Server::start(&dir.0, &args);
    let id = submit_long(&server).await;
    let queued = submit_quick(&server).await;
    // Queued behind the long job, the quick one has no draft yet.
    let none = server.get(&format!("/v1/jobs/{queued}/draft.svg")).await;
    assert_eq!(none.status, StatusCode::NOT_FOUND, "{}", none.text());
    assert_eq!(problem(&none)["code"], "result-not-found");
    assert!(server.get(&format!("/v1/jobs/{queued}")).await.json()["draft"].is_null());

    // The long job's first draft comes after its init stage, long before its end.
    let path = format!("/v1/jobs/{id}/events");
    let events = read_stream(&server, &path, None, |events| {
        events.iter().any(|event| event.name == "draft")
    })
    .await;
    let first = events.iter().find(|event| event.name == "draft").unwrap();
    assert_eq!(first.data["status"], "running", "{first:?}");
    assert_eq!(first.data["draft"]["stage"], "init", "{first:?}");
    let url = format!("/v1/jobs/{id}/draft.svg");
    assert_eq!(first.data["draft"]["url"], url.as_str());
    assert!(
        events
            .iter()
            .take_while(|event| event.name != "draft")
            .all(|event| event.data["draft"].is_null()),
        "a draft came in a progress event: {events:?}"
    );
    let svg = server.get(&url).await;
    assert_eq!(svg.status, StatusCode::OK, "{}", svg.text());
    assert_eq!(svg.header("content-type"), Some("image/svg+xml"));
    assert_eq!(svg.header("cache-control"), Some("private, no-cache"));
    let text = svg.text();
    for layer in ["albedo", "shade", "light"] {
        assert!(
            text.contains(&format!("<g id=\"{layer}\"")),
            "no {layer} layer: {text}"
        );
    }
    assert!(text.contains("mix-blend-mode:multiply"), "{text}");
    assert!(text.matches("<path ").count() > 1, "{text}");
    let canceled = server.cancel(&id).await;
    assert!(canceled.status.is_success(), "{}", canceled.text());

    // The quick job then runs to its end: its last draft is the refinement's, and stays with
    // the results.
    let job = server.wait_for(&queued, PATIENCE, terminal).await;
    assert_eq!(job["status"], "succeeded", "{job}");
    assert_eq!(job["draft"]["stage"], "refine", "{job}");
    let kept = server.get(&format!("/v1/jobs/{queued}/draft.svg")).await;
    assert_eq!(kept.status, StatusCode::OK, "{}", kept.text());
    assert!(kept.text().starts_with("<svg") || kept.text().starts_with("<?xml"));
}

#[tokio::test]
async fn png_flattened_svg_and_pdf_are_served_as_the_cli_makes_them() {
    let dir = DataDir::new("png");
    let mut args = vec!["--workers", "1", "--max-pixels", "20000"];
    args.extend_from_slice(BIG_BUDGET);
    let server = Server::start(&dir.0, &args);
    let code = |reply: &service_support::Reply| (reply.status, problem(reply)["code"].clone());

    // Not before the job has succeeded, as for the other results.
    let long = submit_long(&server).await;
    for result in ["png?width=10", "svg?flatten=true", "pdf"] {
        let early = server.get(&format!("/v1/jobs/{long}/{result}")).await;
        assert_eq!(
            code(&early),
            (StatusCode::CONFLICT, json!("job-not-succeeded")),
            "{result}"
        );
    }
    let canceled = server.cancel(&long).await;
    // 200 when it was still queued (canceled at once), 202 when it was running.
    assert!(
        [StatusCode::OK, StatusCode::ACCEPTED].contains(&canceled.status),
        "{}",
        canceled.text()
    );

    let id = submit_quick(&server).await;
    let job = server.wait_for(&id, PATIENCE, terminal).await;
    assert_eq!(job["status"], "succeeded", "{job}");
    let png = server.get(&format!("/v1/jobs/{id}/png?width=100")).await;
    assert_eq!(
        (png.status, png.header("content-type")),
        (StatusCode::OK, Some("image/png"))
    );
    let image = image::load_from_memory(&png.body).unwrap();
    assert_eq!((image.width(), image.height()), (100, 100));

    // The same bytes as `covec render` of the job's scene at that width.
    let scene = server.get(&format!("/v1/jobs/{id}/scene.json")).await;
    let scene_bytes = scene.body.clone();
    let (scene_path, cli_png) = (dir.0.with_extension("json"), dir.0.with_extension("png"));
    std::fs::write(&scene_path, &scene.body).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_covec"))
        .arg("render")
        .arg(&scene_path)
        .arg("-o")
        .arg(&cli_png)
        .args(["--width", "100"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(std::fs::read(&cli_png).unwrap(), png.body.to_vec());

    // Default width: the original image's (48).
    let default = server.get(&format!("/v1/jobs/{id}/png")).await;
    let image = image::load_from_memory(&default.body).unwrap();
    assert_eq!((image.width(), image.height()), (48, 48));

    for width in ["0", "-3", "wide", "1.5", ""] {
        let bad = server
            .get(&format!("/v1/jobs/{id}/png?width={width}"))
            .await;
        assert_eq!(
            code(&bad),
            (StatusCode::UNPROCESSABLE_ENTITY, json!("invalid-params")),
            "width={width}"
        );
    }
    let huge = server.get(&format!("/v1/jobs/{id}/png?width=200")).await;
    assert_eq!(
        code(&huge),
        (StatusCode::PAYLOAD_TOO_LARGE, json!("too-many-pixels"))
    );
    assert_eq!(
        (
            problem(&huge)["limit"].clone(),
            problem(&huge)["actual"].clone()
        ),
        (json!(20000), json!(40000))
    );

    // The flattened SVG and the PDF: the same bytes as `covec` writes from the job's scene.
    let flat = server.get(&format!("/v1/jobs/{id}/svg?flatten=true")).await;
    assert_eq!(
        (flat.status, flat.header("content-type")),
        (StatusCode::OK, Some("image/svg+xml"))
    );
    let flat_text = flat.text();
    roxmltree::Document::parse(&flat_text).expect("well-formed flattened SVG");
    assert!(!flat_text.contains("blend") && !flat_text.contains("opacity"));
    let pdf = server.get(&format!("/v1/jobs/{id}/pdf")).await;
    assert_eq!(
        (pdf.status, pdf.header("content-type")),
        (StatusCode::OK, Some("application/pdf"))
    );
    let scene: covec::scene::Scene = serde_json::from_slice(&scene.body).unwrap();
    let expected = covec::output::artefacts(
        &scene,
        &[
            covec::output::FileKind::FlatSvg,
            covec::output::FileKind::Pdf,
        ],
    );
    assert_eq!(flat.body.to_vec(), expected[0].bytes);
    assert_eq!(pdf.body.to_vec(), expected[1].bytes);
    for flatten in ["yes", "2", ""] {
        let bad = server
            .get(&format!("/v1/jobs/{id}/svg?flatten={flatten}"))
            .await;
        assert_eq!(
            code(&bad),
            (StatusCode::BAD_REQUEST, json!("bad-query")),
            "flatten={flatten}"
        );
    }

    // Compressed when the client accepts gzip: SVG, JSON and PDF, not PNG or event streams.
    let gzip = [("accept-encoding", "gzip")];
    for (result, plain) in [
        ("svg?flatten=true", &flat.body),
        ("scene.json", &scene_bytes),
        ("pdf", &pdf.body),
    ] {
        let reply = server
            .get_with(&format!("/v1/jobs/{id}/{result}"), &gzip)
            .await;
        assert_eq!(reply.header("content-encoding"), Some("gzip"), "{result}");
        let mut unpacked = Vec::new();
        std::io::Read::read_to_end(
            &mut flate2::read::GzDecoder::new(&reply.body[..]),
            &mut unpacked,
        )
        .unwrap();
        assert_eq!(&unpacked[..], &plain[..], "{result}");
        assert!(reply.body.len() < plain.len(), "{result}");
    }
    for result in ["png?width=40", "events"] {
        let reply = server
            .get_with(&format!("/v1/jobs/{id}/{result}"), &gzip)
            .await;
        assert_eq!(reply.status, StatusCode::OK, "{result}");
        assert_eq!(reply.header("content-encoding"), None, "{result}");
    }
}

/// `--log-format json`: every line on stderr is one JSON object a log collector can read, and a
/// job's lines carry its id.
#[tokio::test]
async fn json_logs_are_one_object_per_line() {
    let dir = DataDir::new("json-logs");
    let server = Server::start(&dir.0, &["--workers", "1", "--log-format", "json"]);
    let id = submit_quick(&server).await;
    let job = server.wait_for(&id, PATIENCE, terminal).await;
    assert_eq!(job["status"], "succeeded", "{job}");
    server.stop();
    let log = std::fs::read_to_string(dir.0.with_extension("log")).unwrap();
    let lines: Vec<serde_json::Value> = log
        .lines()
        .map(|line| serde_json::from_str(line).unwrap_or_else(|error| panic!("{error}: {line:?}")))
        .collect();
    assert!(
        lines.iter().all(|line| line["level"].is_string()
            && line["timestamp"].is_string()
            && line["fields"].is_object()),
        "{log}"
    );
    assert!(
        lines.iter().any(|line| line.to_string().contains(&id)),
        "no line names the job: {log}"
    );
}
