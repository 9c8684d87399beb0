//! The API replicas' side of the queue in PostgreSQL: admitting a job (with the queue's and the
//! client's limits and its Idempotency-Key), canceling one, and the claims on delivering its
//! webhook events (see the parent module for the rules).

use std::time::Duration;

use super::{CLIENT_LOCK, DROP_KEY, KEEP_WEBHOOK, Postgres, by_key, to_json};
use crate::service::model::JobRecord;
use crate::service::store::StoreError;

/// How long an API replica's claim on delivering a job's webhook events holds unless renewed
/// ([`Postgres::renew_deliveries`]): when the replica stops, another takes the deliveries over
/// after this. Short, as a delay to the receiver; renewals come every few seconds.
pub const DELIVERY_LEASE: Duration = Duration::from_secs(10);

/// What inserting a submitted job did.
pub enum Inserted {
    Created,
    /// A live job holds this (owner, Idempotency-Key): its record.
    Existing(Box<JobRecord>),
    /// The queue holds this many jobs already.
    Full(usize),
    /// The job's client has this many jobs queued already, its limit.
    KeyFull(usize),
}

/// What asking a job to cancel did.
pub enum Canceled {
    /// It was queued and is now canceled.
    Ended,
    /// It is running: its worker stops it at its next heartbeat.
    Stopping,
    /// It had ended already (or is gone).
    Nothing,
}

