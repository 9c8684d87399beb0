//! The seam of the job records: what every backend's record keeping does (SQLite, PostgreSQL,
//! memory; each in its folder under `service/backend/`). [`Store`](super::Store) holds one and
//! answers through it.

use super::error::StoreError;
use crate::service::model::{JobRecord, Status};

/// Where job records live. Each method is documented on the [`Store`](super::Store) method
/// of the same name.
pub trait Records: Send + Sync {
    fn save(&self, record: &JobRecord) -> Result<(), StoreError>;
    fn save_webhook(&self, record: &JobRecord) -> Result<(), StoreError>;
    fn tombstone(&self, id: &str) -> Result<(), StoreError>;
    fn get(&self, id: &str) -> Result<Option<JobRecord>, StoreError>;
    fn idempotent(
        &self,
        owner: &Option<String>,
        key: &str,
        created_since: u64,
    ) -> Result<Option<JobRecord>, StoreError>;
    fn drop_idempotency_keys(&self, created_before: u64) -> Result<usize, StoreError>;
    fn results_due(&self, now: u64, limit: usize) -> Result<Vec<String>, StoreError>;
    fn expire_records(
        &self,
        ended_before: u64,
        expired_before: u64,
        limit: usize,
    ) -> Result<Vec<String>, StoreError>;
    fn expired_owner(&self, id: &str) -> Result<Option<Option<String>>, StoreError>;
    /// `before` is given: the caller puts an open end past every id.
    fn list_ids(
        &self,
        owner: &Option<String>,
        status: Option<Status>,
        before: &str,
        limit: usize,
    ) -> Result<Vec<String>, StoreError>;
    fn has_record(&self, id: &str) -> Result<bool, StoreError>;
    fn check(&self) -> Result<(), StoreError>;
}

/// Records that only this process writes, whose jobs it runs itself (the embedded and the
/// memory backend): what it resumes at start.
pub trait LocalRecords: Records {
    /// Drops tombstones, moves unreadable rows to a quarantine (logged; the server starts
    /// without them) and returns the queued and running records, oldest first. Ended records
    /// stay, read when asked for.
    fn recover(&self) -> Result<Recovered, StoreError>;
    /// The records whose webhook deliveries are not all made or given up (to resume them
    /// after a start).
    fn webhooks_pending(&self) -> Result<Vec<JobRecord>, StoreError>;
}

/// What [`LocalRecords::recover`] found.
pub struct Recovered {
    /// The readable queued and running records, oldest first.
    pub records: Vec<JobRecord>,
    /// Ids of rows that could not be read, moved to the quarantine.
    pub quarantined: Vec<String>,
}
