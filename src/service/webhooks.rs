//! Webhooks: a job's owner names a URL at submission and covec POSTs the job there when it
//! starts and/or completes, so a batch client needs neither polls nor open event streams.
//!
//! Messages follow Standard Webhooks (<https://www.standardwebhooks.com>): a JSON body
//! `{"type": "job.completed", "timestamp", "data": <job>}` with `webhook-id` (the same for every
//! attempt of one event: receivers deduplicate on it), `webhook-timestamp` (Unix seconds of the
//! attempt) and `webhook-signature` (`v1,` + base64 of HMAC-SHA256 over `id.timestamp.body`,
//! keyed with the server's secret). A failed attempt (no 2xx within the timeout) is retried
//! with doubling delays up to a bounded number of attempts.
//!
//! Server-side request forgery: destinations must be on the configured allow-list (none by
//! default, so webhooks are off); loopback only when configured (tests). The check runs at
//! submission; redirects are never followed.
//!
//! Durability: each delivery, with its attempts and the time of the next one, is part of the
//! job record, saved after every attempt. After a restart deliveries go on where they were, so
//! an event is delivered at least once; a receiver may see an attempt again if the server
//! stopped between sending it and saving its outcome (the `webhook-id` is the same).

use std::sync::Arc;
use std::time::Duration;

use axum::body::Bytes;
use axum::http::{Method, Request, Uri};
use base64::Engine;
use hmac::{Hmac, KeyInit, Mac};
use http_body_util::Full;
use hyper_rustls::HttpsConnector;
use hyper_util::client::legacy::Client;
use hyper_util::client::legacy::connect::HttpConnector;
use hyper_util::rt::TokioExecutor;
use serde::Serialize;
use sha2::Sha256;
use tracing::{info, warn};

use super::job::JobEntry;
use super::model::{
    Attempt, Delivery, DeliveryStatus, JobRecord, Status, Webhook, WebhookEvent, now_ms,
};
use super::queue::Queue;
use super::queue::REAP_EVERY;
use super::store::StoreError;
use super::view::WebhookMessage;

/// Webhook settings of `covec serve`.
#[derive(Clone, Debug)]
pub struct WebhookConfig {
    /// Signing secret, Standard Webhooks form `whsec_<base64>` (the key is the decoded bytes;
    /// any other text is used as it is). Needed when `allowed_hosts` is not empty.
    pub secret: Option<String>,
    /// Hosts webhooks may go to: exact names, or `*.example.com` for its subdomains. Default
    /// none: webhooks are refused.
    pub allowed_hosts: Vec<String>,
    /// Also allow loopback destinations (`localhost`, 127.0.0.0/8, ::1). For tests. Default off.
    pub allow_loopback: bool,
    /// Attempts per event, the first included. Default 8.
    pub max_attempts: u32,
    /// Delay before the first retry; each later one doubles it. Default 10 s (8 attempts span
    /// about 21 minutes).
    pub first_retry: Duration,
    /// Longest wait for a receiver's answer. Default 10 s.
    pub timeout: Duration,
}

impl Default for WebhookConfig {
    fn default() -> Self {
        Self {
            secret: None,
            allowed_hosts: Vec::new(),
            allow_loopback: false,
            max_attempts: 8,
            first_retry: Duration::from_secs(10),
            timeout: Duration::from_secs(10),
        }
    }
}

/// A webhook setting that cannot work.
#[derive(Debug, thiserror::Error)]
pub enum WebhookConfigError {
    /// Destinations allowed but nothing to sign with.
    #[error("webhook destinations are allowed but no webhook secret is set")]
    NoSecret,
    /// `whsec_` followed by something other than base64.
    #[error("the webhook secret starts with `whsec_` but the rest is not base64")]
    BadSecret,
}

/// Longest webhook URL accepted.
const MAX_URL_CHARS: usize = 2048;
/// How often a task waiting for a job's event checks that the job still exists.
const EXISTENCE_CHECK: Duration = Duration::from_secs(30);

type HttpClient = Client<HttpsConnector<HttpConnector>, Full<Bytes>>;

/// The webhook dispatcher: checks destinations at submission and delivers events.
pub struct Webhooks {
    config: WebhookConfig,
    key: Vec<u8>,
    client: HttpClient,
    queue: Arc<Queue>,
}

/// The webhook a submission asks for, as sent.
#[derive(Default, Serialize)]
pub struct WebhookRequest {
    pub url: Option<String>,
    pub events: Option<Vec<String>>,
}

