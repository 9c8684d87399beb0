//! Job records, the queue and its leases in PostgreSQL (`--database-url`), shared by
//! API replicas (`covec serve`) and workers (`covec worker`).
//!
//! The queue is the `jobs` table: a worker claims the queued row the fair rule picks
//! ([`crate::service::fair`]) with `FOR UPDATE SKIP LOCKED` (two workers never take one job),
//! claims one at a time (an advisory lock), holding it by a lease it renews
//! while it runs; every write of a running job is fenced by the lease's token, so a worker
//! whose lease expired can no longer save anything, and a job never ends twice. Leases that
//! expire (a worker killed) are reaped: the job is queued again, or failed after
//! [`MAX_ATTEMPTS`] runs. Idempotency keys are a unique index, so they hold across replicas.
//!
//! tokio-postgres with a deadpool pool rather than sqlx: plain SQL strings checked by the
//! tests against a real server, no macros and no database or offline query cache at build
//! time, and a small dependency tree. Like the object store's bucket, the client runs on
//! a small runtime of its own: every caller is blocking code (a runner, a `spawn_blocking`
//! task, start-up), which hands each request over and waits for it.
//!
//! Migrations are the files in `migrations/`, applied in order at start (under an advisory
//! lock, so replicas starting together apply each once) and recorded in `schema_migrations`.

use std::collections::HashMap;
use std::str::FromStr;
use std::time::{Duration, SystemTime};

use deadpool_postgres::{Manager, ManagerConfig, Pool, RecyclingMethod};
use tokio_postgres::Row;

mod leases;
mod replicas;

mod tls;

use crate::service::model::{JobRecord, Status};
use crate::service::store::{Records, StoreError, parse_record, with_sources};
pub use leases::{Beat, Claim, MAX_ATTEMPTS};
pub use replicas::{Canceled, Inserted};
use tls::TlsSettings;

/// The schema, version by version; a version once released is never edited.
const MIGRATIONS: [(i32, &str); 4] = [
    (1, include_str!("../../../../../migrations/0001_jobs.sql")),
    (
        2,
        include_str!("../../../../../migrations/0002_webhook_deliveries.sql"),
    ),
    (
        3,
        include_str!("../../../../../migrations/0003_fair_queue.sql"),
    ),
    (
        4,
        include_str!("../../../../../migrations/0004_bounded_records.sql"),
    ),
];

/// Advisory lock ids: migrations, claims (one at a time, so each sees the running counts the
/// last one left), and a client's submissions (its queued count and insert together).
const MIGRATION_LOCK: i64 = 7_316_290_414;
const CLAIM_LOCK: i64 = 7_316_290_415;
const CLIENT_LOCK: i32 = 7316;

/// Connections per process: a handful of short statements at a time.
const POOL_SIZE: usize = 8;

/// How long a request waits for a connection (also to open one), so a database that is down
/// gives an error in seconds instead of a hang.
const CONNECT_WAIT: Duration = Duration::from_secs(10);

/// The columns a record is read from; [`record_of`] parses them.
const RECORD_COLUMNS: &str = "id, record::text, status, cancel_requested, attempts";

/// Every full write of a record keeps the webhook deliveries stored: the API replica that
/// delivers them writes only that field ([`Postgres::save_webhook`]).
const KEEP_WEBHOOK: &str = "|| jsonb_build_object('webhook', jobs.record -> 'webhook')";

/// Takes an expired Idempotency-Key off a job, column and record.
const DROP_KEY: &str = "idempotency_key = NULL, record = record - 'idempotency'";

pub struct Postgres {
    pool: Pool,
    /// This process, in the claims it holds on webhook deliveries.
    replica: String,
    /// Taken out and shut down in the background on drop (as the object store's).
    runtime: Option<tokio::runtime::Runtime>,
}

impl Drop for Postgres {
    fn drop(&mut self) {
        if let Some(runtime) = self.runtime.take() {
            runtime.shutdown_background();
        }
    }
}

/// A change to a job since the last look ([`Postgres::changes`]).
pub enum Change {
    Live(Box<JobRecord>),
    Deleted(String),
}

