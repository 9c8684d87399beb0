//! The job queue and its workers.
//!
//! Live job state is held in memory (one `watch` channel per job, so polls and SSE streams read
//! it without touching the database) and written through to the [`Store`] on every status
//! change. `workers` runner threads take queued jobs in order; each runs its job's pipeline
//! inside its own rayon pool (`threads / workers` threads), so the async runtime never runs
//! pipeline work. One pool per job slot rather than one shared pool: in a shared pool a thread
//! waiting inside one job's parallel loop may pick up another whole job (rayon work-stealing),
//! stalling the first job, and its cancellation, until the second ends.

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::panic::AssertUnwindSafe;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use axum::body::Bytes;
use tokio::sync::watch;
use tracing::{info, info_span, warn};

use super::error::ApiError;
use super::model::{CancelReason, JobRecord, ProgressView, Status, now_ms};
use super::ops::Metrics;
use super::store::{Store, StoreError, digest, retry_transient};
use super::submit::{InputLimits, decode_inputs, input_error};
use crate::pipeline::{self, Observer, Progress};
use crate::render::Image;

/// Age after which a job directory without a job is swept while the server runs: far longer
/// than a submission takes between writing its files and its record.
pub const ORPHAN_AGE: Duration = Duration::from_secs(600);

/// Queue and worker settings.
#[derive(Clone, Debug)]
pub struct QueueConfig {
    /// Jobs run at once. Default 1 (one job uses every thread).
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
}

impl Default for QueueConfig {
    fn default() -> Self {
        Self {
            workers: 1,
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
            max_queued: 64,
            job_time_limit: Duration::from_secs(600),
            retention: Duration::from_secs(24 * 3600),
        }
    }
}

/// One job's live state.
pub struct JobEntry {
    pub id: String,
    pub owner: Option<String>,
    /// The current record; every change is broadcast to `/events` subscribers.
    pub record: watch::Sender<JobRecord>,
    cancel: AtomicBool,
    cancel_reason: Mutex<Option<CancelReason>>,
    deleted: AtomicBool,
}

impl JobEntry {
    fn new(record: JobRecord) -> Arc<Self> {
        Arc::new(Self {
            id: record.id.clone(),
            owner: record.owner.clone(),
            record: watch::Sender::new(record),
            cancel: AtomicBool::new(false),
            cancel_reason: Mutex::new(None),
            deleted: AtomicBool::new(false),
        })
    }

    pub fn snapshot(&self) -> JobRecord {
        self.record.borrow().clone()
    }

    /// Asks a running pipeline to stop; the first reason wins.
    fn request_cancel(&self, reason: CancelReason) {
        let mut current = lock(&self.cancel_reason);
        current.get_or_insert(reason);
        self.cancel.store(true, Ordering::Relaxed);
        self.record
            .send_modify(|record| record.cancel_requested = true);
    }
}

struct State {
    /// Every known job by id (ids sort by creation time).
    jobs: BTreeMap<String, Arc<JobEntry>>,
    pending: VecDeque<String>,
    /// (owner, key) → job id.
    idempotency: HashMap<(Option<String>, String), String>,
    running: usize,
    draining: bool,
}

pub struct Queue {
    config: QueueConfig,
    limits: InputLimits,
    store: Arc<Store>,
    metrics: Arc<Metrics>,
    runtime: tokio::runtime::Handle,
    /// [`InputLimits::decode_slots`], shared by the requests that decode a submission and the
    /// runners that decode a job's stored inputs: both hold a full-size decode in memory, so
    /// both count against one bound.
    decode_slots: Arc<tokio::sync::Semaphore>,
    state: Mutex<State>,
    /// Signalled when a job is queued, a job ends, or draining starts.
    changed: Condvar,
    runners_alive: AtomicUsize,
    runners: Mutex<Vec<JoinHandle<()>>>,
}

/// A page of a listing: each job with its queue position while queued.
pub type Page = Vec<(JobRecord, Option<usize>)>;

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
}

