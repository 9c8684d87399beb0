//! `covec serve`: the HTTP vectorisation service (api/openapi.yaml, `covec openapi`, is its
//! contract).
//!
//! Clients submit an image as a job, follow its progress by polling or Server-Sent Events, and
//! fetch the layered SVG, per-layer SVGs, JSON scene and stage previews. Jobs run on a dedicated
//! worker pool (`queue`), records and results persist in a data directory (`store`), and every
//! error is an RFC 9457 problem (`error`).
//!
//! Each resource module lists its routes as [`Endpoint`]s; [`app`] builds the router from
//! [`endpoints`], which a test compares with the OpenAPI document ([`openapi_document`],
//! generated from the handlers' attributes).

mod auth;
mod backend;
mod conn;
mod derived;
mod download;
mod edits;
mod error;
mod fair;
#[doc(hidden)]
pub mod fuzzing;
mod inputs;
mod jobs;
mod limits;
mod model;
mod openapi;
mod ops;
mod queue;
mod rate;
mod results;
mod runner;
mod signed;
mod store;
mod submit;
mod telemetry;
mod view;
mod webhooks;

pub use backend::RecordsAt;
pub use conn::ConnectionLimits;
pub use fair::{KeyLimits, Scheduling};
pub use inputs::InputLimits;
pub use openapi::document as openapi_document;
pub use ops::LIVENESS_PATH;
pub use queue::QueueConfig;
pub use webhooks::{WebhookConfig, WebhookConfigError};

use std::collections::HashSet;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use axum::extract::Request;
use axum::handler::Handler;
use axum::http::{HeaderValue, Method};
use axum::middleware;
use axum::routing::{MethodFilter, MethodRouter, on};
use tokio::sync::watch;
use tower_http::compression::CompressionLayer;
use tower_http::cors::{AllowHeaders, AllowOrigin, Any, CorsLayer};
use tower_http::request_id::{
    MakeRequestUuid, PropagateRequestIdLayer, RequestId, SetRequestIdLayer,
};
use tower_http::trace::TraceLayer;

use error::ApiError;
use queue::{Queue, QueueError};
use store::StoreError;
use telemetry::Metrics;

/// Everything `covec serve` can be told.
#[derive(Clone, Debug)]
pub struct Config {
    /// Listening address. Default 127.0.0.1:8080.
    pub addr: SocketAddr,
    /// Job records and artefacts. Default `./covec-data`.
    pub data_dir: PathBuf,
    /// Artefacts in this S3-compatible bucket (`s3://bucket/prefix`, credentials, region and
    /// endpoint from the usual `AWS_*` variables) instead of the data directory. Default none.
    pub object_store: Option<String>,
    /// Where job records, the queue and idempotency keys live: SQLite in the data directory
    /// (the default), a PostgreSQL database shared with other replicas and `covec worker`s, or
    /// this process's memory.
    pub records: RecordsAt,
    /// Workers, queue length, time limit, retention.
    pub queue: QueueConfig,
    /// What one job may send and ask for.
    pub limits: InputLimits,
    /// Read timeouts and the connection cap.
    pub connections: ConnectionLimits,
    /// Accepted API keys; empty (the default) means no authentication.
    pub api_keys: Vec<String>,
    /// Start without API keys on an address other hosts can reach (by default [`serve`]
    /// refuses to: anyone who reaches it could read every job). Default false.
    pub allow_anonymous: bool,
    /// Signed result URLs: the secret and how long a token lasts.
    pub signed_urls: SignedUrlConfig,
    /// `covec serve`: serve `/healthz`, `/readyz` and `/metrics` on this address too, and
    /// `/metrics` only there. Default none.
    pub ops_addr: Option<SocketAddr>,
    /// Origins allowed by CORS; `*` allows any. Default none (no CORS headers).
    pub cors_origins: Vec<String>,
    /// How long running jobs may finish after a shutdown signal. Default 30 s.
    pub shutdown_grace: Duration,
    /// Longest `Prefer: wait` honoured on a submission (RFC 7240); longer requests wait this
    /// long. Default 60 s; 0 ignores the preference.
    pub max_wait: Duration,
    /// Webhook signing, allowed destinations and retries.
    pub webhooks: WebhookConfig,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            addr: SocketAddr::from(([127, 0, 0, 1], 8080)),
            data_dir: PathBuf::from("covec-data"),
            object_store: None,
            records: RecordsAt::default(),
            queue: QueueConfig::default(),
            limits: InputLimits::default(),
            connections: ConnectionLimits::default(),
            api_keys: Vec::new(),
            allow_anonymous: false,
            signed_urls: SignedUrlConfig::default(),
            ops_addr: None,
            cors_origins: Vec::new(),
            shutdown_grace: Duration::from_secs(30),
            max_wait: Duration::from_secs(60),
            webhooks: WebhookConfig::default(),
        }
    }
}

