//! Persistence: job records in SQLite in the data directory (the embedded default) or in
//! PostgreSQL shared by API replicas and workers ([`Postgres`], `--database-url`); artefacts as
//! files in the data directory or as objects in an S3-compatible bucket ([`Artefacts`]).
//!
//! Records go through rusqlite rather than sqlx: every access is a short synchronous statement
//! made from a worker thread or a `spawn_blocking` task, so an async driver buys nothing, and
//! rusqlite links the system libsqlite3 (no bundled C build, no proc macros) which keeps the
//! build quick. The table holds one JSON record per job keyed by id, with the columns its queries
//! read beside it (written from the record on every save); PostgreSQL keeps the same shape.
//!
//! Artefacts live under `jobs/<id>/` and are written whole or not at all (see [`Artefacts`]),
//! so a crash never leaves a half-written file under a served name.

use std::collections::BTreeMap;
use std::fs;
use std::path::Path;
use std::sync::Mutex;
use std::time::Duration;

use rusqlite::{Connection, OptionalExtension, params};
use sha2::{Digest, Sha256};

mod artefacts;
mod error;
mod postgres;
mod postgres_tls;

use super::model::{JobRecord, Status, Webhook, is_job_id, now_ms};
use artefacts::Artefacts;
use error::io_error;
pub use error::{StoreError, retry_transient};
pub use postgres::{Beat, Canceled, Change, Claim, Inserted, MAX_ATTEMPTS, Postgres};

pub struct Store {
    artefacts: Artefacts,
    records: Records,
}

/// Where job records live.
enum Records {
    /// SQLite in the data directory: one writer connection, one for listings.
    Sqlite {
        db: Mutex<Connection>,
        reader: Mutex<Connection>,
    },
    Postgres(Postgres),
}

/// What [`Store::recover`] found.
pub struct Recovered {
    /// The readable queued and running records, oldest first.
    pub records: Vec<JobRecord>,
    /// Ids of rows that could not be read, moved to the `quarantine` table.
    pub quarantined: Vec<String>,
}

impl Store {
    /// Opens (creating if needed) the data directory; records go to its SQLite database or,
    /// given `database_url` (`postgres://…`), to that PostgreSQL database (migrated first);
    /// artefacts go to the data directory or, given `object_store` (`s3://bucket/prefix`), to
    /// that bucket.
    pub fn open(
        root: &Path,
        object_store: Option<&str>,
        database_url: Option<&str>,
    ) -> Result<Self, StoreError> {
        fs::create_dir_all(root).map_err(io_error(root))?;
        let artefacts = Artefacts::open(root, object_store)?;
        let records = match database_url {
            Some(url) => Records::Postgres(Postgres::connect(url)?),
            None => open_sqlite(root)?,
        };
        Ok(Self { artefacts, records })
    }

    /// The PostgreSQL records, when records live there (the shared backend).
    pub fn shared(&self) -> Option<&Postgres> {
        match &self.records {
            Records::Postgres(postgres) => Some(postgres),
            Records::Sqlite { .. } => None,
        }
    }