fn lock<T>(mutex: &Mutex<T>) -> MutexGuard<'_, T> {
    mutex
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
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
        let workers = config.workers.max(1);
        let threads_per_job = (config.threads / workers).max(1);
        let mut state = State {
            jobs: BTreeMap::new(),
            pending: VecDeque::new(),
            idempotency: HashMap::new(),
            running: 0,
            draining: false,
        };
        let decode_slots = Arc::new(tokio::sync::Semaphore::new(limits.decode_slots.max(1)));
        let recovered = store.recover()?;
        metrics.set_quarantined(recovered.quarantined.len());
        for mut record in recovered.records {
            if !record.status.is_terminal() {
                info!(job_id = %record.id, "re-queued after restart");
                record.status = Status::Queued;
                record.started_at = None;
                record.progress = None;
                record.cancel_requested = false;
                record.previews.clear();
                store.remove_outputs(&record.id)?;
                store.save(&record)?;
                state.pending.push_back(record.id.clone());
            }
            if let Some(idempotency) = &record.idempotency {
                state.idempotency.insert(
                    (record.owner.clone(), idempotency.key.clone()),
                    record.id.clone(),
                );
            }
            state.jobs.insert(record.id.clone(), JobEntry::new(record));
        }
        let queue = Arc::new(Self {
            config: QueueConfig { workers, ..config },
            limits,
            store,
            metrics,
            runtime: tokio::runtime::Handle::current(),
            decode_slots,
            state: Mutex::new(state),
            changed: Condvar::new(),
            runners_alive: AtomicUsize::new(0),
            runners: Mutex::new(Vec::new()),
        });
        // Nothing is being admitted yet: every directory without a record is an orphan.
        let swept = queue.sweep_orphans(Duration::ZERO);
        if swept > 0 {
            info!(swept, "orphaned job directories removed at start");
        }
        for index in 0..workers {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads_per_job)
                .thread_name(move |thread| format!("covec-pipeline-{index}-{thread}"))
                .start_handler(|_| lower_thread_priority())
                .build()?;
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

    pub fn workers(&self) -> usize {
        self.config.workers
    }

    /// The decode slots (see the field).
    pub fn decode_slots(&self) -> Arc<tokio::sync::Semaphore> {
        Arc::clone(&self.decode_slots)
    }

    pub fn store(&self) -> &Store {
        &self.store
    }

    /// (queued, running) job counts.
    pub fn depth(&self) -> (usize, usize) {
        let state = lock(&self.state);
        (state.pending.len(), state.running)
    }

    /// Ready to take work: not draining and every runner alive.
    pub fn is_ready(&self) -> bool {
        !lock(&self.state).draining
            && self.runners_alive.load(Ordering::SeqCst) == self.config.workers
    }

    /// The job, if it exists and `owner` may see it.
    pub fn get(&self, id: &str, owner: &Option<String>) -> Option<Arc<JobEntry>> {
        lock(&self.state)
            .jobs
            .get(id)
            .filter(|entry| &entry.owner == owner)
            .cloned()
    }

    /// Every job, oldest first (for work resumed after a restart, such as webhook deliveries).
    pub fn entries(&self) -> Vec<Arc<JobEntry>> {
        lock(&self.state).jobs.values().cloned().collect()
    }

    /// Jobs ahead of this one, while it is queued.
    pub fn queue_position(&self, id: &str) -> Option<usize> {
        lock(&self.state)
            .pending
            .iter()
            .position(|queued| queued == id)
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
        let mut ids = self.store.list_ids(owner, status, before, limit + 1)?;
        let more = ids.len() > limit;
        ids.truncate(limit);
        let state = lock(&self.state);
        let page = ids
            .iter()
            .filter_map(|id| state.jobs.get(id))
            .map(|entry| entry.snapshot())
            // The live state wins over a stored status a failed write left behind.
            .filter(|record| status.is_none_or(|status| record.status == status))
            .map(|record| {
                let position = state.pending.iter().position(|queued| *queued == record.id);
                (record, position)
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

    /// Refuses new work when draining or full.
    pub fn check_capacity(&self) -> Result<(), ApiError> {
        let state = lock(&self.state);
        self.capacity_error(&state).map_or(Ok(()), Err)
    }

    fn capacity_error(&self, state: &State) -> Option<ApiError> {
        if state.draining {
            return Some(ApiError::ShuttingDown);
        }
        if state.pending.len() >= self.config.max_queued {
            // Time for the queue ahead to clear, from the mean job duration so far.
            let mean = self.metrics.mean_job_seconds().unwrap_or(10.0);
            let seconds = (state.pending.len() as f64 * mean / self.config.workers as f64)
                .ceil()
                .max(1.0);
            return Some(ApiError::QueueFull(state.pending.len(), seconds as u64));
        }
        None
    }

    /// Stores inputs and record, then queues the job (or replays an idempotent duplicate).
    pub fn admit(
        &self,
        record: JobRecord,
        inputs: Vec<(String, Bytes)>,
    ) -> Result<Admission, ApiError> {
        let id = record.id.clone();
        for (name, bytes) in &inputs {
            if let Err(error) = self.store.write_artefact(&id, name, bytes) {
                let _ = self.store.remove_artefacts(&id);
                return Err(error.into());
            }
        }
        let mut state = lock(&self.state);
        let refuse = |state: MutexGuard<'_, State>, error: ApiError| {
            drop(state);
            let _ = self.store.remove_artefacts(&id);
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
                let _ = self.store.remove_artefacts(&id);
                return result;
            }
        }
        if let Some(error) = self.capacity_error(&state) {
            return refuse(state, error);
        }
        if let Err(error) = self.store.save(&record) {
            return refuse(state, ApiError::from(error));
        }
        if let Some(idempotency) = &record.idempotency {
            state
                .idempotency
                .insert((record.owner.clone(), idempotency.key.clone()), id.clone());
        }
        let entry = JobEntry::new(record);
        state.jobs.insert(id.clone(), Arc::clone(&entry));
        state.pending.push_back(id);
        drop(state);
        self.changed.notify_one();
        Ok(Admission::Created(entry))
    }

    /// Cancels a job: a queued one ends at once, a running one within one iteration.
    /// Returns whether the job was running (the cancel is then still in progress).
    pub fn cancel(&self, entry: &JobEntry) -> Result<bool, ApiError> {
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
        state.pending.retain(|queued| *queued != entry.id);
        drop(state);
        self.finish(entry, Status::Canceled, None, Some(CancelReason::User))?;
        Ok(false)
    }

    /// Deletes a job: its record for good, then its files. The tombstone comes first: if it
    /// cannot be written nothing has changed (the job stays, whole); once it is, no later
    /// write brings the job back. A running job is stopped and its runner removes the files
    /// when it stops (removing them here would race the files it is still writing); files
    /// that cannot be removed are left to the orphan sweep.
    pub fn delete(&self, entry: &JobEntry) -> Result<(), ApiError> {
        self.store.tombstone(&entry.id)?;
        let mut state = lock(&self.state);
        entry.deleted.store(true, Ordering::SeqCst);
        let running = entry.record.borrow().status == Status::Running;
        entry.request_cancel(CancelReason::User);
        state.pending.retain(|queued| *queued != entry.id);
        state.jobs.remove(&entry.id);
        if let Some(idempotency) = &entry.record.borrow().idempotency {
            state
                .idempotency
                .remove(&(entry.owner.clone(), idempotency.key.clone()));
        }
        drop(state);
        if !running {
            self.remove_deleted_files(&entry.id);
        }
        Ok(())
    }

    fn remove_deleted_files(&self, id: &str) {
        if let Err(error) = self.store.remove_artefacts(id) {
            warn!(job_id = %id, "removing a deleted job's files (left to the sweep): {error}");
        }
    }

    /// Removes job directories no job owns that are older than `min_age` (see
    /// [`Store::sweep_orphans`]); returns how many.
    pub fn sweep_orphans(&self, min_age: Duration) -> usize {
        let removed = self
            .store
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
            if let Err(error) = self.store.remove_artefacts(&entry.id) {
                warn!("removing expired results: {error}");
                continue;
            }
            entry
                .record
                .send_modify(|record| record.data_removed = true);
            if let Err(error) = self.store.save(&entry.snapshot()) {
                warn!("saving expired job: {error}");
            }
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
        for handle in lock(&self.runners).drain(..) {
            let _ = handle.join();
        }
    }

    /// A runner thread: takes queued jobs in order until draining.
    fn run_jobs(self: Arc<Self>, pool: &rayon::ThreadPool) {
        loop {
            let mut state = lock(&self.state);
            while state.pending.is_empty() && !state.draining {
                state = self.changed.wait(state).unwrap_or_else(|p| p.into_inner());
            }
            if state.draining {
                break;
            }
            let id = state.pending.pop_front().expect("checked non-empty");
            let Some(entry) = state.jobs.get(&id).cloned() else {
                continue;
            };
            state.running += 1;
            // Marked running under the queue lock, so `cancel` never sees a job that is
            // neither pending nor running.
            entry.record.send_modify(|record| {
                record.status = Status::Running;
                record.started_at = Some(now_ms());
            });
            drop(state);
            self.run_job(&entry, pool);
            // Under the lock `delete` reads the status with: either it saw the job running and
            // the files are removed here, or it saw the job ended and removed them itself.
            let deleted = {
                let mut state = lock(&self.state);
                state.running -= 1;
                entry.deleted.load(Ordering::SeqCst)
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
        let started = Instant::now();
        if let Err(error) = retry_transient("saving running state", || {
            self.store.save(&entry.snapshot())
        }) {
            warn!("saving running state: {error}");
        }
        info!("started");
        let outcome = self.execute(entry, pool);
        if entry.deleted.load(Ordering::SeqCst) {
            info!("deleted while running");
            return;
        }
        let label = match &outcome {
            Outcome::Succeeded(_) => "succeeded",
            Outcome::Failed(_) => "failed",
            Outcome::Canceled => "canceled",
            Outcome::Interrupted => "interrupted",
        };
        self.metrics.job_finished(label, started.elapsed());
        info!(
            outcome = label,
            seconds = started.elapsed().as_secs_f32(),
            "finished"
        );
        let saved = match outcome {
            Outcome::Succeeded(mode) => {
                entry.record.send_modify(|record| record.mode = Some(mode));
                self.finish(entry, Status::Succeeded, None, None)
            }
            Outcome::Failed(error) => self.finish(
                entry,
                Status::Failed,
                Some(error),
                *lock(&entry.cancel_reason),
            ),
            Outcome::Canceled => {
                self.finish(entry, Status::Canceled, None, Some(CancelReason::User))
            }
            Outcome::Interrupted => {
                // Saved as queued: the next start runs it again.
                entry.record.send_modify(|record| {
                    record.status = Status::Queued;
                    record.started_at = None;
                    record.progress = None;
                    record.cancel_requested = false;
                });
                retry_transient("saving an interrupted job", || {
                    self.store.save(&entry.snapshot())
                })
                .map_err(ApiError::from)
            }
        };
        if let Err(error) = saved {
            warn!("saving the outcome: {error}");
        }
    }

    /// Marks a job terminal and persists it.
    fn finish(
        &self,
        entry: &JobEntry,
        status: Status,
        error: Option<ApiError>,
        reason: Option<CancelReason>,
    ) -> Result<(), ApiError> {
        let now = now_ms();
        entry.record.send_modify(|record| {
            record.status = status;
            record.completed_at = Some(now);
            record.expires_at = Some(now + self.config.retention.as_millis() as u64);
            record.error = error.as_ref().map(ApiError::problem);
            record.cancel_reason = reason;
        });
        retry_transient("saving the outcome", || self.store.save(&entry.snapshot()))
            .map_err(ApiError::from)
    }

    fn execute(&self, entry: &Arc<JobEntry>, pool: &rayon::ThreadPool) -> Outcome {
        let record = entry.snapshot();
        let read = |name: &str| {
            retry_transient("reading the job's inputs", || {
                self.store.read_artefact(&entry.id, name)
            })
        };
        let inputs = (|| {
            let missing = || ApiError::Internal("the job's input files are missing".into());
            let image = read("input/image")
                .map_err(ApiError::from)?
                .ok_or_else(missing)?;
            let albedo = if record.inputs.albedo {
                Some(
                    read("input/albedo")
                        .map_err(ApiError::from)?
                        .ok_or_else(missing)?,
                )
            } else {
                None
            };
            let labels = if record.inputs.labels {
                Some(
                    read("input/labels")
                        .map_err(ApiError::from)?
                        .ok_or_else(missing)?,
                )
            } else {
                None
            };
            let masks = (0..record.inputs.masks)
                .map(|index| {
                    Ok(Bytes::from(
                        read(&format!("input/mask-{index}"))
                            .map_err(ApiError::from)?
                            .ok_or_else(missing)?,
                    ))
                })
                .collect::<Result<Vec<_>, ApiError>>()?;
            // A runner waits for its slot as long as it takes (the semaphore is never closed).
            let _slot = self
                .runtime
                .block_on(Arc::clone(&self.decode_slots).acquire_owned());
            decode_inputs(
                &image,
                albedo.as_deref(),
                &masks,
                labels.as_deref(),
                &self.limits,
                record.inputs.accept_truncated,
            )
        })();
        let inputs = match inputs {
            Ok(inputs) => inputs,
            Err(error) => return Outcome::Failed(error),
        };
        let deadline = {
            let (limit, entry) = (self.config.job_time_limit, Arc::clone(entry));
            self.runtime.spawn(async move {
                tokio::time::sleep(limit).await;
                entry.request_cancel(CancelReason::Deadline);
            })
        };
        let observer = JobObserver {
            store: &self.store,
            entry,
        };
        let result = std::panic::catch_unwind(AssertUnwindSafe(|| {
            pool.install(|| pipeline::run(&inputs, &record.params, &observer, &entry.cancel))
        }));
        deadline.abort();
        match result {
            Ok(Ok(output)) => match self.write_results(entry, &output) {
                Ok(()) => Outcome::Succeeded(output.mode.into()),
                Err(error) => Outcome::Failed(ApiError::from(error)),
            },
            Ok(Err(pipeline::Error::Canceled)) => match *lock(&entry.cancel_reason) {
                Some(CancelReason::Deadline) => {
                    Outcome::Failed(ApiError::TimeLimit(self.config.job_time_limit.as_secs()))
                }
                Some(CancelReason::Shutdown) => Outcome::Interrupted,
                Some(CancelReason::User) | None => Outcome::Canceled,
            },
            Ok(Err(pipeline::Error::Input(error))) => Outcome::Failed(input_error("inputs")(error)),
            Ok(Err(pipeline::Error::Params(message))) => {
                Outcome::Failed(ApiError::InvalidParams(message))
            }
            Ok(Err(pipeline::Error::Internal(message))) => {
                warn!(job_id = %entry.id, "internal error in the pipeline: {message}");
                Outcome::Failed(ApiError::Internal(message))
            }
            Err(panic) => {
                let message = panic
                    .downcast_ref::<&str>()
                    .map(|s| s.to_string())
                    .or_else(|| panic.downcast_ref::<String>().cloned())
                    .unwrap_or_else(|| "panic".into());
                Outcome::Failed(ApiError::PipelineCrashed(message))
            }
        }
    }

    /// The run's files, in [`pipeline::Output::artefacts`] order (`result.svg` last), with
    /// their digests in the record (saved when the job is marked succeeded).
    fn write_results(&self, entry: &JobEntry, output: &pipeline::Output) -> Result<(), StoreError> {
        let mut checksums = BTreeMap::new();
        for artefact in output.artefacts() {
            let name = artefact.kind.name();
            retry_transient("writing the results", || {
                self.store.write_artefact(&entry.id, &name, &artefact.bytes)
            })?;
            checksums.insert(name, digest(&artefact.bytes));
        }
        entry
            .record
            .send_modify(|record| record.checksums = checksums);
        Ok(())
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
            None => match self.store.folder_digest(id, name) {
                Ok(digest) => digest,
                Err(error @ StoreError::CorruptRecord { .. }) => {
                    tracing::error!(job_id = %id, name, %error, "unreadable digests");
                    return Err(ApiError::CorruptResult(name.to_owned()));
                }
                Err(error) => return Err(error.into()),
            },
        };
        let bytes = self.store.read_artefact(id, name)?;
        if let (Some(bytes), Some(expected)) = (&bytes, expected)
            && digest(bytes) != expected
        {
            tracing::error!(job_id = %id, name, "a stored result does not match its digest");
            return Err(ApiError::CorruptResult(name.to_owned()));
        }
        Ok(bytes)
    }
}

enum Outcome {
    Succeeded(pipeline::Mode),
    Failed(ApiError),
    Canceled,
    /// Stopped by shutdown; runs again after restart.
    Interrupted,
}

/// Pipeline threads run at nice 10, so the HTTP threads win the CPU whenever both want it and
/// polls stay fast while every core is busy with jobs. (On Linux `setpriority` with `who = 0`
/// applies to the calling thread only.) Best effort: failure leaves the default priority.
fn lower_thread_priority() {
    #[cfg(target_os = "linux")]
    // SAFETY: plain syscall on the current thread; no memory is shared.
    unsafe {
        libc::setpriority(libc::PRIO_PROCESS, 0, PIPELINE_NICE);
    }
}

#[cfg(target_os = "linux")]
const PIPELINE_NICE: libc::c_int = 10;

/// Turns pipeline callbacks into job progress and stored previews.
struct JobObserver<'a> {
    store: &'a Store,
    entry: &'a JobEntry,
}

impl Observer for JobObserver<'_> {
    fn progress(&self, progress: &Progress) {
        let view = ProgressView::from(progress);
        self.entry
            .record
            .send_modify(|record| record.progress = Some(view));
    }

    fn preview(&self, name: &str, image: &Image) {
        let safe = !name.is_empty()
            && name
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_');
        if !safe {
            warn!(name, "preview with an unusable name skipped");
            return;
        }
        let png = crate::imageio::encode_png(image);
        match self
            .store
            .write_artefact(&self.entry.id, &format!("previews/{name}.png"), &png)
        {
            Ok(()) => self.entry.record.send_modify(|record| {
                if !record.previews.iter().any(|existing| existing == name) {
                    record.previews.push(name.to_owned());
                }
            }),
            Err(error) => warn!(name, "storing a preview: {error}"),
        }
    }
}
