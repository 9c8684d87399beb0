//! Shared by the service integration tests: starts the real `covec serve` binary on a loopback
//! port with its own data directory, and talks HTTP/1.1 to it.

#![allow(dead_code)] // each test binary uses a different part

pub mod postgres;
pub mod s3;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use http_body_util::{BodyExt, Full};
use hyper::body::Bytes;
use hyper::{Method, Request, StatusCode};
use hyper_util::client::legacy::Client;
use hyper_util::client::legacy::connect::HttpConnector;
use hyper_util::rt::TokioExecutor;
use serde_json::Value;

/// A data directory under the system temp dir, removed on drop. With
/// `COVEC_TEST_BACKEND=postgres` it comes with the shared backend: its own throwaway
/// PostgreSQL, which every [`Server`] started on it uses for its records (`--database-url`),
/// and, when the run has an S3 server (`COVEC_TEST_S3_ENDPOINT`, started by scripts/test.sh),
/// its own bucket there for the artefacts (`--object-store`). With `COVEC_TEST_BACKEND=memory`
/// its servers keep records in memory (`--in-memory`), except on a directory made with
/// [`DataDir::persistent`]. scripts/test.sh runs the service tests all three ways;
/// [`DataDir::read_job_file`] and its siblings reach a job's files on each.
pub struct DataDir(pub PathBuf, Option<Box<Shared>>);

/// Where a data directory's servers keep job files.
#[derive(PartialEq)]
enum Files {
    /// In the backend's bucket, when the run has an S3 server; else under the directory.
    Backend,
    /// Under the directory.
    Local,
}

/// A data directory's shared backend.
struct Shared {
    database: postgres::Postgres,
    bucket: Option<Bucket>,
}

/// A bucket of its own on the run's S3 server.
struct Bucket {
    server: s3::S3Server,
    name: String,
}

/// Where a job's files live in the bucket: `s3://bucket/PREFIX/jobs/ID/…`.
const BUCKET_PREFIX: &str = "covec";

/// What every server on a data directory gets from its shared backend.
struct BackendArgs {
    data_dir: PathBuf,
    database_url: String,
    /// `--object-store`'s URL: the data directory's bucket, if its files are in one.
    object_store: Option<String>,
    /// The bucket's server's AWS_* variables.
    env: Vec<(String, String)>,
}

static BACKENDS: Mutex<Vec<BackendArgs>> = Mutex::new(Vec::new());

/// The data directories whose servers keep records in memory.
static IN_MEMORY: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// The backend the run asks for.
fn test_backend() -> Option<String> {
    std::env::var("COVEC_TEST_BACKEND").ok()
}

impl DataDir {
    pub fn new(name: &str) -> Self {
        let dir = Self::with_files(name, Files::Backend);
        if test_backend().as_deref() == Some("memory") {
            lock(&IN_MEMORY).push(dir.0.clone());
        }
        dir
    }

    /// A data directory whose records are kept where they outlive its server and the test can
    /// read them (tests that restart a server on it, or look into the database): on the memory
    /// run, the embedded backend's.
    pub fn persistent(name: &str) -> Self {
        Self::with_files(name, Files::Backend)
    }

    /// A data directory whose servers keep job files under it on either backend (for tests of
    /// faults of the disk under them).
    pub fn with_local_files(name: &str) -> Self {
        Self::with_files(name, Files::Local)
    }

    fn with_files(name: &str, files: Files) -> Self {
        let mut dir = Self::plain(name);
        if test_backend().as_deref() == Some("postgres") {
            let database = postgres::Postgres::start();
            let mut object_store = None;
            let mut env = Vec::new();
            let server = s3::S3Server::shared().filter(|_| files == Files::Backend);
            let bucket = server.map(|server| {
                static NEXT: AtomicUsize = AtomicUsize::new(0);
                let name = format!(
                    "covec-{}-{}",
                    std::process::id(),
                    NEXT.fetch_add(1, Ordering::SeqCst)
                );
                server
                    .curl("PUT", &format!("/{name}"), None)
                    .expect("creating the bucket");
                object_store = Some(format!("s3://{name}/{BUCKET_PREFIX}"));
                env = server.env();
                Bucket { server, name }
            });
            lock(&BACKENDS).push(BackendArgs {
                data_dir: dir.0.clone(),
                database_url: database.url.clone(),
                object_store,
                env,
            });
            dir.1 = Some(Box::new(Shared { database, bucket }));
        }
        dir
    }