impl Postgres {
    /// Connects (checking the server answers), over TLS as `url` asks ([`TlsSettings`]), and
    /// applies pending migrations.
    pub fn connect(url: &str) -> Result<Self, StoreError> {
        let (tls, url) = TlsSettings::take_from(url)?;
        let mut config = tokio_postgres::Config::from_str(&url).map_err(|error| {
            StoreError::DatabaseUrl(format!("not a PostgreSQL connection string: {error}"))
        })?;
        config.ssl_mode(tls.ssl_mode());
        let manager = Manager::from_config(
            config,
            tls.connector()?,
            ManagerConfig {
                recycling_method: RecyclingMethod::Fast,
            },
        );
        let pool = Pool::builder(manager)
            .max_size(POOL_SIZE)
            .runtime(deadpool_postgres::Runtime::Tokio1)
            .wait_timeout(Some(CONNECT_WAIT))
            .create_timeout(Some(CONNECT_WAIT))
            .build()
            .map_err(|error| StoreError::DatabaseUrl(error.to_string()))?;
        // Made last: from here on an error drops it through `Drop` (callers may be inside
        // another runtime, where dropping one plainly panics).
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("covec-postgres")
            .enable_all()
            .build()
            .map_err(|error| StoreError::DatabaseUrl(format!("runtime: {error}")))?;
        let postgres = Self {
            pool,
            replica: uuid::Uuid::now_v7().simple().to_string(),
            runtime: Some(runtime),
        };
        postgres.migrate()?;
        Ok(postgres)
    }

    /// Runs `request` with a pooled connection on the client's runtime and waits for it.
    fn run<T: Send + 'static, F>(
        &self,
        request: impl FnOnce(deadpool_postgres::Object) -> F + Send + 'static,
    ) -> Result<T, StoreError>
    where
        F: Future<Output = Result<T, StoreError>> + Send,
    {
        let runtime = self.runtime.as_ref().expect("the runtime lives until drop");
        let pool = self.pool.clone();
        let (answer, answered) = std::sync::mpsc::channel();
        runtime.spawn(async move {
            let result = match pool.get().await {
                Ok(client) => request(client).await,
                Err(error) => Err(StoreError::DatabasePool(with_sources(&error))),
            };
            let _ = answer.send(result);
        });
        answered.recv().map_err(|_| StoreError::DatabaseStopped)?
    }

    fn migrate(&self) -> Result<(), StoreError> {
        self.run(|mut client| async move {
            let transaction = client.transaction().await?;
            // One replica at a time; the others then find the versions applied.
            transaction
                .execute("SELECT pg_advisory_xact_lock($1)", &[&MIGRATION_LOCK])
                .await?;
            transaction
                .batch_execute(
                    "CREATE TABLE IF NOT EXISTS schema_migrations (
                         version integer PRIMARY KEY,
                         applied_at timestamptz NOT NULL DEFAULT now()
                     )",
                )
                .await?;
            for (version, sql) in MIGRATIONS {
                let applied = transaction
                    .query_opt(
                        "SELECT 1 FROM schema_migrations WHERE version = $1",
                        &[&version],
                    )
                    .await?
                    .is_some();
                if !applied {
                    tracing::info!(version, "applying database migration");
                    transaction.batch_execute(sql).await?;
                    transaction
                        .execute(
                            "INSERT INTO schema_migrations (version) VALUES ($1)",
                            &[&version],
                        )
                        .await?;
                }
            }
            transaction.commit().await?;
            Ok(())
        })
    }

    /// Every job changed after `since` (the queued and running jobs when `None`), and the mark to pass next
    /// time. The mark trails the database clock by a margin, so a change committed just after
    /// a statement that began earlier is still seen; a change may come twice.
    pub fn changes(
        &self,
        since: Option<SystemTime>,
    ) -> Result<(Vec<Change>, SystemTime), StoreError> {
        self.run(move |client| async move {
            let mark: SystemTime = client
                .query_one("SELECT clock_timestamp() - interval '5 seconds'", &[])
                .await?
                .get(0);
            let rows = match since {
                Some(since) => {
                    client
                        .query(
                            &format!(
                                "SELECT {RECORD_COLUMNS}, deleted FROM jobs WHERE updated_at > $1
                                 ORDER BY updated_at"
                            ),
                            &[&since],
                        )
                        .await?
                }
                None => {
                    client
                        .query(
                            &format!(
                                "SELECT {RECORD_COLUMNS}, deleted FROM jobs
                                 WHERE status IN ('queued', 'running') AND NOT deleted
                                 ORDER BY id"
                            ),
                            &[],
                        )
                        .await?
                }
            };
            let mut changes = Vec::with_capacity(rows.len());
            for row in &rows {
                if row.get::<_, bool>(5) {
                    changes.push(Change::Deleted(row.get(0)));
                    continue;
                }
                match record_of(row) {
                    Ok(record) => changes.push(Change::Live(Box::new(record))),
                    // Left out (and logged), as the embedded store's quarantine does.
                    Err(error) => tracing::error!(%error, "unreadable job record skipped"),
                }
            }
            Ok((changes, mark))
        })
    }

    /// (queued, running) jobs.
    pub fn depth(&self) -> Result<(usize, usize), StoreError> {
        self.run(|client| async move {
            let row = client
                .query_one(
                    "SELECT count(*) FILTER (WHERE status = 'queued'),
                            count(*) FILTER (WHERE status = 'running')
                     FROM jobs WHERE status IN ('queued', 'running') AND NOT deleted",
                    &[],
                )
                .await?;
            Ok((row.get::<_, i64>(0) as usize, row.get::<_, i64>(1) as usize))
        })
    }

    /// When each client last had a job claimed, in Unix ms (for queue positions).
    pub fn served(&self) -> Result<HashMap<String, u64>, StoreError> {
        self.run(|client| async move {
            let rows = client
                .query(
                    "SELECT client, (extract(epoch FROM last_served) * 1000)::bigint
                     FROM queue_clients",
                    &[],
                )
                .await?;
            Ok(rows
                .iter()
                .map(|row| (row.get(0), row.get::<_, i64>(1).max(0) as u64))
                .collect())
        })
    }

    /// Removes the rows of jobs deleted more than `age` ago (long after any worker saw it).
    pub fn purge_tombstones(&self, age: Duration) -> Result<u64, StoreError> {
        self.run(move |client| async move {
            Ok(client
                .execute(
                    "DELETE FROM jobs WHERE deleted
                     AND updated_at < clock_timestamp() - make_interval(secs => $1)",
                    &[&age.as_secs_f64()],
                )
                .await?)
        })
    }
}

