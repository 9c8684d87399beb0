//! One job's live state in this process ([`JobEntry`]: its record broadcast to whoever
//! follows it, a cancel request, a delete mark) and why a run failed ([`JobFailure`]).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use tokio::sync::watch;

use super::inputs::InputError;
use super::model::{CancelReason, JobRecord, Problem, Status};
use super::store::StoreError;

/// A lock that outlives a panic of a holder: the data it guards is kept consistent by each
/// holder's own steps.
pub fn lock<T>(mutex: &Mutex<T>) -> MutexGuard<'_, T> {
    mutex
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// One job's live state.
pub struct JobEntry {
    pub id: String,
    pub owner: Option<String>,
    /// The current record; every change is broadcast to `/events` subscribers.
    pub record: watch::Sender<JobRecord>,
    cancel: AtomicBool,
    cancel_reason: Mutex<Option<CancelReason>>,
    pub deleted: AtomicBool,
}

impl JobEntry {
    pub fn new(record: JobRecord) -> Arc<Self> {
        Arc::new(Self {
            id: record.id.clone(),
            owner: record.owner.clone(),
            record: watch::Sender::new(record),
            cancel: AtomicBool::new(false),
            cancel_reason: Mutex::new(None),
            deleted: AtomicBool::new(false),
        })
    }

    /// The flag the pipeline polls to stop ([`JobEntry::request_cancel`] sets it).
    pub fn cancel_flag(&self) -> &AtomicBool {
        &self.cancel
    }

    /// Why the pipeline was asked to stop, if it was.
    pub fn cancel_reason(&self) -> Option<CancelReason> {
        *lock(&self.cancel_reason)
    }

    /// Marks the job ended (see [`JobRecord::end`]).
    pub fn end(
        &self,
        status: Status,
        failure: Option<JobFailure>,
        reason: Option<CancelReason>,
        retention: Duration,
    ) {
        let problem = failure.map(Problem::from);
        self.record
            .send_modify(|record| record.end(status, problem, reason, retention));
    }

    pub fn snapshot(&self) -> JobRecord {
        self.record.borrow().clone()
    }

    /// Asks a running pipeline to stop; the first reason wins.
    pub fn request_cancel(&self, reason: CancelReason) {
        let mut current = lock(&self.cancel_reason);
        current.get_or_insert(reason);
        self.cancel.store(true, Ordering::Relaxed);
        self.record
            .send_modify(|record| record.cancel_requested = true);
    }
}

/// Why a job failed. Its record keeps what a client reads of it, the [`Problem`] the service's
/// edge makes of it (`impl From<JobFailure> for Problem`).
#[derive(Debug, thiserror::Error)]
pub enum JobFailure {
    #[error(transparent)]
    Input(#[from] InputError),
    #[error(transparent)]
    Storage(#[from] StoreError),
    #[error("the job's input files are missing")]
    MissingInputs,
    /// The wall-clock limit, in seconds, that stopped the run.
    #[error("the job ran longer than the limit of {0} s")]
    TimeLimit(u64),
    #[error("invalid parameters: {0}")]
    InvalidParams(String),
    #[error("internal error: {0}")]
    Internal(String),
    /// The pipeline panicked, with this message.
    #[error("the pipeline failed unexpectedly: {0}")]
    Crashed(String),
    /// Leases that expired before the job was given up.
    #[error("the job's worker stopped without finishing it {0} times")]
    WorkersLost(u32),
}