    /// The SQLite writer connection; [`StoreError::NotEmbedded`] on the shared backend, whose
    /// records are written through [`Store::shared`] instead.
    fn db(&self) -> Result<std::sync::MutexGuard<'_, Connection>, StoreError> {
        match &self.records {
            Records::Sqlite { db, .. } => {
                Ok(db.lock().unwrap_or_else(|poisoned| poisoned.into_inner()))
            }
            Records::Postgres(_) => Err(StoreError::NotEmbedded),
        }
    }

    /// Writes a job's record, unless the job was deleted: a tombstone is final, so a worker
    /// finishing or a cancel racing a DELETE cannot bring the record back.
    ///
    /// On the shared backend only a job no worker holds is written, and its webhook deliveries
    /// are kept ([`Postgres::save_idle`]).
    pub fn save(&self, record: &JobRecord) -> Result<(), StoreError> {
        if let Some(postgres) = self.shared() {
            return postgres.save_idle(record);
        }
        save_row(&*self.db()?, record)
    }

    /// Writes a job's webhook deliveries: its whole record on the embedded backend, only that
    /// field on the shared one (where a worker may be writing the rest).
    pub fn save_webhook(&self, record: &JobRecord) -> Result<(), StoreError> {
        match self.shared() {
            Some(postgres) => postgres.save_webhook(record),
            None => self.save(record),
        }
    }

    /// Marks a job deleted for good (its row goes at the next start, when no one can still be
    /// writing it). The commit point of a DELETE: until it is written nothing else changes.
    pub fn tombstone(&self, id: &str) -> Result<(), StoreError> {
        if let Some(postgres) = self.shared() {
            return postgres.tombstone(id);
        }
        self.db()?
            .execute("UPDATE jobs SET deleted = 1 WHERE id = ?1", params![id])?;
        Ok(())
    }

    /// At start: drops tombstones, moves unreadable rows to the `quarantine` table (logged;
    /// the server starts without them) and returns the queued and running records, oldest
    /// first. Ended records stay in the store, read when asked for ([`Store::get`]): start-up
    /// reads the live jobs through an index, whatever the number of records.
    pub fn recover(&self) -> Result<Recovered, StoreError> {
        let connection = self.db()?;
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
        let rows: Vec<(String, String)> = db
            .prepare(
                "SELECT id, record FROM jobs INDEXED BY jobs_live
                 WHERE status IN ('queued', 'running') OR status IS NULL ORDER BY id",
            )?
            .query_map([], |row| Ok((row.get(0)?, row.get(1)?)))?
            .collect::<Result<_, _>>()?;
        let mut recovered = Recovered {
            records: Vec::with_capacity(rows.len()),
            quarantined: Vec::new(),
        };
        for (id, json) in rows {
            match parse_record(&id, &json) {
                Ok(record) => {
                    if !record.status.is_terminal() {
                        recovered.records.push(record);
                    } else {
                        // The status column disagrees with the record (a hand-edited row).
                        save_row(&db, &record)?;
                    }
                }
                Err(error) => {
                    quarantine(&db, &id, &json, &error)?;
                    recovered.quarantined.push(id);
                }
            }
        }
        db.commit()?;
        Ok(recovered)
    }

    /// The record of job `id`, if it has one. An unreadable row is moved to the quarantine
    /// (as at start) and answered [`StoreError::CorruptRecord`].
    pub fn get(&self, id: &str) -> Result<Option<JobRecord>, StoreError> {
        if let Some(postgres) = self.shared() {
            return postgres.get(id);
        }
        let db = self.db()?;
        let json: Option<String> = db
            .prepare_cached("SELECT record FROM jobs WHERE id = ?1 AND deleted = 0")?
            .query_row(params![id], |row| row.get(0))
            .optional()?;
        let Some(json) = json else {
            return Ok(None);
        };
        match parse_record(id, &json) {
            Ok(record) => Ok(Some(record)),
            Err(error) => {
                quarantine(&db, id, &json, &error)?;
                Err(error)
            }
        }
    }

    /// The newest job of `owner` holding Idempotency-Key `key` created at or after
    /// `created_since` (Unix ms): keys older than that have expired.
    pub fn idempotent(
        &self,
        owner: &Option<String>,
        key: &str,
        created_since: u64,
    ) -> Result<Option<JobRecord>, StoreError> {
        if let Some(postgres) = self.shared() {
            return postgres.idempotent(owner, key, created_since);
        }
        let id: Option<String> = self
            .db()?
            .prepare_cached(
                "SELECT id FROM jobs INDEXED BY jobs_by_idempotency_key
                 WHERE owner IS ?1 AND idempotency_key = ?2 AND created_at >= ?3 AND deleted = 0
                 ORDER BY id DESC LIMIT 1",
            )?
            .query_row(params![owner, key, created_since as i64], |row| row.get(0))
            .optional()?;
        match id {
            Some(id) => self.get(&id),
            None => Ok(None),
        }
    }

    /// Removes the Idempotency-Keys of jobs created before `created_before` (Unix ms) from
    /// their records; returns how many.
    pub fn drop_idempotency_keys(&self, created_before: u64) -> Result<usize, StoreError> {
        if let Some(postgres) = self.shared() {
            return postgres.drop_idempotency_keys(created_before);
        }
        Ok(self.db()?.execute(
            "UPDATE jobs INDEXED BY jobs_keys_by_age
             SET idempotency_key = NULL, record = CASE WHEN json_valid(record)
                 THEN json_remove(record, '$.idempotency') ELSE record END
             WHERE idempotency_key IS NOT NULL AND created_at < ?1",
            params![created_before as i64],
        )?)
    }

    /// Up to `limit` ids of jobs whose results were due for removal at `now` (Unix ms) and are
    /// not removed yet.
    pub fn results_due(&self, now: u64, limit: usize) -> Result<Vec<String>, StoreError> {
        if let Some(postgres) = self.shared() {
            return postgres.results_due(now, limit);
        }
        Ok(self
            .db()?
            .prepare_cached(
                "SELECT id FROM jobs INDEXED BY jobs_results_due
                 WHERE results_expire_at IS NOT NULL AND results_expire_at <= ?1 AND deleted = 0
                 LIMIT ?2",
            )?
            .query_map(params![now as i64, limit as i64], |row| row.get(0))?
            .collect::<Result<_, _>>()?)
    }

    /// Deletes up to `limit` records of jobs that ended before `ended_before` (Unix ms),
    /// leaving each an entry in `expired_jobs` (its id and owner: what tells `410 Gone` from
    /// `404`), and the entries written before `expired_before`; returns the deleted jobs' ids.
    pub fn expire_records(
        &self,
        ended_before: u64,
        expired_before: u64,
        limit: usize,
    ) -> Result<Vec<String>, StoreError> {
        if let Some(postgres) = self.shared() {
            return postgres.expire_records(ended_before, expired_before, limit);
        }
        let connection = self.db()?;
        let db = connection.unchecked_transaction()?;
        let ids: Vec<String> = db
            .prepare_cached(
                "SELECT id FROM jobs INDEXED BY jobs_by_completion
                 WHERE status IN ('succeeded', 'failed', 'canceled') AND completed_at < ?1
                     AND deleted = 0
                 LIMIT ?2",
            )?
            .query_map(params![ended_before as i64, limit as i64], |row| row.get(0))?
            .collect::<Result<_, _>>()?;
        let now = now_ms() as i64;
        for id in &ids {
            db.execute(
                "INSERT OR REPLACE INTO expired_jobs (id, owner, expired_at)
                 SELECT id, owner, ?2 FROM jobs WHERE id = ?1",
                params![id, now],
            )?;
            db.execute("DELETE FROM jobs WHERE id = ?1", params![id])?;
        }
        db.execute(
            "DELETE FROM expired_jobs WHERE expired_at < ?1",
            params![expired_before as i64],
        )?;
        db.commit()?;
        Ok(ids)
    }

    /// The owner of job `id` if its record was deleted by [`Store::expire_records`] (and its
    /// entry is still kept).
    pub fn expired_owner(&self, id: &str) -> Result<Option<Option<String>>, StoreError> {
        if let Some(postgres) = self.shared() {
            return postgres.expired_owner(id);
        }
        Ok(self
            .db()?
            .prepare_cached("SELECT owner FROM expired_jobs WHERE id = ?1")?
            .query_row(params![id], |row| row.get(0))
            .optional()?)
    }

    /// Embedded backend: the records whose webhook deliveries are not all made or given up
    /// (to resume them after a start).
    pub fn webhooks_pending(&self) -> Result<Vec<JobRecord>, StoreError> {
        let rows: Vec<(String, String)> = self
            .db()?
            .prepare(
                "SELECT id, record FROM jobs INDEXED BY jobs_webhook_pending
                 WHERE webhook_pending = 1 AND deleted = 0 ORDER BY id",
            )?
            .query_map([], |row| Ok((row.get(0)?, row.get(1)?)))?
            .collect::<Result<_, _>>()?;
        let mut records = Vec::with_capacity(rows.len());
        for (id, json) in rows {
            match parse_record(&id, &json) {
                Ok(record) => records.push(record),
                Err(error) => tracing::error!(job_id = %id, %error, "unreadable job record"),
            }
        }
        Ok(records)
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
        let reader = match &self.records {
            Records::Sqlite { reader, .. } => reader,
            Records::Postgres(postgres) => {
                return postgres.list_ids(owner, status, before, limit);
            }
        };
        let reader = reader
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
        if let Some(postgres) = self.shared() {
            return postgres.has_record(id);
        }
        Ok(self.db()?.query_row(
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
        let ages = match self.artefacts.job_ages() {
            Ok(ages) => ages,
            Err(error) => {
                tracing::warn!(%error, "listing job folders for the orphan sweep");
                return 0;
            }
        };
        let mut removed = 0;
        for (id, age) in ages {
            if age < min_age || keep(&id) || !matches!(self.has_record(&id), Ok(false)) {
                continue;
            }
            match self.artefacts.remove_job(&id) {
                Ok(()) => removed += 1,
                Err(error) => {
                    tracing::warn!(dir = %id, %error, "removing an orphaned job directory")
                }
            }
        }
        removed
    }

    /// Writes `jobs/<id>/<name>` whole or not at all.
    pub fn write_artefact(&self, id: &str, name: &str, bytes: &[u8]) -> Result<(), StoreError> {
        self.artefacts.write(id, name, bytes)
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
        self.artefacts.read(id, name)
    }

    /// Whether `jobs/<id>/<name>` exists, without reading it.
    pub fn has_artefact(&self, id: &str, name: &str) -> Result<bool, StoreError> {
        self.artefacts.exists(id, name)
    }

    /// Removes every file of a job; missing files are not an error.
    pub fn remove_artefacts(&self, id: &str) -> Result<(), StoreError> {
        self.artefacts.remove_job(id)
    }

    /// Removes what a run produced (previews and results), keeping the inputs for a re-run.
    pub fn remove_outputs(&self, id: &str) -> Result<(), StoreError> {
        self.artefacts.remove_outputs(id)
    }

    /// Checks that the artefact storage accepts writes and the database answers (for `/readyz`).
    pub fn check(&self) -> Result<(), StoreError> {
        self.artefacts.check()?;
        if let Some(postgres) = self.shared() {
            return postgres.check();
        }
        self.db()?.query_row("SELECT 1", [], |_| Ok(()))?;
        Ok(())
    }
}

/// The data directory's SQLite database, with the listing columns and indexes added to a
/// database written before they existed.
fn open_sqlite(root: &Path) -> Result<Records, StoreError> {
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
    let mut added = Vec::new();
    for (column, kind) in [
        ("owner", "TEXT"),
        ("status", "TEXT"),
        ("deleted", "INTEGER NOT NULL DEFAULT 0"),
        ("created_at", "INTEGER"),
        ("completed_at", "INTEGER"),
        ("results_expire_at", "INTEGER"),
        ("idempotency_key", "TEXT"),
        ("webhook_pending", "INTEGER NOT NULL DEFAULT 0"),
    ] {
        if !columns.iter().any(|name| name == column) {
            db.execute_batch(&format!("ALTER TABLE jobs ADD COLUMN {column} {kind}"))?;
            added.push(column);
        }
    }
    if added.contains(&"created_at") {
        // Rows from before the expiry columns, once. Every job with a webhook is marked: the
        // first start resumes them, and saves those whose deliveries are done without the mark.
        db.execute_batch(
            "UPDATE jobs SET created_at = json_extract(record, '$.created_at'),
                 completed_at = json_extract(record, '$.completed_at'),
                 results_expire_at = CASE WHEN json_extract(record, '$.data_removed')
                     THEN NULL ELSE json_extract(record, '$.expires_at') END,
                 idempotency_key = json_extract(record, '$.idempotency.key'),
                 webhook_pending = json_extract(record, '$.webhook') IS NOT NULL
             WHERE json_valid(record)",
        )?;
    }
    // Each query on records reads one of these: nothing at start or in the
    // periodic expiry walks every record.
    db.execute_batch(
        "CREATE INDEX IF NOT EXISTS jobs_by_owner ON jobs (owner, id);
         CREATE INDEX IF NOT EXISTS jobs_by_owner_status ON jobs (owner, status, id);
         CREATE INDEX IF NOT EXISTS jobs_live ON jobs (status, id)
             WHERE status IN ('queued', 'running') OR status IS NULL;
         CREATE INDEX IF NOT EXISTS jobs_by_completion ON jobs (completed_at)
             WHERE status IN ('succeeded', 'failed', 'canceled') AND deleted = 0;
         CREATE INDEX IF NOT EXISTS jobs_results_due ON jobs (results_expire_at)
             WHERE results_expire_at IS NOT NULL;
         CREATE INDEX IF NOT EXISTS jobs_by_idempotency_key ON jobs (owner, idempotency_key)
             WHERE idempotency_key IS NOT NULL;
         CREATE INDEX IF NOT EXISTS jobs_keys_by_age ON jobs (created_at)
             WHERE idempotency_key IS NOT NULL;
         CREATE INDEX IF NOT EXISTS jobs_webhook_pending ON jobs (id) WHERE webhook_pending = 1;
         CREATE INDEX IF NOT EXISTS jobs_deleted ON jobs (id) WHERE deleted = 1;
         CREATE TABLE IF NOT EXISTS expired_jobs (
             id TEXT PRIMARY KEY, owner TEXT, expired_at INTEGER NOT NULL
         );
         CREATE INDEX IF NOT EXISTS expired_jobs_by_age ON expired_jobs (expired_at);",
    )?;
    // Listing reads on its own connection, so a page never waits for a worker's write
    // (rusqlite's connections wait up to 5 s for a lock held by the other).
    let reader = Connection::open(&path)?;
    Ok(Records::Sqlite {
        db: Mutex::new(db),
        reader: Mutex::new(reader),
    })
}

/// Writes a record into its row (unless the row is a tombstone), with the columns beside it
/// that the listing and expiry queries read ([`open_sqlite`]).
fn save_row(db: &Connection, record: &JobRecord) -> Result<(), StoreError> {
    let json = serde_json::to_string(record).expect("a job record always serialises");
    let results_expire_at = record.expires_at.filter(|_| !record.data_removed);
    let key = record.idempotency.as_ref().map(|i| &i.key);
    let webhook_pending = record.webhook.as_ref().is_some_and(Webhook::unfinished);
    db.prepare_cached(
        "INSERT INTO jobs (id, owner, status, record, created_at, completed_at,
             results_expire_at, idempotency_key, webhook_pending)
         VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9)
         ON CONFLICT(id) DO UPDATE SET owner = excluded.owner, status = excluded.status,
             record = excluded.record, created_at = excluded.created_at,
             completed_at = excluded.completed_at,
             results_expire_at = excluded.results_expire_at,
             idempotency_key = excluded.idempotency_key,
             webhook_pending = excluded.webhook_pending
         WHERE jobs.deleted = 0",
    )?
    .execute(params![
        record.id,
        record.owner,
        record.status.name(),
        json,
        record.created_at as i64,
        record.completed_at.map(|at| at as i64),
        results_expire_at.map(|at| at as i64),
        key,
        webhook_pending
    ])?;
    Ok(())
}

/// Moves an unreadable row to the `quarantine` table (logged): kept for a look, never served.
fn quarantine(db: &Connection, id: &str, json: &str, error: &StoreError) -> Result<(), StoreError> {
    tracing::error!(job_id = %id, %error, "unreadable job record quarantined");
    db.execute(
        "INSERT OR REPLACE INTO quarantine (id, record, reason, at) VALUES (?1, ?2, ?3, ?4)",
        params![id, json, error.to_string(), now_ms() as i64],
    )?;
    db.execute("DELETE FROM jobs WHERE id = ?1", params![id])?;
    Ok(())
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
    super::model::hex(&Sha256::digest(bytes))
}