impl Records for Postgres {
    /// The live job `id`.
    fn get(&self, id: &str) -> Result<Option<JobRecord>, StoreError> {
        let id = id.to_owned();
        self.run(move |client| async move {
            let row = client
                .query_opt(
                    &format!("SELECT {RECORD_COLUMNS} FROM jobs WHERE id = $1 AND NOT deleted"),
                    &[&id],
                )
                .await?;
            row.as_ref().map(record_of).transpose()
        })
    }

    /// Up to `limit` ids of `owner`'s live jobs (with `status` if given) strictly older than
    /// `before`, newest first; one index range scan.
    fn list_ids(
        &self,
        owner: &Option<String>,
        status: Option<Status>,
        before: &str,
        limit: usize,
    ) -> Result<Vec<String>, StoreError> {
        let (owner, before) = (owner.clone().unwrap_or_default(), before.to_owned());
        self.run(move |client| async move {
            let limit = limit as i64;
            let rows = match status {
                Some(status) => {
                    client
                        .query(
                            "SELECT id FROM jobs WHERE coalesce(owner, '') = $1 AND status = $2
                                 AND id < $3 AND NOT deleted ORDER BY id DESC LIMIT $4",
                            &[&owner, &status.name(), &before, &limit],
                        )
                        .await?
                }
                None => {
                    client
                        .query(
                            "SELECT id FROM jobs WHERE coalesce(owner, '') = $1 AND id < $2
                                 AND NOT deleted ORDER BY id DESC LIMIT $3",
                            &[&owner, &before, &limit],
                        )
                        .await?
                }
            };
            Ok(rows.iter().map(|row| row.get(0)).collect())
        })
    }

    fn idempotent(
        &self,
        owner: &Option<String>,
        key: &str,
        created_since: u64,
    ) -> Result<Option<JobRecord>, StoreError> {
        let (owner, key) = (owner.clone(), Some(key.to_owned()));
        self.run(
            move |client| async move { by_key(&client, &owner, &key, created_since as i64).await },
        )
    }

    fn drop_idempotency_keys(&self, created_before: u64) -> Result<usize, StoreError> {
        self.run(move |client| async move {
            let dropped = client
                .execute(
                    &format!(
                        "UPDATE jobs SET {DROP_KEY} WHERE idempotency_key IS NOT NULL
                             AND (record ->> 'created_at')::bigint < $1"
                    ),
                    &[&(created_before as i64)],
                )
                .await?;
            Ok(dropped as usize)
        })
    }

    fn results_due(&self, now: u64, limit: usize) -> Result<Vec<String>, StoreError> {
        self.run(move |client| async move {
            let rows = client
                .query(
                    "SELECT id FROM jobs WHERE record ->> 'data_removed' = 'false' AND NOT deleted
                         AND (record ->> 'expires_at')::bigint <= $1
                     LIMIT $2",
                    &[&(now as i64), &(limit as i64)],
                )
                .await?;
            Ok(rows.iter().map(|row| row.get(0)).collect())
        })
    }