impl Postgres {
    /// Inserts a queued job unless the queue holds `max_queued` jobs, its client `key_limit`
    /// queued jobs, or a live job has its Idempotency-Key (then that job's record). The
    /// client's count and the insert hold its advisory lock, so replicas admitting its jobs
    /// at once cannot pass the limit together.
    /// A key used before `keys_since` (Unix ms) has expired: the job that held it keeps its
    /// record but not the key.
    pub fn insert(
        &self,
        record: &JobRecord,
        max_queued: usize,
        key_limit: Option<usize>,
        keys_since: u64,
    ) -> Result<Inserted, StoreError> {
        let json = to_json(record);
        let (id, owner) = (record.id.clone(), record.owner.clone());
        let (job_client, priority) = (record.client.clone(), record.priority.name());
        let key = record.idempotency.as_ref().map(|i| i.key.clone());
        let (replica, lease) = (self.replica.clone(), DELIVERY_LEASE.as_secs_f64());
        let webhook = record.webhook.is_some();
        let keys_since = keys_since as i64;
        self.run(move |mut client| async move {
            // The earlier job, looked for first: a replay is answered even when the queue is full.
            if let Some(existing) = by_key(&client, &owner, &key, keys_since).await? {
                return Ok(Inserted::Existing(Box::new(existing)));
            }
            let transaction = client.transaction().await?;
            transaction
                .execute(
                    "SELECT pg_advisory_xact_lock($1, hashtext($2))",
                    &[&CLIENT_LOCK, &job_client],
                )
                .await?;
            let row = transaction
                .query_one(
                    "SELECT count(*), count(*) FILTER (WHERE client = $1)
                     FROM jobs WHERE status = 'queued' AND NOT deleted",
                    &[&job_client],
                )
                .await?;
            let (queued, mine) = (row.get::<_, i64>(0) as usize, row.get::<_, i64>(1) as usize);
            if queued >= max_queued {
                return Ok(Inserted::Full(queued));
            }
            if key_limit.is_some_and(|limit| mine >= limit) {
                return Ok(Inserted::KeyFull(mine));
            }
            if let Some(key) = &key {
                // An expired holder of the key frees it for this job (the unique index).
                transaction
                    .execute(
                        &format!(
                            "UPDATE jobs SET {DROP_KEY}
                             WHERE coalesce(owner, '') = $1 AND idempotency_key = $2
                                 AND (record ->> 'created_at')::bigint < $3"
                        ),
                        &[&owner.clone().unwrap_or_default(), key, &keys_since],
                    )
                    .await?;
            }
            // With its webhook deliveries claimed by this replica in the same statement, so
            // no job with a webhook is ever without a deliverer.
            let inserted: i64 = transaction
                .query_one(
                    "WITH job AS (
                         INSERT INTO jobs (id, owner, status, record, idempotency_key, client,
                             priority)
                         VALUES ($1, $2, 'queued', $3::text::jsonb, $4, $8, $9)
                         ON CONFLICT DO NOTHING RETURNING id),
                     deliverer AS (
                         INSERT INTO webhook_deliveries (job_id, replica, lease_expires_at)
                         SELECT id, $5, clock_timestamp() + make_interval(secs => $6)
                         FROM job WHERE $7)
                     SELECT count(*) FROM job",
                    &[
                        &id,
                        &owner,
                        &json,
                        &key,
                        &replica,
                        &lease,
                        &webhook,
                        &job_client,
                        &priority,
                    ],
                )
                .await?
                .get(0);
            transaction.commit().await?;
            if inserted == 1 {
                return Ok(Inserted::Created);
            }
            // Another replica inserted the same key meanwhile.
            match by_key(&client, &owner, &key, keys_since).await? {
                Some(existing) => Ok(Inserted::Existing(Box::new(existing))),
                None => Err(StoreError::CorruptRecord {
                    id,
                    reason: "its insert conflicted with no live job".into(),
                }),
            }
        })
    }

    /// Cancels a queued job (its record becomes `ended`), or asks the worker running it to stop.
    pub fn cancel(&self, ended: &JobRecord) -> Result<Canceled, StoreError> {
        let (id, json) = (ended.id.clone(), to_json(ended));
        self.run(move |client| async move {
            let canceled = client
                .execute(
                    &format!(
                        "UPDATE jobs SET status = 'canceled', record = $2::text::jsonb {KEEP_WEBHOOK}
                         WHERE id = $1 AND status = 'queued' AND NOT deleted"
                    ),
                    &[&id, &json],
                )
                .await?;
            if canceled == 1 {
                return Ok(Canceled::Ended);
            }
            let asked = client
                .execute(
                    "UPDATE jobs SET cancel_requested = true
                     WHERE id = $1 AND status = 'running' AND NOT deleted",
                    &[&id],
                )
                .await?;
            Ok(if asked == 1 {
                Canceled::Stopping
            } else {
                Canceled::Nothing
            })
        })
    }

    /// Renews this replica's claims on webhook deliveries and takes over those whose claim
    /// expired (their replica stopped); the jobs taken over.
    pub fn renew_deliveries(&self) -> Result<Vec<String>, StoreError> {
        let (replica, lease) = (self.replica.clone(), DELIVERY_LEASE.as_secs_f64());
        self.run(move |client| async move {
            client
                .execute(
                    "UPDATE webhook_deliveries
                     SET lease_expires_at = clock_timestamp() + make_interval(secs => $2)
                     WHERE replica = $1",
                    &[&replica, &lease],
                )
                .await?;
            let taken = client
                .query(
                    "UPDATE webhook_deliveries
                     SET replica = $1, lease_expires_at = clock_timestamp() + make_interval(secs => $2)
                     WHERE job_id IN (
                         SELECT job_id FROM webhook_deliveries
                         WHERE lease_expires_at < clock_timestamp()
                         ORDER BY lease_expires_at LIMIT 100 FOR UPDATE SKIP LOCKED)
                     RETURNING job_id",
                    &[&replica, &lease],
                )
                .await?;
            Ok(taken.iter().map(|row| row.get(0)).collect())
        })
    }

    /// This replica is done with the job's webhook deliveries: all made or given up, or the
    /// job is gone.
    pub fn deliveries_done(&self, id: &str) -> Result<(), StoreError> {
        let (id, replica) = (id.to_owned(), self.replica.clone());
        self.run(move |client| async move {
            client
                .execute(
                    "DELETE FROM webhook_deliveries WHERE job_id = $1 AND replica = $2",
                    &[&id, &replica],
                )
                .await?;
            Ok(())
        })
    }
}
