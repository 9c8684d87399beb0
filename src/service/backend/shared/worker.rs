//! Workers on the shared backend: job slots that claim queued jobs from PostgreSQL, run them
//! and save what they left (`covec worker`, and `covec serve --database-url` with workers).
//!
//! A slot claims the queued job the fair rule picks ([`crate::service::fair`]) under a lease
//! ([`Postgres::claim`]); while the job runs
//! a heartbeat thread renews the lease, stores the record when it changed (progress and
//! previews, at most every [`BEAT`]) and learns of a cancel or a delete. Expired leases (a
//! worker that vanished) are reaped by every slot now and then ([`REAP_EVERY`]). On shutdown
//! a slot takes no new job; running ones finish within the grace period or are put back in
//! the queue without the attempt counting.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use tracing::{info, info_span, warn};

use super::postgres::{Beat, Claim, MAX_ATTEMPTS, Postgres};
use crate::service::fair::Scheduling;
use crate::service::job::{JobEntry, JobFailure, lock};
use crate::service::model::{CancelReason, Problem};
use crate::service::queue::{QueueError, REAP_EVERY};
use crate::service::runner::{Runner, Settled, job_pool};
use crate::service::store::retry_transient;

/// Longest gap between two heartbeats of a running job: how stale its progress row may be,
/// and how long a cancel from any replica waits before the worker sees it.
pub const BEAT: Duration = Duration::from_millis(500);

/// How long an idle slot waits before it looks for a queued job again.
const IDLE_POLL: Duration = Duration::from_millis(250);

/// Takes back the jobs whose lease expired ([`Postgres::reap`]): queued again, or failed with
/// `workers-lost` after [`MAX_ATTEMPTS`]. Failures are logged: the next look tries again.
pub fn reap_expired(postgres: &Postgres, retention: Duration) {
    let lost = Problem::from(JobFailure::WorkersLost(MAX_ATTEMPTS as u32));
    if let Err(error) = postgres.reap(lost, retention) {
        warn!("taking back expired leases: {error}");
    }
}

/// Job slots and how long a lease lasts.
#[derive(Clone, Debug)]
pub struct WorkerConfig {
    /// Jobs run at once (each in a pool of `threads / slots` threads).
    pub slots: usize,
    /// Pipeline threads in total.
    pub threads: usize,
    /// How long a claim holds without a heartbeat: after a worker vanishes, its job waits
    /// this long before another worker takes it. Default 30 s.
    pub lease: Duration,
    /// The rule's batch age and running limits (the same in every process).
    pub scheduling: Scheduling,
}

pub struct Workers {
    runner: Arc<Runner>,
    postgres: Arc<Postgres>,
    lease: Duration,
    scheduling: Scheduling,
    draining: AtomicBool,
    /// Jobs being run, for a shutdown past its grace to stop them.
    running: Mutex<Vec<Arc<JobEntry>>>,
    /// Signalled when a job ends or draining starts.
    changed: Condvar,
    alive: AtomicUsize,
    slots: usize,
    handles: Mutex<Vec<JoinHandle<()>>>,
}

impl Workers {
    /// Starts the slots (none when `config.slots` is 0).
    pub fn start(
        runner: Arc<Runner>,
        postgres: Arc<Postgres>,
        config: &WorkerConfig,
    ) -> Result<Arc<Self>, QueueError> {
        let threads_per_job = (config.threads / config.slots.max(1)).max(1);
        let workers = Arc::new(Self {
            runner,
            postgres,
            lease: config.lease.max(BEAT * 2),
            scheduling: config.scheduling.clone(),
            draining: AtomicBool::new(false),
            running: Mutex::new(Vec::new()),
            changed: Condvar::new(),
            alive: AtomicUsize::new(0),
            slots: config.slots,
            handles: Mutex::new(Vec::new()),
        });
        for slot in 0..config.slots {
            let pool = job_pool(slot, threads_per_job)?;
            let worker = Arc::clone(&workers);
            workers.alive.fetch_add(1, Ordering::SeqCst);
            let handle = std::thread::Builder::new()
                .name(format!("covec-worker-{slot}"))
                .spawn(move || worker.run_slot(&pool))
                .inspect_err(|_| {
                    workers.alive.fetch_sub(1, Ordering::SeqCst);
                })?;
            lock(&workers.handles).push(handle);
        }
        Ok(workers)
    }

    /// What runs the jobs (its store and metrics serve the worker's probes).
    pub fn runner(&self) -> &Arc<Runner> {
        &self.runner
    }

    /// Job slots started.
    pub fn slots(&self) -> usize {
        self.slots
    }

    /// Every slot is alive and taking work.
    pub fn is_ready(&self) -> bool {
        !self.draining.load(Ordering::SeqCst) && self.alive.load(Ordering::SeqCst) == self.slots
    }

    /// Stops taking jobs, lets running ones finish for up to `grace`, then stops them (they
    /// go back to the queue for another worker) and waits for the slots to end.
    pub fn drain(&self, grace: Duration) {
        let deadline = Instant::now() + grace;
        let mut running = lock(&self.running);
        self.draining.store(true, Ordering::SeqCst);
        self.changed.notify_all();
        while !running.is_empty() && Instant::now() < deadline {
            running = self
                .changed
                .wait_timeout(running, deadline - Instant::now())
                .unwrap_or_else(|p| p.into_inner())
                .0;
        }
        if !running.is_empty() {
            info!(
                running = running.len(),
                "shutdown grace over: putting running jobs back in the queue"
            );
            for entry in running.iter() {
                entry.request_cancel(CancelReason::Shutdown);
            }
        }
        drop(running);
        for handle in lock(&self.handles).drain(..) {
            let _ = handle.join();
        }
    }

