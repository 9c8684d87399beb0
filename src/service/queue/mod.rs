//! The job queue: the live state of jobs, the fair rule that orders them, and the operations
//! on them, over a backend ([`Backend`]: the seam each backend implements in its folder under
//! `service/backend/`).
//!
//! Live job state is held in memory (one `watch` channel per job, so polls and SSE streams read
//! it without touching the database): the queued and running jobs, and ended jobs only while
//! something holds them (an event stream, a webhook delivery, a request). Every other record is
//! read from the [`Store`] when asked for, so memory does not grow with the jobs ever run, and
//! records are deleted after the record retention ([`Queue::expire`]).

mod backend;
mod local;
pub mod state;

use std::collections::HashMap;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use tracing::{info, info_span, warn};

use super::fair::Scheduling;
use super::inputs::{EncodedInputs, InputLimits};
use super::job::{JobEntry, lock};
use super::model::{CancelReason, JobRecord, Placement, Status, now_ms};
use super::runner::Runner;
use super::store::{Store, StoreError, digest, retry_transient};
use super::telemetry::{Metrics, QueueGauges};
pub use backend::Backend;
pub use local::Local;
use state::State;

/// Most records one statement of [`Queue::expire`] handles: its transaction stays short, and a
/// backlog (a server stopped for days) is worked off in batches.
const EXPIRY_BATCH: usize = 1000;

/// How often expired leases are taken back, and webhook deliveries another process stopped
/// making are taken over.
pub const REAP_EVERY: Duration = Duration::from_secs(2);

/// The default lease (see [`QueueConfig::lease`]).
pub const DEFAULT_LEASE: Duration = Duration::from_secs(30);

/// Queue and worker settings.
#[derive(Clone, Debug)]
pub struct QueueConfig {
    /// Jobs run at once. Default 1 (one job uses every thread). On the shared backend 0 is
    /// allowed: an API replica that runs no job.
    pub workers: usize,
    /// Pipeline threads in total, shared out among the workers (at least one each).
    /// Default: the number of cores.
    pub threads: usize,
    /// Most jobs waiting; beyond it `POST /v1/jobs` answers 503 with `Retry-After`. Default 64.
    pub max_queued: usize,
    /// Wall-clock limit of one run; then the job fails with code `time-limit`. Default 600 s.
    pub job_time_limit: Duration,
    /// How long results are kept after a job ends. Default 24 h.
    pub retention: Duration,
    /// How long a job's record is kept after it ends; then the job answers `410 Gone` (for as
    /// long again) and then `404`. Separate from `retention`: a client may look at what became
    /// of a job long after its results are gone. Default 30 days.
    pub record_retention: Duration,
    /// How long an Idempotency-Key holds after its job was created; a reuse after that creates
    /// a new job. Default 24 h.
    pub idempotency_window: Duration,
    /// Shared backend: how long a worker's claim holds without a heartbeat. Default 30 s.
    pub lease: Duration,
    /// Age after which a job's files without a record are swept while the server runs (and at
    /// start on the shared backend, where other replicas may be admitting jobs): far longer
    /// than a submission takes between writing its files and its record. Default 600 s.
    pub orphan_age: Duration,
    /// Which job runs next, and what each key may hold.
    pub scheduling: Scheduling,
}

impl Default for QueueConfig {
    fn default() -> Self {
        Self {
            workers: 1,
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
            max_queued: 64,
            job_time_limit: Duration::from_secs(600),
            retention: Duration::from_secs(24 * 3600),
            record_retention: Duration::from_secs(30 * 24 * 3600),
            idempotency_window: Duration::from_secs(24 * 3600),
            lease: DEFAULT_LEASE,
            orphan_age: Duration::from_secs(600),
            scheduling: Scheduling::default(),
        }
    }
}

impl QueueConfig {
    /// Creation time (Unix ms) from which Idempotency-Keys still hold.
    pub fn keys_since(&self) -> u64 {
        now_ms().saturating_sub(self.idempotency_window.as_millis() as u64)
    }
}

