//! Webhooks end to end: a receiver in the test gets each job's completion once, signed as
//! Standard Webhooks; failed attempts are retried and shown on the job; deliveries go on after
//! the server is killed; destinations outside the allow-list are refused at submission.
#![cfg(all(feature = "cli", feature = "service"))]

use crate::service_support;

use std::collections::HashMap;
use std::convert::Infallible;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use base64::Engine;
use hmac::{Hmac, KeyInit, Mac};
use http_body_util::{BodyExt, Full};
use hyper::body::{Bytes, Incoming};
use hyper::{Request, Response, StatusCode};
use hyper_util::rt::TokioIo;
use serde_json::{Value, json};
use service_support::{DataDir, QUICK_PARAMS, Server, problem, test_png};
use sha2::Sha256;

const SECRET_KEY: &[u8] = b"covec webhook test key";
const PATIENCE: Duration = Duration::from_secs(60);

fn secret() -> String {
    format!(
        "whsec_{}",
        base64::engine::general_purpose::STANDARD.encode(SECRET_KEY)
    )
}

/// One message as the receiver got it, signature checked.
#[derive(Clone, Debug)]
struct Message {
    id: String,
    body: Value,
}

/// A webhook receiver on a loopback port: answers 500 to the first `failures` attempts of each
/// message id, then 204, and keeps every message whose signature verifies.
struct Receiver {
    url: String,
    accepted: Arc<Mutex<Vec<Message>>>,
    attempts: Arc<Mutex<HashMap<String, usize>>>,
    task: tokio::task::JoinHandle<()>,
}

impl Receiver {
    async fn start(failures: usize, port: u16) -> Self {
        let listener = tokio::net::TcpListener::bind(("127.0.0.1", port))
            .await
            .unwrap();
        let url = format!("http://{}/hook", listener.local_addr().unwrap());
        let accepted = Arc::new(Mutex::new(Vec::new()));
        let attempts = Arc::new(Mutex::new(HashMap::new()));
        let (kept, counts) = (accepted.clone(), attempts.clone());
        let task = tokio::spawn(async move {
            loop {
                let (stream, _) = listener.accept().await.unwrap();
                let (kept, counts) = (kept.clone(), counts.clone());
                let service = hyper::service::service_fn(move |request: Request<Incoming>| {
                    let (kept, counts) = (kept.clone(), counts.clone());
                    async move {
                        let status = receive(request, failures, &kept, &counts).await;
                        let response = Response::builder()
                            .status(status)
                            .body(Full::new(Bytes::new()))
                            .unwrap();
                        Ok::<_, Infallible>(response)
                    }
                });
                tokio::spawn(async move {
                    let _ = hyper::server::conn::http1::Builder::new()
                        .serve_connection(TokioIo::new(stream), service)
                        .await;
                });
            }
        });
        Self {
            url,
            accepted,
            attempts,
            task,
        }
    }

    fn messages(&self) -> Vec<Message> {
        self.accepted.lock().unwrap().clone()
    }
}

impl Drop for Receiver {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// Verifies the Standard Webhooks headers the way a receiver would (the README's recipe).
async fn receive(
    request: Request<Incoming>,
    failures: usize,
    kept: &Mutex<Vec<Message>>,
    counts: &Mutex<HashMap<String, usize>>,
) -> StatusCode {
    let header = |name: &str| {
        request
            .headers()
            .get(name)
            .and_then(|value| value.to_str().ok())
            .unwrap_or("")
            .to_owned()
    };
    let (id, timestamp, signatures) = (
        header("webhook-id"),
        header("webhook-timestamp"),
        header("webhook-signature"),
    );
    let body = request.into_body().collect().await.unwrap().to_bytes();
    let mut mac = Hmac::<Sha256>::new_from_slice(SECRET_KEY).unwrap();
    mac.update(format!("{id}.{timestamp}.").as_bytes());
    mac.update(&body);
    let expected = format!(
        "v1,{}",
        base64::engine::general_purpose::STANDARD.encode(mac.finalize().into_bytes())
    );
    let fresh = timestamp
        .parse::<u64>()
        .is_ok_and(|t| t.abs_diff(now_seconds()) <= 300);
    if !fresh || !signatures.split(' ').any(|s| s == expected) {
        return StatusCode::UNAUTHORIZED;
    }
    let attempt = {
        let mut counts = counts.lock().unwrap();
        let count = counts.entry(id.clone()).or_insert(0);
        *count += 1;
        *count
    };
    if attempt <= failures {
        return StatusCode::INTERNAL_SERVER_ERROR;
    }
    kept.lock().unwrap().push(Message {
        id,
        body: serde_json::from_slice(&body).unwrap(),
    });
    StatusCode::NO_CONTENT
}

fn now_seconds() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs()
}