/// Signed result URLs (`signed`).
#[derive(Clone, Debug)]
pub struct SignedUrlConfig {
    /// The HMAC key; every API replica needs the same one. Default none: a random key made
    /// at start (tokens then work on this process only, until it stops).
    pub secret: Option<String>,
    /// How long a token lasts (up to a quarter longer, so that polls a little apart get the
    /// same URLs). Default 15 minutes.
    pub lifetime: Duration,
}

impl Default for SignedUrlConfig {
    fn default() -> Self {
        Self {
            secret: None,
            lifetime: Duration::from_secs(15 * 60),
        }
    }
}

/// Shared by every handler.
#[derive(Clone)]
pub struct AppState {
    queue: Arc<Queue>,
    metrics: Arc<Metrics>,
    limits: InputLimits,
    key_ids: Arc<HashSet<String>>,
    cors_origins: Arc<Vec<String>>,
    /// Becomes true when the server begins to stop (ends event streams).
    shutdown: watch::Sender<bool>,
    max_wait: Duration,
    /// Bounds the renders of derived files running at once ([`derived::RENDERS`]).
    renders: Arc<tokio::sync::Semaphore>,
    /// Where those renders run: threads below the HTTP threads' priority.
    render_pool: Arc<rayon::ThreadPool>,
    /// Signs and checks signed result URLs.
    signer: Arc<signed::UrlSigner>,
    /// `/metrics` is served on the ops port, not here.
    metrics_elsewhere: bool,
    webhooks: Arc<webhooks::Webhooks>,
    /// Per-key submission rates.
    rates: Arc<fair::SubmissionRates>,
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
    async fn decode_slot(&self) -> Result<tokio::sync::OwnedSemaphorePermit, ApiError> {
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
    handler: MethodRouter<AppState>,
}

fn endpoint<H, T>(method: Method, path: &'static str, handler: H) -> Endpoint
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

/// Every API route of the service. The web page (`/`, [`crate::web::routes`]) is merged in
/// [`app`]: it is not part of the API document.
pub fn endpoints() -> Vec<Endpoint> {
    let mut all = jobs::endpoints();
    all.extend(results::endpoints());
    all.extend(edits::endpoints());
    all.extend(limits::endpoints());
    all.extend(ops::endpoints());
    all
}

/// The whole HTTP application.
pub fn app(state: AppState) -> Router {
    let mut router = Router::new();
    for endpoint in endpoints() {
        router = router.route(endpoint.path, endpoint.handler);
    }
    let cors = cors_layer(&state.cors_origins);
    router
        .merge(crate::web::routes())
        .fallback(|request: Request| async move {
            ApiError::RouteNotFound(request.uri().path().to_owned())
        })
        .method_not_allowed_fallback(|request: Request| async move {
            ApiError::MethodNotAllowed(request.method().to_string())
        })
        .layer(middleware::from_fn_with_state(
            state.clone(),
            auth::require_key,
        ))
        .layer(middleware::from_fn_with_state(
            state.clone(),
            ops::record_http,
        ))
        // A body limit for the upload route; the submission reader enforces the same number.
        .layer(axum::extract::DefaultBodyLimit::max(
            state.limits.max_body_bytes as usize,
        ))
        // gzip when the client accepts it, for SVG, JSON, PDF and the page (above 32 bytes);
        // the default predicate leaves PNG and other images, and event streams, as they are.
        .layer(CompressionLayer::new())
        .layer(
            TraceLayer::new_for_http().make_span_with(|request: &Request| {
                let request_id = request
                    .extensions()
                    .get::<RequestId>()
                    .and_then(|id| id.header_value().to_str().ok())
                    .unwrap_or("-");
                tracing::info_span!(
                    "request",
                    request_id,
                    method = %request.method(),
                    path = request.uri().path(),
                    job_id = tracing::field::Empty,
                )
            }),
        )
        .layer(PropagateRequestIdLayer::x_request_id())
        .layer(SetRequestIdLayer::x_request_id(MakeRequestUuid))
        .layer(cors)
        .with_state(state)
}

fn cors_layer(origins: &[String]) -> CorsLayer {
    if origins.is_empty() {
        return CorsLayer::new();
    }
    // Request headers mirrored, not `*`: the Fetch standard's wildcard does not cover
    // `Authorization`, so a keyed page's preflight would fail.
    let layer = CorsLayer::new()
        .allow_methods([Method::GET, Method::POST, Method::DELETE])
        .allow_headers(AllowHeaders::mirror_request())
        .expose_headers(Any)
        .max_age(Duration::from_secs(3600));
    if origins.iter().any(|origin| origin == "*") {
        layer.allow_origin(Any)
    } else {
        let values = origins
            .iter()
            .map(|origin| HeaderValue::from_str(origin).expect("checked in AppState::open"));
        layer.allow_origin(AllowOrigin::list(values))
    }
}

/// Runs the service until SIGINT/SIGTERM, then drains: stops accepting and starting jobs, ends
/// event streams and idle connections, lets running jobs and responses finish for
/// `shutdown_grace` (longer jobs are re-queued for the next start, other connections dropped).
/// `on_listening` gets the bound address (useful with port 0).
pub async fn serve(
    config: Config,
    on_listening: impl FnOnce(SocketAddr),
) -> Result<(), ServeError> {
    if config.api_keys.is_empty() && !config.allow_anonymous && !config.addr.ip().is_loopback() {
        return Err(ServeError::Anonymous(config.addr));
    }
    let state = AppState::open(&config)?;
    let listener = tokio::net::TcpListener::bind(config.addr)
        .await
        .map_err(|source| ServeError::Bind {
            addr: config.addr,
            source,
        })?;
    let addr = listener.local_addr()?;
    tracing::info!(%addr, data_dir = %config.data_dir.display(), workers = state.queue.workers(), "listening");
    on_listening(addr);

    let sweeper = tokio::spawn(sweep_expired(
        state.queue.clone(),
        state.rates.clone(),
        config
            .queue
            .retention
            .min(config.queue.record_retention)
            .min(config.queue.idempotency_window),
        config.queue.orphan_age,
    ));
    let metrics_upkeep = tokio::spawn(telemetry::upkeep(state.metrics.clone()));
    let ops_port = match config.ops_addr {
        Some(addr) => {
            let listener = tokio::net::TcpListener::bind(addr)
                .await
                .map_err(|source| ServeError::Bind { addr, source })?;
            tracing::info!(addr = %listener.local_addr()?, "probes and metrics");
            Some(tokio::spawn(conn::accept(
                listener,
                ops::serve_app(state.clone()),
                config.connections,
                state.shutdown.subscribe(),
            )))
        }
        None => None,
    };
    let shutdown = state.shutdown.clone();
    let signal = tokio::spawn(async move {
        stop_signal().await;
        shutdown.send_replace(true);
    });
    let connections = conn::accept(
        listener,
        app(state.clone()),
        config.connections,
        state.shutdown.subscribe(),
    )
    .await;
    tracing::info!("shutting down: no new connections or jobs");
    signal.abort();
    sweeper.abort();
    metrics_upkeep.abort();
    // Jobs and connections wind down together, so the whole stop takes one grace period.
    let queue = state.queue.clone();
    let grace = config.shutdown_grace;
    let drain = tokio::task::spawn_blocking(move || queue.drain(grace));
    conn::close(connections, grace).await;
    if let Some(Ok(connections)) = match ops_port {
        Some(port) => Some(port.await),
        None => None,
    } {
        conn::close(connections, Duration::from_secs(1)).await;
    }
    drain.await.map_err(std::io::Error::other)?;
    tracing::info!("stopped");
    Ok(())
}

/// Runs `covec worker`: job slots on the shared backend ([`backend::Workers`]), without an
/// HTTP API, until SIGINT/SIGTERM; then running jobs finish for `shutdown_grace` or go back to
/// the queue. Uses the data directory or object store, the database, the queue's workers,
/// threads, time limit, retention and lease, the input and connection limits of `config`.
/// Given `ops_addr`, serves the worker's probes and metrics there
/// ([`ops::worker_app`]); `on_listening` gets the bound address.
pub async fn work(
    config: Config,
    ops_addr: Option<SocketAddr>,
    on_listening: impl FnOnce(SocketAddr),
) -> Result<(), ServeError> {
    let RecordsAt::Database(database_url) = &config.records else {
        return Err(ServeError::WorkersNotShared);
    };
    // Job durations are recorded here (for `/metrics` on the ops port, if any), so the samples
    // need upkeep.
    let metrics = Arc::new(Metrics::default());
    let metrics_upkeep = tokio::spawn(telemetry::upkeep(metrics.clone()));
    let runner_of = |store| {
        Arc::new(runner::Runner {
            decode_slots: Arc::new(tokio::sync::Semaphore::new(
                config.limits.decode_slots.max(1),
            )),
            store,
            limits: config.limits.clone(),
            runtime: tokio::runtime::Handle::current(),
            job_time_limit: config.queue.job_time_limit,
            retention: config.queue.retention,
            metrics: metrics.clone(),
        })
    };
    let slots = config.queue.workers.max(1);
    let workers = backend::start_workers(
        &config.data_dir,
        config.object_store.as_deref(),
        database_url,
        runner_of,
        &backend::WorkerConfig {
            slots,
            threads: config.queue.threads,
            lease: config.queue.lease,
            scheduling: config.queue.scheduling.clone(),
        },
    )?;
    tracing::info!(slots, "worker started");
    let (stopping, stopped) = tokio::sync::watch::channel(false);
    let ops_port = match ops_addr {
        Some(addr) => {
            let listener = tokio::net::TcpListener::bind(addr)
                .await
                .map_err(|source| ServeError::Bind { addr, source })?;
            let addr = listener.local_addr()?;
            tracing::info!(%addr, "probes and metrics");
            on_listening(addr);
            let app = ops::worker_app(&workers);
            Some(tokio::spawn(conn::accept(
                listener,
                app,
                config.connections,
                stopped,
            )))
        }
        None => None,
    };
    stop_signal().await;
    tracing::info!("shutting down: no new jobs");
    let grace = config.shutdown_grace;
    tokio::task::spawn_blocking(move || workers.drain(grace))
        .await
        .map_err(std::io::Error::other)?;
    // Probes answered "not ready" while the jobs drained; now the port closes.
    stopping.send_replace(true);
    if let Some(Ok(connections)) = match ops_port {
        Some(port) => Some(port.await),
        None => None,
    } {
        conn::close(connections, Duration::from_secs(1)).await;
    }
    metrics_upkeep.abort();
    tracing::info!("stopped");
    Ok(())
}

/// Removes expired results, records and Idempotency-Keys, job directories no job owns, and
/// the rate state of keys idle for a while, periodically (a tenth of the shortest of
/// `retention` and the other two periods, 1 to 60 s).
async fn sweep_expired(
    queue: Arc<Queue>,
    rates: Arc<fair::SubmissionRates>,
    retention: Duration,
    orphan_age: Duration,
) {
    let period = (retention / 10).clamp(Duration::from_secs(1), Duration::from_secs(60));
    let mut ticks = tokio::time::interval(period);
    loop {
        ticks.tick().await;
        rates.shrink();
        let queue = queue.clone();
        let (removed, orphans) = tokio::task::spawn_blocking(move || {
            (
                queue.expire(model::now_ms()),
                queue.sweep_orphans(orphan_age),
            )
        })
        .await
        .unwrap_or((0, 0));
        if removed > 0 {
            tracing::info!(removed, "expired job results removed");
        }
        if orphans > 0 {
            tracing::info!(orphans, "orphaned job directories removed");
        }
    }
}

async fn stop_signal() {
    let interrupt = tokio::signal::ctrl_c();
    #[cfg(unix)]
    {
        let mut terminate =
            tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
                .expect("SIGTERM handler");
        tokio::select! {
            _ = interrupt => {}
            _ = terminate.recv() => {}
        }
    }
    #[cfg(not(unix))]
    let _ = interrupt.await;
}

#[cfg(test)]
mod tests;
