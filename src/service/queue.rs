//! The job queue and its workers.
//!
//! Live job state is held in memory (one `watch` channel per job, so polls and SSE streams read
//! it without touching the database): the queued and running jobs, and ended jobs only while
//! something holds them (an event stream, a webhook delivery, a request). Every other record is
//! read from the [`Store`] when asked for, so memory does not grow with the jobs ever run, and
//! records are deleted after the record retention ([`Queue::expire`]). On the embedded backend
//! live state is written through to the store on every status change. On the shared backend
//! (PostgreSQL) the database is the truth and the memory a copy: the queue, leases and
//! idempotency keys are rows, jobs run in [`Workers`] (here or in `covec worker` processes),
//! and a follower thread brings every change made anywhere to the jobs in the copy (and the
//! queued and running jobs into it) every [`FOLLOW_EVERY`], so polls, listings and SSE on any
//! replica see jobs running on any worker.
//!
//! Embedded: `workers` runner threads take queued jobs by the fair rule ([`super::fair`]);
//! each runs its job's pipeline inside its own rayon pool (`threads / workers` threads), so the
//! async runtime never runs pipeline work. One pool per job slot rather than one shared pool:
//! in a shared pool a thread waiting inside one job's parallel loop may pick up another whole
//! job (rayon work-stealing), stalling the first job, and its cancellation, until the second
//! ends.

use std::collections::{BTreeMap, HashMap};
use std::sync::Weak;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime};

use tracing::{info, info_span, warn};

use super::fair::{FairQueue, Scheduling};
use super::inputs::{EncodedInputs, InputLimits};
use super::model::{CancelReason, JobRecord, Placement, Status, Webhook, now_ms};
use super::runner::{JobEntry, Runner, Settled, job_pool, lock};
use super::store::{
    Canceled, Change, Inserted, Postgres, Store, StoreError, digest, retry_transient,
};
use super::telemetry::Metrics;
use super::worker::{DEFAULT_LEASE, REAP_EVERY, WorkerConfig, WorkerError, Workers, reap_expired};

/// How often an API replica on the shared backend brings other processes' changes into its
/// copy of the jobs (and reads the queue depth): what SSE and polls lag behind a worker.
pub const FOLLOW_EVERY: Duration = Duration::from_millis(200);

/// How long a deleted job's row stays on the shared backend (so workers and replicas see the
/// delete) before it is purged.
const TOMBSTONE_AGE: Duration = Duration::from_secs(3600);

/// Most records one statement of [`Queue::expire`] handles: its transaction stays short, and a
/// backlog (a server stopped for days) is worked off in batches.
const EXPIRY_BATCH: usize = 1000;

/// Ended jobs held in memory below which [`State::hold`] does not look for released ones.
const HELD_PRUNE_MIN: usize = 256;

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

struct State {
    /// The queued and running jobs by id (ids sort by creation time).
    live: BTreeMap<String, Arc<JobEntry>>,
    /// Ended jobs by id while something holds their entry, so every holder shares one (a
    /// webhook delivery's record changes reach a poll); released ones are pruned in
    /// [`State::hold`].
    held: HashMap<String, Weak<JobEntry>>,
    /// `held`'s size at which it is next pruned: twice its size after the last pruning, so
    /// pruning costs O(1) per entry and `held` stays within twice the entries in use.
    prune_at: usize,
    /// The queued and running jobs, by key: the queue itself on the embedded backend, a copy
    /// of the database's for queue positions on the shared one.
    fair: FairQueue,
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
    /// The job's entry, if it is live or held.
    fn get(&self, id: &str) -> Option<Arc<JobEntry>> {
        self.live
            .get(id)
            .cloned()
            .or_else(|| self.held.get(id).and_then(Weak::upgrade))
    }

    /// Adds a job to those known (unless it is known already: then that entry).
    fn remember(&mut self, entry: Arc<JobEntry>) -> Arc<JobEntry> {
        if let Some(known) = self.get(&entry.id) {
            return known;
        }
        self.file(&entry);
        entry
    }

    /// Files a known job by its status: a queued or running one is kept, an ended one only
    /// referred to for as long as something holds it.
    fn file(&mut self, entry: &Arc<JobEntry>) {
        let ended = {
            let record = entry.record.borrow();
            self.fair.track(&record);
            record.status.is_terminal()
        };
        if ended {
            self.live.remove(&entry.id);
            self.hold(entry);
        } else {
            self.held.remove(&entry.id);
            self.live.insert(entry.id.clone(), Arc::clone(entry));
        }
    }

    fn hold(&mut self, entry: &Arc<JobEntry>) {
        if self.held.len() >= self.prune_at {
            self.held.retain(|_, held| held.strong_count() > 0);
            self.prune_at = (2 * self.held.len()).max(HELD_PRUNE_MIN);
        }
        self.held.insert(entry.id.clone(), Arc::downgrade(entry));
    }