    /// A data directory without a shared backend.
    pub fn plain(name: &str) -> Self {
        static NEXT: AtomicUsize = AtomicUsize::new(0);
        let path = std::env::temp_dir().join(format!(
            "covec-{name}-{}-{}",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::SeqCst)
        ));
        let _ = std::fs::remove_dir_all(&path);
        std::fs::create_dir_all(&path).unwrap();
        Self(path, None)
    }

    /// Whether this directory's servers keep records in PostgreSQL.
    pub fn is_shared(&self) -> bool {
        self.1.is_some()
    }

    /// The bucket holding this directory's artefacts, if they are not on the local disk.
    fn bucket(&self) -> Option<&Bucket> {
        self.1.as_ref().and_then(|shared| shared.bucket.as_ref())
    }

    /// Whether a job's files are on the local disk (so disk faults can reach them).
    pub fn keeps_files_locally(&self) -> bool {
        self.bucket().is_none()
    }

    /// The database, on the shared backend.
    pub fn database(&self) -> Option<&postgres::Postgres> {
        self.1.as_ref().map(|shared| &shared.database)
    }

    fn job_key(bucket: &Bucket, id: &str, name: &str) -> String {
        format!("/{}/{BUCKET_PREFIX}/jobs/{id}/{name}", bucket.name)
    }

    /// A job's stored file (`name` as in the job's folder, e.g. `result.svg`), if present.
    pub fn read_job_file(&self, id: &str, name: &str) -> Option<Vec<u8>> {
        match self.bucket() {
            Some(bucket) => bucket
                .server
                .curl("GET", &Self::job_key(bucket, id, name), None),
            None => std::fs::read(self.0.join("jobs").join(id).join(name)).ok(),
        }
    }

    /// Replaces (or creates) a job's stored file.
    pub fn write_job_file(&self, id: &str, name: &str, bytes: &[u8]) {
        match self.bucket() {
            Some(bucket) => {
                bucket
                    .server
                    .curl("PUT", &Self::job_key(bucket, id, name), Some(bytes))
                    .expect("writing to the bucket");
            }
            None => {
                let path = self.0.join("jobs").join(id).join(name);
                std::fs::create_dir_all(path.parent().unwrap()).unwrap();
                std::fs::write(path, bytes).unwrap();
            }
        }
    }

    /// Whether any file of job `id` is stored.
    pub fn job_files_exist(&self, id: &str) -> bool {
        match self.bucket() {
            Some(bucket) => !bucket
                .server
                .keys(&bucket.name, &format!("{BUCKET_PREFIX}/jobs/{id}/"))
                .is_empty(),
            None => self.0.join("jobs").join(id).exists(),
        }
    }

    /// Makes every later store of a job's files fail: the jobs directory replaced by a file
    /// (root ignores permissions), or the bucket emptied and removed.
    pub fn break_storage(&self) {
        match self.bucket() {
            Some(bucket) => {
                for key in bucket.server.keys(&bucket.name, "") {
                    bucket
                        .server
                        .curl("DELETE", &format!("/{}/{key}", bucket.name), None)
                        .expect("emptying the bucket");
                }
                bucket
                    .server
                    .curl("DELETE", &format!("/{}", bucket.name), None)
                    .expect("removing the bucket");
            }
            None => {
                let jobs = self.0.join("jobs");
                let _ = std::fs::remove_dir_all(&jobs);
                std::fs::write(&jobs, b"not a directory").unwrap();
            }
        }
    }

    /// How many jobs have files stored.
    pub fn jobs_with_files(&self) -> usize {
        match self.bucket() {
            Some(bucket) => {
                let keys = bucket
                    .server
                    .keys(&bucket.name, &format!("{BUCKET_PREFIX}/jobs/"));
                let ids: std::collections::BTreeSet<_> = keys
                    .iter()
                    .filter_map(|key| key.split('/').nth(2))
                    .collect();
                ids.len()
            }
            None => std::fs::read_dir(self.0.join("jobs")).map_or(0, |entries| {
                entries
                    .filter(|entry| entry.as_ref().unwrap().path().is_dir())
                    .count()
            }),
        }
    }
}

