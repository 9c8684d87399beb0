//! Persistence in the data directory: job records in SQLite, artefacts as plain files.
//!
//! Records go through rusqlite rather than sqlx: every access is a short synchronous statement
//! made from a worker thread or a `spawn_blocking` task, so an async driver buys nothing, and
//! rusqlite links the system libsqlite3 (no bundled C build, no proc macros) which keeps the
//! build quick. The table holds one JSON record per job keyed by id; a PostgreSQL store would
//! keep the same shape.
//!
//! Artefacts live under `jobs/<id>/` and are written atomically (temporary file, fsync, rename),
//! so a crash never leaves a half-written file under a served name.

use std::collections::BTreeMap;
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Duration;

use rusqlite::{Connection, params};
use sha2::{Digest, Sha256};

use super::error::ApiError;
use super::model::{JobRecord, Status, is_job_id, now_ms};

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
}

impl StoreError {
    /// What failed without where: clients never see the data directory's paths (they stay in
    /// the server log).
    pub fn public_detail(&self) -> String {
        match self {
            StoreError::Io { source, .. } => format!("storage: {source}"),
            StoreError::Sqlite(error) => format!("job database: {error}"),
            StoreError::CorruptRecord { id, .. } => format!("job record {id} is corrupt"),
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
            StoreError::Sqlite(_) | StoreError::CorruptRecord { .. } => false,
        }
    }
}

/// Out of file descriptors (`EMFILE`, `ENFILE`), for which std has no error kind.
fn out_of_descriptors(error: &std::io::Error) -> bool {
    #[cfg(target_os = "linux")]
    return matches!(error.raw_os_error(), Some(libc::EMFILE | libc::ENFILE));
    #[cfg(not(target_os = "linux"))]
    return false;
}

/// The waits before each retry of a job's own storage operation that failed transiently
/// ([`retry_transient`]): 6.2 s in all, time for a burst of connections to close or for
/// expired results to free space.
pub const RETRY_DELAYS: [Duration; 5] = [
    Duration::from_millis(200),
    Duration::from_millis(400),
    Duration::from_millis(800),
    Duration::from_millis(1600),
    Duration::from_millis(3200),
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

impl From<StoreError> for ApiError {
    fn from(error: StoreError) -> Self {
        tracing::error!(%error, "storage error");
        ApiError::Internal(error.public_detail())
    }
}

fn io_error(path: &Path) -> impl FnOnce(std::io::Error) -> StoreError + '_ {
    move |source| StoreError::Io {
        path: path.to_owned(),
        source,
    }
}

pub struct Store {
    root: PathBuf,
    db: Mutex<Connection>,
    reader: Mutex<Connection>,
}

/// What [`Store::recover`] found.
pub struct Recovered {
    /// Every readable record, oldest first.
    pub records: Vec<JobRecord>,
    /// Ids of rows that could not be read, moved to the `quarantine` table.
    pub quarantined: Vec<String>,
}

impl Store {
    /// Opens (creating if needed) the data directory and its database, adding the listing
    /// columns and indexes to a database written before they existed.
    pub fn open(root: &Path) -> Result<Self, StoreError> {
        fs::create_dir_all(root.join("jobs")).map_err(io_error(root))?;
        let path = root.join("jobs.sqlite3");
        let db = Connection::open(&path)?;
        // WAL: readers never block the writer; NORMAL sync is durable across process crashes.
        db.pragma_update(None, "journal_mode", "WAL")?;
        db.pragma_update(None, "synchronous", "NORMAL")?;
        db.execute_batch(
            "CREATE TABLE IF NOT EXISTS jobs (id TEXT PRIMARY KEY, record TEXT NOT NULL);
             CREATE TABLE IF NOT EXISTS quarantine (
                 id TEXT PRIMARY KEY, record TEXT NOT NULL, reason TEXT NOT NULL, at INTEGER NOT NULL
             );",
        )?;
        let columns: Vec<String> = db
            .prepare("SELECT name FROM pragma_table_info('jobs')")?
            .query_map([], |row| row.get(0))?
            .collect::<Result<_, _>>()?;
        for (column, kind) in [
            ("owner", "TEXT"),
            ("status", "TEXT"),
            ("deleted", "INTEGER NOT NULL DEFAULT 0"),
        ] {
            if !columns.iter().any(|name| name == column) {
                db.execute_batch(&format!("ALTER TABLE jobs ADD COLUMN {column} {kind}"))?;
            }
        }
        db.execute_batch(
            "CREATE INDEX IF NOT EXISTS jobs_by_owner ON jobs (owner, id);
             CREATE INDEX IF NOT EXISTS jobs_by_owner_status ON jobs (owner, status, id);",
        )?;
        // Listing reads on its own connection, so a page never waits for a worker's write
        // (rusqlite's connections wait up to 5 s for a lock held by the other).
        let reader = Connection::open(&path)?;
        Ok(Self {
            root: root.to_owned(),
            db: Mutex::new(db),
            reader: Mutex::new(reader),
        })
    }

