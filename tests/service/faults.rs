//! Storage faults and crashes on a real `covec serve` over loopback (issue 13): deleted jobs
//! stay deleted, unreadable records do not stop the server, deletes never leave half-done
//! state, orphaned files are swept, and a kill -9 loop loses no accepted job.
#![cfg(all(feature = "cli", feature = "service"))]

use crate::service_support;

use std::path::Path;
use std::process::Command;
use std::sync::Arc;
use std::time::{Duration, Instant};

use hyper::{Method, StatusCode};
use service_support::{DataDir, LONG_PARAMS, QUICK_PARAMS, Server, test_png};

async fn submit(server: &Server, params: &str, size: u32) -> String {
    let created = server
        .submit(
            &[("image", &test_png(size)), ("params", params.as_bytes())],
            &[],
        )
        .await;
    assert_eq!(created.status, StatusCode::CREATED, "{}", created.text());
    created.json()["id"].as_str().unwrap().to_owned()
}

async fn delete(server: &Server, id: &str) -> service_support::Reply {
    server
        .request(Method::DELETE, &format!("/v1/jobs/{id}"), &[], Vec::new())
        .await
}

/// A server on `dir` with one worker, and a quick job it has run to success.
async fn one_finished_job(dir: &DataDir) -> (Server, String) {
    let server = Server::start(&dir.0, &["--workers", "1"]);
    let id = submit(&server, QUICK_PARAMS, 32).await;
    server
        .wait_for(&id, Duration::from_secs(60), |job| {
            job["status"] == "succeeded"
        })
        .await;
    (server, id)
}

