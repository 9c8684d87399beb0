//! The seam between the queue and its backend: what differs between the embedded backend
//! (SQLite and the data directory, jobs run here: [`Embedded`]) and the shared one (PostgreSQL
//! and an object store or shared directory, jobs run by workers anywhere: [`Shared`]). The one
//! place that tells them apart; the [`Queue`] around it keeps the live state and the fair rule.

use std::sync::Arc;
use std::time::Instant;

use super::embedded::Embedded;
use super::shared::Shared;
use super::state::State;
use super::{Admission, Queue, QueueConfig, QueueError, Refusal};
use crate::service::model::JobRecord;
use crate::service::runner::{JobEntry, Runner};
use crate::service::store::StoreError;
use crate::service::telemetry::Metrics;

pub(super) enum Backend {
    Embedded(Embedded),
    Shared(Shared),
}

impl Backend {
    /// The backend the store's records imply: on the embedded one the queued and running jobs
    /// are loaded into `state` and at least one job slot runs; the shared one starts this
    /// process's slots, if any (`config.workers` 0 is an API replica).
    pub fn open(
        runner: &Arc<Runner>,
        config: &mut QueueConfig,
        metrics: &Metrics,
        state: &mut State,
    ) -> Result<Self, QueueError> {
        if runner.store.shared().is_some() {
            return Ok(Backend::Shared(Shared::open(runner, config)?));
        }
        config.workers = config.workers.max(1);
        Ok(Backend::Embedded(Embedded::recover(
            &runner.store,
            metrics,
            state,
        )?))
    }

    /// Starts the threads that move jobs: runners, or the follower of the database.
    pub fn start(&self, queue: &Arc<Queue>) -> Result<(), QueueError> {
        match self {
            Backend::Embedded(embedded) => embedded.start(queue),
            Backend::Shared(shared) => shared.start(queue),
        }
    }

    /// (queued, running): of this process, or of every process on the shared backend (as the
    /// follower last read them).
    pub fn depth(&self, state: &State) -> (usize, usize) {
        match self {
            Backend::Embedded(_) => state.fair.depth(),
            Backend::Shared(shared) => shared.depth(),
        }
    }

    /// Every job slot of this process alive.
    pub fn is_ready(&self, workers: usize) -> bool {
        match self {
            Backend::Embedded(embedded) => embedded.is_ready(workers),
            Backend::Shared(shared) => shared.is_ready(),
        }
    }

    /// Queues a job whose inputs are stored, or replays the earlier one with its
    /// Idempotency-Key.
    pub fn admit(&self, queue: &Queue, record: JobRecord) -> Result<Admission, Refusal> {
        match self {
            Backend::Embedded(_) => Embedded::admit(queue, record),
            Backend::Shared(_) => Shared::admit(queue, record),
        }
    }

    /// Cancels a job; true when it was running (and is still stopping).
    pub fn cancel(&self, queue: &Queue, entry: &Arc<JobEntry>) -> Result<bool, Refusal> {
        match self {
            Backend::Embedded(_) => Embedded::cancel(queue, entry),
            Backend::Shared(shared) => shared.cancel(queue, entry),
        }
    }

    /// At start: the jobs whose webhook deliveries this process is to resume (on the shared
    /// backend none: they are taken over by [`Backend::deliveries_to_take_over`]).
    pub fn deliveries_to_resume(&self, queue: &Queue) -> Result<Vec<Arc<JobEntry>>, StoreError> {
        match self {
            Backend::Embedded(_) => Embedded::unfinished_deliveries(queue),
            Backend::Shared(_) => Ok(Vec::new()),
        }
    }

    /// Every so often: the jobs whose deliveries another replica stopped making (shared
    /// backend), this replica's own claims renewed.
    pub fn deliveries_to_take_over(&self, queue: &Queue) -> Result<Vec<Arc<JobEntry>>, StoreError> {
        match self {
            Backend::Embedded(_) => Ok(Vec::new()),
            Backend::Shared(_) => Shared::take_over_deliveries(queue),
        }
    }

    /// The job's deliveries are all made or given up: another replica need not take them over.
    pub fn deliveries_done(&self, queue: &Queue, id: &str) -> Result<(), StoreError> {
        match self {
            Backend::Embedded(_) => Ok(()),
            Backend::Shared(_) => Shared::deliveries_done(queue, id),
        }
    }

    /// An unreadable record was read: the embedded store has moved it to its quarantine.
    pub fn met_unreadable(&self, metrics: &Metrics) {
        if let Backend::Embedded(_) = self {
            metrics.quarantined(1);
        }
    }

    /// The periodic clean-up beyond the store's expiry.
    pub fn purge(&self, queue: &Queue) {
        if let Backend::Shared(_) = self {
            Shared::purge(queue);
        }
    }

    /// Stops job slots not run by the queue's own threads, waiting for them until `deadline`.
    pub fn drain(&self, deadline: Instant) {
        if let Backend::Shared(shared) = self {
            shared.drain(deadline);
        }
    }
}
