//! Serving: `covec serve` (the API and the jobs) and `covec worker` (jobs only) until a stop
//! signal, then draining; the periodic clean-up; the errors that stop either.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use super::queue::Queue;
use super::state::{AppState, ServeError};
use super::telemetry::{self, Metrics};
use super::{Config, RecordsAt, app, backend, conn, fair, model, ops, runner};

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
