//! The queue of a backend whose jobs all run in this process, over records only it writes
//! (the embedded and the memory backend): written through on every status change.
//!
//! `workers` runner threads take queued jobs by the fair rule ([`crate::service::fair`]); each
//! runs its job's pipeline inside its own rayon pool (`threads / workers` threads), so the async
//! runtime never runs pipeline work. One pool per job slot rather than one shared pool: in a
//! shared pool a thread waiting inside one job's parallel loop may pick up another whole job
//! (rayon work-stealing), stalling the first job, and its cancellation, until the second ends.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use tracing::{info, info_span, warn};

use super::state::State;
use super::{Admission, Backend, Queue, QueueConfig, QueueError, Refusal};
use crate::service::job::{JobEntry, lock};
use crate::service::model::{CancelReason, JobRecord, Status, Webhook, now_ms};
use crate::service::runner::{Runner, Settled, job_pool};
use crate::service::store::{LocalRecords, StoreError, retry_transient};
use crate::service::telemetry::Metrics;

pub struct Local {
    records: Arc<dyn LocalRecords>,
    /// Runner threads still taking jobs.
    runners_alive: Arc<AtomicUsize>,
}

impl Local {
    /// The queue over `records`, which the store holds too.
    pub fn new(records: Arc<dyn LocalRecords>) -> Self {
        Self {
            records,
            runners_alive: Arc::new(AtomicUsize::new(0)),
        }
    }
}

impl Backend for Local {
    /// Loads the queued and running jobs into `state`, queued again (a run cut short by the
    /// stop starts over); at least one runner.
    fn open(
        &mut self,
        runner: &Arc<Runner>,
        config: &mut QueueConfig,
        metrics: &Metrics,
        state: &mut State,
    ) -> Result<(), QueueError> {
        config.workers = config.workers.max(1);
        let store = &runner.store;
        let recovered = self.records.recover()?;
        metrics.quarantined(recovered.quarantined.len());
        for mut record in recovered.records {
            info!(job_id = %record.id, "re-queued after restart");
            record.requeue();
            store.remove_outputs(&record.id)?;
            store.save(&record)?;
            state.remember(JobEntry::new(record));
        }
        Ok(())
    }

    /// Sweeps orphans and starts the runner threads.
    fn start(&self, queue: &Arc<Queue>) -> Result<(), QueueError> {
        // Nothing is being admitted yet: every directory without a record is an orphan.
        let swept = queue.sweep_orphans(Duration::ZERO);
        if swept > 0 {
            info!(swept, "orphaned job directories removed at start");
        }
        let workers = queue.config.workers;
        let threads_per_job = (queue.config.threads / workers).max(1);
        for index in 0..workers {
            let pool = job_pool(index, threads_per_job)?;
            let (runner, alive) = (Arc::clone(queue), Arc::clone(&self.runners_alive));
            alive.fetch_add(1, Ordering::SeqCst);
            let handle = std::thread::Builder::new()
                .name(format!("covec-job-{index}"))
                .spawn(move || {
                    run_jobs(&runner, &pool);
                    alive.fetch_sub(1, Ordering::SeqCst);
                })
                .inspect_err(|_| {
                    self.runners_alive.fetch_sub(1, Ordering::SeqCst);
                })?;
            lock(&queue.threads).push(handle);
        }
        Ok(())
    }

    fn depth(&self, state: &State) -> (usize, usize) {
        state.fair.depth()
    }

    /// Every runner alive.
    fn is_ready(&self, workers: usize) -> bool {
        self.runners_alive.load(Ordering::SeqCst) == workers
    }

    /// Queues the job, or replays the earlier one with its Idempotency-Key. The key is looked
    /// up under the queue lock, so of two submissions with one key only the first is admitted.
    fn admit(&self, queue: &Queue, record: JobRecord) -> Result<Admission, Refusal> {
        let mut state = lock(&queue.state);
        if let Some(idempotency) = &record.idempotency {
            let earlier = queue.store().idempotent(
                &record.owner,
                &idempotency.key,
                queue.config.keys_since(),
            )?;
            if let Some(earlier) = earlier {
                return if earlier.idempotency.as_ref() == Some(idempotency) {
                    Ok(Admission::Replayed(state.remember(JobEntry::new(earlier))))
                } else {
                    Err(Refusal::IdempotencyMismatch)
                };
            }
        }
        let queued = state.fair.depth().0;
        if let Some(refusal) = state.refusal(&queue.config, &queue.metrics, queued, &record.client)
        {
            return Err(refusal);
        }
        queue.store().save(&record)?;
        let entry = state.remember(JobEntry::new(record));
        drop(state);
        queue.changed.notify_one();
        Ok(Admission::Created(entry))
    }

