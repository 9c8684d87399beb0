//! The shared backend: job records, the queue and its leases in PostgreSQL ([`postgres`]),
//! shared by API replicas and workers; artefacts in an object store or a shared directory.
//!
//! Its queue: PostgreSQL is the truth and the memory a copy. The queue, leases
//! and idempotency keys are rows; jobs run in [`Workers`] (here or in `covec worker`
//! processes); a follower thread brings every change made anywhere to the jobs in the copy (and
//! the queued and running jobs into it) every [`FOLLOW_EVERY`], so polls, listings and SSE on
//! any replica see jobs running on any worker.

mod postgres;
pub mod worker;

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

use tracing::{info, warn};

use crate::service::job::{JobEntry, lock};
use crate::service::model::{CancelReason, JobRecord, Status, Webhook};
use crate::service::queue::state::{State, queue_full};
use crate::service::queue::{
    Admission, Backend, Queue, QueueConfig, QueueError, REAP_EVERY, Refusal,
};
use crate::service::runner::Runner;
use crate::service::store::{Records, StoreError, retry_transient};
use crate::service::telemetry::Metrics;
pub use postgres::Postgres;
use postgres::{Canceled, Change, Inserted};
use worker::{WorkerConfig, Workers, reap_expired};

/// How often an API replica brings other processes' changes into its copy of the jobs (and
/// reads the queue depth): what SSE and polls lag behind a worker.
const FOLLOW_EVERY: Duration = Duration::from_millis(200);

/// How long a deleted job's row stays (so workers and replicas see the delete) before it is
/// purged.
const TOMBSTONE_AGE: Duration = Duration::from_secs(3600);

pub struct Shared {
    postgres: Arc<Postgres>,
    /// This process's job slots, if it runs any (`--workers 0`: an API replica).
    workers: Option<Arc<Workers>>,
    /// The (queued, running) counts of every process, as the follower last read them.
    depth: Arc<Mutex<(usize, usize)>>,
}

impl Shared {
    /// The queue over `postgres`, which the store holds as its records too.
    pub fn new(postgres: Arc<Postgres>) -> Self {
        Self {
            postgres,
            workers: None,
            depth: Arc::new(Mutex::new((0, 0))),
        }
    }
}

impl Backend for Shared {
    /// Starts this process's job slots, if `config` asks for any (`--workers 0`: an API
    /// replica).
    fn open(
        &mut self,
        runner: &Arc<Runner>,
        config: &mut QueueConfig,
        _metrics: &Metrics,
        _state: &mut State,
    ) -> Result<(), QueueError> {
        if config.workers > 0 {
            self.workers = Some(Workers::start(
                Arc::clone(runner),
                Arc::clone(&self.postgres),
                &WorkerConfig {
                    slots: config.workers,
                    threads: config.threads,
                    lease: config.lease,
                    scheduling: config.scheduling.clone(),
                },
            )?);
        }
        Ok(())
    }

    /// Reads the jobs into the copy, starts the follower and sweeps old orphans.
    fn start(&self, queue: &Arc<Queue>) -> Result<(), QueueError> {
        let mark = follow(queue, &self.postgres, &self.depth, None)?;
        let (follower, postgres, depth) = (
            Arc::clone(queue),
            Arc::clone(&self.postgres),
            Arc::clone(&self.depth),
        );
        let handle = std::thread::Builder::new()
            .name("covec-follower".into())
            .spawn(move || follow_changes(&follower, &postgres, &depth, mark))?;
        lock(&queue.threads).push(handle);
        // Other replicas may be admitting jobs: only old directories are orphans.
        queue.sweep_orphans(queue.config.orphan_age);
        Ok(())
    }

    /// (queued, running) of every process.
    fn depth(&self, _state: &State) -> (usize, usize) {
        *lock(&self.depth)
    }

    /// Every job slot of this process alive (an API replica without slots is always ready).
    fn is_ready(&self, _workers: usize) -> bool {
        self.workers
            .as_ref()
            .is_none_or(|workers| workers.is_ready())
    }

