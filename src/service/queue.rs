//! The job queue and its workers.
//!
//! Live job state is held in memory (one `watch` channel per job, so polls and SSE streams read
//! it without touching the database). On the embedded backend it is written through to the
//! [`Store`] on every status change. On the shared backend (PostgreSQL) the database is the
//! truth and the memory a copy: the queue, leases and idempotency keys are rows, jobs run in
//! [`Workers`] (here or in `covec worker` processes), and a follower thread brings every
//! change made anywhere into the copy every [`FOLLOW_EVERY`], so polls, listings and SSE on
//! any replica see jobs running on any worker.
//!
//! Embedded: `workers` runner threads take queued jobs by the fair rule ([`super::fair`]);
//! each runs its job's pipeline inside its own rayon pool (`threads / workers` threads), so the
//! async runtime never runs pipeline work. One pool per job slot rather than one shared pool:
//! in a shared pool a thread waiting inside one job's parallel loop may pick up another whole
//! job (rayon work-stealing), stalling the first job, and its cancellation, until the second
//! ends.

use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime};

use axum::body::Bytes;
use tracing::{info, info_span, warn};

use super::error::ApiError;
use super::fair::{FairQueue, Scheduling};
use super::model::{CancelReason, JobRecord, Placement, Status, Webhook, now_ms};
use super::ops::Metrics;
use super::runner::{JobEntry, Runner, Settled, job_pool, lock};
use super::store::{
    Canceled, Change, Inserted, Postgres, Store, StoreError, digest, retry_transient,
};
use super::submit::InputLimits;
use super::worker::{DEFAULT_LEASE, REAP_EVERY, WorkerConfig, WorkerError, Workers, reap_expired};

/// How often an API replica on the shared backend brings other processes' changes into its
/// copy of the jobs (and reads the queue depth): what SSE and polls lag behind a worker.
pub const FOLLOW_EVERY: Duration = Duration::from_millis(200);

/// How long a deleted job's row stays on the shared backend (so workers and replicas see the
/// delete) before it is purged.
const TOMBSTONE_AGE: Duration = Duration::from_secs(3600);

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
            lease: DEFAULT_LEASE,
            orphan_age: Duration::from_secs(600),
            scheduling: Scheduling::default(),
        }
    }
}

struct State {
    /// Every known job by id (ids sort by creation time).
    jobs: BTreeMap<String, Arc<JobEntry>>,
    /// The queued and running jobs, by key: the queue itself on the embedded backend, a copy
    /// of the database's for queue positions on the shared one.
    fair: FairQueue,
    /// (owner, key) → job id.
    idempotency: HashMap<(Option<String>, String), String>,
    running: usize,
    draining: bool,
}

pub struct Queue {
    config: QueueConfig,
    /// Runs jobs; its decode slots ([`InputLimits::decode_slots`]) are shared by the requests
    /// that decode a submission and the runners that decode a job's stored inputs: both hold
    /// a full-size decode in memory, so both count against one bound.
    runner: Arc<Runner>,
    metrics: Arc<Metrics>,
    state: Mutex<State>,
    /// Signalled when a job is queued, a job ends, or draining starts.
    changed: Condvar,
    runners_alive: AtomicUsize,
    /// Embedded runners, and the shared backend's follower thread.
    runners: Mutex<Vec<JoinHandle<()>>>,
    /// Shared backend: this process's job slots (if any), and the (queued, running) counts
    /// the follower last read from the database.
    workers: Option<Arc<Workers>>,
    shared_depth: Mutex<(usize, usize)>,
}

impl State {
    /// Adds a job to those known (unless it is known already: then that entry).
    fn remember(&mut self, entry: Arc<JobEntry>) -> Arc<JobEntry> {
        if let Some(known) = self.jobs.get(&entry.id) {
            return Arc::clone(known);
        }
        self.fair.track(&entry.record.borrow());
        if let Some(idempotency) = &entry.record.borrow().idempotency {
            self.idempotency.insert(
                (entry.owner.clone(), idempotency.key.clone()),
                entry.id.clone(),
            );
        }
        self.jobs.insert(entry.id.clone(), Arc::clone(&entry));
        entry
    }