/// Waits up to `timeout` for `check`; false if it never held.
async fn eventually(timeout: Duration, check: impl Fn() -> bool) -> bool {
    let started = Instant::now();
    while started.elapsed() < timeout {
        if check() {
            return true;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    check()
}

/// Item 5: a cancel racing a DELETE on a queued job must not bring the record back (before the
/// tombstone, 7 of 200 such jobs were back as `canceled` after a restart); neither may a
/// running job deleted while its runner stops.
#[tokio::test(flavor = "multi_thread")]
async fn deleted_jobs_stay_deleted_across_cancel_races_and_restarts() {
    let dir = DataDir::new("tombstone");
    // The shared backend sweeps files of deleted jobs at start once this old.
    let args = [
        "--workers",
        "1",
        "--max-queued",
        "200",
        "--max-iterations",
        "10000000",
        "--orphan-age",
        "1",
    ];
    let server = Arc::new(Server::start(&dir.0, &args));
    // One long job holds the only worker, so the others stay queued.
    let running = submit(&server, LONG_PARAMS, 64).await;
    server
        .wait_for(&running, Duration::from_secs(20), |job| {
            job["status"] == "running"
        })
        .await;
    let mut queued = Vec::new();
    for _ in 0..150 {
        queued.push(submit(&server, QUICK_PARAMS, 32).await);
    }
    let races: Vec<_> = queued
        .iter()
        .cloned()
        .map(|id| {
            let server = Arc::clone(&server);
            tokio::spawn(async move {
                let (canceled, deleted) = tokio::join!(server.cancel(&id), delete(&server, &id));
                assert!(
                    [StatusCode::OK, StatusCode::NOT_FOUND].contains(&canceled.status),
                    "cancel: {} {}",
                    canceled.status,
                    canceled.text()
                );
                assert_eq!(deleted.status, StatusCode::NO_CONTENT, "{}", deleted.text());
            })
        })
        .collect();
    for race in races {
        race.await.unwrap();
    }
    let deleted = delete(&server, &running).await;
    assert_eq!(deleted.status, StatusCode::NO_CONTENT, "{}", deleted.text());
    Arc::into_inner(server).unwrap().kill();
    tokio::time::sleep(Duration::from_millis(2100)).await;

    let server = Server::start(&dir.0, &args);
    let mut back = Vec::new();
    for id in queued.iter().chain([&running]) {
        let reply = server.get(&format!("/v1/jobs/{id}")).await;
        if reply.status != StatusCode::NOT_FOUND || dir.job_files_exist(id) {
            back.push(format!("{id}: {} {}", reply.status, reply.text()));
        }
    }
    assert!(
        back.is_empty(),
        "deleted jobs back after a restart: {back:#?}"
    );
    let listed = server.get("/v1/jobs?limit=100").await.json();
    assert_eq!(listed["items"].as_array().unwrap().len(), 0, "{listed}");
}

/// Item 9: deleting running jobs (whose runners are writing previews) answers 204 every time,
/// and the runner removes the files once it stops.
#[tokio::test(flavor = "multi_thread")]
async fn deleting_running_jobs_answers_204_and_leaves_no_files() {
    let dir = DataDir::new("delete-running");
    let server = Server::start(&dir.0, &["--workers", "2", "--max-iterations", "10000000"]);
    for _ in 0..6 {
        let id = submit(&server, LONG_PARAMS, 64).await;
        server
            .wait_for(&id, Duration::from_secs(20), |job| {
                job["status"] == "running"
                    && job["previews"].as_array().is_some_and(|p| !p.is_empty())
            })
            .await;
        let reply = delete(&server, &id).await;
        assert_eq!(reply.status, StatusCode::NO_CONTENT, "{}", reply.text());
        assert_eq!(
            server.get(&format!("/v1/jobs/{id}")).await.status,
            StatusCode::NOT_FOUND
        );
        assert!(
            eventually(Duration::from_secs(10), || !dir.job_files_exist(&id)).await,
            "{id}'s files still exist"
        );
    }
}

/// Item 8: an unreadable job record is quarantined at start (a log line and a metric); the
/// server starts and serves the other jobs. On the shared backend (no quarantine there: the
/// database keeps the row) a record of the wrong shape is a problem, and the others serve.
#[tokio::test(flavor = "multi_thread")]
async fn a_corrupt_job_record_is_quarantined_and_the_server_starts() {
    let dir = DataDir::new("quarantine");
    let server = Server::start(&dir.0, &["--workers", "1"]);
    let good = submit(&server, QUICK_PARAMS, 32).await;
    let bad = submit(&server, QUICK_PARAMS, 32).await;
    for id in [&good, &bad] {
        server
            .wait_for(id, Duration::from_secs(60), |job| {
                job["status"] == "succeeded"
            })
            .await;
    }
    server.stop();
    if let Some(database) = dir.database() {
        // jsonb keeps the text valid JSON, so the damage is a record of the wrong shape.
        database.query(&format!(
            "UPDATE jobs SET record = '{{\"id\": 5}}' WHERE id = '{bad}'"
        ));
        let server = Server::start(&dir.0, &["--workers", "1"]);
        let reply = server.get(&format!("/v1/jobs/{good}/svg")).await;
        assert_eq!(reply.status, StatusCode::OK);
        let reply = server.get(&format!("/v1/jobs/{bad}")).await;
        let problem = service_support::problem(&reply);
        assert!(
            [StatusCode::NOT_FOUND, StatusCode::INTERNAL_SERVER_ERROR].contains(&reply.status),
            "{problem}"
        );
        // One unreadable row does not hide the others from a listing.
        let listed = server.get("/v1/jobs").await;
        assert_eq!(listed.status, StatusCode::OK, "{}", listed.text());
        let listed = listed.json();
        let ids: Vec<_> = listed["items"]
            .as_array()
            .unwrap()
            .iter()
            .map(|job| &job["id"])
            .collect();
        assert_eq!(ids, [&serde_json::json!(good)], "{listed}");
        server.stop();
        return;
    }
    let db = rusqlite::Connection::open(dir.0.join("jobs.sqlite3")).unwrap();
    db.execute(
        "UPDATE jobs SET record = '{\"id\": truncated' WHERE id = ?1",
        [&bad],
    )
    .unwrap();
    drop(db);

    let server = Server::start(&dir.0, &["--workers", "1"]);
    let reply = server.get(&format!("/v1/jobs/{good}/svg")).await;
    assert_eq!(reply.status, StatusCode::OK);
    let reply = server.get(&format!("/v1/jobs/{bad}")).await;
    assert_eq!(reply.status, StatusCode::NOT_FOUND, "{}", reply.text());
    let metrics = server.get("/metrics").await.text();
    assert!(
        metrics.contains("covec_jobs_quarantined 1"),
        "no quarantine count in {metrics}"
    );
    server.stop();
    let log = std::fs::read_to_string(dir.0.with_extension("log")).unwrap();
    assert!(
        log.contains("unreadable job record quarantined") && log.contains(&bad),
        "no quarantine line in the log"
    );
    // The row and its files are kept for a look, not swept.
    assert!(dir.job_files_exist(&bad));
    let db = rusqlite::Connection::open(dir.0.join("jobs.sqlite3")).unwrap();
    let kept: String = db
        .query_row(
            "SELECT record FROM quarantine WHERE id = ?1",
            [&bad],
            |row| row.get(0),
        )
        .unwrap();
    assert_eq!(kept, "{\"id\": truncated");
}

/// Item 10: directories no job owns (an upload interrupted by a crash, a refused submission)
/// are removed at start (on the shared backend once `--orphan-age` old, since other replicas
/// may be admitting jobs); a job's own directory stays.
#[tokio::test(flavor = "multi_thread")]
async fn orphaned_job_directories_are_swept_at_start() {
    let dir = DataDir::new("orphans");
    let (server, id) = one_finished_job(&dir).await;
    server.stop();
    let orphan = "job_0192a1b2c3d4e5f60718293a4b5c6d7e";
    dir.write_job_file(orphan, "input/image", &test_png(32));
    if dir.is_shared() {
        // Young files are someone's upload in flight: kept.
        let server = Server::start(&dir.0, &["--workers", "1", "--orphan-age", "60"]);
        assert!(dir.job_files_exist(orphan), "a young orphan was swept");
        server.stop();
        // Stored times have whole seconds.
        tokio::time::sleep(Duration::from_millis(2100)).await;
    }

    let server = Server::start(&dir.0, &["--workers", "1", "--orphan-age", "1"]);
    assert!(!dir.job_files_exist(orphan), "the orphan is still there");
    assert!(dir.job_files_exist(&id));
    assert_eq!(
        server.get(&format!("/v1/jobs/{id}/svg")).await.status,
        StatusCode::OK
    );
    let metrics = server.get("/metrics").await.text();
    assert!(metrics.contains("covec_orphans_swept_total 1"), "{metrics}");
}

/// The fault suite's crash case: kill -9 at arbitrary moments of mixed traffic (submits,
/// cancels, deletes, reads). After each restart every job whose submission got a 201 and that
/// was not deleted exists, and no job whose DELETE got a 204 is back.
#[tokio::test(flavor = "multi_thread")]
async fn kill_9_during_mixed_traffic_loses_no_job_and_revives_no_deleted_one() {
    let dir = DataDir::new("kill-loop");
    let args = [
        "--workers",
        "1",
        "--max-queued",
        "500",
        "--max-iterations",
        "10000000",
    ];
    let mut accepted: Vec<String> = Vec::new();
    let mut deleted: Vec<String> = Vec::new();
    let rounds = 6;
    for round in 0..rounds {
        let server = Arc::new(Server::start(&dir.0, &args));
        // Every earlier promise holds after the crash.
        for id in &accepted {
            let reply = server.get(&format!("/v1/jobs/{id}")).await;
            assert_eq!(reply.status, StatusCode::OK, "round {round}: {id} lost");
        }
        for id in &deleted {
            let reply = server.get(&format!("/v1/jobs/{id}")).await;
            assert_eq!(
                reply.status,
                StatusCode::NOT_FOUND,
                "round {round}: {id} back"
            );
        }
        let traffic: Vec<_> = (0..4)
            .map(|client| {
                let server = Arc::clone(&server);
                tokio::spawn(async move {
                    let (mut accepted, mut deleted) = (Vec::new(), Vec::new());
                    for i in 0.. {
                        let image = test_png(32);
                        let params = if (client + i) % 3 == 0 {
                            LONG_PARAMS
                        } else {
                            QUICK_PARAMS
                        };
                        let (content_type, body) = service_support::multipart(&[
                            ("image", &image),
                            ("params", params.as_bytes()),
                        ]);
                        let Ok(reply) = server
                            .try_request(
                                Method::POST,
                                "/v1/jobs",
                                &[("content-type", &content_type)],
                                body,
                            )
                            .await
                        else {
                            break;
                        };
                        if reply.status != StatusCode::CREATED {
                            continue;
                        }
                        let id = reply.json()["id"].as_str().unwrap().to_owned();
                        let path = format!("/v1/jobs/{id}");
                        let deleting = i % 4 == 0;
                        let outcome = match i % 4 {
                            0 => {
                                server
                                    .try_request(Method::DELETE, &path, &[], Vec::new())
                                    .await
                            }
                            1 => {
                                server
                                    .try_request(
                                        Method::POST,
                                        &format!("{path}/cancel"),
                                        &[],
                                        Vec::new(),
                                    )
                                    .await
                            }
                            _ => {
                                server
                                    .try_request(Method::GET, &path, &[], Vec::new())
                                    .await
                            }
                        };
                        match outcome {
                            Ok(reply) if reply.status == StatusCode::NO_CONTENT => deleted.push(id),
                            Ok(_) => accepted.push(id),
                            Err(_) => {
                                // Killed during the second request: a DELETE may or may not
                                // have happened; anything else leaves the job accepted.
                                if !deleting {
                                    accepted.push(id);
                                }
                                break;
                            }
                        }
                    }
                    (accepted, deleted)
                })
            })
            .collect();
        // Kill at a different moment each round.
        tokio::time::sleep(Duration::from_millis(300 + 170 * round)).await;
        server.sigkill();
        for task in traffic {
            let (mut a, mut d) = task.await.unwrap();
            accepted.append(&mut a);
            deleted.append(&mut d);
        }
        drop(server);
    }
    let server = Server::start(&dir.0, &args);
    let mut lost = 0;
    for id in &accepted {
        if server.get(&format!("/v1/jobs/{id}")).await.status != StatusCode::OK {
            lost += 1;
        }
    }
    let mut back = 0;
    for id in &deleted {
        if server.get(&format!("/v1/jobs/{id}")).await.status != StatusCode::NOT_FOUND {
            back += 1;
        }
    }
    println!(
        "{rounds} kill -9s: {} accepted jobs, {lost} lost; {} deleted, {back} back",
        accepted.len(),
        deleted.len()
    );
    assert!(
        accepted.len() > 20 && deleted.len() > 5,
        "too little traffic"
    );
    assert_eq!((lost, back), (0, 0));
}

/// A small tmpfs for the data directory, unmounted on drop; `None` (the test then says it is
/// skipped) where the machine does not allow mounting.
struct Tmpfs(std::path::PathBuf);

impl Tmpfs {
    fn mount(dir: &Path, size: &str) -> Option<Self> {
        let ok = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"])
            .arg(dir)
            .stderr(std::process::Stdio::null())
            .status()
            .is_ok_and(|status| status.success());
        ok.then(|| Self(dir.to_owned()))
    }
}

/// `dir` made read-only by a read-only bind mount over itself, until dropped.
struct ReadOnly(std::path::PathBuf);

impl ReadOnly {
    fn bind(dir: &Path) -> Self {
        for args in [&["--bind"][..], &["-o", "remount,bind,ro"][..]] {
            let status = Command::new("mount")
                .args(args)
                .arg(dir)
                .arg(dir)
                .status()
                .unwrap();
            assert!(status.success(), "mount {args:?}");
        }
        Self(dir.to_owned())
    }
}

impl Drop for ReadOnly {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.0).status();
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg("-l").arg(&self.0).status();
    }
}