/// The fields are the backends' to use (`service/backend/`); the rest of the service goes
/// through the methods.
pub struct Queue {
    pub(crate) config: QueueConfig,
    /// Runs jobs; its decode slots ([`InputLimits::decode_slots`]) are shared by the requests
    /// that decode a submission and the runners that decode a job's stored inputs: both hold
    /// a full-size decode in memory, so both count against one bound.
    pub(crate) runner: Arc<Runner>,
    pub(crate) metrics: Arc<Metrics>,
    pub(crate) state: Mutex<State>,
    /// Signalled when a job is queued, a job ends, or draining starts.
    pub(crate) changed: Condvar,
    /// What differs between backends.
    backend: Box<dyn Backend>,
    /// Local runners, or the shared backend's follower thread.
    pub(crate) threads: Mutex<Vec<JoinHandle<()>>>,
}

/// Which jobs' webhook deliveries this process makes, as the backend decides
/// ([`Queue::deliveries`]).
pub struct Deliveries<'a> {
    queue: &'a Queue,
}

impl Deliveries<'_> {
    /// At start: the jobs whose deliveries this process is to resume.
    pub fn to_resume(&self) -> Result<Vec<Arc<JobEntry>>, StoreError> {
        self.queue.backend.deliveries_to_resume(self.queue)
    }

    /// Every so often: the jobs whose deliveries another replica stopped making.
    pub fn to_take_over(&self) -> Result<Vec<Arc<JobEntry>>, StoreError> {
        self.queue.backend.deliveries_to_take_over(self.queue)
    }

    /// The job's deliveries are all made or given up.
    pub fn done(&self, id: &str) -> Result<(), StoreError> {
        self.queue.backend.deliveries_done(self.queue, id)
    }
}

/// A page of a listing: each job with its queue position while queued.
pub type Page = Vec<(JobRecord, Option<Placement>)>;

/// What admitting a submission did.
pub enum Admission {
    Created(Arc<JobEntry>),
    /// An earlier job with the same Idempotency-Key and the same request.
    Replayed(Arc<JobEntry>),
}

