//! The job backends, one folder each, each implementing the two seams: where job records live
//! ([`Records`]) and how jobs move ([`queue::Backend`]).
//! - [`embedded`]: SQLite and the data directory; jobs run here.
//! - [`shared`]: PostgreSQL and an object store or a shared directory; jobs run by workers
//!   anywhere (`covec worker`, or `covec serve` with workers).
//! - [`memory`]: records and queue in this process, nothing survives a restart; jobs run here.
//!
//! This file is the one place that chooses among them: the rest of the service holds a
//! [`Store`] and a [`queue::Backend`], never a backend by name.

mod embedded;
mod memory;
mod shared;

use std::path::Path;
use std::sync::Arc;

use super::queue::{self, Local, QueueError};
use super::runner::Runner;
use super::store::{LocalRecords, Records, Store, StoreError, io_error};
pub use shared::worker::{WorkerConfig, Workers};

/// Where job records live, as the command line chose.
#[derive(Clone, Debug, Default, PartialEq)]
pub enum RecordsAt {
    /// SQLite in the data directory (the embedded backend).
    #[default]
    DataDir,
    /// PostgreSQL at this URL (`postgres://…`), migrated first (the shared backend).
    Database(String),
    /// In this process (the memory backend).
    Memory,
}

/// Where job records and artefacts live.
pub struct Storage<'a> {
    /// Created if needed; artefacts go there unless `object_store` is given.
    pub data_dir: &'a Path,
    /// Artefacts in this S3-compatible bucket (`s3://bucket/prefix`).
    pub object_store: Option<&'a str>,
    pub records: &'a RecordsAt,
}

/// The store and the queue's backend `storage` names.
pub fn open(storage: &Storage) -> Result<(Arc<Store>, Box<dyn queue::Backend>), StoreError> {
    let (records, backend): (Arc<dyn Records>, Box<dyn queue::Backend>) = match storage.records {
        RecordsAt::DataDir => {
            std::fs::create_dir_all(storage.data_dir).map_err(io_error(storage.data_dir))?;
            let sqlite: Arc<dyn LocalRecords> = Arc::new(embedded::Sqlite::open(storage.data_dir)?);
            (sqlite.clone(), Box::new(Local::new(sqlite)))
        }
        RecordsAt::Database(url) => {
            let postgres = Arc::new(shared::Postgres::connect(url)?);
            (postgres.clone(), Box::new(shared::Shared::new(postgres)))
        }
        RecordsAt::Memory => {
            let memory: Arc<dyn LocalRecords> = Arc::new(memory::Memory::default());
            (memory.clone(), Box::new(Local::new(memory)))
        }
    };
    let store = Store::open(storage.data_dir, storage.object_store, records)?;
    Ok((Arc::new(store), backend))
}

/// `covec worker`'s job slots, on the shared backend's database at `database_url`: the runner
/// `runner_of` makes from the store runs the jobs.
pub fn start_workers(
    data_dir: &Path,
    object_store: Option<&str>,
    database_url: &str,
    runner_of: impl FnOnce(Arc<Store>) -> Arc<Runner>,
    config: &WorkerConfig,
) -> Result<Arc<Workers>, QueueError> {
    let postgres = Arc::new(shared::Postgres::connect(database_url)?);
    let store = Store::open(data_dir, object_store, postgres.clone())?;
    Workers::start(runner_of(Arc::new(store)), postgres, config)
}