    /// Drops a deleted (or expired) job from those known; whoever still holds its entry sees
    /// it marked deleted.
    fn forget(&mut self, id: &str) {
        self.fair.forget(id);
        let entry = self.live.remove(id).or_else(|| {
            let held = self.held.remove(id)?;
            held.upgrade()
        });
        if let Some(entry) = entry {
            entry.deleted.store(true, Ordering::SeqCst);
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
    #[error(transparent)]
    Workers(#[from] WorkerError),
}

impl Queue {
    /// Loads the queued and running jobs, queued again (a run cut short by the stop starts
    /// over), and starts the runners. Call from inside the tokio runtime.
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
            live: BTreeMap::new(),
            held: HashMap::new(),
            prune_at: HELD_PRUNE_MIN,
            fair: FairQueue::default(),
            running: 0,
            draining: false,
        };
        if !shared {
            let recovered = store.recover()?;
            metrics.quarantined(recovered.quarantined.len());
            for mut record in recovered.records {
                info!(job_id = %record.id, "re-queued after restart");
                record.requeue();
                store.remove_outputs(&record.id)?;
                store.save(&record)?;
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
                Change::Live(record) => match state.get(&record.id) {
                    Some(entry) => {
                        entry.record.send_if_modified(|current| {
                            let mut record = *record;
                            // Deliveries are made here by this copy: the stored ones may lag.
                            if webhook_progress(&current.webhook)
                                > webhook_progress(&record.webhook)
                            {
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
                if !self.is_shared() {
                    self.metrics.quarantined(1);
                }
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

    /// Embedded backend: the jobs whose webhook deliveries are unfinished, oldest first (to
    /// resume them after a start). Records marked so whose deliveries are all done lose the
    /// mark.
    pub fn unfinished_webhooks(&self) -> Result<Vec<Arc<JobEntry>>, StoreError> {
        let mut entries = Vec::new();
        for record in self.store().webhooks_pending()? {
            if record.webhook.as_ref().is_some_and(Webhook::unfinished) {
                entries.push(lock(&self.state).remember(JobEntry::new(record)));
            } else {
                self.store().save(&record)?;
            }
        }
        Ok(entries)
    }

    /// How many jobs are held in memory: the live ones and the ended ones in use.
    pub fn in_memory(&self) -> usize {
        let state = lock(&self.state);
        let held = state.held.values().filter(|held| held.strong_count() > 0);
        state.live.len() + held.count()
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
                    .map(|&position| self.placement_at(&state, position, now));
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
        let Some(earlier) = self.store().idempotent(owner, key, self.keys_since())? else {
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

    /// Creation time (Unix ms) from which Idempotency-Keys still hold.
    fn keys_since(&self) -> u64 {
        now_ms().saturating_sub(self.config.idempotency_window.as_millis() as u64)
    }

    /// Refuses new work of `client` when draining, when the queue is full, or when the
    /// client's queued jobs are at its limit. On the shared backend this looks at the copy;
    /// the insert checks again in the database.
    pub fn check_capacity(&self, client: &str) -> Result<(), Refusal> {
        let state = lock(&self.state);
        self.capacity_error(&state, client).map_or(Ok(()), Err)
    }

    fn capacity_error(&self, state: &State, client: &str) -> Option<Refusal> {
        if state.draining {
            return Some(Refusal::ShuttingDown);
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
    fn key_queue_full(&self, state: &State, limit: usize, queued: usize) -> Refusal {
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
        Refusal::KeyQueueFull {
            limit: limit as u64,
            actual: queued as u64,
            retry_after: seconds as u64,
        }
    }

    /// 503 `queue-full`, with the time for the queue ahead to clear from the mean job
    /// duration so far.
    fn queue_full(&self, queued: usize) -> Refusal {
        let mean = self.metrics.mean_job_seconds().unwrap_or(10.0);
        let seconds = (queued as f64 * mean / self.config.workers.max(1) as f64)
            .ceil()
            .max(1.0);
        Refusal::QueueFull {
            queued,
            retry_after: seconds as u64,
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
        let mut state = lock(&self.state);
        let refuse = |state: MutexGuard<'_, State>, error: Refusal| {
            drop(state);
            let _ = self.store().remove_artefacts(&id);
            Err(error)
        };
        if let Some(postgres) = self.shared() {
            if state.draining {
                return refuse(state, Refusal::ShuttingDown);
            }
            drop(state);
            let admitted = self.admit_shared(postgres, record);
            if !matches!(admitted, Ok(Admission::Created(_))) {
                let _ = self.store().remove_artefacts(&id);
            }
            return admitted;
        }
        // Looked up under the queue lock, so of two submissions with one key only the first
        // is admitted.
        if let Some(idempotency) = &record.idempotency {
            let earlier =
                match self
                    .store()
                    .idempotent(&record.owner, &idempotency.key, self.keys_since())
                {
                    Ok(earlier) => earlier,
                    Err(error) => return refuse(state, error.into()),
                };
            if let Some(earlier) = earlier {
                let result = if earlier.idempotency.as_ref() == Some(idempotency) {
                    Ok(Admission::Replayed(state.remember(JobEntry::new(earlier))))
                } else {
                    Err(Refusal::IdempotencyMismatch)
                };
                drop(state);
                let _ = self.store().remove_artefacts(&id);
                return result;
            }
        }
        if let Some(error) = self.capacity_error(&state, &record.client) {
            return refuse(state, error);
        }
        if let Err(error) = self.store().save(&record) {
            return refuse(state, Refusal::from(error));
        }
        let entry = state.remember(JobEntry::new(record));
        drop(state);
        self.changed.notify_one();
        Ok(Admission::Created(entry))
    }

    /// Queues a job in the database (the unique index decides between replicas which of two
    /// submissions with one Idempotency-Key is first).
    fn admit_shared(&self, postgres: &Postgres, record: JobRecord) -> Result<Admission, Refusal> {
        let key_limit = self.config.scheduling.limits_of(&record.client).queued;
        match postgres.insert(
            &record,
            self.config.max_queued,
            key_limit,
            self.keys_since(),
        )? {
            Inserted::Created => {
                let entry = lock(&self.state).remember(JobEntry::new(record));
                Ok(Admission::Created(entry))
            }
            Inserted::Existing(earlier) if earlier.idempotency == record.idempotency => {
                let entry = lock(&self.state).remember(JobEntry::new(*earlier));
                Ok(Admission::Replayed(entry))
            }
            Inserted::Existing(_) => Err(Refusal::IdempotencyMismatch),
            Inserted::Full(queued) => Err(self.queue_full(queued)),
            Inserted::KeyFull(queued) => {
                let limit = key_limit.unwrap_or(queued);
                Err(self.key_queue_full(&lock(&self.state), limit, queued))
            }
        }
    }

    /// Cancels a job: a queued one ends at once, a running one within one iteration.
    /// Returns whether the job was running (the cancel is then still in progress).
    pub fn cancel(&self, entry: &Arc<JobEntry>) -> Result<bool, Refusal> {
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
        let saved = self.save(entry);
        lock(&self.state).file(entry);
        saved.map(|()| false)
    }

    /// [`Queue::cancel`] in the database: a queued job (whatever the copy says) ends there;
    /// a running one's worker stops it at its next heartbeat.
    fn cancel_shared(&self, postgres: &Postgres, entry: &Arc<JobEntry>) -> Result<bool, Refusal> {
        let mut ended = entry.snapshot();
        ended.end(
            Status::Canceled,
            None,
            Some(CancelReason::User),
            self.config.retention,
        );
        let outcome = postgres.cancel(&ended)?;
        if matches!(outcome, Canceled::Ended) {
            info!(job_id = %entry.id, "canceled while queued");
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
            entry.record.send_replace(current);
            lock(&self.state).file(entry);
        }
        Ok(matches!(outcome, Canceled::Stopping))
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
                    self.save(&entry)
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
        self.expire_records(now);
        if let Err(error) = self.store().drop_idempotency_keys(self.keys_since()) {
            warn!("removing expired idempotency keys: {error}");
        }
        if let Some(postgres) = self.shared()
            && let Err(error) = postgres.purge_tombstones(TOMBSTONE_AGE)
        {
            warn!("purging deleted jobs: {error}");
        }
        removed
    }

    /// Deletes the records of jobs that ended more than the record retention ago (their files
    /// too, if any are left), and forgets the expired ids kept as long again.
    fn expire_records(&self, now: u64) {
        let cutoff = now.saturating_sub(self.config.record_retention.as_millis() as u64);
        loop {
            let expired = match self.store().expire_records(cutoff, cutoff, EXPIRY_BATCH) {
                Ok(expired) => expired,
                Err(error) => {
                    warn!("deleting expired job records: {error}");
                    return;
                }
            };
            for id in &expired {
                lock(&self.state).forget(id);
                self.remove_deleted_files(id);
            }
            if !expired.is_empty() {
                info!(records = expired.len(), "expired job records deleted");
            }
            if expired.len() < EXPIRY_BATCH {
                return;
            }
        }
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
            let Some(entry) = state.live.get(&id).cloned() else {
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
                    state.file(&entry);
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
    fn save(&self, entry: &JobEntry) -> Result<(), Refusal> {
        retry_transient("saving the job", || self.store().save(&entry.snapshot()))
            .map_err(Refusal::from)
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