/// A server that signs with the test's secret and may call loopback receivers.
fn webhook_server(dir: &DataDir, first_retry_seconds: &str) -> Server {
    let secret = secret();
    let args = [
        "--webhook-secret",
        secret.as_str(),
        "--webhook-allow-loopback",
        "--webhook-first-retry",
        first_retry_seconds,
    ];
    Server::start(&dir.0, &args)
}

async fn submit(server: &Server, webhook: &str, events: Option<&[&str]>) -> (StatusCode, Value) {
    let mut body = json!({
        "image": base64::engine::general_purpose::STANDARD.encode(test_png(32)),
        "params": serde_json::from_str::<Value>(QUICK_PARAMS).unwrap(),
        "webhook": webhook,
    });
    if let Some(events) = events {
        body["webhook_events"] = json!(events);
    }
    let reply = server.post_json("/v1/jobs", &body).await;
    let status = reply.status;
    (status, reply.json())
}

/// Polls the job until its webhook has no pending delivery left.
async fn settled(server: &Server, id: &str) -> Value {
    server
        .wait_for(id, PATIENCE, |job| {
            let deliveries = job["webhook"]["deliveries"].as_array();
            ["succeeded", "failed", "canceled"].contains(&job["status"].as_str().unwrap())
                && deliveries.is_some_and(|all| {
                    all.len() == job["webhook"]["events"].as_array().unwrap().len()
                        && all.iter().all(|d| d["status"] != "pending")
                })
        })
        .await
}

#[tokio::test]
async fn every_completion_arrives_once_signed() {
    let receiver = Receiver::start(0, 0).await;
    let dir = DataDir::new("webhooks-once");
    let server = webhook_server(&dir, "1");
    let mut ids = Vec::new();
    for events in [None, Some(&["started", "completed"][..]), None] {
        let (status, job) = submit(&server, &receiver.url, events).await;
        assert_eq!(status, StatusCode::CREATED, "{job}");
        ids.push(job["id"].as_str().unwrap().to_owned());
    }
    for id in &ids {
        let job = settled(&server, id).await;
        for delivery in job["webhook"]["deliveries"].as_array().unwrap() {
            assert_eq!(delivery["status"], "delivered", "{job}");
            assert_eq!(delivery["attempts"].as_array().unwrap().len(), 1, "{job}");
            assert_eq!(delivery["attempts"][0]["status_code"], 204, "{job}");
        }
    }
    let messages = receiver.messages();
    let completions: Vec<_> = messages
        .iter()
        .filter(|m| m.body["type"] == "job.completed")
        .collect();
    for id in &ids {
        let for_job: Vec<_> = completions
            .iter()
            .filter(|m| m.body["data"]["id"] == id.as_str())
            .collect();
        assert_eq!(for_job.len(), 1, "{id}: {messages:?}");
        assert_eq!(for_job[0].body["data"]["status"], "succeeded");
        assert_eq!(for_job[0].id, format!("msg_{id}_completed"));
    }
    assert_eq!(completions.len(), ids.len(), "{messages:?}");
    let started: Vec<_> = messages
        .iter()
        .filter(|m| m.body["type"] == "job.started")
        .collect();
    assert_eq!(started.len(), 1, "only the second job asked for `started`");
    assert_eq!(started[0].body["data"]["id"], ids[1].as_str());
}

#[tokio::test]
async fn a_receiver_that_fails_twice_gets_the_third_attempt() {
    let receiver = Receiver::start(2, 0).await;
    let dir = DataDir::new("webhooks-retry");
    let server = webhook_server(&dir, "1");
    let (status, job) = submit(&server, &receiver.url, None).await;
    assert_eq!(status, StatusCode::CREATED, "{job}");
    let id = job["id"].as_str().unwrap();
    let job = settled(&server, id).await;
    let delivery = &job["webhook"]["deliveries"][0];
    assert_eq!(delivery["status"], "delivered", "{job}");
    let codes: Vec<_> = delivery["attempts"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a["status_code"].as_u64().unwrap())
        .collect();
    assert_eq!(codes, [500, 500, 204], "{job}");
    assert_eq!(receiver.messages().len(), 1);
    assert_eq!(
        receiver.attempts.lock().unwrap()[&format!("msg_{id}_completed")],
        3
    );
}