    /// Queues a job in the database (the unique index decides between replicas which of two
    /// submissions with one Idempotency-Key is first).
    fn admit(&self, queue: &Queue, record: JobRecord) -> Result<Admission, Refusal> {
        if lock(&queue.state).draining {
            return Err(Refusal::ShuttingDown);
        }
        let config = &queue.config;
        let key_limit = config.scheduling.limits_of(&record.client).queued;
        match self.postgres.insert(
            &record,
            config.max_queued,
            key_limit,
            queue.config.keys_since(),
        )? {
            Inserted::Created => {
                let entry = lock(&queue.state).remember(JobEntry::new(record));
                Ok(Admission::Created(entry))
            }
            Inserted::Existing(earlier) if earlier.idempotency == record.idempotency => {
                let entry = lock(&queue.state).remember(JobEntry::new(*earlier));
                Ok(Admission::Replayed(entry))
            }
            Inserted::Existing(_) => Err(Refusal::IdempotencyMismatch),
            Inserted::Full(queued) => Err(queue_full(config, &queue.metrics, queued)),
            Inserted::KeyFull(queued) => {
                let limit = key_limit.unwrap_or(queued);
                let state = lock(&queue.state);
                Err(state.key_queue_full(config, &queue.metrics, limit, queued))
            }
        }
    }

    /// Cancels in the database: a queued job (whatever the copy says) ends there; a running
    /// one's worker stops it at its next heartbeat.
    fn cancel(&self, queue: &Queue, entry: &Arc<JobEntry>) -> Result<bool, Refusal> {
        let postgres = &self.postgres;
        let mut ended = entry.snapshot();
        ended.end(
            Status::Canceled,
            None,
            Some(CancelReason::User),
            queue.config.retention,
        );
        let outcome = postgres.cancel(&ended)?;
        if matches!(outcome, Canceled::Ended) {
            info!(job_id = %entry.id, "canceled while queued");
            // The follower reads the depth again within FOLLOW_EVERY; until then a job
            // submitted right after this cancel must not be refused for the room it freed.
            let mut depth = lock(&self.depth);
            depth.0 = depth.0.saturating_sub(1);
        }
        let current = match outcome {
            Canceled::Ended => Some(ended),
            Canceled::Stopping | Canceled::Nothing => postgres.get(&entry.id)?,
        };
        if let Some(current) = current {
            entry.record.send_replace(current);
            lock(&queue.state).file(entry);
        }
        Ok(matches!(outcome, Canceled::Stopping))
    }

    /// Stops this process's job slots, waiting for them until `deadline`.
    fn drain(&self, deadline: Instant) {
        if let Some(workers) = &self.workers {
            workers.drain(deadline.saturating_duration_since(Instant::now()));
        }
    }

    /// Renews this replica's claims on webhook deliveries and takes those whose deliverer
    /// stopped: their jobs, to deliver from here.
    fn deliveries_to_take_over(&self, queue: &Queue) -> Result<Vec<Arc<JobEntry>>, StoreError> {
        let postgres = &self.postgres;
        let mut entries = Vec::new();
        for id in postgres.renew_deliveries()? {
            match queue.find(&id)? {
                Some(entry) => entries.push(entry),
                None => postgres.deliveries_done(&id)?,
            }
        }
        Ok(entries)
    }

    /// Gives up this replica's claim on the job's deliveries.
    fn deliveries_done(&self, _queue: &Queue, id: &str) -> Result<(), StoreError> {
        retry_transient("ending webhook deliveries", || {
            self.postgres.deliveries_done(id)
        })
    }

    /// Drops deleted jobs' rows once every process has seen them go.
    fn purge(&self, _queue: &Queue) {
        if let Err(error) = self.postgres.purge_tombstones(TOMBSTONE_AGE) {
            warn!("purging deleted jobs: {error}");
        }
    }
}

