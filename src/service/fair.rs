//! Fair scheduling: which queued job runs next when many keys share the workers, and what each
//! key may hold.
//!
//! A key is a client ([`super::auth::Client`]): an API key, or without keys an `X-Client-Key`;
//! anonymous requests are one key together. The next job is chosen by this rule, the same on
//! every backend (here for the local queue and the copy every replica keeps, and in the
//! claim statement of `Postgres::claim` (`backend/shared/postgres/leases.rs`) for PostgreSQL):
//!
//! 1. Only keys below their running limit take part.
//! 2. Interactive jobs go first. A batch job that has waited longer than the batch age counts
//!    as interactive, so batch work is never starved.
//! 3. Among the keys with a job of the best class waiting: the key with the fewest jobs
//!    running, then the key whose last job started longest ago (a key never served first),
//!    then the key whose such job is oldest; that key's oldest job of the class runs.
//!
//! With one worker this is round-robin over the keys with work waiting; with several it also
//! evens out how many each key has running.

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::num::NonZeroU32;
use std::time::Duration;

use governor::clock::{Clock, DefaultClock};
use governor::middleware::StateInformationMiddleware;
use governor::state::{InMemoryState, NotKeyed, keyed::DefaultKeyedStateStore};
use governor::{Quota, RateLimiter};

use super::model::{JobRecord, Priority, Status};
use super::rate::{RateRefusal, RateState};

/// What one key may hold; `None` is no limit.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct KeyLimits {
    /// Jobs waiting; then `POST /v1/jobs` answers 429 `key-queue-full`.
    pub queued: Option<usize>,
    /// Jobs running at once; further jobs wait their turn.
    pub running: Option<usize>,
    /// Submissions per minute (a burst of as many); then 429 `rate-limited`.
    pub per_minute: Option<NonZeroU32>,
}

/// The scheduling rule's settings.
#[derive(Clone, Debug)]
pub struct Scheduling {
    /// How long a batch job waits before it counts as interactive. Default 300 s.
    pub batch_age: Duration,
    /// Every key's limits, unless overridden.
    pub limits: KeyLimits,
    /// Limits of particular keys, by client id ([`super::model::key_id`] of the key).
    pub overrides: HashMap<String, KeyLimits>,
}

impl Default for Scheduling {
    fn default() -> Self {
        Self {
            batch_age: Duration::from_secs(300),
            limits: KeyLimits::default(),
            overrides: HashMap::new(),
        }
    }
}

impl Scheduling {
    /// Applies one override, `KEY:LIMIT=N` (`LIMIT` one of `queued`, `running`, `rate`; `N` 0
    /// for no limit; `KEY` an API key, or an `X-Client-Key` on a server without keys). The
    /// key's other limits stay the defaults: set those first.
    pub fn override_limit(&mut self, entry: &str) -> Result<(), String> {
        let malformed = || format!("`{entry}` is not KEY:LIMIT=N (LIMIT queued, running or rate)");
        let (key, setting) = entry.trim().rsplit_once(':').ok_or_else(malformed)?;
        let (name, value) = setting.split_once('=').ok_or_else(malformed)?;
        let value: u32 = value.trim().parse().map_err(|_| malformed())?;
        if key.trim().is_empty() {
            return Err(malformed());
        }
        let limits = self
            .overrides
            .entry(super::model::key_id(key.trim()))
            .or_insert(self.limits);
        match name.trim() {
            "queued" => limits.queued = (value > 0).then_some(value as usize),
            "running" => limits.running = (value > 0).then_some(value as usize),
            "rate" => limits.per_minute = NonZeroU32::new(value),
            _ => return Err(malformed()),
        }
        Ok(())
    }

    /// The limits of `client`: its override, else every key's.
    pub fn limits_of(&self, client: &str) -> KeyLimits {
        self.overrides.get(client).copied().unwrap_or(self.limits)
    }

    /// Whether a job of this priority, created at `created_at` (Unix ms), counts as
    /// interactive at `now`.
    fn urgent(&self, priority: Priority, created_at: u64, now: u64) -> bool {
        priority == Priority::Interactive
            || created_at.saturating_add(self.batch_age.as_millis() as u64) <= now
    }
}

/// A queued job as the rule sees it.
struct Waiting {
    client: String,
    priority: Priority,
    created_at: u64,
}

/// How many recent run times the start estimate averages.
const RECENT_RUNS: usize = 20;