    /// Ends a queued job at once; asks a running one to stop (true: still stopping).
    fn cancel(&self, queue: &Queue, entry: &Arc<JobEntry>) -> Result<bool, Refusal> {
        let mut state = lock(&queue.state);
        let status = entry.record.borrow().status;
        match status {
            Status::Running => {
                entry.request_cancel(CancelReason::User);
                return Ok(true);
            }
            Status::Queued => {}
            _ => return Ok(false),
        }
        state.fair.forget(&entry.id);
        drop(state);
        entry.end(
            Status::Canceled,
            None,
            Some(CancelReason::User),
            queue.config.retention,
        );
        let saved = super::save(queue.store(), entry);
        lock(&queue.state).file(entry);
        saved.map(|()| false)
    }

    /// The jobs whose webhook deliveries are unfinished, oldest first (to resume them after a
    /// start). Records marked so whose deliveries are all done lose the mark.
    fn deliveries_to_resume(&self, queue: &Queue) -> Result<Vec<Arc<JobEntry>>, StoreError> {
        let mut entries = Vec::new();
        for record in self.records.webhooks_pending()? {
            if record.webhook.as_ref().is_some_and(Webhook::unfinished) {
                entries.push(lock(&queue.state).remember(JobEntry::new(record)));
            } else {
                queue.store().save(&record)?;
            }
        }
        Ok(entries)
    }

    /// An unreadable record was moved to the quarantine.
    fn met_unreadable(&self, metrics: &Metrics) {
        metrics.quarantined(1);
    }
}

/// A runner thread: takes queued jobs by the fair rule until draining.
fn run_jobs(queue: &Arc<Queue>, pool: &rayon::ThreadPool) {
    loop {
        let mut state = lock(&queue.state);
        let id = loop {
            if state.draining {
                break None;
            }
            if let Some(id) = state.fair.next(&queue.config.scheduling, now_ms()) {
                break Some(id);
            }
            // Nothing queued, or only keys at their running limit: a submission or a job's end
            // changes that.
            state = queue.changed.wait(state).unwrap_or_else(|p| p.into_inner());
        };
        let Some(id) = id else {
            break;
        };
        let Some(entry) = state.live.get(&id).cloned() else {
            state.fair.forget(&id);
            continue;
        };
        state.running += 1;
        // Marked running under the queue lock, so `cancel` never sees a job that is neither
        // queued nor running.
        entry.record.send_modify(|record| {
            record.status = Status::Running;
            record.started_at = Some(now_ms());
        });
        let client = entry.record.borrow().client.clone();
        state.fair.track(&entry.record.borrow());
        state.fair.serve(&client);
        drop(state);
        run_job(queue, &entry, pool);
        // Under the lock `delete` reads the status with: either it saw the job running and the
        // files are removed here, or it saw the job ended and removed them itself.
        let deleted = {
            let mut state = lock(&queue.state);
            state.running -= 1;
            let deleted = entry.deleted.load(Ordering::SeqCst);
            if !deleted {
                // Ended, or queued again by a shutdown.
                state.file(&entry);
            }
            deleted
        };
        if deleted {
            super::remove_deleted_files(queue.store(), &entry.id);
        }
        queue.changed.notify_all();
    }
}

fn run_job(queue: &Queue, entry: &Arc<JobEntry>, pool: &rayon::ThreadPool) {
    let _span = info_span!("job", job_id = %entry.id).entered();
    if let Err(error) = retry_transient("saving running state", || {
        queue.store().save(&entry.snapshot())
    }) {
        warn!("saving running state: {error}");
    }
    // Saved as queued when interrupted: the next start runs it again.
    if queue.runner.run(entry, pool) != Settled::Deleted
        && let Err(error) = super::save(queue.store(), entry)
    {
        warn!("saving the outcome: {error}");
    }
}