/// Brings the changes since `since` (everything when `None`) into the copy, and the queue
/// depth; returns the mark for the next look.
fn follow(
    queue: &Queue,
    postgres: &Postgres,
    depth: &Mutex<(usize, usize)>,
    since: Option<SystemTime>,
) -> Result<SystemTime, StoreError> {
    let (changes, mark) = postgres.changes(since)?;
    let counts = postgres.depth()?;
    let served = postgres.served()?;
    *lock(depth) = counts;
    let mut state = lock(&queue.state);
    state.fair.set_served(served);
    for change in changes {
        match change {
            Change::Live(record) => match state.get(&record.id) {
                Some(entry) => {
                    entry.record.send_if_modified(|current| {
                        let mut record = *record;
                        // Deliveries are made here by this copy: the stored ones may lag.
                        if webhook_progress(&current.webhook) > webhook_progress(&record.webhook) {
                            record.webhook = current.webhook.clone();
                        }
                        let modified = *current != record;
                        *current = record;
                        modified
                    });
                    state.file(&entry);
                }
                None if !record.status.is_terminal() => {
                    state.remember(JobEntry::new(*record));
                }
                // Ended, and not held here: read from the database when asked for.
                None => {}
            },
            Change::Deleted(id) => state.forget(&id),
        }
    }
    Ok(mark)
}

/// The follower thread: [`follow`] every [`FOLLOW_EVERY`], and takes back expired
/// leases (when no worker is left to) until draining.
fn follow_changes(
    queue: &Queue,
    postgres: &Postgres,
    depth: &Mutex<(usize, usize)>,
    mut mark: SystemTime,
) {
    let mut last_reap = Instant::now();
    loop {
        {
            let state = lock(&queue.state);
            let (state, _) = queue
                .changed
                .wait_timeout(state, FOLLOW_EVERY)
                .unwrap_or_else(|p| p.into_inner());
            if state.draining {
                return;
            }
        }
        match follow(queue, postgres, depth, Some(mark)) {
            Ok(next) => mark = next,
            Err(error) => warn!("following the job database: {error}"),
        }
        if last_reap.elapsed() >= REAP_EVERY {
            last_reap = Instant::now();
            reap_expired(postgres, queue.config.retention);
        }
    }
}

/// How far a job's webhook deliveries have got: attempts made, then deliveries begun (a
/// delivery is begun, pending with no attempt yet, before its first attempt). The follower
/// keeps the copy's deliveries when they are further on than the stored ones: the replica
/// delivering them writes the stored ones after each step, so those lag; a begun delivery
/// replaced by a stored record read before it was saved would never be attempted.
fn webhook_progress(webhook: &Option<Webhook>) -> (usize, usize) {
    webhook.as_ref().map_or((0, 0), |webhook| {
        let attempts = webhook
            .deliveries
            .iter()
            .map(|delivery| delivery.attempts.len())
            .sum();
        (attempts, webhook.deliveries.len())
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::service::model::{Attempt, Delivery, DeliveryStatus, WebhookEvent};

    fn delivery(event: WebhookEvent, attempts: usize, status: DeliveryStatus) -> Delivery {
        let attempt = Attempt {
            at: 1,
            status_code: Some(204),
            error: None,
        };
        Delivery {
            id: format!("msg_{}", event.name()),
            event,
            status,
            attempts: vec![attempt; attempts],
            next_attempt_at: None,
        }
    }

    /// The race the chaos harness found (one completion webhook lost in an hour): the
    /// delivering replica begins the `completed` delivery (pending, no attempt yet) while the
    /// follower brings in the stored record of the job's end, read before that delivery was
    /// saved, with as many attempts. The copy's deliveries must win, or the begun delivery
    /// vanishes and is never attempted.
    #[test]
    fn a_begun_delivery_outranks_a_stored_record_without_it() {
        let webhook = |deliveries| {
            Some(Webhook {
                url: "http://hooks.example/".into(),
                events: vec![WebhookEvent::Started, WebhookEvent::Completed],
                deliveries,
            })
        };
        let started = delivery(WebhookEvent::Started, 2, DeliveryStatus::Delivered);
        let stored = webhook(vec![started.clone()]);
        let begun = webhook(vec![
            started.clone(),
            delivery(WebhookEvent::Completed, 0, DeliveryStatus::Pending),
        ]);
        assert!(webhook_progress(&begun) > webhook_progress(&stored));
        // An attempt made counts before deliveries begun.
        let attempted = webhook(vec![delivery(
            WebhookEvent::Started,
            3,
            DeliveryStatus::Delivered,
        )]);
        assert!(webhook_progress(&attempted) > webhook_progress(&begun));
    }
}