/// Why a submission's webhook is refused (422 `invalid-params` or `webhook-host-not-allowed`).
#[derive(Debug, thiserror::Error)]
pub enum WebhookRefusal {
    /// A malformed `webhook` or `webhook_events`.
    #[error("{0}")]
    Invalid(String),
    #[error("webhooks to `{0}` are not allowed by this server")]
    HostNotAllowed(String),
}

impl Webhooks {
    /// Checks the configuration and, on the shared backend, starts taking over the deliveries
    /// of replicas that stopped (call inside the runtime).
    pub fn start(
        config: WebhookConfig,
        queue: Arc<Queue>,
    ) -> Result<Arc<Self>, WebhookConfigError> {
        let key = match config.secret.as_deref() {
            Some(secret) => match secret.strip_prefix("whsec_") {
                Some(encoded) => base64::engine::general_purpose::STANDARD
                    .decode(encoded)
                    .map_err(|_| WebhookConfigError::BadSecret)?,
                None => secret.as_bytes().to_vec(),
            },
            None if config.allowed_hosts.is_empty() && !config.allow_loopback => Vec::new(),
            None => return Err(WebhookConfigError::NoSecret),
        };
        let connector = hyper_rustls::HttpsConnectorBuilder::new()
            .with_webpki_roots()
            .https_or_http()
            .enable_http1()
            .build();
        let webhooks = Arc::new(Self {
            config,
            key,
            client: Client::builder(TokioExecutor::new()).build(connector),
            queue,
        });
        // On the shared backend deliveries are made by the replica that admitted the job, and
        // taken over by another when that one stops (docs/operations.md).
        tokio::spawn(Arc::clone(&webhooks).take_over());
        Ok(webhooks)
    }

    /// Resumes the unfinished deliveries of stored jobs (after a start).
    pub fn resume(self: &Arc<Self>) -> Result<(), StoreError> {
        for entry in self.queue.deliveries().to_resume()? {
            self.follow(entry);
        }
        Ok(())
    }

    /// The webhook a submission asks for, if any, once its URL and events are checked: 422
    /// `invalid-params` for a malformed one, `webhook-host-not-allowed` for a destination
    /// outside the allow-list.
    pub fn target(&self, request: WebhookRequest) -> Result<Option<Webhook>, WebhookRefusal> {
        let Some(url) = request.url else {
            if request.events.is_some() {
                return Err(WebhookRefusal::Invalid(
                    "`webhook_events` needs a `webhook` URL".into(),
                ));
            }
            return Ok(None);
        };
        let malformed = || {
            WebhookRefusal::Invalid(format!(
                "`webhook` must be an absolute http or https URL of at most {MAX_URL_CHARS} \
                 characters, without user information, not `{url}`"
            ))
        };
        if url.len() > MAX_URL_CHARS {
            return Err(malformed());
        }
        let uri: Uri = url.parse().map_err(|_| malformed())?;
        let authority = uri.authority().ok_or_else(malformed)?;
        if !matches!(uri.scheme_str(), Some("http" | "https")) || authority.as_str().contains('@') {
            return Err(malformed());
        }
        let host = authority
            .host()
            .trim_start_matches('[')
            .trim_end_matches(']')
            .trim_end_matches('.')
            .to_ascii_lowercase();
        if host.is_empty() {
            return Err(malformed());
        }
        if !self.allows(&host) {
            return Err(WebhookRefusal::HostNotAllowed(host));
        }
        let events = match request.events {
            None => vec![WebhookEvent::Completed],
            Some(names) => {
                let mut events = Vec::new();
                for name in names {
                    let event = WebhookEvent::from_name(&name).ok_or_else(|| {
                        WebhookRefusal::Invalid(format!(
                            "`webhook_events` may hold `started` and `completed`, not `{name}`"
                        ))
                    })?;
                    if !events.contains(&event) {
                        events.push(event);
                    }
                }
                if events.is_empty() {
                    return Err(WebhookRefusal::Invalid("`webhook_events` is empty".into()));
                }
                events
            }
        };
        Ok(Some(Webhook {
            url,
            events,
            deliveries: Vec::new(),
        }))
    }

    fn allows(&self, host: &str) -> bool {
        let loopback = host == "localhost"
            || host.ends_with(".localhost")
            || host
                .parse::<std::net::IpAddr>()
                .is_ok_and(|ip| ip.is_loopback());
        if loopback {
            return self.config.allow_loopback;
        }
        self.config.allowed_hosts.iter().any(|allowed| {
            let allowed = allowed.trim().trim_end_matches('.').to_ascii_lowercase();
            match allowed.strip_prefix("*.") {
                Some(domain) => host
                    .strip_suffix(domain)
                    .is_some_and(|sub| sub.len() > 1 && sub.ends_with('.')),
                None => host == allowed,
            }
        })
    }