    /// Drops a deleted job from those known.
    fn forget(&mut self, id: &str) {
        self.fair.forget(id);
        let Some(entry) = self.jobs.remove(id) else {
            return;
        };
        entry.deleted.store(true, Ordering::SeqCst);
        if let Some(idempotency) = &entry.record.borrow().idempotency {
            self.idempotency
                .remove(&(entry.owner.clone(), idempotency.key.clone()));
        }
    }
}

/// Webhook delivery attempts made so far.
fn deliveries_made(webhook: &Option<Webhook>) -> usize {
    webhook.as_ref().map_or(0, |webhook| {
        webhook
            .deliveries
            .iter()
            .map(|delivery| delivery.attempts.len())
            .sum()
    })
}

/// A page of a listing: each job with its queue position while queued.
pub type Page = Vec<(JobRecord, Option<Placement>)>;

/// What admitting a submission did.
pub enum Admission {
    Created(Arc<JobEntry>),
    /// An earlier job with the same Idempotency-Key and the same request.
    Replayed(Arc<JobEntry>),
}

#[derive(Debug, thiserror::Error)]
pub enum QueueError {
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("worker pool: {0}")]
    Pool(#[from] rayon::ThreadPoolBuildError),
    #[error("worker thread: {0}")]
    Thread(#[from] std::io::Error),
    #[error(transparent)]
    Workers(#[from] WorkerError),
}

impl Queue {
    /// Loads every stored job, re-queues those that were queued or running when the server
    /// stopped, and starts the runners. Call from inside the tokio runtime.
    pub fn start(
        config: QueueConfig,
        limits: InputLimits,
        store: Arc<Store>,
        metrics: Arc<Metrics>,
    ) -> Result<Arc<Self>, QueueError> {
        let shared = store.shared().is_some();
        // The shared backend may run no job here (`--workers 0`: an API replica).
        let workers = if shared {
            config.workers
        } else {
            config.workers.max(1)
        };
        let mut state = State {
            jobs: BTreeMap::new(),
            fair: FairQueue::default(),
            idempotency: HashMap::new(),
            running: 0,
            draining: false,
        };
        if !shared {
            let recovered = store.recover()?;
            metrics.set_quarantined(recovered.quarantined.len());
            for mut record in recovered.records {
                if !record.status.is_terminal() {
                    info!(job_id = %record.id, "re-queued after restart");
                    record.requeue();
                    store.remove_outputs(&record.id)?;
                    store.save(&record)?;
                }
                state.remember(JobEntry::new(record));
            }
        }
        let runner = Arc::new(Runner {
            decode_slots: Arc::new(tokio::sync::Semaphore::new(limits.decode_slots.max(1))),
            store,
            limits,
            runtime: tokio::runtime::Handle::current(),
            job_time_limit: config.job_time_limit,
            retention: config.retention,
            metrics: Arc::clone(&metrics),
        });
        let job_slots = if shared && workers > 0 {
            Some(Workers::start(
                Arc::clone(&runner),
                &WorkerConfig {
                    slots: workers,
                    threads: config.threads,
                    lease: config.lease,
                    scheduling: config.scheduling.clone(),
                },
            )?)
        } else {
            None
        };
        let queue = Arc::new(Self {
            config: QueueConfig { workers, ..config },
            runner,
            metrics,
            state: Mutex::new(state),
            changed: Condvar::new(),
            runners_alive: AtomicUsize::new(0),
            runners: Mutex::new(Vec::new()),
            workers: job_slots,
            shared_depth: Mutex::new((0, 0)),
        });
        if let Some(postgres) = queue.shared() {
            let mark = queue.follow(postgres, None)?;
            let follower = Arc::clone(&queue);
            let handle = std::thread::Builder::new()
                .name("covec-follower".into())
                .spawn(move || follower.follow_changes(mark))?;
            lock(&queue.runners).push(handle);
            // Other replicas may be admitting jobs: only old directories are orphans.
            queue.sweep_orphans(queue.config.orphan_age);
            return Ok(queue);
        }
        // Nothing is being admitted yet: every directory without a record is an orphan.
        let swept = queue.sweep_orphans(Duration::ZERO);
        if swept > 0 {
            info!(swept, "orphaned job directories removed at start");
        }
        let threads_per_job = (queue.config.threads / workers).max(1);
        for index in 0..workers {
            let pool = job_pool(index, threads_per_job)?;
            let runner = Arc::clone(&queue);
            queue.runners_alive.fetch_add(1, Ordering::SeqCst);
            let handle = std::thread::Builder::new()
                .name(format!("covec-job-{index}"))
                .spawn(move || runner.run_jobs(&pool))
                .inspect_err(|_| {
                    queue.runners_alive.fetch_sub(1, Ordering::SeqCst);
                })?;
            lock(&queue.runners).push(handle);
        }
        Ok(queue)
    }

    /// The PostgreSQL records, on the shared backend.
    fn shared(&self) -> Option<&Postgres> {
        self.runner.store.shared()
    }

    /// Whether records, queue and leases are in PostgreSQL, shared with other processes.
    pub fn is_shared(&self) -> bool {
        self.shared().is_some()
    }

    /// Brings the changes since `since` (everything when `None`) into the copy, and the queue
    /// depth; returns the mark for the next look.
    fn follow(
        &self,
        postgres: &Postgres,
        since: Option<SystemTime>,
    ) -> Result<SystemTime, StoreError> {
        let (changes, mark) = postgres.changes(since)?;
        let depth = postgres.depth()?;
        let served = postgres.served()?;
        *lock(&self.shared_depth) = depth;
        let mut state = lock(&self.state);
        state.fair.set_served(served);
        for change in changes {
            match change {
                Change::Live(record) => match state.jobs.get(&record.id).cloned() {
                    Some(entry) => {
                        state.fair.track(&record);
                        entry.record.send_if_modified(|current| {
                            let mut record = *record;
                            // Deliveries are made here by this copy: the stored ones may lag.
                            if deliveries_made(&current.webhook) > deliveries_made(&record.webhook)
                            {
                                record.webhook = current.webhook.clone();
                            }
                            let modified = *current != record;
                            *current = record;
                            modified
                        });
                    }
                    None => {
                        state.remember(JobEntry::new(*record));
                    }
                },
                Change::Deleted(id) => state.forget(&id),
            }
        }
        Ok(mark)
    }

    /// The follower thread (shared backend): [`Queue::follow`] every [`FOLLOW_EVERY`], and
    /// takes back expired leases (when no worker is left to) until draining.
    fn follow_changes(self: Arc<Self>, mut mark: SystemTime) {
        let mut last_reap = Instant::now();
        let postgres = self
            .shared()
            .expect("the follower runs on the shared backend");
        loop {
            {
                let state = lock(&self.state);
                let (state, _) = self
                    .changed
                    .wait_timeout(state, FOLLOW_EVERY)
                    .unwrap_or_else(|p| p.into_inner());
                if state.draining {
                    return;
                }
            }
            match self.follow(postgres, Some(mark)) {
                Ok(next) => mark = next,
                Err(error) => warn!("following the job database: {error}"),
            }
            if last_reap.elapsed() >= REAP_EVERY {
                last_reap = Instant::now();
                reap_expired(postgres, self.config.retention);
            }
        }
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

    /// (queued, running) job counts: of every process on the shared backend (as the follower
    /// last read them).
    pub fn depth(&self) -> (usize, usize) {
        if self.is_shared() {
            return *lock(&self.shared_depth);
        }
        lock(&self.state).fair.depth()
    }

    /// Ready to take work: not draining and every runner (or job slot) alive.
    pub fn is_ready(&self) -> bool {
        if lock(&self.state).draining {
            return false;
        }
        match (&self.workers, self.is_shared()) {
            (Some(workers), _) => workers.is_ready(),
            (None, true) => true,
            (None, false) => self.runners_alive.load(Ordering::SeqCst) == self.config.workers,
        }
    }

    /// The job from this process's copy, if it is there.
    pub fn cached(&self, id: &str) -> Option<Arc<JobEntry>> {
        lock(&self.state).jobs.get(id).cloned()
    }

    /// The job from the database, on the shared backend, remembered in the copy: for a job
    /// just admitted by another replica, which the copy has not caught up with. Blocking.
    pub fn load(&self, id: &str) -> Result<Option<Arc<JobEntry>>, StoreError> {
        let Some(postgres) = self.shared() else {
            return Ok(None);
        };
        Ok(postgres
            .get(id)?
            .map(|record| lock(&self.state).remember(JobEntry::new(record))))
    }

    /// Every job, oldest first (for work resumed after a restart, such as webhook deliveries).
    pub fn entries(&self) -> Vec<Arc<JobEntry>> {
        lock(&self.state).jobs.values().cloned().collect()
    }

    /// Where a job stands while it is queued.
    pub fn placement(&self, id: &str) -> Option<Placement> {
        self.placement_in(&lock(&self.state), id)
    }

    /// The job's place by the fair rule, and its estimated start: the jobs ahead take the mean
    /// run time of recent successes each, on as many workers as run jobs now (at least this
    /// process's, at least one), and the running jobs are taken as half done. On the shared
    /// backend from the copy (as fresh as the follower's last look).
    fn placement_in(&self, state: &State, id: &str) -> Option<Placement> {
        let now = now_ms();
        let position = state.fair.position(id, &self.config.scheduling, now)?;
        Some(self.placement_at(state, position, now))
    }

    /// The placement of the job `position` jobs from the front, at `now`.
    fn placement_at(&self, state: &State, position: usize, now: u64) -> Placement {
        let running = state.fair.depth().1;
        let workers = running.max(self.config.workers).max(1);
        let estimated_start_at = state.fair.mean_run_ms().map(|mean| {
            let jobs_ahead = position as f64 + running as f64 / 2.0;
            now + (jobs_ahead * mean as f64 / workers as f64) as u64
        });
        Placement {
            position,
            estimated_start_at,
        }
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
        if let Some(postgres) = self.shared() {
            // Jobs admitted by another replica since the follower last looked.
            let missing: Vec<_> = {
                let state = lock(&self.state);
                ids.iter()
                    .filter(|id| !state.jobs.contains_key(*id))
                    .cloned()
                    .collect()
            };
            for id in missing {
                match postgres.get(&id) {
                    Ok(Some(record)) => {
                        lock(&self.state).remember(JobEntry::new(record));
                    }
                    Ok(None) => {}
                    // One unreadable row must not hide the rest of the page (the follower
                    // leaves it out too; GET of that job is the place to see the problem).
                    Err(error @ StoreError::CorruptRecord { .. }) => {
                        warn!(%error, "unreadable job record left out of a listing")
                    }
                    Err(error) => return Err(error),
                }
            }
        }
        let state = lock(&self.state);
        let records: Vec<JobRecord> = ids
            .iter()
            .filter_map(|id| state.jobs.get(id))
            .map(|entry| entry.snapshot())
            // The live state wins over a stored status a failed write left behind.
            .filter(|record| status.is_none_or(|status| record.status == status))
            .collect();
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
                    .map(|&position| self.placement_at(&state, position, now));
                (record, placement)
            })
            .collect();
        Ok((page, more))
    }

    /// The earlier job for this Idempotency-Key, if any: `Ok` when the request matches it.
    pub fn find_idempotent(
        &self,
        owner: &Option<String>,
        key: &str,
        fingerprint: &str,
    ) -> Result<Option<Arc<JobEntry>>, ApiError> {
        let state = lock(&self.state);
        let Some(entry) = state
            .idempotency
            .get(&(owner.clone(), key.to_owned()))
            .and_then(|id| state.jobs.get(id))
        else {
            return Ok(None);
        };
        let same = entry
            .record
            .borrow()
            .idempotency
            .as_ref()
            .is_some_and(|i| i.fingerprint == fingerprint);
        if same {
            Ok(Some(Arc::clone(entry)))
        } else {
            Err(ApiError::IdempotencyMismatch)
        }
    }

    /// Refuses new work of `client` when draining, when the queue is full, or when the
    /// client's queued jobs are at its limit. On the shared backend this looks at the copy;
    /// the insert checks again in the database.
    pub fn check_capacity(&self, client: &str) -> Result<(), ApiError> {
        let state = lock(&self.state);
        self.capacity_error(&state, client).map_or(Ok(()), Err)
    }

    fn capacity_error(&self, state: &State, client: &str) -> Option<ApiError> {
        if state.draining {
            return Some(ApiError::ShuttingDown);
        }
        let queued = match self.is_shared() {
            true => lock(&self.shared_depth).0,
            false => state.fair.depth().0,
        };
        if queued >= self.config.max_queued {
            return Some(self.queue_full(queued));
        }
        let limit = self.config.scheduling.limits_of(client).queued?;
        let mine = state.fair.queued_of(client);
        (mine >= limit).then(|| self.key_queue_full(state, limit, mine))
    }

    /// 429 `key-queue-full`, retry after about the time one of the key's jobs takes to start:
    /// a mean run time for each key waiting (the rule serves them in turn), shared by the
    /// workers running now.
    fn key_queue_full(&self, state: &State, limit: usize, queued: usize) -> ApiError {
        let mean = state
            .fair
            .mean_run_ms()
            .map(|ms| ms as f64 / 1000.0)
            .or_else(|| self.metrics.mean_job_seconds())
            .unwrap_or(10.0);
        let workers = state.fair.depth().1.max(self.config.workers).max(1);
        let seconds = (state.fair.keys_waiting() as f64 * mean / workers as f64)
            .ceil()
            .max(1.0);
        ApiError::KeyQueueFull {
            limit: limit as u64,
            actual: queued as u64,
            retry_after: seconds as u64,
        }
    }

    /// 503 `queue-full`, with the time for the queue ahead to clear from the mean job
    /// duration so far.
    fn queue_full(&self, queued: usize) -> ApiError {
        let mean = self.metrics.mean_job_seconds().unwrap_or(10.0);
        let seconds = (queued as f64 * mean / self.config.workers.max(1) as f64)
            .ceil()
            .max(1.0);
        ApiError::QueueFull(queued, seconds as u64)
    }

    /// Stores inputs and record, then queues the job (or replays an idempotent duplicate).
    pub fn admit(
        &self,
        record: JobRecord,
        inputs: Vec<(String, Bytes)>,
    ) -> Result<Admission, ApiError> {
        let id = record.id.clone();
        for (name, bytes) in &inputs {
            if let Err(error) = self.store().write_artefact(&id, name, bytes) {
                let _ = self.store().remove_artefacts(&id);
                return Err(error.into());
            }
        }
        let mut state = lock(&self.state);
        let refuse = |state: MutexGuard<'_, State>, error: ApiError| {
            drop(state);
            let _ = self.store().remove_artefacts(&id);
            Err(error)
        };
        if let Some(idempotency) = &record.idempotency {
            let key = (record.owner.clone(), idempotency.key.clone());
            if let Some(earlier) = state
                .idempotency
                .get(&key)
                .and_then(|earlier| state.jobs.get(earlier))
                .cloned()
            {
                let same = earlier.record.borrow().idempotency.as_ref() == Some(idempotency);
                let result = if same {
                    Ok(Admission::Replayed(earlier))
                } else {
                    Err(ApiError::IdempotencyMismatch)
                };
                drop(state);
                let _ = self.store().remove_artefacts(&id);
                return result;
            }
        }
        if let Some(postgres) = self.shared() {
            if state.draining {
                return refuse(state, ApiError::ShuttingDown);
            }
            drop(state);
            let admitted = self.admit_shared(postgres, record);
            if !matches!(admitted, Ok(Admission::Created(_))) {
                let _ = self.store().remove_artefacts(&id);
            }
            return admitted;
        }
        if let Some(error) = self.capacity_error(&state, &record.client) {
            return refuse(state, error);
        }
        if let Err(error) = self.store().save(&record) {
            return refuse(state, ApiError::from(error));
        }
        let entry = state.remember(JobEntry::new(record));
        drop(state);
        self.changed.notify_one();
        Ok(Admission::Created(entry))
    }

    /// Queues a job in the database (the unique index decides between replicas which of two
    /// submissions with one Idempotency-Key is first).
    fn admit_shared(&self, postgres: &Postgres, record: JobRecord) -> Result<Admission, ApiError> {
        let key_limit = self.config.scheduling.limits_of(&record.client).queued;
        match postgres.insert(&record, self.config.max_queued, key_limit)? {
            Inserted::Created => {
                let entry = lock(&self.state).remember(JobEntry::new(record));
                Ok(Admission::Created(entry))
            }
            Inserted::Existing(earlier) if earlier.idempotency == record.idempotency => {
                let entry = lock(&self.state).remember(JobEntry::new(*earlier));
                Ok(Admission::Replayed(entry))
            }
            Inserted::Existing(_) => Err(ApiError::IdempotencyMismatch),
            Inserted::Full(queued) => Err(self.queue_full(queued)),
            Inserted::KeyFull(queued) => {
                let limit = key_limit.unwrap_or(queued);
                Err(self.key_queue_full(&lock(&self.state), limit, queued))
            }
        }
    }

    /// Cancels a job: a queued one ends at once, a running one within one iteration.
    /// Returns whether the job was running (the cancel is then still in progress).
    pub fn cancel(&self, entry: &JobEntry) -> Result<bool, ApiError> {
        if let Some(postgres) = self.shared() {
            return self.cancel_shared(postgres, entry);
        }
        let mut state = lock(&self.state);
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
            self.config.retention,
        );
        self.save(entry)?;
        Ok(false)
    }

    /// [`Queue::cancel`] in the database: a queued job (whatever the copy says) ends there;
    /// a running one's worker stops it at its next heartbeat.
    fn cancel_shared(&self, postgres: &Postgres, entry: &JobEntry) -> Result<bool, ApiError> {
        let mut ended = entry.snapshot();
        ended.end(
            Status::Canceled,
            None,
            Some(CancelReason::User),
            self.config.retention,
        );
        let outcome = postgres.cancel(&ended)?;
        if matches!(outcome, Canceled::Ended) {
            // The follower reads the depth again within FOLLOW_EVERY; until then a job
            // submitted right after this cancel must not be refused for the room it freed.
            let mut depth = lock(&self.shared_depth);
            depth.0 = depth.0.saturating_sub(1);
        }
        let current = match outcome {
            Canceled::Ended => Some(ended),
            Canceled::Stopping | Canceled::Nothing => postgres.get(&entry.id)?,
        };
        if let Some(current) = current {
            lock(&self.state).fair.track(&current);
            entry.record.send_replace(current);
        }
        Ok(matches!(outcome, Canceled::Stopping))
    }

    /// Deletes a job: its record for good, then its files. The tombstone comes first: if it
    /// cannot be written nothing has changed (the job stays, whole); once it is, no later
    /// write brings the job back. A running job is stopped and its runner removes the files
    /// when it stops (removing them here would race the files it is still writing); files
    /// that cannot be removed are left to the orphan sweep.
    pub fn delete(&self, entry: &JobEntry) -> Result<(), ApiError> {
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
            self.remove_deleted_files(&entry.id);
        }
        Ok(())
    }

    fn remove_deleted_files(&self, id: &str) {
        if let Err(error) = self.store().remove_artefacts(id) {
            warn!(job_id = %id, "removing a deleted job's files (left to the sweep): {error}");
        }
    }

    /// Removes job directories no job owns that are older than `min_age` (see
    /// [`Store::sweep_orphans`]); returns how many.
    pub fn sweep_orphans(&self, min_age: Duration) -> usize {
        let removed = self
            .store()
            .sweep_orphans(min_age, |id| lock(&self.state).jobs.contains_key(id));
        self.metrics.orphans_swept(removed);
        removed
    }

    /// Removes the results of jobs whose retention has passed; returns how many.
    pub fn expire(&self, now: u64) -> usize {
        let expired: Vec<_> = lock(&self.state)
            .jobs
            .values()
            .filter(|entry| {
                let record = entry.record.borrow();
                !record.data_removed && record.expires_at.is_some_and(|expires| expires <= now)
            })
            .cloned()
            .collect();
        for entry in &expired {
            let _span = info_span!("expire", job_id = %entry.id).entered();
            if let Err(error) = self.store().remove_artefacts(&entry.id) {
                warn!("removing expired results: {error}");
                continue;
            }
            entry
                .record
                .send_modify(|record| record.data_removed = true);
            if let Err(error) = self.store().save(&entry.snapshot()) {
                warn!("saving expired job: {error}");
            }
        }
        if let Some(postgres) = self.shared()
            && let Err(error) = postgres.purge_tombstones(TOMBSTONE_AGE)
        {
            warn!("purging deleted jobs: {error}");
        }
        expired.len()
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
            for entry in state.jobs.values() {
                if entry.record.borrow().status == Status::Running {
                    entry.request_cancel(CancelReason::Shutdown);
                }
            }
        }
        drop(state);
        if let Some(workers) = &self.workers {
            workers.drain(deadline.saturating_duration_since(Instant::now()));
        }
        for handle in lock(&self.runners).drain(..) {
            let _ = handle.join();
        }
    }

    /// A runner thread: takes queued jobs by the fair rule until draining.
    fn run_jobs(self: Arc<Self>, pool: &rayon::ThreadPool) {
        loop {
            let mut state = lock(&self.state);
            let id = loop {
                if state.draining {
                    break None;
                }
                if let Some(id) = state.fair.next(&self.config.scheduling, now_ms()) {
                    break Some(id);
                }
                // Nothing queued, or only keys at their running limit: a submission or a
                // job's end changes that.
                state = self.changed.wait(state).unwrap_or_else(|p| p.into_inner());
            };
            let Some(id) = id else {
                break;
            };
            let Some(entry) = state.jobs.get(&id).cloned() else {
                state.fair.forget(&id);
                continue;
            };
            state.running += 1;
            // Marked running under the queue lock, so `cancel` never sees a job that is
            // neither queued nor running.
            entry.record.send_modify(|record| {
                record.status = Status::Running;
                record.started_at = Some(now_ms());
            });
            let client = entry.record.borrow().client.clone();
            state.fair.track(&entry.record.borrow());
            state.fair.serve(&client);
            drop(state);
            self.run_job(&entry, pool);
            // Under the lock `delete` reads the status with: either it saw the job running and
            // the files are removed here, or it saw the job ended and removed them itself.
            let deleted = {
                let mut state = lock(&self.state);
                state.running -= 1;
                let deleted = entry.deleted.load(Ordering::SeqCst);
                if !deleted {
                    // Ended, or queued again by a shutdown.
                    state.fair.track(&entry.record.borrow());
                }
                deleted
            };
            if deleted {
                self.remove_deleted_files(&entry.id);
            }
            self.changed.notify_all();
        }
        self.runners_alive.fetch_sub(1, Ordering::SeqCst);
    }

    fn run_job(&self, entry: &Arc<JobEntry>, pool: &rayon::ThreadPool) {
        let _span = info_span!("job", job_id = %entry.id).entered();
        if let Err(error) = retry_transient("saving running state", || {
            self.store().save(&entry.snapshot())
        }) {
            warn!("saving running state: {error}");
        }
        // Saved as queued when interrupted: the next start runs it again.
        if self.runner.run(entry, pool) != Settled::Deleted
            && let Err(error) = self.save(entry)
        {
            warn!("saving the outcome: {error}");
        }
    }

    /// Persists a job's record, retrying transient failures.
    fn save(&self, entry: &JobEntry) -> Result<(), ApiError> {
        retry_transient("saving the job", || self.store().save(&entry.snapshot()))
            .map_err(ApiError::from)
    }

    /// A stored file of a job, checked against the digest recorded when it was written: in the
    /// job's record for its results, in its folder's digests for an edit's files (a file cut
    /// short or altered on disk is an error, never served as if whole).
    pub fn read_result(&self, id: &str, name: &str) -> Result<Option<Vec<u8>>, ApiError> {
        let recorded = lock(&self.state)
            .jobs
            .get(id)
            .and_then(|entry| entry.record.borrow().checksums.get(name).cloned());
        let expected = match recorded {
            Some(digest) => Some(digest),
            None => match self.store().folder_digest(id, name) {
                Ok(digest) => digest,
                Err(error @ StoreError::CorruptRecord { .. }) => {
                    tracing::error!(job_id = %id, name, %error, "unreadable digests");
                    return Err(ApiError::CorruptResult(name.to_owned()));
                }
                Err(error) => return Err(error.into()),
            },
        };
        let bytes = self.store().read_artefact(id, name)?;
        if let (Some(bytes), Some(expected)) = (&bytes, expected)
            && digest(bytes) != expected
        {
            tracing::error!(job_id = %id, name, "a stored result does not match its digest");
            return Err(ApiError::CorruptResult(name.to_owned()));
        }
        Ok(bytes)
    }
}
