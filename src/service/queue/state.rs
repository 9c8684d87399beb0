//! The jobs a process knows: the queued and running ones, and ended ones while something holds
//! them, with the fair queue that orders them; and what follows from it (placements, capacity).

use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::Ordering;
use std::sync::{Arc, Weak};

use super::{QueueConfig, Refusal};
use crate::service::fair::FairQueue;
use crate::service::job::JobEntry;
use crate::service::model::{Placement, now_ms};
use crate::service::telemetry::Metrics;

/// Ended jobs held in memory below which [`State::hold`] does not look for released ones.
const HELD_PRUNE_MIN: usize = 256;

pub struct State {
    /// The queued and running jobs by id (ids sort by creation time).
    pub live: BTreeMap<String, Arc<JobEntry>>,
    /// Ended jobs by id while something holds their entry, so every holder shares one (a
    /// webhook delivery's record changes reach a poll); released ones are pruned in
    /// [`State::hold`].
    pub held: HashMap<String, Weak<JobEntry>>,
    /// `held`'s size at which it is next pruned: twice its size after the last pruning, so
    /// pruning costs O(1) per entry and `held` stays within twice the entries in use.
    prune_at: usize,
    /// The queued and running jobs, by key: the queue itself on the embedded backend, a copy
    /// of the database's for queue positions on the shared one.
    pub fair: FairQueue,
    pub running: usize,
    pub draining: bool,
}

impl State {
    pub fn new() -> Self {
        Self {
            live: BTreeMap::new(),
            held: HashMap::new(),
            prune_at: HELD_PRUNE_MIN,
            fair: FairQueue::default(),
            running: 0,
            draining: false,
        }
    }

    /// The job's entry, if it is live or held.
    pub fn get(&self, id: &str) -> Option<Arc<JobEntry>> {
        self.live
            .get(id)
            .cloned()
            .or_else(|| self.held.get(id).and_then(Weak::upgrade))
    }

    /// Adds a job to those known (unless it is known already: then that entry).
    pub fn remember(&mut self, entry: Arc<JobEntry>) -> Arc<JobEntry> {
        if let Some(known) = self.get(&entry.id) {
            return known;
        }
        self.file(&entry);
        entry
    }

    /// Files a known job by its status: a queued or running one is kept, an ended one only
    /// referred to for as long as something holds it.
    pub fn file(&mut self, entry: &Arc<JobEntry>) {
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
    pub fn forget(&mut self, id: &str) {
        self.fair.forget(id);
        let entry = self.live.remove(id).or_else(|| {
            let held = self.held.remove(id)?;
            held.upgrade()
        });
        if let Some(entry) = entry {
            entry.deleted.store(true, Ordering::SeqCst);
        }
    }

    /// The job's place by the fair rule, and its estimated start (see [`State::placement_at`]).
    pub fn placement(&self, config: &QueueConfig, id: &str) -> Option<Placement> {
        let now = now_ms();
        let position = self.fair.position(id, &config.scheduling, now)?;
        Some(self.placement_at(config, position, now))
    }

    /// The placement of the job `position` jobs from the front, at `now`: the jobs ahead take
    /// the mean run time of recent successes each, on as many workers as run jobs now (at
    /// least this process's, at least one), and the running jobs are taken as half done. On
    /// the shared backend from the copy (as fresh as the follower's last look).
    pub fn placement_at(&self, config: &QueueConfig, position: usize, now: u64) -> Placement {
        let running = self.fair.depth().1;
        let workers = running.max(config.workers).max(1);
        let estimated_start_at = self.fair.mean_run_ms().map(|mean| {
            let jobs_ahead = position as f64 + running as f64 / 2.0;
            now + (jobs_ahead * mean as f64 / workers as f64) as u64
        });
        Placement {
            position,
            estimated_start_at,
        }
    }

    /// Why new work of `client` is refused, if it is: draining, the queue full (`queued`
    /// jobs), or the client's queued jobs at its limit.
    pub fn refusal(
        &self,
        config: &QueueConfig,
        metrics: &Metrics,
        queued: usize,
        client: &str,
    ) -> Option<Refusal> {
        if self.draining {
            return Some(Refusal::ShuttingDown);
        }
        if queued >= config.max_queued {
            return Some(queue_full(config, metrics, queued));
        }
        let limit = config.scheduling.limits_of(client).queued?;
        let mine = self.fair.queued_of(client);
        (mine >= limit).then(|| self.key_queue_full(config, metrics, limit, mine))
    }

    /// 429 `key-queue-full`, retry after about the time one of the key's jobs takes to start:
    /// a mean run time for each key waiting (the rule serves them in turn), shared by the
    /// workers running now.
    pub fn key_queue_full(
        &self,
        config: &QueueConfig,
        metrics: &Metrics,
        limit: usize,
        queued: usize,
    ) -> Refusal {
        let mean = self
            .fair
            .mean_run_ms()
            .map(|ms| ms as f64 / 1000.0)
            .or_else(|| metrics.mean_job_seconds())
            .unwrap_or(10.0);
        let workers = self.fair.depth().1.max(config.workers).max(1);
        let seconds = (self.fair.keys_waiting() as f64 * mean / workers as f64)
            .ceil()
            .max(1.0);
        Refusal::KeyQueueFull {
            limit: limit as u64,
            actual: queued as u64,
            retry_after: seconds as u64,
        }
    }
}

/// 503 `queue-full`, with the time for the queue ahead to clear from the mean job duration so
/// far.
pub fn queue_full(config: &QueueConfig, metrics: &Metrics, queued: usize) -> Refusal {
    let mean = metrics.mean_job_seconds().unwrap_or(10.0);
    let seconds = (queued as f64 * mean / config.workers.max(1) as f64)
        .ceil()
        .max(1.0);
    Refusal::QueueFull {
        queued,
        retry_after: seconds as u64,
    }
}