    fn db(&self) -> std::sync::MutexGuard<'_, Connection> {
        self.db
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    /// Writes a job's record, unless the job was deleted: a tombstone is final, so a worker
    /// finishing or a cancel racing a DELETE cannot bring the record back.
    pub fn save(&self, record: &JobRecord) -> Result<(), StoreError> {
        let json = serde_json::to_string(record).expect("a job record always serialises");
        self.db().execute(
            "INSERT INTO jobs (id, owner, status, record) VALUES (?1, ?2, ?3, ?4)
             ON CONFLICT(id) DO UPDATE SET owner = excluded.owner, status = excluded.status,
                 record = excluded.record
             WHERE jobs.deleted = 0",
            params![record.id, record.owner, record.status.name(), json],
        )?;
        Ok(())
    }

    /// Marks a job deleted for good (its row goes at the next start, when no one can still be
    /// writing it). The commit point of a DELETE: until it is written nothing else changes.
    pub fn tombstone(&self, id: &str) -> Result<(), StoreError> {
        self.db()
            .execute("UPDATE jobs SET deleted = 1 WHERE id = ?1", params![id])?;
        Ok(())
    }

    /// At start: drops tombstones, moves unreadable rows to the `quarantine` table (logged;
    /// the server starts without them) and returns every other record, oldest first.
    pub fn recover(&self) -> Result<Recovered, StoreError> {
        let connection = self.db();
        // One transaction: a backfill of many rows is one commit, not one each.
        let db = connection.unchecked_transaction()?;
        db.execute("DELETE FROM jobs WHERE deleted = 1", [])?;
        // Rows from before the listing columns: filled in one statement (the loop below
        // quarantines those that are not JSON).
        db.execute(
            "UPDATE jobs SET owner = json_extract(record, '$.owner'),
                 status = json_extract(record, '$.status')
             WHERE status IS NULL AND json_valid(record)",
            [],
        )?;
        let rows: Vec<(String, String, Option<String>)> = db
            .prepare("SELECT id, record, status FROM jobs ORDER BY id")?
            .query_map([], |row| Ok((row.get(0)?, row.get(1)?, row.get(2)?)))?
            .collect::<Result<_, _>>()?;
        let mut recovered = Recovered {
            records: Vec::with_capacity(rows.len()),
            quarantined: Vec::new(),
        };
        for (id, json, status) in rows {
            match parse_record(&id, &json) {
                Ok(record) => {
                    if status.as_deref() != Some(record.status.name()) {
                        // The columns disagree with the record (a hand-edited row).
                        db.execute(
                            "UPDATE jobs SET owner = ?2, status = ?3 WHERE id = ?1",
                            params![id, record.owner, record.status.name()],
                        )?;
                    }
                    recovered.records.push(record);
                }
                Err(error) => {
                    tracing::error!(job_id = %id, %error, "unreadable job record quarantined");
                    db.execute(
                        "INSERT OR REPLACE INTO quarantine (id, record, reason, at)
                         VALUES (?1, ?2, ?3, ?4)",
                        params![id, json, error.to_string(), now_ms() as i64],
                    )?;
                    db.execute("DELETE FROM jobs WHERE id = ?1", params![id])?;
                    recovered.quarantined.push(id);
                }
            }
        }
        db.commit()?;
        Ok(recovered)
    }