/// Why the queue did not do what a request asked; the handlers answer with its problem.
#[derive(Debug, thiserror::Error)]
pub enum Refusal {
    #[error("the server is shutting down")]
    ShuttingDown,
    /// Every queue slot is taken; `retry_after` in seconds.
    #[error("the job queue is full ({queued} jobs)")]
    QueueFull { queued: usize, retry_after: u64 },
    /// The client's queued jobs are at its limit; `retry_after` in seconds.
    #[error("this key has {actual} jobs queued, its limit is {limit}")]
    KeyQueueFull {
        limit: u64,
        actual: u64,
        retry_after: u64,
    },
    #[error("this Idempotency-Key was used with a different request")]
    IdempotencyMismatch,
    /// The named stored file does not match its recorded digest.
    #[error("the stored result `{0}` is damaged")]
    CorruptResult(String),
    #[error(transparent)]
    Storage(#[from] StoreError),
}

#[derive(Debug, thiserror::Error)]
pub enum QueueError {
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("worker pool: {0}")]
    Pool(#[from] rayon::ThreadPoolBuildError),
    #[error("worker thread: {0}")]
    Thread(#[from] std::io::Error),
}

impl Queue {
    /// Loads the jobs `backend` holds (on a local one the queued and running jobs, queued
    /// again: a run cut short by the stop starts over), and starts its runners. Call from
    /// inside the tokio runtime.
    pub fn start(
        mut config: QueueConfig,
        limits: InputLimits,
        store: Arc<Store>,
        metrics: Arc<Metrics>,
        mut backend: Box<dyn Backend>,
    ) -> Result<Arc<Self>, QueueError> {
        let runner = Arc::new(Runner {
            decode_slots: Arc::new(tokio::sync::Semaphore::new(limits.decode_slots.max(1))),
            store,
            limits,
            runtime: tokio::runtime::Handle::current(),
            job_time_limit: config.job_time_limit,
            retention: config.retention,
            metrics: Arc::clone(&metrics),
        });
        let mut state = State::new();
        backend.open(&runner, &mut config, &metrics, &mut state)?;
        let queue = Arc::new(Self {
            config,
            runner,
            metrics,
            state: Mutex::new(state),
            changed: Condvar::new(),
            backend,
            threads: Mutex::new(Vec::new()),
        });
        queue.backend.start(&queue)?;
        Ok(queue)
    }

    pub fn workers(&self) -> usize {
        self.config.workers
    }

    /// The decode slots (see [`Queue::runner`]).
    pub fn decode_slots(&self) -> Arc<tokio::sync::Semaphore> {
        Arc::clone(&self.runner.decode_slots)
    }

    pub fn store(&self) -> &Store {
        &self.runner.store
    }

    /// The queue's gauges for `/metrics`: queued and running jobs (of every process on the
    /// shared backend, as the follower last read them), and the jobs held in memory (the live
    /// ones and the ended ones in use).
    pub fn gauges(&self) -> QueueGauges {
        let state = lock(&self.state);
        let (queued, running) = self.backend.depth(&state);
        let held = state.held.values().filter(|held| held.strong_count() > 0);
        QueueGauges {
            queued,
            running,
            in_memory: state.live.len() + held.count(),
        }
    }

    /// Ready to take work: not draining and every runner (or job slot) alive.
    pub fn is_ready(&self) -> bool {
        if lock(&self.state).draining {
            return false;
        }
        self.backend.is_ready(self.config.workers)
    }

    /// The job from memory when it is live or held, else from the store (an ended job, or on
    /// the shared backend one just admitted by another replica, which the copy has not caught
    /// up with), remembered while it is held. An unreadable record is none (and quarantined on
    /// the embedded backend). Blocking when the job is not in memory.
    pub fn find(&self, id: &str) -> Result<Option<Arc<JobEntry>>, StoreError> {
        if let Some(entry) = lock(&self.state).get(id) {
            return Ok(Some(entry));
        }
        let record = match self.store().get(id) {
            Ok(record) => record,
            Err(error @ StoreError::CorruptRecord { .. }) => {
                self.backend.met_unreadable(&self.metrics);
                warn!(job_id = %id, "{error}");
                None
            }
            Err(error) => return Err(error),
        };
        Ok(record.map(|record| lock(&self.state).remember(JobEntry::new(record))))
    }

    /// Whether job `id` is gone with its record expired (and `owner`'s): `410 Gone`, not `404`.
    /// Blocking.
    pub fn expired(&self, id: &str, owner: &Option<String>) -> Result<bool, StoreError> {
        Ok(self.store().expired_owner(id)?.as_ref() == Some(owner))
    }

    /// What the webhook deliverer asks of the backend.
    pub fn deliveries(&self) -> Deliveries<'_> {
        Deliveries { queue: self }
    }

    /// Where a job stands while it is queued.
    pub fn placement(&self, id: &str) -> Option<Placement> {
        lock(&self.state).placement(&self.config, id)
    }

    /// A page of `owner`'s jobs, newest first, strictly older than `before`, and whether more
    /// follow. The page comes from the store's index; the queue lock is held only to look up
    /// the page's own jobs. Blocking: call it off the async workers.
    pub fn list(
        &self,
        owner: &Option<String>,
        status: Option<Status>,
        before: Option<&str>,
        limit: usize,
    ) -> Result<(Page, bool), StoreError> {
        let mut ids = self.store().list_ids(owner, status, before, limit + 1)?;
        let more = ids.len() > limit;
        ids.truncate(limit);
        // From memory when there, else from the store (not remembered: nothing holds them).
        let mut records = Vec::with_capacity(ids.len());
        for id in &ids {
            let known = lock(&self.state).get(id).map(|entry| entry.snapshot());
            let record = match known {
                Some(record) => Some(record),
                None => match self.store().get(id) {
                    Ok(record) => record,
                    Err(StoreError::CorruptRecord { .. }) => None,
                    Err(error) => return Err(error),
                },
            };
            // The live state wins over a stored status a failed write left behind.
            records.extend(record.filter(|r| status.is_none_or(|status| r.status == status)));
        }
        let state = lock(&self.state);
        // One pass of the rule places every queued job of the page.
        let now = now_ms();
        let positions = match records.iter().any(|r| r.status == Status::Queued) {
            true => state.fair.positions(&self.config.scheduling, now),
            false => HashMap::new(),
        };
        let page = records
            .into_iter()
            .map(|record| {
                let placement = positions
                    .get(&record.id)
                    .map(|&position| state.placement_at(&self.config, position, now));
                (record, placement)
            })
            .collect();
        Ok((page, more))
    }

    /// The earlier job for this Idempotency-Key (within [`QueueConfig::idempotency_window`]),
    /// if any: `Ok` when the request matches it. Blocking.
    pub fn find_idempotent(
        &self,
        owner: &Option<String>,
        key: &str,
        fingerprint: &str,
    ) -> Result<Option<Arc<JobEntry>>, Refusal> {
        let Some(earlier) = self
            .store()
            .idempotent(owner, key, self.config.keys_since())?
        else {
            return Ok(None);
        };
        let same = earlier
            .idempotency
            .as_ref()
            .is_some_and(|i| i.fingerprint == fingerprint);
        if !same {
            return Err(Refusal::IdempotencyMismatch);
        }
        Ok(Some(lock(&self.state).remember(JobEntry::new(earlier))))
    }

    /// Refuses new work of `client` when draining, when the queue is full, or when the
    /// client's queued jobs are at its limit. On the shared backend this looks at the copy;
    /// the insert checks again in the database.
    pub fn check_capacity(&self, client: &str) -> Result<(), Refusal> {
        let state = lock(&self.state);
        let queued = self.backend.depth(&state).0;
        match state.refusal(&self.config, &self.metrics, queued, client) {
            Some(refusal) => Err(refusal),
            None => Ok(()),
        }
    }

    /// Stores inputs and record, then queues the job (or replays an idempotent duplicate).
    pub fn admit(&self, record: JobRecord, inputs: EncodedInputs) -> Result<Admission, Refusal> {
        let id = record.id.clone();
        for (kind, bytes) in inputs.into_files() {
            if let Err(error) = self.store().write_artefact(&id, &kind.name(), &bytes) {
                let _ = self.store().remove_artefacts(&id);
                return Err(error.into());
            }
        }
        let admitted = self.backend.admit(self, record);
        if !matches!(admitted, Ok(Admission::Created(_))) {
            let _ = self.store().remove_artefacts(&id);
        }
        admitted
    }

    /// Cancels a job: a queued one ends at once, a running one within one iteration.
    /// Returns whether the job was running (the cancel is then still in progress).
    pub fn cancel(&self, entry: &Arc<JobEntry>) -> Result<bool, Refusal> {
        self.backend.cancel(self, entry)
    }

    /// Deletes a job: its record for good, then its files. The tombstone comes first: if it
    /// cannot be written nothing has changed (the job stays, whole); once it is, no later
    /// write brings the job back. A running job is stopped and its runner removes the files
    /// when it stops (removing them here would race the files it is still writing); files
    /// that cannot be removed are left to the orphan sweep.
    pub fn delete(&self, entry: &JobEntry) -> Result<(), Refusal> {
        self.store().tombstone(&entry.id)?;
        let mut state = lock(&self.state);
        // On the shared backend the job's worker, wherever it is, learns it at its next
        // heartbeat and removes the files itself.
        let running = entry.record.borrow().status == Status::Running;
        entry.request_cancel(CancelReason::User);
        state.forget(&entry.id);
        entry.deleted.store(true, Ordering::SeqCst);
        drop(state);
        if !running {
            remove_deleted_files(self.store(), &entry.id);
        }
        Ok(())
    }

    /// Removes job directories no job owns that are older than `min_age` (see
    /// [`Store::sweep_orphans`]); returns how many.
    pub fn sweep_orphans(&self, min_age: Duration) -> usize {
        let removed = self
            .store()
            .sweep_orphans(min_age, |id| lock(&self.state).get(id).is_some());
        self.metrics.orphans_swept(removed);
        removed
    }

    /// Removes the results of jobs whose retention has passed (returns how many), the records
    /// of jobs whose record retention has, and expired Idempotency-Keys. Blocking.
    pub fn expire(&self, now: u64) -> usize {
        let mut removed = 0;
        loop {
            let due = match self.store().results_due(now, EXPIRY_BATCH) {
                Ok(due) => due,
                Err(error) => {
                    warn!("looking for expired results: {error}");
                    break;
                }
            };
            let mut failed = false;
            for id in &due {
                let _span = info_span!("expire", job_id = %id).entered();
                let removal = self.find(id).map_err(Refusal::from).and_then(|entry| {
                    let Some(entry) = entry else { return Ok(()) };
                    self.store().remove_artefacts(id)?;
                    entry
                        .record
                        .send_modify(|record| record.data_removed = true);
                    save(self.store(), &entry)
                });
                match removal {
                    Ok(()) => removed += 1,
                    Err(error) => {
                        warn!("removing expired results: {error}");
                        failed = true;
                    }
                }
            }
            // A failed one would come back in the next batch: left to the next sweep.
            if due.len() < EXPIRY_BATCH || failed {
                break;
            }
        }
        expire_records(self, now);
        if let Err(error) = self.store().drop_idempotency_keys(self.config.keys_since()) {
            warn!("removing expired idempotency keys: {error}");
        }
        self.backend.purge(self);
        removed
    }

    /// Stops taking jobs, lets running ones finish for up to `grace`, then stops them; they are
    /// saved as queued and run again after the next start.
    pub fn drain(&self, grace: Duration) {
        let deadline = Instant::now() + grace;
        let mut state = lock(&self.state);
        state.draining = true;
        self.changed.notify_all();
        while state.running > 0 && Instant::now() < deadline {
            state = self
                .changed
                .wait_timeout(state, deadline - Instant::now())
                .unwrap_or_else(|p| p.into_inner())
                .0;
        }
        if state.running > 0 {
            info!(
                running = state.running,
                "shutdown grace over: stopping running jobs"
            );
            for entry in state.live.values() {
                if entry.record.borrow().status == Status::Running {
                    entry.request_cancel(CancelReason::Shutdown);
                }
            }
        }
        drop(state);
        self.backend.drain(deadline);
        for handle in lock(&self.threads).drain(..) {
            let _ = handle.join();
        }
    }

    /// A stored file of a job, checked against the digest recorded when it was written: in the
    /// job's record for its results, in its folder's digests for an edit's files (a file cut
    /// short or altered on disk is an error, never served as if whole).
    pub fn read_result(&self, id: &str, name: &str) -> Result<Option<Vec<u8>>, Refusal> {
        let recorded = self
            .find(id)?
            .and_then(|entry| entry.record.borrow().checksums.get(name).cloned());
        let expected = match recorded {
            Some(digest) => Some(digest),
            None => match self.store().folder_digest(id, name) {
                Ok(digest) => digest,
                Err(error @ StoreError::CorruptRecord { .. }) => {
                    tracing::error!(job_id = %id, name, %error, "unreadable digests");
                    return Err(Refusal::CorruptResult(name.to_owned()));
                }
                Err(error) => return Err(error.into()),
            },
        };
        let bytes = self.store().read_artefact(id, name)?;
        if let (Some(bytes), Some(expected)) = (&bytes, expected)
            && digest(bytes) != expected
        {
            tracing::error!(job_id = %id, name, "a stored result does not match its digest");
            return Err(Refusal::CorruptResult(name.to_owned()));
        }
        Ok(bytes)
    }
}

/// Deletes the records of jobs that ended more than the record retention ago (their files
/// too, if any are left), and forgets the expired ids kept as long again.
fn expire_records(queue: &Queue, now: u64) {
    let cutoff = now.saturating_sub(queue.config.record_retention.as_millis() as u64);
    loop {
        let expired = match queue.store().expire_records(cutoff, cutoff, EXPIRY_BATCH) {
            Ok(expired) => expired,
            Err(error) => {
                warn!("deleting expired job records: {error}");
                return;
            }
        };
        for id in &expired {
            lock(&queue.state).forget(id);
            remove_deleted_files(queue.store(), id);
        }
        if !expired.is_empty() {
            info!(records = expired.len(), "expired job records deleted");
        }
        if expired.len() < EXPIRY_BATCH {
            return;
        }
    }
}

/// Persists a job's record, retrying transient failures.
pub(crate) fn save(store: &Store, entry: &JobEntry) -> Result<(), Refusal> {
    retry_transient("saving the job", || store.save(&entry.snapshot())).map_err(Refusal::from)
}

/// Removes a deleted job's files; what cannot be removed is left to the orphan sweep.
pub(crate) fn remove_deleted_files(store: &Store, id: &str) {
    if let Err(error) = store.remove_artefacts(id) {
        warn!(job_id = %id, "removing a deleted job's files (left to the sweep): {error}");
    }
}
