//! Bounded records (issue 20): ended jobs' records are deleted after the record retention (the
//! job then answers 410, never 404, until that too expires), Idempotency-Keys expire, memory
//! holds only the jobs in use, and a restart does not read every stored record. Over a real
//! server; scripts/test.sh runs this binary on both backends.
#![cfg(all(feature = "cli", feature = "service"))]

use crate::service_support;

use std::time::{Duration, Instant};

use hyper::StatusCode;
use service_support::{DataDir, QUICK_PARAMS, Reply, Server, problem, test_png};

/// Longest wait for a sweep the test expects (sweeps run every second with these settings).
const SWEEP_PATIENCE: Duration = Duration::from_secs(30);

async fn submit_keyed(server: &Server, key: &str) -> Reply {
    server
        .submit(
            &[
                ("image", &test_png(32)),
                ("params", QUICK_PARAMS.as_bytes()),
            ],
            &[("idempotency-key", key)],
        )
        .await
}

/// Submits with `key`, waits for success and returns the job's id.
async fn finished_keyed(server: &Server, key: &str) -> String {
    let created = submit_keyed(server, key).await;
    assert_eq!(created.status, StatusCode::CREATED, "{}", created.text());
    let id = created.json()["id"].as_str().unwrap().to_owned();
    let job = server
        .wait_for(&id, Duration::from_secs(60), |job| {
            !["queued", "running"].contains(&job["status"].as_str().unwrap())
        })
        .await;
    assert_eq!(job["status"], "succeeded", "{job}");
    id
}

/// One value from the store of `dir`: `sqlite` on the embedded backend, `postgres` on the
/// shared one (its text as `psql` prints it).
fn stored(dir: &DataDir, sqlite: &str, postgres: &str) -> String {
    match dir.database() {
        Some(database) => database.query(postgres).trim().to_owned(),
        None => {
            let db = rusqlite::Connection::open(dir.0.join("jobs.sqlite3")).unwrap();
            db.query_row(sqlite, [], |row| row.get::<_, i64>(0))
                .unwrap()
                .to_string()
        }
    }
}

/// The value of `name` on `/metrics`.
async fn gauge(server: &Server, name: &str) -> f64 {
    let text = server.get("/metrics").await.text();
    text.lines()
        .find_map(|line| line.strip_prefix(name)?.strip_prefix(' '))
        .unwrap_or_else(|| panic!("no {name} in {text}"))
        .parse()
        .unwrap()
}

