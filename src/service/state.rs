//! What every handler shares ([`AppState`], opened from the [`Config`], or [`ServeError`]),
//! and how a resource module names its routes ([`Endpoint`]).

use std::collections::HashSet;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use axum::handler::Handler;
use axum::http::{HeaderValue, Method};
use axum::routing::{MethodFilter, MethodRouter, on};
use tokio::sync::watch;

use super::error::ApiError;
use super::inputs::InputLimits;
use super::queue::Queue;
use super::queue::QueueError;
use super::store::StoreError;
use super::telemetry::Metrics;
use super::{Config, WebhookConfigError, backend, derived, fair, model, signed, webhooks};

/// Shared by every handler.
#[derive(Clone)]
pub struct AppState {
    pub(super) queue: Arc<Queue>,
    pub(super) metrics: Arc<Metrics>,
    pub(super) limits: InputLimits,
    pub(super) key_ids: Arc<HashSet<String>>,
    pub(super) cors_origins: Arc<Vec<String>>,
    /// Becomes true when the server begins to stop (ends event streams).
    pub(super) shutdown: watch::Sender<bool>,
    pub(super) max_wait: Duration,
    /// Bounds the renders of derived files running at once ([`derived::RENDERS`]).
    pub(super) renders: Arc<tokio::sync::Semaphore>,
    /// Where those renders run: threads below the HTTP threads' priority.
    pub(super) render_pool: Arc<rayon::ThreadPool>,
    /// Signs and checks signed result URLs.
    pub(super) signer: Arc<signed::UrlSigner>,
    /// `/metrics` is served on the ops port, not here.
    pub(super) metrics_elsewhere: bool,
    pub(super) webhooks: Arc<webhooks::Webhooks>,
    /// Per-key submission rates.
    pub(super) rates: Arc<fair::SubmissionRates>,
}

/// Why the server could not start or stopped with an error.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    /// The data directory or job database.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// Starting the workers.
    #[error(transparent)]
    Queue(#[from] QueueError),
    /// The listening address.
    #[error("cannot listen on {addr}: {source}")]
    #[allow(missing_docs)]
    Bind {
        addr: SocketAddr,
        source: std::io::Error,
    },
    /// Serving connections.
    #[error("server: {0}")]
    Io(#[from] std::io::Error),
    /// A `--cors-origins` value.
    #[error("CORS origin `{0}` is not a valid header value")]
    CorsOrigin(String),
    /// The webhook settings.
    #[error(transparent)]
    Webhooks(#[from] WebhookConfigError),
    /// `covec worker` without the shared backend.
    #[error("workers need the PostgreSQL backend (--database-url)")]
    WorkersNotShared,
    /// No API keys on an address other hosts can reach, without `allow_anonymous`.
    #[error(
        "refusing to serve {0} without API keys: anyone who reaches it could read every job; give --api-keys (COVEC_API_KEYS), listen on loopback, or pass --allow-anonymous (COVEC_ALLOW_ANONYMOUS=true)"
    )]
    Anonymous(SocketAddr),
}

impl AppState {
    /// Opens the data directory, recovers jobs and starts the workers. Call inside the runtime.
    pub fn open(config: &Config) -> Result<Self, ServeError> {
        for origin in &config.cors_origins {
            if origin != "*" && HeaderValue::from_str(origin).is_err() {
                return Err(ServeError::CorsOrigin(origin.clone()));
            }
        }
        let (store, backend) = backend::open(&backend::Storage {
            data_dir: &config.data_dir,
            object_store: config.object_store.as_deref(),
            records: &config.records,
        })?;
        let metrics = Arc::new(Metrics::default());
        let queue = Queue::start(
            config.queue.clone(),
            config.limits.clone(),
            store,
            metrics.clone(),
            backend,
        )?;
        let webhooks = webhooks::Webhooks::start(config.webhooks.clone(), queue.clone())?;
        webhooks.resume()?;
        let signer = signed::UrlSigner::new(
            config.signed_urls.secret.as_deref(),
            config.signed_urls.lifetime,
        )?;
        Ok(Self {
            webhooks,
            queue,
            metrics,
            limits: config.limits.clone(),
            key_ids: Arc::new(
                config
                    .api_keys
                    .iter()
                    .map(|key| model::key_id(key))
                    .collect(),
            ),
            cors_origins: Arc::new(config.cors_origins.clone()),
            shutdown: watch::Sender::new(false),
            max_wait: config.max_wait,
            renders: Arc::new(tokio::sync::Semaphore::new(derived::RENDERS)),
            render_pool: Arc::new(derived::render_pool(config.queue.threads)?),
            signer: Arc::new(signer),
            metrics_elsewhere: config.ops_addr.is_some(),
            rates: Arc::new(fair::SubmissionRates::new(&config.queue.scheduling)),
        })
    }
}

impl AppState {
    /// A permit to decode one request's images: waits up to [`InputLimits::decode_wait`] for
    /// one of the [`InputLimits::decode_slots`], then refuses with 503 `decode-busy`.
    pub(super) async fn decode_slot(&self) -> Result<tokio::sync::OwnedSemaphorePermit, ApiError> {
        let permit = self.queue.decode_slots().acquire_owned();
        let wait = self.limits.decode_wait;
        match tokio::time::timeout(wait, permit).await {
            Ok(permit) => permit.map_err(|error| ApiError::Internal(error.to_string())),
            // A client told to retry at once would only be refused again.
            Err(_) => Err(ApiError::DecodeBusy(wait.as_secs().max(1))),
        }
    }
}

/// One route: a method and an OpenAPI-style path, with its handler.
pub struct Endpoint {
    /// The HTTP method.
    pub method: Method,
    /// The path as the OpenAPI document writes it, e.g. `/v1/jobs/{id}`.
    pub path: &'static str,
    pub(super) handler: MethodRouter<AppState>,
}

pub(super) fn endpoint<H, T>(method: Method, path: &'static str, handler: H) -> Endpoint
where
    H: Handler<T, AppState>,
    T: 'static,
{
    let filter = MethodFilter::try_from(method.clone()).expect("endpoints use standard methods");
    Endpoint {
        method,
        path,
        handler: on(filter, handler),
    }
}
