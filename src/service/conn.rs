//! Accepting connections: HTTP/1.1 with header and body read timeouts, a cap on open
//! connections, and a shutdown that ends idle and half-open ones.
//!
//! `axum::serve` sets none of these, so a client that opens connections and sends nothing (or
//! half a request) could hold them, and the process's file descriptors, forever.

use std::collections::BTreeMap;
use std::convert::Infallible;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use axum::Router;
use axum::body::Body;
use axum::extract::Request;
use http_body_util::BodyExt;
use hyper::body::Incoming;
use hyper::server::conn::http1;
use hyper::service::service_fn;
use hyper_util::rt::{TokioIo, TokioTimer};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{Notify, watch};
use tokio::task::JoinSet;
use tower::ServiceExt;
use tower_http::timeout::TimeoutBody;

/// How long clients may take, and how many may be connected at once.
#[derive(Clone, Copy, Debug)]
pub struct ConnectionLimits {
    /// Longest wait for a request's headers, from the connection's first byte or the end of the
    /// previous response: also how long an idle keep-alive connection stays open. Default 10 s.
    pub header_read_timeout: Duration,
    /// Longest pause while reading a request body; then the request fails. Default 30 s.
    pub body_read_timeout: Duration,
    /// Most open connections; a new one beyond it closes the oldest idle or half-sent one (or
    /// is refused when every one is answering a request). Keep it well below the open-file
    /// limit (`ulimit -n`): jobs need files too. Default 512.
    pub max_connections: usize,
}

impl Default for ConnectionLimits {
    fn default() -> Self {
        Self {
            header_read_timeout: Duration::from_secs(10),
            body_read_timeout: Duration::from_secs(30),
            max_connections: 512,
        }
    }
}

/// Serves connections until `stopping` turns true; returns the connections still open, each
/// already told to close once its current response is sent.
pub async fn accept(
    listener: TcpListener,
    app: Router,
    limits: ConnectionLimits,
    mut stopping: watch::Receiver<bool>,
) -> JoinSet<()> {
    let open = Arc::new(OpenConnections::default());
    let mut connections = JoinSet::new();
    let mut next_id = 0_u64;
    loop {
        // Finished connections' tasks, so the set stays as large as the open connections.
        while connections.try_join_next().is_some() {}
        let stream = tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok((stream, _)) => stream,
                Err(error) => {
                    // Out of file descriptors, mostly: let some close rather than spin.
                    tracing::warn!(%error, "accepting a connection");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                }
            },
            _ = stopped(&mut stopping) => break,
        };
        // Always accepting and evicting idle connections, rather than leaving new ones in the
        // listen backlog, keeps clients served while others hold connections open: the backlog
        // is short, and connections beyond it wait seconds for SYN retries.
        let Some(connection) = open.admit(next_id, limits.max_connections) else {
            tracing::warn!(
                max_connections = limits.max_connections,
                "every connection is busy: refusing a new one"
            );
            continue;
        };
        next_id += 1;
        connections.spawn(serve_connection(
            stream,
            app.clone(),
            limits,
            stopping.clone(),
            Registered {
                open: Arc::clone(&open),
                connection,
            },
        ));
    }
    connections
}

/// Waits up to `grace` for the connections to finish their responses, then drops the rest
/// (stalled uploads, readers that stopped reading).
pub async fn close(mut connections: JoinSet<()>, grace: Duration) {
    let all_done = async { while connections.join_next().await.is_some() {} };
    if tokio::time::timeout(grace, all_done).await.is_err() {
        tracing::info!(
            open = connections.len(),
            "shutdown grace over: closing connections"
        );
        connections.shutdown().await;
    }
}

/// One open connection, as the accept loop sees it.
#[derive(Default)]
struct Connection {
    id: u64,
    /// Requests being answered (until their response body is sent or dropped).
    in_flight: AtomicUsize,
    /// Told to close: it was idle when a new connection needed its place.
    evict: Notify,
}

impl Connection {
    fn is_idle(&self) -> bool {
        self.in_flight.load(Ordering::SeqCst) == 0
    }
}

/// The open connections, oldest first.
#[derive(Default)]
struct OpenConnections(Mutex<BTreeMap<u64, Arc<Connection>>>);

impl OpenConnections {
    /// Registers a new connection, evicting the oldest idle one (no request in flight: waiting
    /// for, or in the middle of, a request's headers) when `max` are open. `None` when all are
    /// busy.
    fn admit(&self, id: u64, max: usize) -> Option<Arc<Connection>> {
        let mut open = self.0.lock().unwrap_or_else(|p| p.into_inner());
        if open.len() >= max.max(1) {
            let idle = open
                .values()
                .find(|connection| connection.is_idle())
                .map(|connection| connection.id)?;
            if let Some(evicted) = open.remove(&idle) {
                evicted.evict.notify_one();
            }
        }
        let connection = Arc::new(Connection {
            id,
            ..Connection::default()
        });
        open.insert(id, Arc::clone(&connection));
        Some(connection)
    }
}

/// A connection in [`OpenConnections`], removed from it on drop.
struct Registered {
    open: Arc<OpenConnections>,
    connection: Arc<Connection>,
}

impl Drop for Registered {
    fn drop(&mut self) {
        let mut open = self.open.0.lock().unwrap_or_else(|p| p.into_inner());
        open.remove(&self.connection.id);
    }
}

/// Counts a request as in flight until its response body is dropped.
struct InFlight(Arc<Connection>);

impl InFlight {
    fn start(connection: &Arc<Connection>) -> Self {
        connection.in_flight.fetch_add(1, Ordering::SeqCst);
        Self(Arc::clone(connection))
    }
}

impl Drop for InFlight {
    fn drop(&mut self) {
        self.0.in_flight.fetch_sub(1, Ordering::SeqCst);
    }
}

async fn serve_connection(
    stream: TcpStream,
    app: Router,
    limits: ConnectionLimits,
    mut stopping: watch::Receiver<bool>,
    registered: Registered,
) {
    let connection = Arc::clone(&registered.connection);
    let body_timeout = limits.body_read_timeout;
    let tracked = Arc::clone(&connection);
    let service = service_fn(move |request: Request<Incoming>| {
        let in_flight = InFlight::start(&tracked);
        let request = request.map(|body| Body::new(TimeoutBody::new(body_timeout, body)));
        let response = app.clone().oneshot(request);
        async move {
            let response = response.await?;
            // The guard lives in the body, so a streamed response (events) counts as busy.
            Ok::<_, Infallible>(response.map(|body| {
                Body::new(body.map_frame(move |frame| {
                    let _ = &in_flight;
                    frame
                }))
            }))
        }
    });
    let mut builder = http1::Builder::new();
    builder
        .timer(TokioTimer::new())
        .header_read_timeout(limits.header_read_timeout);
    let http = builder.serve_connection(TokioIo::new(stream), service);
    tokio::pin!(http);
    let result = tokio::select! {
        result = http.as_mut() => result,
        _ = connection.evict.notified() => return,
        _ = stopped(&mut stopping) => {
            if connection.is_idle() {
                // Idle or half-sent: nothing to finish.
                return;
            }
            // Closes after the response being sent.
            http.as_mut().graceful_shutdown();
            http.await
        }
    };
    if let Err(error) = result {
        tracing::debug!(%error, "connection ended");
    }
}

/// Resolves once the server is stopping (or its state is gone).
async fn stopped(stopping: &mut watch::Receiver<bool>) {
    let _ = stopping.wait_for(|stop| *stop).await;
}