/// Item 9 and the fault suite's full-disk case: on a full disk and on a read-only one, a
/// DELETE either answers 204 and the job never comes back, or answers a 5xx problem and the
/// job is whole (its record and results still served). Needs `mount` (root): skipped, loudly,
/// elsewhere.
#[tokio::test(flavor = "multi_thread")]
async fn deletes_on_a_full_or_read_only_disk_leave_no_half_done_state() {
    let dir = DataDir::with_local_files("full-disk");
    let Some(tmpfs) = Tmpfs::mount(&dir.0, "24m") else {
        eprintln!("SKIPPED: cannot mount a tmpfs here (needs root); full-disk case not run");
        return;
    };
    // The shared backend sweeps files a delete left at start once this old.
    let args = ["--workers", "1", "--orphan-age", "1"];
    let server = Server::start(&dir.0, &args);
    let mut jobs = Vec::new();
    for _ in 0..3 {
        jobs.push(submit(&server, QUICK_PARAMS, 32).await);
    }
    for id in &jobs {
        server
            .wait_for(id, Duration::from_secs(60), |job| {
                job["status"] == "succeeded"
            })
            .await;
    }
    // Full: a filler file takes every free byte.
    let filler = dir.0.join("filler");
    {
        use std::io::Write;
        let mut file = std::fs::File::create(&filler).unwrap();
        let block = vec![0_u8; 1 << 16];
        while file.write_all(&block).is_ok() {}
        let _ = file.sync_all();
    }
    let full = delete(&server, &jobs[0]).await;
    std::fs::remove_file(&filler).unwrap();
    // The jobs directory read-only (the database stays writable).
    let read_only = {
        let _read_only = ReadOnly::bind(&dir.0.join("jobs"));
        delete(&server, &jobs[1]).await
    };
    for reply in [&full, &read_only] {
        assert!(
            reply.status == StatusCode::NO_CONTENT || reply.status.is_server_error(),
            "{} {}",
            reply.status,
            reply.text()
        );
        if reply.status.is_server_error() {
            service_support::problem(reply);
        }
    }
    println!(
        "DELETE on a full disk: {}; on a read-only disk: {}",
        full.status, read_only.status
    );
    // Consistent now and after a restart (with the files swept once the disk is back).
    server.kill();
    tokio::time::sleep(Duration::from_millis(1100)).await;
    let server = Server::start(&dir.0, &args);
    for (id, reply) in [(&jobs[0], &full), (&jobs[1], &read_only)] {
        let job = server.get(&format!("/v1/jobs/{id}")).await;
        let svg = server.get(&format!("/v1/jobs/{id}/svg")).await;
        if reply.status == StatusCode::NO_CONTENT {
            assert_eq!(job.status, StatusCode::NOT_FOUND, "{id} back");
            assert!(!dir.job_files_exist(id), "{id}'s files left");
        } else {
            assert_eq!(job.status, StatusCode::OK, "{id} half deleted");
            assert_eq!(svg.status, StatusCode::OK, "{id}'s result lost");
        }
    }
    let svg = server.get(&format!("/v1/jobs/{}/svg", jobs[2])).await;
    assert_eq!(svg.status, StatusCode::OK);
    server.kill();
    drop(tmpfs);
}