/// What the scheduler knows: the queued jobs, the running ones by key, when each key was last
/// served, and recent run times. Authoritative on the embedded backend; on the shared one a
/// copy kept up to date by the follower, for queue positions.
#[derive(Default)]
pub struct FairQueue {
    /// Queued jobs by id (ids sort by creation time).
    waiting: BTreeMap<String, Waiting>,
    /// Running jobs' keys by job id, and their count by key.
    running_jobs: HashMap<String, String>,
    running: HashMap<String, usize>,
    /// A stamp that grows with each start, by key: when the key last had a job started.
    served: HashMap<String, u64>,
    /// Run times of the last [`RECENT_RUNS`] jobs that succeeded, in ms.
    recent: VecDeque<u64>,
}

impl FairQueue {
    /// Follows a job's status: a queued job waits, a running one counts against its key, and
    /// any other leaves (a success adds its run time to the recent ones).
    pub fn track(&mut self, record: &JobRecord) {
        let known = self.forget(&record.id);
        match record.status {
            Status::Queued => {
                self.waiting.insert(
                    record.id.clone(),
                    Waiting {
                        client: record.client.clone(),
                        priority: record.priority,
                        created_at: record.created_at,
                    },
                );
            }
            Status::Running => {
                self.running_jobs
                    .insert(record.id.clone(), record.client.clone());
                *self.running.entry(record.client.clone()).or_default() += 1;
            }
            Status::Succeeded => {
                if let (true, Some(started), Some(completed)) =
                    (known, record.started_at, record.completed_at)
                {
                    if self.recent.len() == RECENT_RUNS {
                        self.recent.pop_front();
                    }
                    self.recent.push_back(completed.saturating_sub(started));
                }
            }
            Status::Failed | Status::Canceled => {}
        }
    }

    /// Stops following a job; returns whether it was queued or running.
    pub fn forget(&mut self, id: &str) -> bool {
        if self.waiting.remove(id).is_some() {
            return true;
        }
        let Some(client) = self.running_jobs.remove(id) else {
            return false;
        };
        if let Some(count) = self.running.get_mut(&client) {
            *count -= 1;
            if *count == 0 {
                self.running.remove(&client);
            }
        }
        true
    }

    /// Marks `client` as served now (a job of its was just started).
    pub fn serve(&mut self, client: &str) {
        let stamp = self.served.values().max().map_or(1, |last| last + 1);
        self.served.insert(client.to_owned(), stamp);
    }

    /// Replaces when each key was last served (shared backend: read from the database, where
    /// the claims record it).
    pub fn set_served(&mut self, served: HashMap<String, u64>) {
        self.served = served;
    }

    /// (queued, running) jobs.
    pub fn depth(&self) -> (usize, usize) {
        (self.waiting.len(), self.running_jobs.len())
    }

    /// Jobs of `client` waiting.
    pub fn queued_of(&self, client: &str) -> usize {
        self.waiting
            .values()
            .filter(|waiting| waiting.client == client)
            .count()
    }

    /// Keys with a job waiting.
    pub fn keys_waiting(&self) -> usize {
        let keys: std::collections::HashSet<&str> = self
            .waiting
            .values()
            .map(|waiting| waiting.client.as_str())
            .collect();
        keys.len()
    }

    /// The job to start now, if any key below its running limit has one waiting.
    pub fn next(&self, policy: &Scheduling, now: u64) -> Option<String> {
        let mut next = None;
        self.schedule(policy, now, |id, blocked| {
            next = (!blocked).then(|| id.to_owned());
            false
        });
        next
    }

    /// How many waiting jobs start before `id` if no other arrives (keys at their running
    /// limit come after the others); `None` when it is not waiting.
    pub fn position(&self, id: &str, policy: &Scheduling, now: u64) -> Option<usize> {
        self.waiting.get(id)?;
        let mut ahead = 0;
        self.schedule(policy, now, |scheduled, _| {
            if scheduled == id {
                return false;
            }
            ahead += 1;
            true
        });
        Some(ahead)
    }

    /// Every waiting job's [`FairQueue::position`], in one pass of the rule.
    pub fn positions(&self, policy: &Scheduling, now: u64) -> HashMap<String, usize> {
        let mut positions = HashMap::with_capacity(self.waiting.len());
        self.schedule(policy, now, |id, _| {
            positions.insert(id.to_owned(), positions.len());
            true
        });
        positions
    }

    /// Mean run time of recent successes, in ms.
    pub fn mean_run_ms(&self) -> Option<u64> {
        let count = self.recent.len() as u64;
        (count > 0).then(|| self.recent.iter().sum::<u64>() / count)
    }

