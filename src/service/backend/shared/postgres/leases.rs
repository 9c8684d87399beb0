//! The workers' side of the queue in PostgreSQL: claiming a job under a lease, the heartbeat
//! that renews it, the fenced write of the outcome, and reaping the leases that expired (see
//! the parent module for the rules).

use std::time::Duration;

use super::{CLAIM_LOCK, KEEP_WEBHOOK, Postgres, RECORD_COLUMNS, record_of, to_json};
use crate::service::fair::Scheduling;
use crate::service::model::{JobRecord, Problem, Status};
use crate::service::store::StoreError;

/// Runs of one job, the first included, before a job whose worker keeps vanishing is failed
/// (`workers-lost`): one lost worker is bad luck, three in a row is likely the job itself.
pub const MAX_ATTEMPTS: i32 = 3;

/// What a running job's heartbeat learned.
pub enum Beat {
    /// The lease is renewed; whether a cancel was asked for.
    Held { cancel: bool },
    /// The job was deleted: stop and remove its files.
    Deleted,
    /// Another worker holds the job now (this lease expired): stop and save nothing.
    Lost,
}

/// A claimed job: its record (marked running) and the lease's token.
pub struct Claim {
    pub record: JobRecord,
    pub token: String,
}

impl Postgres {
    /// Takes the queued job the fair rule picks ([`crate::service::fair`]: keys below their
    /// running limit; interactive first, a batch job counting as interactive once it has
    /// waited `batch_age`; then the key with the fewest running, the one served longest ago,
    /// its oldest job), if any, with a lease of `lease` under a new token, and records its
    /// client as served. Its record comes back marked running (started now), one attempt more.
    /// Claims take turns (an advisory lock), so each sees the running counts the last left.
    pub fn claim(&self, lease: Duration, policy: &Scheduling) -> Result<Option<Claim>, StoreError> {
        let token = uuid::Uuid::now_v7().simple().to_string();
        let default_running = policy.limits.running.map_or(i64::MAX, |limit| limit as i64);
        let (limited, running_limits): (Vec<String>, Vec<i64>) = policy
            .overrides
            .iter()
            .map(|(client, limits)| {
                let limit = limits.running.map_or(i64::MAX, |limit| limit as i64);
                (client.clone(), limit)
            })
            .unzip();
        let batch_age_ms = policy.batch_age.as_millis() as i64;
        self.run(move |mut client| async move {
            let transaction = client.transaction().await?;
            transaction
                .execute("SELECT pg_advisory_xact_lock($1)", &[&CLAIM_LOCK])
                .await?;
            let picked = transaction
                .query_opt(
                    "WITH running AS (
                         SELECT client, count(*) AS jobs FROM jobs
                         WHERE status = 'running' AND NOT deleted GROUP BY client
                     ), limits AS (
                         SELECT * FROM unnest($1::text[], $2::bigint[]) AS l (client, running)
                     )
                     SELECT j.id, (extract(epoch FROM statement_timestamp()) * 1000)::bigint
                     FROM jobs j
                         LEFT JOIN running r ON r.client = j.client
                         LEFT JOIN limits l ON l.client = j.client
                         LEFT JOIN queue_clients s ON s.client = j.client
                     WHERE j.status = 'queued' AND NOT j.deleted
                         AND coalesce(r.jobs, 0) < coalesce(l.running, $3)
                     ORDER BY
                         j.priority = 'batch' AND (j.record ->> 'created_at')::bigint
                             > (extract(epoch FROM clock_timestamp()) * 1000)::bigint - $4,
                         coalesce(r.jobs, 0), s.last_served NULLS FIRST, j.id
                     LIMIT 1 FOR UPDATE OF j SKIP LOCKED",
                    &[&limited, &running_limits, &default_running, &batch_age_ms],
                )
                .await?;
            let Some(picked) = picked else {
                return Ok(None);
            };
            let id: String = picked.get(0);
            // When the choice was made (the statement's start, when it saw the queue): a job
            // submitted after it was not there to choose.
            let chosen_at = picked.get::<_, i64>(1).max(0) as u64;
            let row = transaction
                .query_one(
                    &format!(
                        "UPDATE jobs SET status = 'running', attempts = attempts + 1,
                             cancel_requested = false, lease_owner = $1,
                             lease_expires_at = clock_timestamp() + make_interval(secs => $2)
                         WHERE id = $3
                         RETURNING {RECORD_COLUMNS}, client"
                    ),
                    &[&token, &lease.as_secs_f64(), &id],
                )
                .await?;
            let served: String = row.get(5);
            transaction
                .execute(
                    "INSERT INTO queue_clients (client, last_served) VALUES ($1, clock_timestamp())
                     ON CONFLICT (client) DO UPDATE SET last_served = excluded.last_served",
                    &[&served],
                )
                .await?;
            transaction.commit().await?;
            let mut record = record_of(&row)?;
            record.started_at = Some(chosen_at);
            Ok(Some(Claim { record, token }))
        })
    }

    /// Renews a running job's lease for `lease`, storing its record when given (progress,
    /// previews), and says whether to go on.
    pub fn heartbeat(
        &self,
        token: &str,
        lease: Duration,
        record: Option<&JobRecord>,
        id: &str,
    ) -> Result<Beat, StoreError> {
        let (id, token, json) = (id.to_owned(), token.to_owned(), record.map(to_json));
        self.run(move |client| async move {
            let row = client
                .query_opt(
                    &format!(
                        "UPDATE jobs SET
                             lease_expires_at = clock_timestamp() + make_interval(secs => $3),
                             record = coalesce($4::text::jsonb {KEEP_WEBHOOK}, jobs.record)
                         WHERE id = $1 AND lease_owner = $2 AND status = 'running' AND NOT deleted
                         RETURNING cancel_requested"
                    ),
                    &[&id, &token, &lease.as_secs_f64(), &json],
                )
                .await?;
            if let Some(row) = row {
                return Ok(Beat::Held { cancel: row.get(0) });
            }
            let deleted = client
                .query_opt("SELECT deleted FROM jobs WHERE id = $1", &[&id])
                .await?
                .is_none_or(|row| row.get(0));
            Ok(if deleted { Beat::Deleted } else { Beat::Lost })
        })
    }

    /// Saves the record a run left, if the lease is still `token`'s, and releases the job:
    /// ended, or queued again (`requeued`, stopped by shutdown: that attempt does not count).
    /// Returns whether it was saved.
    pub fn settle(&self, token: &str, record: &JobRecord) -> Result<bool, StoreError> {
        let (id, token, json) = (record.id.clone(), token.to_owned(), to_json(record));
        let status = record.status.name();
        let refund: i32 = (record.status == Status::Queued).into();
        self.run(move |client| async move {
            let saved = client
                .execute(
                    &format!(
                        "UPDATE jobs SET status = $3, record = $4::text::jsonb {KEEP_WEBHOOK},
                             attempts = attempts - $5, cancel_requested = false,
                             lease_owner = NULL, lease_expires_at = NULL
                         WHERE id = $1 AND lease_owner = $2 AND NOT deleted"
                    ),
                    &[&id, &token, &status, &json, &refund],
                )
                .await?;
            Ok(saved == 1)
        })
    }

    /// Takes back the jobs whose lease expired (their worker stopped without a word): each is
    /// queued again, or failed with `lost` once it has had [`MAX_ATTEMPTS`] runs. Returns
    /// (requeued, failed).
    pub fn reap(&self, lost: Problem, retention: Duration) -> Result<(usize, usize), StoreError> {
        self.run(move |mut client| async move {
            let transaction = client.transaction().await?;
            let rows = transaction
                .query(
                    &format!(
                        "SELECT {RECORD_COLUMNS} FROM jobs WHERE status = 'running'
                             AND lease_expires_at < clock_timestamp() AND NOT deleted
                         FOR UPDATE SKIP LOCKED"
                    ),
                    &[],
                )
                .await?;
            let (mut requeued, mut failed) = (0, 0);
            for row in &rows {
                let mut record = record_of(row)?;
                if record.attempts as i32 >= MAX_ATTEMPTS {
                    record.end(Status::Failed, Some(lost.clone()), None, retention);
                    failed += 1;
                } else {
                    record.requeue();
                    requeued += 1;
                }
                tracing::warn!(
                    job_id = %record.id,
                    attempts = record.attempts,
                    status = record.status.name(),
                    "a worker's lease expired"
                );
                transaction
                    .execute(
                        &format!(
                            "UPDATE jobs SET status = $2, record = $3::text::jsonb {KEEP_WEBHOOK},
                                 cancel_requested = false, lease_owner = NULL,
                                 lease_expires_at = NULL
                             WHERE id = $1"
                        ),
                        &[&record.id, &record.status.name(), &to_json(&record)],
                    )
                    .await?;
            }
            transaction.commit().await?;
            Ok((requeued, failed))
        })
    }
}
