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
//! generated from the handlers' attributes). This file assembles: the settings, the router;
//! what the handlers share is in `state.rs`, serving and draining in `serve.rs`.

mod auth;
mod backend;
mod conn;
mod derived;
mod download;
mod edits;
mod error;
mod events;
mod fair;
#[doc(hidden)]
pub mod fuzzing;
mod inputs;
mod job;
mod jobs;
mod limits;
mod model;
mod openapi;
mod ops;
mod queue;
mod rate;
mod results;
mod runner;
mod serve;
mod signed;
mod state;
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
pub use serve::{serve, work};
pub use state::{AppState, Endpoint, ServeError};
pub use webhooks::{WebhookConfig, WebhookConfigError};

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use axum::Router;
use axum::extract::Request;
use axum::http::{HeaderValue, Method};
use axum::middleware;
use tower_http::compression::CompressionLayer;
use tower_http::cors::{AllowHeaders, AllowOrigin, Any, CorsLayer};
use tower_http::request_id::{
    MakeRequestUuid, PropagateRequestIdLayer, RequestId, SetRequestIdLayer,
};
use tower_http::trace::TraceLayer;

use error::ApiError;

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

/// Every API route of the service. The web page (`/`, [`crate::web::routes`]) is merged in
/// [`app`]: it is not part of the API document.
pub fn endpoints() -> Vec<Endpoint> {
    let mut all = jobs::endpoints();
    all.extend(events::endpoints());
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

#[cfg(test)]
mod tests;