    /// Delivers the job's events as they happen (a task per job with a webhook).
    pub fn follow(self: &Arc<Self>, entry: Arc<JobEntry>) {
        if entry.record.borrow().webhook.is_some() {
            tokio::spawn(Arc::clone(self).run(entry));
        }
    }

    /// Every [`REAP_EVERY`]: follows the jobs whose deliverer stopped (shared backend), this
    /// replica's claims renewed.
    async fn take_over(self: Arc<Self>) {
        loop {
            tokio::time::sleep(REAP_EVERY).await;
            let queue = Arc::clone(&self.queue);
            let taken =
                tokio::task::spawn_blocking(move || queue.deliveries().to_take_over()).await;
            match taken {
                Ok(Ok(entries)) => {
                    for entry in entries {
                        info!(job_id = %entry.id, "taking over the webhook deliveries of a stopped replica");
                        self.follow(entry);
                    }
                }
                Ok(Err(error)) => warn!("renewing webhook deliveries: {error}"),
                Err(_) => return,
            }
        }
    }

    /// Delivers the job's events, then gives up this replica's claim on them.
    async fn run(self: Arc<Self>, entry: Arc<JobEntry>) {
        self.deliver_events(&entry).await;
        let (queue, id) = (Arc::clone(&self.queue), entry.id.clone());
        let done = tokio::task::spawn_blocking(move || queue.deliveries().done(&id)).await;
        if let Ok(Err(error)) = done {
            // The claim expires and another replica finds nothing left to deliver.
            warn!(job_id = %entry.id, "ending webhook deliveries: {error}");
        }
    }

    async fn deliver_events(&self, entry: &Arc<JobEntry>) {
        let Some(webhook) = entry.snapshot().webhook else {
            return;
        };
        let mut receiver = entry.record.subscribe();
        for event in WebhookEvent::ALL {
            if !webhook.events.contains(&event) {
                continue;
            }
            let done = delivery(&entry.snapshot(), event)
                .is_some_and(|delivery| delivery.status != DeliveryStatus::Pending);
            if done {
                continue;
            }
            // Wait for the event (a job canceled while queued never starts).
            let happened = loop {
                let wait = receiver.wait_for(|record| {
                    record.status.is_terminal()
                        || (event == WebhookEvent::Started && record.status == Status::Running)
                });
                match tokio::time::timeout(EXISTENCE_CHECK, wait).await {
                    Ok(Ok(record)) => {
                        break event == WebhookEvent::Completed || record.started_at.is_some();
                    }
                    Ok(Err(_)) => return,
                    Err(_) if !self.exists(entry) => return,
                    Err(_) => {}
                }
            };
            if happened {
                self.deliver(entry, event).await;
            }
        }
    }

    /// Whether the job is still there: deleting it (anywhere: the copy follows other
    /// replicas' deletes) or its record expiring marks the entry this task holds.
    fn exists(&self, entry: &JobEntry) -> bool {
        !entry.deleted.load(std::sync::atomic::Ordering::SeqCst)
    }