    /// Plays the rule forward over the waiting jobs, each started job counting as running for
    /// its key, and calls `visit(id, blocked)` in start order until it returns false; `blocked`
    /// says the job's key is at its running limit now (such keys come after every other).
    fn schedule(&self, policy: &Scheduling, now: u64, mut visit: impl FnMut(&str, bool) -> bool) {
        struct Lane<'a> {
            urgent: VecDeque<&'a str>,
            batch: VecDeque<&'a str>,
            running: usize,
            served: Option<u64>,
            blocked: bool,
        }
        let mut lanes: Vec<Lane<'_>> = Vec::new();
        let mut lane_of: HashMap<&str, usize> = HashMap::new();
        for (id, waiting) in &self.waiting {
            let client = waiting.client.as_str();
            let index = *lane_of.entry(client).or_insert_with(|| {
                let running = self.running.get(client).copied().unwrap_or(0);
                lanes.push(Lane {
                    urgent: VecDeque::new(),
                    batch: VecDeque::new(),
                    running,
                    served: self.served.get(client).copied(),
                    blocked: policy
                        .limits_of(client)
                        .running
                        .is_some_and(|limit| running >= limit),
                });
                lanes.len() - 1
            });
            let lane = &mut lanes[index];
            if policy.urgent(waiting.priority, waiting.created_at, now) {
                lane.urgent.push_back(id);
            } else {
                lane.batch.push_back(id);
            }
        }
        let mut stamp = self.served.values().max().copied().unwrap_or(0);
        loop {
            let best = lanes
                .iter()
                .enumerate()
                .filter_map(|(index, lane)| {
                    let (class, head) = match (lane.urgent.front(), lane.batch.front()) {
                        (Some(head), _) => (0, *head),
                        (None, Some(head)) => (1, *head),
                        (None, None) => return None,
                    };
                    Some((
                        (lane.blocked, class, lane.running, lane.served, head),
                        index,
                    ))
                })
                .min_by(|a, b| a.0.cmp(&b.0));
            let Some(((blocked, class, ..), index)) = best else {
                return;
            };
            let lane = &mut lanes[index];
            let id = if class == 0 {
                lane.urgent.pop_front()
            } else {
                lane.batch.pop_front()
            }
            .expect("the lane's head");
            lane.running += 1;
            stamp += 1;
            lane.served = Some(stamp);
            if !visit(id, blocked) {
                return;
            }
        }
    }
}

/// Per-key submission rates (`--rate-per-key`, overrides): one GCRA limiter for every key on
/// the default rate, one of its own for each key with another. Held by one process: with
/// several API replicas each allows the rate (the queued limit, kept in the database, holds
/// across them).
pub struct SubmissionRates {
    default: Option<(NonZeroU32, KeyedLimiter)>,
    overridden: HashMap<String, Option<(NonZeroU32, DirectLimiter)>>,
}

type KeyedLimiter =
    RateLimiter<String, DefaultKeyedStateStore<String>, DefaultClock, StateInformationMiddleware>;
type DirectLimiter = RateLimiter<NotKeyed, InMemoryState, DefaultClock, StateInformationMiddleware>;

impl SubmissionRates {
    pub fn new(policy: &Scheduling) -> Self {
        Self {
            default: policy.limits.per_minute.map(|rate| {
                (
                    rate,
                    RateLimiter::keyed(Quota::per_minute(rate)).with_middleware(),
                )
            }),
            overridden: policy
                .overrides
                .iter()
                .map(|(client, limits)| {
                    let limiter = limits.per_minute.map(|rate| {
                        (
                            rate,
                            RateLimiter::direct(Quota::per_minute(rate)).with_middleware(),
                        )
                    });
                    (client.clone(), limiter)
                })
                .collect(),
        }
    }

    /// Counts a submission of `client`: `Ok(None)` when no rate applies to it, `Ok(state)`
    /// within its rate, `Err` over it.
    pub fn check(&self, client: &str) -> Result<Option<RateState>, RateRefusal> {
        let (outcome, rate) = match self.overridden.get(client) {
            Some(None) => return Ok(None),
            Some(Some((rate, limiter))) => (limiter.check(), *rate),
            None => match &self.default {
                None => return Ok(None),
                Some((rate, limiter)) => (limiter.check_key(&client.to_owned()), *rate),
            },
        };
        match outcome {
            Ok(snapshot) => Ok(Some(RateState::after(rate, &snapshot))),
            Err(not_until) => {
                let wait = not_until.wait_time_from(DefaultClock::default().now());
                let retry_after = wait.as_secs_f64().ceil().max(1.0) as u64;
                Err(RateRefusal {
                    retry_after,
                    state: RateState {
                        per_minute: rate.get(),
                        remaining: 0,
                        // The next one back after the wait, the rest one by one after it.
                        reset_seconds: retry_after
                            + RateState::refill_seconds(rate, rate.get() - 1),
                    },
                })
            }
        }
    }

