//! The one storage error, what a client may see of it, and which failures are worth a retry.

use std::path::{Path, PathBuf};
use std::time::Duration;

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("data directory {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("job database: {0}")]
    Sqlite(#[from] rusqlite::Error),
    #[error("job record {id} is corrupt: {reason}")]
    CorruptRecord { id: String, reason: String },
    /// A request to the object store failed (after object_store's own retries).
    #[error("object store: {0}")]
    ObjectStore(#[from] object_store::Error),
    #[error("object store `{url}`: {reason}")]
    ObjectStoreUrl { url: String, reason: String },
    /// The object store's runtime stopped while a request was waiting (shutdown).
    #[error("object store: stopped")]
    ObjectStoreStopped,
    #[error("job database: {}", with_sources(.0))]
    Postgres(#[from] tokio_postgres::Error),
    /// No connection to PostgreSQL could be had in time (the server is down or unreachable).
    #[error("job database: {0}")]
    DatabasePool(String),
    #[error("job database URL: {0}")]
    DatabaseUrl(String),
    /// The database client's runtime stopped while a request was waiting (shutdown).
    #[error("job database: stopped")]
    DatabaseStopped,
}

impl StoreError {
    /// What failed without where: clients never see the data directory's paths (they stay in
    /// the server log).
    pub fn public_detail(&self) -> String {
        match self {
            StoreError::Io { source, .. } => format!("storage: {source}"),
            StoreError::Sqlite(error) => format!("job database: {error}"),
            StoreError::CorruptRecord { id, .. } => format!("job record {id} is corrupt"),
            // object_store's messages name the bucket and endpoint.
            StoreError::ObjectStore(object_store::Error::NotFound { .. }) => {
                "object store: not found".to_owned()
            }
            StoreError::ObjectStore(_) | StoreError::ObjectStoreStopped => {
                "object store: request failed".to_owned()
            }
            StoreError::ObjectStoreUrl { .. } => "object store: misconfigured".to_owned(),
            // PostgreSQL's messages may name hosts and users.
            StoreError::Postgres(_) | StoreError::DatabasePool(_) | StoreError::DatabaseStopped => {
                "job database: request failed".to_owned()
            }
            StoreError::DatabaseUrl(_) => "job database: misconfigured".to_owned(),
        }
    }
}

impl StoreError {
    /// Whether the same operation may succeed if tried again shortly: the failure is about the
    /// moment (a full disk or quota, no file descriptor or memory left, an interrupted or timed
    /// out call, a busy or locked database), not the data or the directory's permissions (read
    /// only, permission denied, missing, corrupt), which no retry fixes.
    pub fn is_transient(&self) -> bool {
        use std::io::ErrorKind;
        match self {
            StoreError::Io { source, .. } => {
                matches!(
                    source.kind(),
                    ErrorKind::Interrupted
                        | ErrorKind::WouldBlock
                        | ErrorKind::TimedOut
                        | ErrorKind::StorageFull
                        | ErrorKind::QuotaExceeded
                        | ErrorKind::ResourceBusy
                        | ErrorKind::OutOfMemory
                ) || out_of_descriptors(source)
            }
            StoreError::Sqlite(rusqlite::Error::SqliteFailure(error, _)) => matches!(
                error.code,
                rusqlite::ErrorCode::DatabaseBusy
                    | rusqlite::ErrorCode::DatabaseLocked
                    | rusqlite::ErrorCode::DiskFull
                    | rusqlite::ErrorCode::OutOfMemory
            ),
            // A lost connection, a server restarting or refusing connections, a serialisation
            // conflict or deadlock: worth another try. Errors without a SQL state are the
            // connection's own.
            StoreError::Postgres(error) => error.code().is_none_or(|code| {
                let code = code.code();
                // Class 53: out of disk, memory or connections.
                code.starts_with("08")
                    || code.starts_with("57P")
                    || code.starts_with("53")
                    || matches!(code, "40001" | "40P01")
            }),
            StoreError::DatabasePool(_) => true,
            // The bucket out of reach even after object_store's own retries ([`Artefacts`]):
            // the store is down or restarting, as a database refusing connections is.
            StoreError::ObjectStore(error) => store_unreachable(error),
            StoreError::Sqlite(_)
            | StoreError::DatabaseUrl(_)
            | StoreError::DatabaseStopped
            | StoreError::CorruptRecord { .. }
            | StoreError::ObjectStoreUrl { .. }
            | StoreError::ObjectStoreStopped => false,
        }
    }
}

/// Whether an object-store request failed on its connection (refused, reset, closed, timed
/// out): an [`HttpError`](object_store::client::HttpError) among the error's sources, of a
/// connection kind or, when object_store could not tell its kind, caused by a connection's
/// failure. Anything the store answered (a missing bucket, a refused signature) is not.
fn store_unreachable(error: &object_store::Error) -> bool {
    use object_store::client::{HttpError, HttpErrorKind};
    let Some(http) = sources(error).find_map(|error| error.downcast_ref::<HttpError>()) else {
        return false;
    };
    match http.kind() {
        HttpErrorKind::Connect
        | HttpErrorKind::Request
        | HttpErrorKind::Timeout
        | HttpErrorKind::Interrupted => true,
        // A fresh connection closed before the request went out (a store going down accepts
        // and drops connections) is hyper's "canceled", which object_store leaves unknown.
        HttpErrorKind::Unknown => sources(http).any(connection_failed),
        _ => false,
    }
}

/// `error` and its sources, outermost first.
fn sources<'a>(
    error: &'a (dyn std::error::Error + 'static),
) -> impl Iterator<Item = &'a (dyn std::error::Error + 'static)> {
    std::iter::successors(Some(error), |error| error.source())
}