fn lock<T>(mutex: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    mutex
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// The shared backend's arguments and environment for a server on `data_dir`; an
/// `--object-store` of the test's own (`own_store`) wins over the backend's bucket.
fn backend_args(data_dir: &Path, own_store: bool) -> (Vec<String>, Vec<(String, String)>) {
    lock(&BACKENDS)
        .iter()
        .find(|backend| backend.data_dir == data_dir)
        .map(|backend| {
            let mut args = vec!["--database-url".to_owned(), backend.database_url.clone()];
            match (&backend.object_store, own_store) {
                (Some(store), false) => {
                    args.extend(["--object-store".to_owned(), store.clone()]);
                    (args, backend.env.clone())
                }
                _ => (args, Vec::new()),
            }
        })
        .unwrap_or_default()
}

impl Drop for DataDir {
    fn drop(&mut self) {
        lock(&BACKENDS).retain(|backend| backend.data_dir != self.0);
        lock(&IN_MEMORY).retain(|dir| *dir != self.0);
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

pub struct Server {
    child: Child,
    pub base: String,
    client: Client<HttpConnector, Full<Bytes>>,
}

pub struct Reply {
    pub status: StatusCode,
    pub headers: hyper::HeaderMap,
    pub body: Bytes,
}

impl Reply {
    pub fn json(&self) -> Value {
        serde_json::from_slice(&self.body)
            .unwrap_or_else(|error| panic!("{error}: {}", String::from_utf8_lossy(&self.body)))
    }

    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers.get(name).and_then(|value| value.to_str().ok())
    }

    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }
}

impl Server {
    /// Starts `covec serve --addr 127.0.0.1:0 --data-dir DIR ARGS…` and waits for its address.
    pub fn start(data_dir: &Path, args: &[&str]) -> Self {
        Self::start_with_env(data_dir, args, &[])
    }

    /// [`Server::start`] with these environment variables added.
    pub fn start_with_env(data_dir: &Path, args: &[&str], env: &[(&str, &str)]) -> Self {
        Self::start_logged(data_dir, &data_dir.with_extension("log"), args, env)
    }

    /// [`Server::start_with_env`] logging to `log_path` (for servers sharing a data directory).
    pub fn start_logged(
        data_dir: &Path,
        log_path: &Path,
        args: &[&str],
        env: &[(&str, &str)],
    ) -> Self {
        let log = std::fs::File::create(log_path).unwrap();
        let (mut backend_args, backend_env) =
            backend_args(data_dir, args.contains(&"--object-store"));
        if lock(&IN_MEMORY).iter().any(|dir| dir == data_dir) {
            backend_args.push("--in-memory".to_owned());
        }
        let mut child = Command::new(env!("CARGO_BIN_EXE_covec"))
            .args(["serve", "--addr", "127.0.0.1:0", "--data-dir"])
            .arg(data_dir)
            .args(backend_args)
            .args(args)
            .envs(backend_env)
            .envs(env.iter().copied())
            .env("COVEC_LOG", "info")
            .stdout(Stdio::piped())
            .stderr(log)
            .spawn()
            .expect("start covec serve");
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let base = line
            .trim()
            .strip_prefix("covec serve: listening on ")
            .unwrap_or_else(|| {
                panic!(
                    "unexpected first line {line:?}; log: {}",
                    log_path.display()
                )
            })
            .to_owned();
        let client = Client::builder(TokioExecutor::new()).build_http();
        Self {
            child,
            base,
            client,
        }
    }

    pub async fn request(
        &self,
        method: Method,
        path: &str,
        headers: &[(&str, &str)],
        body: Vec<u8>,
    ) -> Reply {
        self.try_request(method, path, headers, body)
            .await
            .unwrap_or_else(|error| panic!("{path}: {error}"))
    }

    /// A request that may fail at the transport level (the server was killed meanwhile).
    pub async fn try_request(
        &self,
        method: Method,
        path: &str,
        headers: &[(&str, &str)],
        body: Vec<u8>,
    ) -> Result<Reply, String> {
        let mut builder = Request::builder()
            .method(method)
            .uri(format!("{}{path}", self.base));
        for (name, value) in headers {
            builder = builder.header(*name, *value);
        }
        let response = self
            .client
            .request(builder.body(Full::new(Bytes::from(body))).unwrap())
            .await
            .map_err(|error| error.to_string())?;
        let (parts, body) = response.into_parts();
        let body = body
            .collect()
            .await
            .map_err(|error| error.to_string())?
            .to_bytes();
        Ok(Reply {
            status: parts.status,
            headers: parts.headers,
            body,
        })
    }

    /// The server process's peak resident memory (`VmHWM`) in KiB, where /proc has it.
    pub fn peak_rss_kib(&self) -> Option<u64> {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.child.id())).ok()?;
        status
            .lines()
            .find_map(|line| line.strip_prefix("VmHWM:"))
            .and_then(|value| value.trim().trim_end_matches("kB").trim().parse().ok())
    }

    /// SIGKILL: the process dies at once, wherever it is.
    pub fn kill(mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// SIGKILL through a shared reference (clients may still hold the server).
    pub fn sigkill(&self) {
        Command::new("kill")
            .args(["-KILL", &self.child.id().to_string()])
            .status()
            .unwrap();
    }

    pub async fn get(&self, path: &str) -> Reply {
        self.get_with(path, &[]).await
    }

    /// A GET with these request headers.
    pub async fn get_with(&self, path: &str, headers: &[(&str, &str)]) -> Reply {
        self.request(Method::GET, path, headers, Vec::new()).await
    }

    /// `POST /v1/jobs/{id}/cancel`.
    pub async fn cancel(&self, id: &str) -> Reply {
        self.request(
            Method::POST,
            &format!("/v1/jobs/{id}/cancel"),
            &[],
            Vec::new(),
        )
        .await
    }

    pub async fn post_json(&self, path: &str, json: &Value) -> Reply {
        self.request(
            Method::POST,
            path,
            &[("content-type", "application/json")],
            json.to_string().into_bytes(),
        )
        .await
    }

    /// Submits a job as multipart with the given parts (name, bytes).
    pub async fn submit(&self, parts: &[(&str, &[u8])], headers: &[(&str, &str)]) -> Reply {
        let (content_type, body) = multipart(parts);
        let mut all = vec![("content-type", content_type.as_str())];
        all.extend_from_slice(headers);
        self.request(Method::POST, "/v1/jobs", &all, body).await
    }

    /// Submits a quick job (a 48 px test image, [`QUICK_PARAMS`]) and waits, at most a minute,
    /// for it to succeed; returns its id.
    pub async fn finished_job(&self) -> String {
        let image = test_png(48);
        let created = self
            .submit(
                &[
                    ("image", image.as_slice()),
                    ("params", QUICK_PARAMS.as_bytes()),
                ],
                &[],
            )
            .await;
        assert_eq!(created.status, StatusCode::CREATED, "{}", created.text());
        let id = created.json()["id"].as_str().unwrap().to_owned();
        let job = self
            .wait_for(&id, Duration::from_secs(60), |job| {
                job["status"] != "queued" && job["status"] != "running"
            })
            .await;
        assert_eq!(job["status"], "succeeded", "{job}");
        id
    }

    /// Polls a job until `done` holds for it, at most `timeout`.
    pub async fn wait_for(
        &self,
        id: &str,
        timeout: Duration,
        done: impl Fn(&Value) -> bool,
    ) -> Value {
        let started = Instant::now();
        loop {
            let job = self.get(&format!("/v1/jobs/{id}")).await;
            assert_eq!(job.status, StatusCode::OK, "{}", job.text());
            let job = job.json();
            if done(&job) {
                return job;
            }
            assert!(
                started.elapsed() < timeout,
                "job {id} not done after {timeout:?}: {job}"
            );
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    /// Reads a Server-Sent Events stream to its end: (event name, data) pairs.
    pub async fn events(&self, path: &str, timeout: Duration) -> Vec<(String, String)> {
        let request = Request::builder()
            .uri(format!("{}{path}", self.base))
            .header("accept", "text/event-stream")
            .body(Full::new(Bytes::new()))
            .unwrap();
        let response = self.client.request(request).await.unwrap();
        assert_eq!(response.status(), StatusCode::OK);
        assert!(
            response.headers()["content-type"]
                .to_str()
                .unwrap()
                .starts_with("text/event-stream")
        );
        // Unbuffered through a proxy (nginx honours the header), uncached.
        assert_eq!(response.headers()["x-accel-buffering"], "no");
        assert_eq!(response.headers()["cache-control"], "no-cache");
        let body = tokio::time::timeout(timeout, response.into_body().collect())
            .await
            .expect("the event stream ends")
            .unwrap()
            .to_bytes();
        let text = String::from_utf8(body.to_vec()).unwrap();
        text.split("\n\n")
            .filter_map(|block| {
                let mut name = None;
                let mut data = None;
                for line in block.lines() {
                    if let Some(value) = line.strip_prefix("event:") {
                        name = Some(value.trim().to_owned());
                    } else if let Some(value) = line.strip_prefix("data:") {
                        data = Some(value.trim().to_owned());
                    }
                }
                Some((name?, data?))
            })
            .collect()
    }

    /// SIGTERM, then wait for a clean exit.
    pub fn stop(mut self) {
        let pid = self.child.id().to_string();
        Command::new("kill").args(["-TERM", &pid]).status().unwrap();
        let started = Instant::now();
        while started.elapsed() < Duration::from_secs(20) {
            if let Some(status) = self.child.try_wait().unwrap() {
                assert!(status.success(), "covec serve exited with {status}");
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        panic!("covec serve did not stop within 20 s of SIGTERM");
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

pub fn multipart(parts: &[(&str, &[u8])]) -> (String, Vec<u8>) {
    let boundary = "covec-test-boundary-7d1f";
    let mut body = Vec::new();
    for (name, bytes) in parts {
        body.extend_from_slice(format!("--{boundary}\r\n").as_bytes());
        let disposition = if *name == "params" {
            format!(
                "Content-Disposition: form-data; name=\"{name}\"\r\nContent-Type: application/json\r\n\r\n"
            )
        } else {
            format!(
                "Content-Disposition: form-data; name=\"{name}\"; filename=\"{name}.png\"\r\nContent-Type: image/png\r\n\r\n"
            )
        };
        body.extend_from_slice(disposition.as_bytes());
        body.extend_from_slice(bytes);
        body.extend_from_slice(b"\r\n");
    }
    body.extend_from_slice(format!("--{boundary}--\r\n").as_bytes());
    (format!("multipart/form-data; boundary={boundary}"), body)
}

/// A small synthetic photo-like PNG: a shaded disc on a gradient background.
pub fn test_png(size: u32) -> Vec<u8> {
    let image = image::RgbImage::from_fn(size, size, |x, y| {
        let (fx, fy) = (x as f32 / size as f32, y as f32 / size as f32);
        let (dx, dy) = (fx - 0.5, fy - 0.5);
        if dx * dx + dy * dy < 0.09 {
            let shade = 1.0 - 0.8 * (dx + dy + 0.6).clamp(0.0, 1.0);
            image::Rgb([(220.0 * shade) as u8 + 20, (60.0 * shade) as u8 + 10, 30])
        } else {
            image::Rgb([60 + (120.0 * fy) as u8, 120, 180 - (60.0 * fx) as u8])
        }
    });
    png(&image::DynamicImage::ImageRgb8(image))
}

pub fn png(image: &image::DynamicImage) -> Vec<u8> {
    let mut bytes = Vec::new();
    image
        .write_to(
            &mut std::io::Cursor::new(&mut bytes),
            image::ImageFormat::Png,
        )
        .unwrap();
    bytes
}

/// Parameters for a job that takes well under a second.
pub const QUICK_PARAMS: &str = r#"{"paths": 8, "max_size": 48, "seed": 1,
  "iterations": {"structure": 3, "reconstruction": 3, "refine_rounds": 1, "refine": 3, "polish": 3}}"#;

/// Parameters for a job that runs for minutes unless canceled.
pub const LONG_PARAMS: &str = r#"{"paths": 64, "max_size": 64, "seed": 1,
  "iterations": {"structure": 100000, "reconstruction": 100000, "refine_rounds": 5, "refine": 100000, "polish": 100000}}"#;

pub fn problem(reply: &Reply) -> Value {
    assert_eq!(
        reply.header("content-type"),
        Some("application/problem+json"),
        "status {}: {}",
        reply.status,
        reply.text()
    );
    let problem = reply.json();
    assert_eq!(
        problem["status"].as_u64(),
        Some(u64::from(reply.status.as_u16())),
        "{problem}"
    );
    assert!(
        problem["type"]
            .as_str()
            .unwrap()
            .starts_with("urn:covec:problem:"),
        "{problem}"
    );
    assert!(!problem["detail"].as_str().unwrap().is_empty(), "{problem}");
    problem
}