    /// Attempts one event's delivery until it is delivered or out of attempts.
    async fn deliver(&self, entry: &JobEntry, event: WebhookEvent) {
        let record = entry.snapshot();
        let Some(url) = record.webhook.as_ref().map(|webhook| webhook.url.clone()) else {
            return;
        };
        let id = format!("msg_{}_{}", entry.id, event.name());
        if delivery(&record, event).is_none() {
            entry.record.send_modify(|record| {
                if let Some(webhook) = &mut record.webhook {
                    webhook.deliveries.push(Delivery {
                        id: id.clone(),
                        event,
                        status: DeliveryStatus::Pending,
                        attempts: Vec::new(),
                        next_attempt_at: Some(now_ms()),
                    });
                }
            });
            self.save(entry).await;
        }
        let body = payload(&entry.snapshot(), event);
        loop {
            let Some(current) = delivery(&entry.snapshot(), event).cloned() else {
                return;
            };
            if current.status != DeliveryStatus::Pending {
                return;
            }
            let wait = current
                .next_attempt_at
                .unwrap_or(0)
                .saturating_sub(now_ms());
            tokio::time::sleep(Duration::from_millis(wait)).await;
            if !self.exists(entry) {
                return;
            }
            let at = now_ms();
            let outcome = self.attempt(&url, &id, &body).await;
            let delivered = matches!(outcome, Ok(code) if (200..300).contains(&code));
            let attempts = current.attempts.len() as u32 + 1;
            match &outcome {
                Ok(code) => {
                    info!(job_id = %entry.id, webhook_id = %id, status = code, attempts, "webhook attempt")
                }
                Err(error) => {
                    warn!(job_id = %entry.id, webhook_id = %id, attempts, "webhook attempt: {error}")
                }
            }
            let status = if delivered {
                DeliveryStatus::Delivered
            } else if attempts >= self.config.max_attempts {
                DeliveryStatus::Failed
            } else {
                DeliveryStatus::Pending
            };
            let next = (status == DeliveryStatus::Pending).then(|| {
                let delay = self.config.first_retry.as_millis() as u64;
                now_ms() + delay.saturating_mul(1 << (attempts - 1).min(20))
            });
            entry.record.send_modify(|record| {
                let Some(delivery) = record
                    .webhook
                    .as_mut()
                    .and_then(|webhook| webhook.deliveries.iter_mut().find(|d| d.event == event))
                else {
                    return;
                };
                delivery.attempts.push(Attempt {
                    at,
                    status_code: outcome.as_ref().ok().copied(),
                    error: outcome.as_ref().err().cloned(),
                });
                delivery.status = status;
                delivery.next_attempt_at = next;
            });
            self.save(entry).await;
        }
    }

    /// One signed POST; the receiver's status, or why there was none.
    async fn attempt(&self, url: &str, id: &str, body: &Bytes) -> Result<u16, String> {
        let timestamp = now_ms() / 1000;
        let request = Request::builder()
            .method(Method::POST)
            .uri(url)
            .header("content-type", "application/json")
            .header("user-agent", concat!("covec/", env!("CARGO_PKG_VERSION")))
            .header("webhook-id", id)
            .header("webhook-timestamp", timestamp.to_string())
            .header("webhook-signature", sign(&self.key, id, timestamp, body))
            .body(Full::new(body.clone()))
            .map_err(|error| error.to_string())?;
        match tokio::time::timeout(self.config.timeout, self.client.request(request)).await {
            Ok(Ok(response)) => Ok(response.status().as_u16()),
            Ok(Err(error)) => Err(format!("request failed: {error}")),
            Err(_) => Err(format!(
                "no answer within {} s",
                self.config.timeout.as_secs_f32()
            )),
        }
    }

    /// Saves the job's record (deliveries included), unless the job was deleted meanwhile.
    async fn save(&self, entry: &JobEntry) {
        if !self.exists(entry) {
            return;
        }
        let (queue, record) = (Arc::clone(&self.queue), entry.snapshot());
        let saved = tokio::task::spawn_blocking(move || queue.store().save_webhook(&record)).await;
        if let Ok(Err(error)) = saved {
            warn!(job_id = %entry.id, "saving webhook deliveries: {error}");
        }
    }
}

/// `v1,` + base64(HMAC-SHA256(key, `id.timestamp.body`)).
fn sign(key: &[u8], id: &str, timestamp: u64, body: &[u8]) -> String {
    let mut mac = Hmac::<Sha256>::new_from_slice(key).expect("HMAC takes any key");
    mac.update(format!("{id}.{timestamp}.").as_bytes());
    mac.update(body);
    let tag = mac.finalize().into_bytes();
    format!(
        "v1,{}",
        base64::engine::general_purpose::STANDARD.encode(tag)
    )
}

fn delivery(record: &JobRecord, event: WebhookEvent) -> Option<&Delivery> {
    record
        .webhook
        .as_ref()?
        .deliveries
        .iter()
        .find(|delivery| delivery.event == event)
}

/// The message body ([`WebhookMessage`]).
fn payload(record: &JobRecord, event: WebhookEvent) -> Bytes {
    let message = WebhookMessage::new(record, event);
    Bytes::from(serde_json::to_vec(&message).expect("views serialise"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The example of the Standard Webhooks reference libraries.
    #[test]
    fn signature_matches_the_standard_webhooks_example() {
        let key = base64::engine::general_purpose::STANDARD
            .decode("MfKQ9r8GKYqrTwjUPD8ILPZIo2LaLaSw")
            .unwrap();
        assert_eq!(
            sign(
                &key,
                "msg_p5jXN8AQM9LWM0D4loKWxJek",
                1614265330,
                b"{\"test\": 2432232314}"
            ),
            "v1,g0hM9SsE+OTPJTGt/tmIKtSyZlE3uFJELVlNIOLJ1OE="
        );
    }
}