    fn expire_records(
        &self,
        ended_before: u64,
        expired_before: u64,
        limit: usize,
    ) -> Result<Vec<String>, StoreError> {
        self.run(move |client| async move {
            let rows = client
                .query(
                    "WITH gone AS (
                         DELETE FROM jobs WHERE id IN (
                             SELECT id FROM jobs
                             WHERE status IN ('succeeded', 'failed', 'canceled') AND NOT deleted
                                 AND (record ->> 'completed_at')::bigint < $1
                             LIMIT $2 FOR UPDATE SKIP LOCKED)
                         RETURNING id, owner),
                     kept AS (
                         INSERT INTO expired_jobs (id, owner, expired_at)
                         SELECT id, owner, (extract(epoch FROM clock_timestamp()) * 1000)::bigint
                         FROM gone ON CONFLICT (id) DO NOTHING)
                     SELECT id FROM gone",
                    &[&(ended_before as i64), &(limit as i64)],
                )
                .await?;
            client
                .execute(
                    "DELETE FROM expired_jobs WHERE expired_at < $1",
                    &[&(expired_before as i64)],
                )
                .await?;
            Ok(rows.iter().map(|row| row.get(0)).collect())
        })
    }

    fn expired_owner(&self, id: &str) -> Result<Option<Option<String>>, StoreError> {
        let id = id.to_owned();
        self.run(move |client| async move {
            let row = client
                .query_opt("SELECT owner FROM expired_jobs WHERE id = $1", &[&id])
                .await?;
            Ok(row.map(|row| row.get(0)))
        })
    }

    /// Whether a live job `id` exists (what the orphan sweep keeps).
    fn has_record(&self, id: &str) -> Result<bool, StoreError> {
        Ok(self.get(id)?.is_some())
    }

    /// Marks a job deleted for good: the commit point of a DELETE. Its worker, if it runs,
    /// learns it at its next heartbeat; the row goes in [`Postgres::purge_tombstones`].
    fn tombstone(&self, id: &str) -> Result<(), StoreError> {
        let id = id.to_owned();
        self.run(move |client| async move {
            client
                .execute("UPDATE jobs SET deleted = true WHERE id = $1", &[&id])
                .await?;
            Ok(())
        })
    }

    /// Writes the record of a job no worker holds (a queued or ended one), keeping its stored
    /// webhook deliveries.
    fn save(&self, record: &JobRecord) -> Result<(), StoreError> {
        let (id, json) = (record.id.clone(), to_json(record));
        self.run(move |client| async move {
            client
                .execute(
                    &format!(
                        "UPDATE jobs SET record = $2::text::jsonb {KEEP_WEBHOOK}
                         WHERE id = $1 AND lease_owner IS NULL AND NOT deleted"
                    ),
                    &[&id, &json],
                )
                .await?;
            Ok(())
        })
    }

    /// Stores a job's webhook deliveries (the one field its delivering replica writes).
    fn save_webhook(&self, record: &JobRecord) -> Result<(), StoreError> {
        let id = record.id.clone();
        let json = serde_json::to_string(&record.webhook).expect("a webhook always serialises");
        self.run(move |client| async move {
            client
                .execute(
                    "UPDATE jobs SET record = jsonb_set(record, '{webhook}', $2::text::jsonb)
                     WHERE id = $1 AND NOT deleted",
                    &[&id, &json],
                )
                .await?;
            Ok(())
        })
    }

    /// Checks that the database answers (for `/readyz`).
    fn check(&self) -> Result<(), StoreError> {
        self.run(|client| async move {
            client.query_one("SELECT 1", &[]).await?;
            Ok(())
        })
    }
}

/// The live job holding `owner`'s Idempotency-Key `key`, if any, created at or after
/// `keys_since` (Unix ms; an older key has expired).
async fn by_key(
    client: &deadpool_postgres::Object,
    owner: &Option<String>,
    key: &Option<String>,
    keys_since: i64,
) -> Result<Option<JobRecord>, StoreError> {
    let Some(key) = key else {
        return Ok(None);
    };
    let owner = owner.clone().unwrap_or_default();
    let row = client
        .query_opt(
            &format!(
                "SELECT {RECORD_COLUMNS} FROM jobs
                 WHERE coalesce(owner, '') = $1 AND idempotency_key = $2 AND NOT deleted
                     AND (record ->> 'created_at')::bigint >= $3"
            ),
            &[&owner, key, &keys_since],
        )
        .await?;
    row.as_ref().map(record_of).transpose()
}

fn to_json(record: &JobRecord) -> String {
    serde_json::to_string(record).expect("a job record always serialises")
}

/// A record from [`RECORD_COLUMNS`]: the JSON, with the queue's columns over it.
fn record_of(row: &Row) -> Result<JobRecord, StoreError> {
    let id: String = row.get(0);
    let mut record = parse_record(&id, row.get(1))?;
    let status: &str = row.get(2);
    record.status = Status::from_name(status).ok_or_else(|| StoreError::CorruptRecord {
        id: id.clone(),
        reason: format!("unknown status `{status}`"),
    })?;
    record.cancel_requested |= row.get::<_, bool>(3);
    record.attempts = row.get::<_, i32>(4).max(0) as u32;
    Ok(record)
}