    /// Drops the state of keys that have not submitted for a while (their buckets are full
    /// again), so the map holds recent keys only.
    pub fn shrink(&self) {
        if let Some((_, limiter)) = &self.default {
            limiter.retain_recent();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::service::model::{InputManifest, new_job_id};

    fn job(client: &str, priority: Priority, created_at: u64) -> JobRecord {
        JobRecord {
            created_at,
            ..JobRecord::queued(
                new_job_id(),
                client.to_owned(),
                priority,
                Default::default(),
                InputManifest::default(),
            )
        }
    }

    /// Starts jobs one at a time (one worker: each ends before the next starts) and returns
    /// their clients in start order.
    fn run_all(queue: &mut FairQueue, jobs: &[JobRecord], policy: &Scheduling, now: u64) -> String {
        let mut order = String::new();
        while let Some(id) = queue.next(policy, now) {
            let mut record = jobs.iter().find(|job| job.id == id).unwrap().clone();
            record.status = Status::Running;
            queue.track(&record);
            queue.serve(&record.client);
            record.status = Status::Succeeded;
            queue.track(&record);
            order.push_str(&record.client);
        }
        order
    }

    #[test]
    fn keys_take_turns_and_interactive_goes_first_until_batch_ages() {
        let policy = Scheduling::default();
        let now = 1_000_000;
        let mut jobs: Vec<_> = (0..4).map(|_| job("a", Priority::Batch, now)).collect();
        jobs.extend((0..2).map(|_| job("b", Priority::Batch, now)));
        jobs.push(job("c", Priority::Interactive, now));
        let mut queue = FairQueue::default();
        for job in &jobs {
            queue.track(job);
        }
        // Positions are the order the jobs start in.
        let last_a = &jobs[3].id;
        assert_eq!(queue.position(&jobs[6].id, &policy, now), Some(0));
        assert_eq!(queue.position(last_a, &policy, now), Some(6));
        let positions = queue.positions(&policy, now);
        for job in &jobs {
            assert_eq!(
                positions.get(&job.id).copied(),
                queue.position(&job.id, &policy, now)
            );
        }
        assert_eq!(run_all(&mut queue, &jobs, &policy, now), "cababaa");

        // A batch job older than the batch age counts as interactive: it goes before a newer
        // interactive job of another key that has been served less recently.
        let old = now - policy.batch_age.as_millis() as u64 - 1;
        let jobs = [
            job("a", Priority::Interactive, now),
            job("b", Priority::Batch, old),
            job("c", Priority::Batch, now),
        ];
        let mut queue = FairQueue::default();
        for job in &jobs {
            queue.track(job);
        }
        queue.serve("b");
        assert_eq!(run_all(&mut queue, &jobs, &policy, now), "abc");
    }

    #[test]
    fn a_key_at_its_running_limit_waits_and_others_go_on() {
        let mut policy = Scheduling::default();
        policy.override_limit("k:running=1").unwrap();
        let client = crate::service::model::key_id("k");
        let now = 5_000;
        let mut running = job(&client, Priority::Interactive, now);
        let waiting = job(&client, Priority::Interactive, now);
        let other = job("other", Priority::Batch, now);
        let mut queue = FairQueue::default();
        for job in [&running, &waiting, &other] {
            queue.track(job);
        }
        running.status = Status::Running;
        queue.track(&running);
        assert_eq!(queue.next(&policy, now), Some(other.id.clone()));
        assert_eq!(queue.position(&waiting.id, &policy, now), Some(1));
        queue.forget(&other.id);
        assert_eq!(queue.next(&policy, now), None, "the key is at its limit");
        running.status = Status::Succeeded;
        queue.track(&running);
        assert_eq!(queue.next(&policy, now), Some(waiting.id.clone()));
        assert_eq!(queue.queued_of(&client), 1);
    }

    #[test]
    fn overrides_are_parsed_or_refused() {
        let mut policy = Scheduling::default();
        policy.limits.queued = Some(10);
        policy.override_limit("key:with:colons:rate=30").unwrap();
        let limits = policy.limits_of(&crate::service::model::key_id("key:with:colons"));
        assert_eq!(limits.queued, Some(10));
        assert_eq!(limits.per_minute, NonZeroU32::new(30));
        for bad in ["nokey", ":queued=1", "k:speed=3", "k:queued=-1", "k:queued"] {
            assert!(policy.override_limit(bad).is_err(), "{bad}");
        }
    }
}
