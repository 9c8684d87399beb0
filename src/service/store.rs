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

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use rusqlite::{Connection, params};

use super::error::ApiError;
use super::model::JobRecord;

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("data directory {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("job database: {0}")]
    Sqlite(#[from] rusqlite::Error),
    #[error("job record {id} is corrupt: {source}")]
    CorruptRecord {
        id: String,
        source: serde_json::Error,
    },
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
}

impl Store {
    /// Opens (creating if needed) the data directory and its database.
    pub fn open(root: &Path) -> Result<Self, StoreError> {
        fs::create_dir_all(root.join("jobs")).map_err(io_error(root))?;
        let db = Connection::open(root.join("jobs.sqlite3"))?;
        // WAL: readers never block the writer; NORMAL sync is durable across process crashes.
        db.pragma_update(None, "journal_mode", "WAL")?;
        db.pragma_update(None, "synchronous", "NORMAL")?;
        db.execute_batch(
            "CREATE TABLE IF NOT EXISTS jobs (id TEXT PRIMARY KEY, record TEXT NOT NULL)",
        )?;
        Ok(Self {
            root: root.to_owned(),
            db: Mutex::new(db),
        })
    }

    fn db(&self) -> std::sync::MutexGuard<'_, Connection> {
        self.db
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    pub fn save(&self, record: &JobRecord) -> Result<(), StoreError> {
        let json = serde_json::to_string(record).expect("a job record always serialises");
        self.db().execute(
            "INSERT INTO jobs (id, record) VALUES (?1, ?2) ON CONFLICT(id) DO UPDATE SET record = excluded.record",
            params![record.id, json],
        )?;
        Ok(())
    }

    pub fn delete(&self, id: &str) -> Result<(), StoreError> {
        self.db()
            .execute("DELETE FROM jobs WHERE id = ?1", params![id])?;
        Ok(())
    }

    /// Every record, oldest first (ids sort by creation time).
    pub fn load_all(&self) -> Result<Vec<JobRecord>, StoreError> {
        let db = self.db();
        let mut statement = db.prepare("SELECT id, record FROM jobs ORDER BY id")?;
        let rows = statement.query_map([], |row| {
            Ok((row.get::<_, String>(0)?, row.get::<_, String>(1)?))
        })?;
        let mut records = Vec::new();
        for row in rows {
            let (id, json) = row?;
            records.push(parse_record(&id, &json)?);
        }
        Ok(records)
    }

    pub fn job_dir(&self, id: &str) -> PathBuf {
        self.root.join("jobs").join(id)
    }

    /// Writes `bytes` to `jobs/<id>/<name>` atomically.
    pub fn write_artefact(&self, id: &str, name: &str, bytes: &[u8]) -> Result<(), StoreError> {
        write_atomic(&self.job_dir(id).join(name), bytes)
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

fn parse_record(id: &str, json: &str) -> Result<JobRecord, StoreError> {
    serde_json::from_str(json).map_err(|source| StoreError::CorruptRecord {
        id: id.to_owned(),
        source,
    })
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