/// Item 10: a result cut short or altered on disk is a 500 `result-corrupt` problem, never a
/// 200 with bad bytes (each result's digest is recorded when it is written).
#[tokio::test(flavor = "multi_thread")]
async fn damaged_results_are_problems_not_200s() {
    let dir = DataDir::new("damaged");
    let (server, id) = one_finished_job(&dir).await;
    let svg = dir.read_job_file(&id, "result.svg").unwrap();
    dir.write_job_file(&id, "result.svg", &svg[..svg.len() / 2]);
    let scene = dir.read_job_file(&id, "scene.json").unwrap();
    let mut altered = scene.clone();
    let last = altered.len() - 2;
    altered[last] ^= 1;
    dir.write_job_file(&id, "scene.json", &altered);
    for path in ["svg", "scene.json", "png"] {
        let reply = server.get(&format!("/v1/jobs/{id}/{path}")).await;
        assert_eq!(reply.status, StatusCode::INTERNAL_SERVER_ERROR, "{path}");
        assert_eq!(service_support::problem(&reply)["code"], "result-corrupt");
    }
    let layer = server
        .get(&format!("/v1/jobs/{id}/layers/albedo.svg"))
        .await;
    assert_eq!(
        layer.status,
        StatusCode::OK,
        "an intact result still serves"
    );
    // Put back whole, they serve again (also after a restart: the digests are stored).
    dir.write_job_file(&id, "result.svg", &svg);
    dir.write_job_file(&id, "scene.json", &scene);
    server.stop();
    let server = Server::start(&dir.0, &["--workers", "1"]);
    let reply = server.get(&format!("/v1/jobs/{id}/svg")).await;
    assert_eq!(
        (reply.status, reply.body.as_ref()),
        (StatusCode::OK, svg.as_slice())
    );
}