    /// Up to `limit` ids of `owner`'s jobs (with `status` if given) strictly older than
    /// `before`, newest first; one index range scan.
    pub fn list_ids(
        &self,
        owner: &Option<String>,
        status: Option<Status>,
        before: Option<&str>,
        limit: usize,
    ) -> Result<Vec<String>, StoreError> {
        // Ids are `job_<hex>`: every one sorts before "k".
        let before = before.unwrap_or("k");
        let reader = self
            .reader
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        let ids = match status {
            Some(status) => reader
                .prepare_cached(
                    "SELECT id FROM jobs INDEXED BY jobs_by_owner_status
                     WHERE owner IS ?1 AND status = ?2 AND id < ?3 AND deleted = 0
                     ORDER BY id DESC LIMIT ?4",
                )?
                .query_map(params![owner, status.name(), before, limit as i64], |row| {
                    row.get(0)
                })?
                .collect::<Result<_, _>>()?,
            None => reader
                .prepare_cached(
                    "SELECT id FROM jobs INDEXED BY jobs_by_owner
                     WHERE owner IS ?1 AND id < ?2 AND deleted = 0
                     ORDER BY id DESC LIMIT ?3",
                )?
                .query_map(params![owner, before, limit as i64], |row| row.get(0))?
                .collect::<Result<_, _>>()?,
        };
        Ok(ids)
    }

    /// Whether a live or quarantined record exists for `id` (what the orphan sweep keeps).
    fn has_record(&self, id: &str) -> Result<bool, StoreError> {
        Ok(self.db().query_row(
            "SELECT EXISTS (SELECT 1 FROM jobs WHERE id = ?1 AND deleted = 0)
                 OR EXISTS (SELECT 1 FROM quarantine WHERE id = ?1)",
            params![id],
            |row| row.get(0),
        )?)
    }

    /// Removes job directories that no record owns (an upload interrupted by a crash, a refused
    /// submission whose clean-up failed, a deleted job whose files could not be removed then)
    /// and that were last changed more than `min_age` ago: a submission being admitted writes
    /// its files before its record. `keep` says whether a directory is a live job's.
    /// Returns how many were removed.
    pub fn sweep_orphans(&self, min_age: Duration, keep: impl Fn(&str) -> bool) -> usize {
        let jobs = self.root.join("jobs");
        let Ok(entries) = fs::read_dir(&jobs) else {
            return 0;
        };
        let mut removed = 0;
        for entry in entries.flatten() {
            let name = entry.file_name().to_string_lossy().into_owned();
            let old_enough = entry
                .metadata()
                .and_then(|metadata| metadata.modified())
                .is_ok_and(|modified| modified.elapsed().is_ok_and(|age| age >= min_age));
            if !old_enough || keep(&name) || !matches!(self.has_record(&name), Ok(false)) {
                continue;
            }
            match fs::remove_dir_all(entry.path()) {
                Ok(()) => removed += 1,
                Err(error) => {
                    tracing::warn!(dir = %name, %error, "removing an orphaned job directory")
                }
            }
        }
        removed
    }

    pub fn job_dir(&self, id: &str) -> PathBuf {
        self.root.join("jobs").join(id)
    }

    /// Writes `bytes` to `jobs/<id>/<name>` atomically.
    pub fn write_artefact(&self, id: &str, name: &str, bytes: &[u8]) -> Result<(), StoreError> {
        write_atomic(&self.job_dir(id).join(name), bytes)
    }

    /// Records the SHA-256 of files stored together under `jobs/<id>/<folder>/` (an edit's
    /// files; a job's own results have theirs in its record), by file name, for
    /// [`Store::folder_digest`] to check them by when they are served.
    pub fn write_folder_digests(
        &self,
        id: &str,
        folder: &str,
        digests: &BTreeMap<String, String>,
    ) -> Result<(), StoreError> {
        let json = serde_json::to_vec(digests).expect("digests serialise");
        self.write_artefact(id, &format!("{folder}/{FOLDER_DIGESTS}"), &json)
    }