/// Polls `GET path` until it answers `status`, at most [`SWEEP_PATIENCE`].
async fn wait_for_status(server: &Server, path: &str, status: StatusCode) -> Reply {
    let started = Instant::now();
    loop {
        let reply = server.get(path).await;
        if reply.status == status {
            return reply;
        }
        assert!(
            started.elapsed() < SWEEP_PATIENCE,
            "{path} still answers {} ({}), not {status}",
            reply.status,
            reply.text()
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}

#[tokio::test(flavor = "multi_thread")]
async fn expired_records_and_their_keys_leave_the_api_the_store_and_memory() {
    let dir = DataDir::persistent("records-expire");
    let server = Server::start(&dir.0, &["--workers", "1", "--record-retention", "3"]);
    let old = finished_keyed(&server, "order-1").await;
    let replay = submit_keyed(&server, "order-1").await;
    assert_eq!(replay.json()["id"], old.as_str(), "{}", replay.text());
    let count = |id: &str| {
        stored(
            &dir,
            &format!("SELECT count(*) FROM jobs WHERE id = '{id}'"),
            &format!("SELECT count(*) FROM jobs WHERE id = '{id}'"),
        )
    };
    assert_eq!(count(&old), "1");

    // Past the record retention: gone from the API with 410, distinct from a 404.
    let gone = wait_for_status(&server, &format!("/v1/jobs/{old}"), StatusCode::GONE).await;
    assert_eq!(problem(&gone)["code"], "job-expired", "{}", gone.text());
    let results = server.get(&format!("/v1/jobs/{old}/svg")).await;
    assert_eq!(results.status, StatusCode::GONE, "{}", results.text());
    let never = server
        .get("/v1/jobs/job_0123456789abcdef0123456789abcdef")
        .await;
    assert_eq!(never.status, StatusCode::NOT_FOUND, "{}", never.text());
    assert_eq!(problem(&never)["code"], "job-not-found");
    let listed = server.get("/v1/jobs").await.json();
    assert!(
        listed["items"].as_array().unwrap().is_empty(),
        "an expired job is still listed: {listed}"
    );
    // From the store, and from memory.
    assert_eq!(count(&old), "0");
    assert_eq!(gauge(&server, "covec_jobs_in_memory").await, 0.0);

    // Its key went with it: the same key makes a new job.
    let new = finished_keyed(&server, "order-1").await;
    assert_ne!(new, old);

    // The expired id itself is forgotten a record retention later: then 404.
    let forgotten =
        wait_for_status(&server, &format!("/v1/jobs/{old}"), StatusCode::NOT_FOUND).await;
    assert_eq!(problem(&forgotten)["code"], "job-not-found");
    let tombstones = stored(
        &dir,
        &format!("SELECT count(*) FROM expired_jobs WHERE id = '{old}'"),
        &format!("SELECT count(*) FROM expired_jobs WHERE id = '{old}'"),
    );
    assert_eq!(tombstones, "0");
    server.stop();
}

#[tokio::test(flavor = "multi_thread")]
async fn an_idempotency_key_expires_after_its_window_while_the_record_stays() {
    let dir = DataDir::persistent("records-keys");
    let server = Server::start(&dir.0, &["--workers", "1", "--idempotency-window", "2"]);
    let first = finished_keyed(&server, "batch-7").await;
    let replay = submit_keyed(&server, "batch-7").await;
    assert_eq!(replay.json()["id"], first.as_str(), "{}", replay.text());
    // The sweep takes the key off the stored record once the window has passed.
    let started = Instant::now();
    let key_of_first = || {
        stored(
            &dir,
            &format!(
                "SELECT count(*) FROM jobs WHERE id = '{first}' AND idempotency_key IS NOT NULL"
            ),
            &format!(
                "SELECT count(*) FROM jobs WHERE id = '{first}' AND idempotency_key IS NOT NULL"
            ),
        )
    };
    while key_of_first() != "0" {
        assert!(started.elapsed() < SWEEP_PATIENCE, "the key stayed stored");
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    let second = finished_keyed(&server, "batch-7").await;
    assert_ne!(second, first, "an expired key replayed its job");
    // The first job is still there; the key now replays the second.
    let job = server.get(&format!("/v1/jobs/{first}")).await;
    assert_eq!(job.status, StatusCode::OK, "{}", job.text());
    let replay = submit_keyed(&server, "batch-7").await;
    assert_eq!(replay.json()["id"], second.as_str(), "{}", replay.text());
    server.stop();
}

/// Copies of stored records.
const COPIES: u32 = 100_000;

#[tokio::test(flavor = "multi_thread")]
async fn a_restart_with_100k_stored_records_is_quick_and_keeps_them() {
    let dir = DataDir::persistent("records-restart");
    let server = Server::start(&dir.0, &["--workers", "1"]);
    let template = server.finished_job().await;
    server.stop();
    // Copies of the finished job's row under new ids, written as the store writes them.
    let copy = |n: u32| format!("job_{n:032x}");
    match dir.database() {
        Some(database) => {
            database.query(&format!(
                "INSERT INTO jobs (id, owner, status, record, client, priority)
                 SELECT 'job_' || lpad(to_hex(n), 32, '0'), owner, status,
                     jsonb_set(record, '{{id}}', to_jsonb('job_' || lpad(to_hex(n), 32, '0'))),
                     client, priority
                 FROM jobs, generate_series(1, {COPIES}) AS n WHERE id = '{template}'"
            ));
        }
        None => {
            let mut db = rusqlite::Connection::open(dir.0.join("jobs.sqlite3")).unwrap();
            let transaction = db.transaction().unwrap();
            let (record, owner, status): (String, Option<String>, String) = transaction
                .query_row(
                    "SELECT record, owner, status FROM jobs WHERE id = ?1",
                    [&template],
                    |row| Ok((row.get(0)?, row.get(1)?, row.get(2)?)),
                )
                .unwrap();
            let mut template_record: serde_json::Value = serde_json::from_str(&record).unwrap();
            {
                let mut insert = transaction
                    .prepare(
                        "INSERT INTO jobs (id, owner, status, record, created_at, completed_at,
                             results_expire_at)
                         SELECT ?1, ?2, ?3, ?4, created_at, completed_at, results_expire_at
                         FROM jobs WHERE id = ?5",
                    )
                    .unwrap();
                for n in 1..=COPIES {
                    template_record["id"] = copy(n).into();
                    insert
                        .execute(rusqlite::params![
                            copy(n),
                            owner,
                            status,
                            template_record.to_string(),
                            template
                        ])
                        .unwrap();
                }
            }
            transaction.commit().unwrap();
        }
    }

    let started = Instant::now();
    let server = Server::start(&dir.0, &["--workers", "1"]);
    let ready = started.elapsed();
    assert!(
        ready < Duration::from_secs(2),
        "{COPIES} stored records: listening after {ready:?}"
    );
    // The records are there, read when asked for; only what is asked for is held.
    let job = server.get(&format!("/v1/jobs/{}", copy(COPIES / 2))).await;
    assert_eq!(job.status, StatusCode::OK, "{}", job.text());
    assert_eq!(job.json()["status"], "succeeded");
    let page = server.get("/v1/jobs?limit=100").await.json();
    assert_eq!(page["items"].as_array().unwrap().len(), 100, "{page}");
    assert!(page["next_cursor"].is_string());
    assert_eq!(gauge(&server, "covec_jobs_in_memory").await, 0.0);
    server.stop();
}
