//! Running one job: decoding its stored inputs, the pipeline in the job's own thread pool,
//! writing its results, and what the outcome makes of its record. Shared by every backend: the
//! local queue's runner threads and the shared backend's workers (`backend/shared/worker.rs`)
//! each take a job their own way, call [`Runner::run`], and persist the record it leaves.

use std::collections::BTreeMap;
use std::panic::AssertUnwindSafe;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use tracing::{info, warn};

use super::inputs::{EncodedInputs, InputError, InputLimits};
use super::job::{JobEntry, JobFailure};
use super::model::{CancelReason, DRAFT_FILE, JobRecord, ProgressView, Status};
use super::store::{Store, StoreError, digest, retry_transient};
use super::telemetry::Metrics;
use crate::pipeline::{self, Observer, Progress};
use crate::render::Image;
use crate::scene::Scene;
use crate::svg::{self, SvgOptions};

/// What running a job needs besides the job.
pub struct Runner {
    pub store: Arc<Store>,
    pub limits: InputLimits,
    /// [`InputLimits::decode_slots`], shared with the requests that decode submissions (see
    /// [`super::queue::Queue::decode_slots`]).
    pub decode_slots: Arc<tokio::sync::Semaphore>,
    pub runtime: tokio::runtime::Handle,
    /// Wall-clock limit of one run.
    pub job_time_limit: Duration,
    /// How long results are kept after a job ends.
    pub retention: Duration,
    pub metrics: Arc<Metrics>,
}

/// What a run left in the job's record.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Settled {
    /// Succeeded, failed or canceled: the record is final.
    Ended,
    /// Stopped by shutdown (or a lost lease): the record is queued again, to run later.
    Interrupted,
    /// The job was deleted while it ran: nothing to save.
    Deleted,
}

impl Runner {
    /// Runs a job marked running, and settles its record by the outcome; the caller persists it.
    pub fn run(&self, entry: &Arc<JobEntry>, pool: &rayon::ThreadPool) -> Settled {
        let started = Instant::now();
        info!("started");
        let outcome = self.execute(entry, pool);
        if entry.deleted.load(Ordering::SeqCst) {
            info!("deleted while running");
            return Settled::Deleted;
        }
        let label = match &outcome {
            Outcome::Succeeded(..) => "succeeded",
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
        match outcome {
            Outcome::Succeeded(mode, reason) => {
                entry.record.send_modify(|record| {
                    record.mode = Some(mode);
                    record.mode_reason = Some(reason);
                });
                entry.end(Status::Succeeded, None, None, self.retention);
            }
            Outcome::Failed(error) => entry.end(
                Status::Failed,
                Some(error),
                entry.cancel_reason(),
                self.retention,
            ),
            Outcome::Canceled => entry.end(
                Status::Canceled,
                None,
                Some(CancelReason::User),
                self.retention,
            ),
            Outcome::Interrupted => {
                entry.record.send_modify(JobRecord::requeue);
                return Settled::Interrupted;
            }
        }
        Settled::Ended
    }

    fn execute(&self, entry: &Arc<JobEntry>, pool: &rayon::ThreadPool) -> Outcome {
        let record = entry.snapshot();
        let inputs = (|| -> Result<_, JobFailure> {
            let inputs = EncodedInputs::load(&record.inputs, |kind| {
                retry_transient("reading the job's inputs", || {
                    self.store.read_artefact(&entry.id, &kind.name())
                })
            })?
            .ok_or(JobFailure::MissingInputs)?;
            // A runner waits for its slot as long as it takes (the semaphore is never closed).
            let _slot = self
                .runtime
                .block_on(Arc::clone(&self.decode_slots).acquire_owned());
            Ok(inputs.decode(&self.limits, record.inputs.accept_truncated)?)
        })();
        let inputs = match inputs {
            Ok(inputs) => inputs,
            Err(error) => return Outcome::Failed(error),
        };
        let deadline = {
            let (limit, entry) = (self.job_time_limit, Arc::clone(entry));
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
            pool.install(|| pipeline::run(&inputs, &record.params, &observer, entry.cancel_flag()))
        }));
        deadline.abort();
        match result {
            Ok(Ok(output)) => match self.write_results(entry, &output) {
                Ok(()) => Outcome::Succeeded(output.mode.into(), output.mode_reason.clone()),
                Err(error) => Outcome::Failed(JobFailure::Storage(error)),
            },
            Ok(Err(pipeline::Error::Canceled)) => match entry.cancel_reason() {
                Some(CancelReason::Deadline) => {
                    Outcome::Failed(JobFailure::TimeLimit(self.job_time_limit.as_secs()))
                }
                Some(CancelReason::Shutdown) => Outcome::Interrupted,
                Some(CancelReason::User) | None => Outcome::Canceled,
            },
            Ok(Err(pipeline::Error::Input(error))) => {
                Outcome::Failed(InputError::refused("inputs")(error).into())
            }
            Ok(Err(pipeline::Error::Params(message))) => {
                Outcome::Failed(JobFailure::InvalidParams(message))
            }
            Ok(Err(pipeline::Error::Internal(message))) => {
                warn!(job_id = %entry.id, "internal error in the pipeline: {message}");
                Outcome::Failed(JobFailure::Internal(message))
            }
            Err(panic) => {
                let message = panic
                    .downcast_ref::<&str>()
                    .map(|s| s.to_string())
                    .or_else(|| panic.downcast_ref::<String>().cloned())
                    .unwrap_or_else(|| "panic".into());
                Outcome::Failed(JobFailure::Crashed(message))
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
}

enum Outcome {
    /// The mode run and why.
    Succeeded(pipeline::Mode, String),
    Failed(JobFailure),
    Canceled,
    /// Stopped by shutdown; runs again after restart.
    Interrupted,
}

/// The thread pool one job slot runs its pipelines in (`covec-pipeline-<slot>-<n>`).
pub fn job_pool(
    slot: usize,
    threads: usize,
) -> Result<rayon::ThreadPool, rayon::ThreadPoolBuildError> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads.max(1))
        .thread_name(move |thread| format!("covec-pipeline-{slot}-{thread}"))
        .start_handler(|_| lower_thread_priority())
        .build()
}

/// Pipeline threads run at nice 10, so the HTTP threads win the CPU whenever both want it and
/// polls stay fast while every core is busy with jobs. (On Linux `setpriority` with `who = 0`
/// applies to the calling thread only.) Best effort: failure leaves the default priority.
pub(super) fn lower_thread_priority() {
    #[cfg(target_os = "linux")]
    // SAFETY: plain syscall on the current thread; no memory is shared.
    unsafe {
        libc::setpriority(libc::PRIO_PROCESS, 0, PIPELINE_NICE);
    }
}

#[cfg(target_os = "linux")]
const PIPELINE_NICE: libc::c_int = 10;

/// Turns pipeline callbacks into job progress, stored previews and the stored draft.
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

    fn draft(&self, stage: &str, scene: &Scene) {
        let svg = svg::to_svg(scene, &SvgOptions::default());
        match self
            .store
            .write_artefact(&self.entry.id, DRAFT_FILE, svg.as_bytes())
        {
            Ok(()) => self
                .entry
                .record
                .send_modify(|record| record.draft = Some(stage.to_owned())),
            Err(error) => warn!(stage, "storing a draft: {error}"),
        }
    }

    fn wants_drafts(&self) -> bool {
        true
    }
}