/// Item 10: a job whose result writes meet a full disk retries them with backoff (a full disk
/// is transient: expiry or an operator frees space) instead of failing for good; once space
/// is freed it succeeds, and stays succeeded after a restart. Needs `mount` (root): skipped,
/// loudly, elsewhere.
#[tokio::test(flavor = "multi_thread")]
async fn a_job_meeting_a_full_disk_retries_its_writes_and_succeeds() {
    let dir = DataDir::with_local_files("transient");
    let Some(tmpfs) = Tmpfs::mount(&dir.0, "24m") else {
        eprintln!("SKIPPED: cannot mount a tmpfs here (needs root); transient-error case not run");
        return;
    };
    let args = ["--workers", "1", "--max-iterations", "10000000"];
    let server = Server::start(&dir.0, &args);
    // The long job holds the one worker, so the quick one starts only once the disk is full.
    let long = submit(&server, LONG_PARAMS, 32).await;
    let quick = submit(&server, QUICK_PARAMS, 32).await;
    server
        .wait_for(&long, Duration::from_secs(60), |job| {
            job["status"] == "running"
        })
        .await;
    let filler = dir.0.join("filler");
    {
        use std::io::Write;
        let mut file = std::fs::File::create(&filler).unwrap();
        let block = vec![0_u8; 1 << 16];
        while file.write_all(&block).is_ok() {}
        let _ = file.sync_all();
    }
    assert_eq!(server.cancel(&long).await.status, StatusCode::ACCEPTED);
    let log = dir.0.with_extension("log");
    let retried = eventually(Duration::from_secs(120), || {
        std::fs::read_to_string(&log).is_ok_and(|log| {
            log.lines()
                .any(|line| line.contains(&quick) && line.contains("transient storage error"))
        })
    })
    .await;
    std::fs::remove_file(&filler).unwrap();
    assert!(retried, "no retry of the quick job's writes logged");
    let job = server
        .wait_for(&quick, Duration::from_secs(60), |job| {
            job["status"] != "queued" && job["status"] != "running"
        })
        .await;
    assert_eq!(job["status"], "succeeded", "{job}");
    assert_eq!(
        server.get(&format!("/v1/jobs/{quick}/svg")).await.status,
        StatusCode::OK
    );
    server.kill();
    let server = Server::start(&dir.0, &args);
    let job = server.get(&format!("/v1/jobs/{quick}")).await.json();
    assert_eq!(job["status"], "succeeded", "{job}");
    assert_eq!(
        server.get(&format!("/v1/jobs/{quick}/svg")).await.status,
        StatusCode::OK
    );
    server.kill();
    drop(tmpfs);
}