    /// Sleeps up to `pause`, waking early when draining starts; returns whether draining.
    fn pause(&self, pause: Duration) -> bool {
        let running = lock(&self.running);
        if self.draining.load(Ordering::SeqCst) {
            return true;
        }
        let _ = self.changed.wait_timeout(running, pause);
        self.draining.load(Ordering::SeqCst)
    }

    fn run_slot(self: Arc<Self>, pool: &rayon::ThreadPool) {
        let mut last_reap: Option<Instant> = None;
        while !self.draining.load(Ordering::SeqCst) {
            if last_reap.is_none_or(|at| at.elapsed() >= REAP_EVERY) {
                last_reap = Some(Instant::now());
                reap_expired(&self.postgres, self.runner.retention);
            }
            match self.postgres.claim(self.lease, &self.scheduling) {
                Ok(Some(claim)) => self.run_claim(claim, pool),
                Ok(None) => {
                    self.pause(IDLE_POLL);
                }
                Err(error) => {
                    warn!("claiming a job: {error}");
                    // The database is down or restarting: look again later.
                    self.pause(IDLE_POLL * 8);
                }
            }
        }
        self.alive.fetch_sub(1, Ordering::SeqCst);
    }

    fn run_claim(&self, claim: Claim, pool: &rayon::ThreadPool) {
        let Claim { record, token } = claim;
        let _span = info_span!("job", job_id = %record.id, attempt = record.attempts).entered();
        if record.attempts > 1 {
            // What an earlier run, whose worker vanished, left behind.
            if let Err(error) = self.runner.store.remove_outputs(&record.id) {
                warn!("removing an earlier run's results: {error}");
            }
        }
        let entry = JobEntry::new(record);
        lock(&self.running).push(Arc::clone(&entry));
        let lost = AtomicBool::new(false);
        let ended = AtomicBool::new(false);
        let done = (Mutex::new(false), Condvar::new());
        let settled = std::thread::scope(|scope| {
            scope.spawn(|| self.heartbeats(&entry, &token, &lost, &ended, &done));
            let settled = self.runner.run(&entry, pool);
            // The lease is kept (heartbeats go on, the record no longer in them) until the
            // outcome is saved: a database that takes no writes for a while (restarting, its
            // disk full) then costs no re-run, as long as it is back within the lease.
            ended.store(true, Ordering::SeqCst);
            if settled != Settled::Deleted {
                self.save_outcome(&entry, &token, &lost);
            }
            *lock(&done.0) = true;
            done.1.notify_all();
            settled
        });
        // Deleted while it ran, or while its outcome was being saved.
        if (settled == Settled::Deleted || entry.deleted.load(Ordering::SeqCst))
            && let Err(error) = self.runner.store.remove_artefacts(&entry.id)
        {
            warn!("removing a deleted job's files (left to the sweep): {error}");
        }
        lock(&self.running).retain(|running| !Arc::ptr_eq(running, &entry));
        self.changed.notify_all();
    }

    /// Saves the record a run left (ended, or queued again), fenced by the lease's token,
    /// retrying while the database cannot take it ([`retry_transient`]).
    fn save_outcome(&self, entry: &JobEntry, token: &str, lost: &AtomicBool) {
        if lost.load(Ordering::SeqCst) {
            warn!("another worker holds the job now: this run's outcome is dropped");
            return;
        }
        let saved = retry_transient("saving the outcome", || {
            self.postgres.settle(token, &entry.snapshot())
        });
        match saved {
            // One line per terminal write: what the chaos checker counts.
            Ok(true) => info!(status = entry.snapshot().status.name(), "outcome saved"),
            Ok(false) => warn!(
                "fenced: the lease is no longer this worker's (expired, or the job deleted); \
                 the outcome write was refused"
            ),
            Err(error) => warn!("saving the outcome: {error}"),
        }
    }

    /// Renews the lease and stores the record every [`BEAT`] until `done` (once the run has
    /// `ended`, the lease only: the outcome is the settle's to write); stops the run when the
    /// job is canceled, deleted or taken over.
    fn heartbeats(
        &self,
        entry: &JobEntry,
        token: &str,
        lost: &AtomicBool,
        ended: &AtomicBool,
        done: &(Mutex<bool>, Condvar),
    ) {
        let mut stored = None;
        loop {
            let record = entry.snapshot();
            let changed = !ended.load(Ordering::SeqCst) && stored.as_ref() != Some(&record);
            let beat =
                self.postgres
                    .heartbeat(token, self.lease, changed.then_some(&record), &entry.id);
            match beat {
                Ok(Beat::Held { cancel }) => {
                    stored = Some(record);
                    if cancel {
                        entry.request_cancel(CancelReason::User);
                    }
                }
                Ok(Beat::Deleted) => {
                    entry.deleted.store(true, Ordering::SeqCst);
                    entry.request_cancel(CancelReason::User);
                }
                Ok(Beat::Lost) => {
                    if !lost.swap(true, Ordering::SeqCst) {
                        warn!("fenced: the lease is another worker's now; heartbeat refused");
                    }
                    entry.request_cancel(CancelReason::Shutdown);
                }
                // The lease outlives a short outage; a long one ends in `Lost`.
                Err(error) => warn!("heartbeat: {error}"),
            }
            let finished = lock(&done.0);
            if *finished {
                return;
            }
            let (finished, _) = done
                .1
                .wait_timeout(finished, BEAT)
                .unwrap_or_else(|p| p.into_inner());
            if *finished {
                return;
            }
        }
    }
}