    /// The digest [`Store::write_folder_digests`] recorded for `jobs/<id>/<name>`; `None` when
    /// its folder has none (a name at the job's top level, a preview, an edit stored before
    /// edits had digests). Digests that do not parse are [`StoreError::CorruptRecord`].
    pub fn folder_digest(&self, id: &str, name: &str) -> Result<Option<String>, StoreError> {
        let Some((folder, file)) = name.rsplit_once('/') else {
            return Ok(None);
        };
        let path = format!("{folder}/{FOLDER_DIGESTS}");
        let Some(json) = self.read_artefact(id, &path)? else {
            return Ok(None);
        };
        let digests: BTreeMap<String, String> =
            serde_json::from_slice(&json).map_err(|error| StoreError::CorruptRecord {
                id: format!("{id}/{path}"),
                reason: error.to_string(),
            })?;
        Ok(digests.get(file).cloned())
    }

    /// Reads `jobs/<id>/<name>`; `None` when it does not exist.
    pub fn read_artefact(&self, id: &str, name: &str) -> Result<Option<Vec<u8>>, StoreError> {
        let path = self.job_dir(id).join(name);
        match fs::read(&path) {
            Ok(bytes) => Ok(Some(bytes)),
            Err(error) if error.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(error) => Err(io_error(&path)(error)),
        }
    }

    /// Whether `jobs/<id>/<name>` exists, without reading it.
    pub fn has_artefact(&self, id: &str, name: &str) -> Result<bool, StoreError> {
        let path = self.job_dir(id).join(name);
        path.try_exists().map_err(io_error(&path))
    }

    /// Removes every file of a job; missing files are not an error.
    pub fn remove_artefacts(&self, id: &str) -> Result<(), StoreError> {
        let dir = self.job_dir(id);
        match fs::remove_dir_all(&dir) {
            Err(error) if error.kind() != std::io::ErrorKind::NotFound => {
                Err(io_error(&dir)(error))
            }
            _ => Ok(()),
        }
    }

    /// Removes what a run produced (previews and results), keeping the inputs for a re-run.
    pub fn remove_outputs(&self, id: &str) -> Result<(), StoreError> {
        let dir = self.job_dir(id);
        for name in ["previews", "layers"] {
            let path = dir.join(name);
            match fs::remove_dir_all(&path) {
                Err(error) if error.kind() != std::io::ErrorKind::NotFound => {
                    return Err(io_error(&path)(error));
                }
                _ => {}
            }
        }
        for name in ["scene.json", "result.svg"] {
            let path = dir.join(name);
            match fs::remove_file(&path) {
                Err(error) if error.kind() != std::io::ErrorKind::NotFound => {
                    return Err(io_error(&path)(error));
                }
                _ => {}
            }
        }
        Ok(())
    }

    /// Checks that the data directory accepts writes and the database answers (for `/readyz`).
    pub fn check(&self) -> Result<(), StoreError> {
        write_atomic(&self.root.join(".ready-check"), b"ok")?;
        self.db().query_row("SELECT 1", [], |_| Ok(()))?;
        Ok(())
    }
}

/// A stored record, if it parses and is the record of the row it is in.
fn parse_record(id: &str, json: &str) -> Result<JobRecord, StoreError> {
    let corrupt = |reason: String| StoreError::CorruptRecord {
        id: id.to_owned(),
        reason,
    };
    let record: JobRecord =
        serde_json::from_str(json).map_err(|error| corrupt(error.to_string()))?;
    if record.id != id || !is_job_id(id) {
        return Err(corrupt(format!("it holds the record of `{}`", record.id)));
    }
    Ok(record)
}

/// The file in a folder of a job that holds its other files' digests.
const FOLDER_DIGESTS: &str = "checksums.json";

/// SHA-256 of a stored file in hex, recorded when it is written and checked when it is served.
pub fn digest(bytes: &[u8]) -> String {
    super::submit::hex(&Sha256::digest(bytes))
}

/// Temporary file in the same directory, fsync, rename over the target.
fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), StoreError> {
    let dir = path.parent().expect("artefact paths have a parent");
    fs::create_dir_all(dir).map_err(io_error(dir))?;
    let file_name = path
        .file_name()
        .expect("artefact paths name a file")
        .to_string_lossy();
    let temporary = dir.join(format!(
        ".{file_name}.{}.tmp",
        uuid::Uuid::now_v7().simple()
    ));
    let result = (|| {
        let mut file = fs::File::create(&temporary)?;
        file.write_all(bytes)?;
        file.sync_all()?;
        fs::rename(&temporary, path)
    })();
    if result.is_err() {
        let _ = fs::remove_file(&temporary);
    }
    result.map_err(io_error(path))
}
