//! The embedded backend's job records: SQLite in the data directory, one table with one JSON
//! record per job and the columns its queries read beside it.

use std::path::Path;
use std::sync::{Mutex, MutexGuard};

use rusqlite::{Connection, OptionalExtension, params};

use crate::service::model::{JobRecord, Status, Webhook, now_ms};
use crate::service::store::{LocalRecords, Records, Recovered, StoreError, parse_record};

/// One writer connection, and one for listings.
pub struct Sqlite {
    db: Mutex<Connection>,
    reader: Mutex<Connection>,
}

impl Sqlite {
    /// The data directory's SQLite database, with the listing columns and indexes added to a
    /// database written before they existed.
    pub fn open(root: &Path) -> Result<Self, StoreError> {
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
        Ok(Self {
            db: Mutex::new(db),
            reader: Mutex::new(reader),
        })
    }

    fn db(&self) -> MutexGuard<'_, Connection> {
        self.db
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }
}

impl Records for Sqlite {
    fn save(&self, record: &JobRecord) -> Result<(), StoreError> {
        save_row(&self.db(), record)
    }

    /// The whole record: this process makes the deliveries and writes the rest.
    fn save_webhook(&self, record: &JobRecord) -> Result<(), StoreError> {
        save_row(&self.db(), record)
    }

    fn tombstone(&self, id: &str) -> Result<(), StoreError> {
        self.db()
            .execute("UPDATE jobs SET deleted = 1 WHERE id = ?1", params![id])?;
        Ok(())
    }

    fn get(&self, id: &str) -> Result<Option<JobRecord>, StoreError> {
        let db = self.db();
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

    fn idempotent(
        &self,
        owner: &Option<String>,
        key: &str,
        created_since: u64,
    ) -> Result<Option<JobRecord>, StoreError> {
        let id: Option<String> = self
            .db()
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

    fn drop_idempotency_keys(&self, created_before: u64) -> Result<usize, StoreError> {
        Ok(self.db().execute(
            "UPDATE jobs INDEXED BY jobs_keys_by_age
             SET idempotency_key = NULL, record = CASE WHEN json_valid(record)
                 THEN json_remove(record, '$.idempotency') ELSE record END
             WHERE idempotency_key IS NOT NULL AND created_at < ?1",
            params![created_before as i64],
        )?)
    }

    fn results_due(&self, now: u64, limit: usize) -> Result<Vec<String>, StoreError> {
        Ok(self
            .db()
            .prepare_cached(
                "SELECT id FROM jobs INDEXED BY jobs_results_due
                 WHERE results_expire_at IS NOT NULL AND results_expire_at <= ?1 AND deleted = 0
                 LIMIT ?2",
            )?
            .query_map(params![now as i64, limit as i64], |row| row.get(0))?
            .collect::<Result<_, _>>()?)
    }

    fn expire_records(
        &self,
        ended_before: u64,
        expired_before: u64,
        limit: usize,
    ) -> Result<Vec<String>, StoreError> {
        let connection = self.db();
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

    fn expired_owner(&self, id: &str) -> Result<Option<Option<String>>, StoreError> {
        Ok(self
            .db()
            .prepare_cached("SELECT owner FROM expired_jobs WHERE id = ?1")?
            .query_row(params![id], |row| row.get(0))
            .optional()?)
    }

    fn has_record(&self, id: &str) -> Result<bool, StoreError> {
        Ok(self.db().query_row(
            "SELECT EXISTS (SELECT 1 FROM jobs WHERE id = ?1 AND deleted = 0)
                 OR EXISTS (SELECT 1 FROM quarantine WHERE id = ?1)",
            params![id],
            |row| row.get(0),
        )?)
    }

    fn list_ids(
        &self,
        owner: &Option<String>,
        status: Option<Status>,
        before: &str,
        limit: usize,
    ) -> Result<Vec<String>, StoreError> {
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

    fn check(&self) -> Result<(), StoreError> {
        self.db().query_row("SELECT 1", [], |_| Ok(()))?;
        Ok(())
    }
}

impl LocalRecords for Sqlite {
    fn recover(&self) -> Result<Recovered, StoreError> {
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

    fn webhooks_pending(&self) -> Result<Vec<JobRecord>, StoreError> {
        let rows: Vec<(String, String)> = self
            .db()
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
}

/// Writes a record into its row (unless the row is a tombstone), with the columns beside it
/// that the listing and expiry queries read ([`Sqlite::open`]).
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