/// Whether `error` is a connection's failure: closed or canceled before an answer came (hyper),
/// or refused, reset, cut or timed out (the socket's own error).
fn connection_failed(error: &(dyn std::error::Error + 'static)) -> bool {
    use std::io::ErrorKind;
    if let Some(error) = error.downcast_ref::<hyper::Error>() {
        return error.is_canceled() || error.is_closed() || error.is_incomplete_message();
    }
    error.downcast_ref::<std::io::Error>().is_some_and(|error| {
        matches!(
            error.kind(),
            ErrorKind::ConnectionRefused
                | ErrorKind::ConnectionReset
                | ErrorKind::ConnectionAborted
                | ErrorKind::NotConnected
                | ErrorKind::BrokenPipe
                | ErrorKind::UnexpectedEof
                | ErrorKind::TimedOut
        )
    })
}

/// Out of file descriptors (`EMFILE`, `ENFILE`), for which std has no error kind.
fn out_of_descriptors(error: &std::io::Error) -> bool {
    #[cfg(target_os = "linux")]
    return matches!(error.raw_os_error(), Some(libc::EMFILE | libc::ENFILE));
    #[cfg(not(target_os = "linux"))]
    return false;
}

/// The waits before each retry of a job's own storage operation that failed transiently
/// ([`retry_transient`]): 111 s in all, time for a database restart or fail-over, an object
/// store down for a minute, or expired results to free a full disk; a job holds its worker
/// (and its lease) meanwhile rather than fail for a passing outage.
pub const RETRY_DELAYS: [Duration; 10] = [
    Duration::from_millis(200),
    Duration::from_millis(400),
    Duration::from_millis(800),
    Duration::from_millis(1600),
    Duration::from_millis(3200),
    Duration::from_millis(6400),
    Duration::from_millis(12_800),
    Duration::from_millis(25_600),
    Duration::from_secs(30),
    Duration::from_secs(30),
];

/// Runs `operation`, and again after each of [`RETRY_DELAYS`] while it fails transiently
/// ([`StoreError::is_transient`]), logging each retry; any other error, or the last transient
/// one, is returned. Blocking (it sleeps): for the job runners, whose work would otherwise be
/// lost. A request handler does not retry: its client gets a 5xx and may.
pub fn retry_transient<T>(
    what: &str,
    mut operation: impl FnMut() -> Result<T, StoreError>,
) -> Result<T, StoreError> {
    let mut delays = RETRY_DELAYS.iter();
    loop {
        match operation() {
            Err(error) if error.is_transient() => {
                let Some(delay) = delays.next() else {
                    return Err(error);
                };
                tracing::warn!(
                    %error,
                    retry_in_ms = delay.as_millis() as u64,
                    "{what}: transient storage error, retrying"
                );
                std::thread::sleep(*delay);
            }
            result => return result,
        }
    }
}

/// Wraps an I/O error with the path it concerns (kept for the log, never shown to clients).
pub fn io_error(path: &Path) -> impl FnOnce(std::io::Error) -> StoreError + '_ {
    move |source| StoreError::Io {
        path: path.to_owned(),
        source,
    }
}