/// Item 10 for edits: an edit's files (scene, SVG, preview and its record) are checked against
/// the digests stored with them, so one cut short or altered on disk is a 500
/// `result-corrupt`, also as the base of a further edit, never a 200 with bad bytes.
#[tokio::test(flavor = "multi_thread")]
async fn damaged_edit_files_are_problems_not_200s() {
    let dir = DataDir::new("damaged-edit");
    let (server, id) = one_finished_job(&dir).await;
    let created = server
        .post_json(
            &format!("/v1/jobs/{id}/edits"),
            &serde_json::json!({"changes": [{"path": "albedo-0", "color": "#00ff00"}]}),
        )
        .await;
    assert_eq!(created.status, StatusCode::CREATED, "{}", created.text());
    let edit = created.json();
    let edit_id = edit["id"].as_str().unwrap();
    let file = |name: &str| format!("edits/{edit_id}/{name}");
    let url = |path: &str| format!("/v1/jobs/{id}/edits/{edit_id}{path}");
    for path in ["", "/svg", "/scene.json", "/preview.png"] {
        assert_eq!(
            server.get(&url(path)).await.status,
            StatusCode::OK,
            "{path}"
        );
    }
    let preview = dir.read_job_file(&id, &file("preview.png")).unwrap();
    dir.write_job_file(&id, &file("preview.png"), &preview[..preview.len() / 2]);
    let mut scene = dir.read_job_file(&id, &file("scene.json")).unwrap();
    let last = scene.len() - 2;
    scene[last] ^= 1;
    dir.write_job_file(&id, &file("scene.json"), &scene);
    let record = dir.read_job_file(&id, &file("edit.json")).unwrap();
    dir.write_job_file(&id, &file("edit.json"), &record[..record.len() - 1]);
    for path in ["", "/scene.json", "/preview.png"] {
        let reply = server.get(&url(path)).await;
        assert_eq!(reply.status, StatusCode::INTERNAL_SERVER_ERROR, "{path}");
        assert_eq!(service_support::problem(&reply)["code"], "result-corrupt");
    }
    assert_eq!(
        server.get(&url("/svg")).await.status,
        StatusCode::OK,
        "an intact file still serves"
    );
    let chained = server
        .post_json(
            &format!("/v1/jobs/{id}/edits"),
            &serde_json::json!({"base": edit_id, "changes": [{"path": "albedo-0", "color": "#0000ff"}]}),
        )
        .await;
    assert_eq!(chained.status, StatusCode::INTERNAL_SERVER_ERROR);
    assert_eq!(service_support::problem(&chained)["code"], "result-corrupt");
    server.kill();
}
