//! A key's submission rate as reported to clients, apart from [`super::fair`] which counts it,
//! so that [`super::error`] can name a refusal without depending on the scheduler.

use std::num::NonZeroU32;

use governor::middleware::StateSnapshot;

/// A key's submission rate after a submission was counted, as the IETF `RateLimit-Policy` and
/// `RateLimit` fields (draft-ietf-httpapi-ratelimit-headers) state it: `per_minute`
/// submissions a minute, `remaining` of them allowed now, and the whole quota back after
/// `reset_seconds`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RateState {
    pub per_minute: u32,
    pub remaining: u32,
    pub reset_seconds: u64,
}

impl RateState {
    /// The `RateLimit-Policy` and `RateLimit` fields (names in lower case, as HTTP/2 sends
    /// them). The policy is named `submissions`: it counts `POST /v1/jobs` by key.
    pub fn fields(&self) -> [(&'static str, String); 2] {
        [
            (
                "ratelimit-policy",
                format!("\"submissions\";q={};w=60", self.per_minute),
            ),
            (
                "ratelimit",
                format!(
                    "\"submissions\";r={};t={}",
                    self.remaining, self.reset_seconds
                ),
            ),
        ]
    }

    /// The state `snapshot` describes (after an allowed submission), at `rate` a minute.
    pub(super) fn after(rate: NonZeroU32, snapshot: &StateSnapshot) -> Self {
        let remaining = snapshot.remaining_burst_capacity().min(rate.get());
        Self {
            per_minute: rate.get(),
            remaining,
            reset_seconds: Self::refill_seconds(rate, rate.get() - remaining),
        }
    }

    /// Seconds until `spent` submissions of a `rate` a minute have come back (one every
    /// 60 / rate seconds), rounded up.
    pub(super) fn refill_seconds(rate: NonZeroU32, spent: u32) -> u64 {
        (u64::from(spent) * 60).div_ceil(u64::from(rate.get()))
    }
}

/// A submission over its key's rate: when the next is allowed, and the state to report.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RateRefusal {
    pub retry_after: u64,
    pub state: RateState,
}