/// A server killed with a delivery pending: the next server goes on with it. On the shared
/// backend the next server is another replica, which takes the delivery over once the killed
/// one's claim expires (`DELIVERY_LEASE`, 10 s).
#[tokio::test]
async fn deliveries_go_on_after_the_server_is_killed() {
    // Nothing listens yet: the first attempt fails; the server dies before the retry is due.
    let port = {
        let probe = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        probe.local_addr().unwrap().port()
    };
    let dir = DataDir::persistent("webhooks-restart");
    let server = webhook_server(&dir, "5");
    let (status, job) = submit(&server, &format!("http://127.0.0.1:{port}/hook"), None).await;
    assert_eq!(status, StatusCode::CREATED, "{job}");
    let id = job["id"].as_str().unwrap().to_owned();
    let job = server
        .wait_for(&id, PATIENCE, |job| {
            job["webhook"]["deliveries"][0]["attempts"]
                .as_array()
                .is_some_and(|attempts| !attempts.is_empty())
        })
        .await;
    let delivery = &job["webhook"]["deliveries"][0];
    assert_eq!(delivery["status"], "pending", "{job}");
    assert!(delivery["attempts"][0]["error"].is_string(), "{job}");
    server.kill();
    let receiver = Receiver::start(0, port).await;
    let server = webhook_server(&dir, "5");
    let job = settled(&server, &id).await;
    let delivery = &job["webhook"]["deliveries"][0];
    assert_eq!(delivery["status"], "delivered", "{job}");
    assert_eq!(delivery["attempts"].as_array().unwrap().len(), 2, "{job}");
    let messages = receiver.messages();
    assert_eq!(messages.len(), 1, "{messages:?}");
    assert_eq!(messages[0].id, format!("msg_{id}_completed"));
}

#[tokio::test]
async fn destinations_outside_the_allow_list_are_refused_at_submission() {
    let dir = DataDir::persistent("webhooks-refused");
    // Default configuration: no destinations allowed, loopback included.
    let server = Server::start(&dir.0, &[]);
    let (status, body) = submit(&server, "http://127.0.0.1:9/hook", None).await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    assert_eq!(body["code"], "webhook-host-not-allowed");
    drop(server);
    let secret = secret();
    let server = Server::start(
        &dir.0,
        &[
            "--webhook-secret",
            &secret,
            "--webhook-hosts",
            "hooks.example.com,*.example.org",
        ],
    );
    for (url, code) in [
        ("http://localhost:8080/x", "webhook-host-not-allowed"),
        ("http://[::1]/x", "webhook-host-not-allowed"),
        ("http://169.254.169.254/latest", "webhook-host-not-allowed"),
        ("https://evil.example.com/x", "webhook-host-not-allowed"),
        ("https://example.org/x", "webhook-host-not-allowed"),
        ("ftp://hooks.example.com/x", "invalid-params"),
        ("https://user@hooks.example.com/x", "invalid-params"),
        ("/relative", "invalid-params"),
    ] {
        let reply = server
            .post_json(
                "/v1/jobs",
                &json!({
                    "image": base64::engine::general_purpose::STANDARD.encode(test_png(32)),
                    "webhook": url,
                }),
            )
            .await;
        assert_eq!(reply.status, StatusCode::UNPROCESSABLE_ENTITY, "{url}");
        assert_eq!(problem(&reply)["code"], code, "{url}");
    }
    let (status, job) = submit(&server, "https://a.b.example.org/hook", Some(&["bogus"])).await;
    assert_eq!(
        (status, job["code"].as_str()),
        (StatusCode::UNPROCESSABLE_ENTITY, Some("invalid-params"))
    );
    let (status, job) = submit(&server, "https://hooks.example.com/hook", None).await;
    assert_eq!(status, StatusCode::CREATED, "{job}");
    assert_eq!(job["webhook"]["url"], "https://hooks.example.com/hook");
    assert_eq!(job["webhook"]["events"], json!(["completed"]));
}
