//! The seam between the queue and its backend: what differs between backends in moving jobs
//! (where they run, how they are admitted and canceled, who makes their webhook deliveries).
//! Each backend implements it in its folder under `service/backend/`; the [`Queue`] around it
//! keeps the live state and the fair rule, and never knows which one it holds.

use std::sync::Arc;
use std::time::Instant;

use super::state::State;
use super::{Admission, Queue, QueueConfig, QueueError, Refusal};
use crate::service::job::JobEntry;
use crate::service::model::JobRecord;
use crate::service::runner::Runner;
use crate::service::store::StoreError;
use crate::service::telemetry::Metrics;

pub trait Backend: Send + Sync {
    /// Before the queue exists: loads the jobs this process holds into `state` and settles
    /// `config.workers` (a backend whose jobs all run here runs at least one).
    fn open(
        &mut self,
        runner: &Arc<Runner>,
        config: &mut QueueConfig,
        metrics: &Metrics,
        state: &mut State,
    ) -> Result<(), QueueError>;

    /// Starts the threads that move jobs: runners, or the follower of the database.
    fn start(&self, queue: &Arc<Queue>) -> Result<(), QueueError>;

    /// (queued, running): of this process, or of every process sharing the queue.
    fn depth(&self, state: &State) -> (usize, usize);

    /// Every job slot of this process alive.
    fn is_ready(&self, workers: usize) -> bool;

    /// Queues a job whose inputs are stored, or replays the earlier one with its
    /// Idempotency-Key.
    fn admit(&self, queue: &Queue, record: JobRecord) -> Result<Admission, Refusal>;

    /// Cancels a job; true when it was running (and is still stopping).
    fn cancel(&self, queue: &Queue, entry: &Arc<JobEntry>) -> Result<bool, Refusal>;

    /// At start: the jobs whose webhook deliveries this process is to resume.
    fn deliveries_to_resume(&self, _queue: &Queue) -> Result<Vec<Arc<JobEntry>>, StoreError> {
        Ok(Vec::new())
    }

    /// Every so often: the jobs whose deliveries another process stopped making, this
    /// process's own claims renewed.
    fn deliveries_to_take_over(&self, _queue: &Queue) -> Result<Vec<Arc<JobEntry>>, StoreError> {
        Ok(Vec::new())
    }

    /// The job's deliveries are all made or given up: no other process need take them over.
    fn deliveries_done(&self, _queue: &Queue, _id: &str) -> Result<(), StoreError> {
        Ok(())
    }

    /// An unreadable record was read (and moved to a quarantine, if the records keep one).
    fn met_unreadable(&self, _metrics: &Metrics) {}

    /// The periodic clean-up beyond the store's expiry.
    fn purge(&self, _queue: &Queue) {}

    /// Stops job slots not run by the queue's own threads, waiting for them until `deadline`.
    fn drain(&self, _deadline: Instant) {}
}