/// `error` and its sources on one line: tokio-postgres and deadpool keep the server's words
/// (a refused login, a certificate that does not match) in the sources, not in the message.
pub fn with_sources(error: &(dyn std::error::Error + 'static)) -> String {
    let mut line = error.to_string();
    for cause in sources(error).skip(1) {
        let words = cause.to_string();
        if !line.ends_with(&words) {
            line.push_str(": ");
            line.push_str(&words);
        }
    }
    line
}

#[cfg(test)]
mod tests {
    use super::*;
    use object_store::client::{HttpError, HttpErrorKind};

    /// An object-store error as object_store reports a transport failure: `source` under an
    /// [`HttpError`] of `kind`.
    fn transport_error(
        kind: HttpErrorKind,
        source: impl std::error::Error + Send + Sync + 'static,
    ) -> StoreError {
        StoreError::ObjectStore(object_store::Error::Generic {
            store: "S3",
            source: Box::new(HttpError::new(kind, source)),
        })
    }

    /// hyper's error for a request that never went out because its connection was gone.
    fn canceled_request() -> hyper::Error {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .build()
            .unwrap();
        runtime.block_on(async {
            let (client, _server) = tokio::io::duplex(64);
            let (mut sender, connection) = hyper::client::conn::http1::handshake::<
                _,
                http_body_util::Empty<&'static [u8]>,
            >(hyper_util::rt::TokioIo::new(client))
            .await
            .unwrap();
            drop(connection);
            let request = hyper::Request::new(http_body_util::Empty::new());
            sender.send_request(request).await.unwrap_err()
        })
    }

    /// The CI failure of the object-store outage test (service_s3): a job's input read on a
    /// connection the store closed at once ended as an unknown transport error, was taken
    /// for a lasting one, and the job failed instead of waiting for the store.
    #[test]
    fn a_request_canceled_by_a_closed_connection_is_worth_a_retry() {
        let canceled = canceled_request();
        assert!(canceled.is_canceled(), "{canceled:?}");
        assert!(transport_error(HttpErrorKind::Unknown, canceled).is_transient());
    }

    #[test]
    fn transport_errors_are_transient_by_kind_or_cause() {
        use std::io::{Error, ErrorKind};
        for kind in [
            HttpErrorKind::Connect,
            HttpErrorKind::Request,
            HttpErrorKind::Timeout,
            HttpErrorKind::Interrupted,
        ] {
            let error = transport_error(kind, Error::other("x"));
            assert!(error.is_transient(), "{kind:?}");
        }
        let reset = Error::from(ErrorKind::ConnectionReset);
        assert!(transport_error(HttpErrorKind::Unknown, reset).is_transient());
        // An unknown failure that is not the connection's, and a body that would not decode,
        // are not the moment's.
        let denied = Error::from(ErrorKind::PermissionDenied);
        assert!(!transport_error(HttpErrorKind::Unknown, denied).is_transient());
        let garbled = Error::from(ErrorKind::ConnectionReset);
        assert!(!transport_error(HttpErrorKind::Decode, garbled).is_transient());
        // What the store answered is no transport error at all.
        let missing = StoreError::ObjectStore(object_store::Error::NotFound {
            path: "jobs/x".into(),
            source: Box::new(Error::other("404")),
        });
        assert!(!missing.is_transient());
    }
}
