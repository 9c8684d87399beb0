//! Where a job's files live: plain files in the data directory (the default) or objects in an
//! S3-compatible bucket (`--object-store s3://bucket/prefix`).
//!
//! Both keep one layout, `jobs/<id>/<name>`, and one promise: a reader sees a whole file or
//! none. Files get it from a rename (temporary file, fsync, rename over the name); objects from
//! S3 itself (a PUT becomes visible whole or not at all, so no temporary name is needed).
//!
//! The bucket is reached through `object_store` (its S3 client: signing, retries, listing
//! pages) on a small tokio runtime of its own. Every caller of this module is blocking code (a
//! job runner, a `spawn_blocking` task, start-up), so each request is handed to that runtime
//! and waited for; no caller's runtime is blocked on and none is needed.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, SystemTime};

use futures_util::StreamExt;
use object_store::aws::AmazonS3Builder;
use object_store::path::Path as ObjectPath;
use object_store::prefix::PrefixStore;
use object_store::{ObjectStore, ObjectStoreExt, PutPayload, RetryConfig};

use super::error::{StoreError, io_error};
use crate::service::model::DRAFT_FILE;

/// The folder of the data directory (or the bucket prefix) that holds one folder per job.
const JOBS: &str = "jobs";

/// What a run produces (removed for a re-run, which keeps the inputs): these folders of a
/// job (`derived`: the files drawn from its scene), and these files.
const OUTPUT_FOLDERS: [&str; 3] = ["previews", "layers", "derived"];
const OUTPUT_FILES: [&str; 3] = ["scene.json", "result.svg", DRAFT_FILE];

/// Written by the readiness check to prove the storage takes writes.
const READY_CHECK: &str = ".ready-check";

/// Retries of one S3 request that failed on the network or with a 5xx/429 (object_store's
/// own retry loop): 4 after the first, at most 10 s in all, so a job runner or a request
/// handler waits seconds, not object_store's default of up to 3 minutes, for a store that is
/// down.
fn s3_retries() -> RetryConfig {
    RetryConfig {
        max_retries: 4,
        retry_timeout: Duration::from_secs(10),
        ..RetryConfig::default()
    }
}

/// A job's files, wherever they are kept.
pub enum Artefacts {
    /// Under `<data dir>/jobs/`.
    Files { root: PathBuf },
    /// Under `<prefix>/jobs/` in a bucket.
    Objects(Objects),
}

/// An S3-compatible bucket and the runtime its client runs on.
pub struct Objects {
    store: Arc<dyn ObjectStore>,
    /// Taken out and shut down in the background on drop: a runtime dropped where blocking is
    /// not allowed (an async test's state) would otherwise panic.
    runtime: Option<tokio::runtime::Runtime>,
}

impl Drop for Objects {
    fn drop(&mut self) {
        if let Some(runtime) = self.runtime.take() {
            runtime.shutdown_background();
        }
    }
}

impl Artefacts {
    /// Files under `root`, or the bucket of `object_store` (`s3://bucket[/prefix]`, with
    /// credentials, region and endpoint from the usual `AWS_*` variables) when given.
    pub fn open(root: &Path, object_store: Option<&str>) -> Result<Self, StoreError> {
        let Some(url) = object_store else {
            let jobs = root.join(JOBS);
            fs::create_dir_all(&jobs).map_err(io_error(&jobs))?;
            return Ok(Self::Files {
                root: root.to_owned(),
            });
        };
        let invalid = |reason: &str| StoreError::ObjectStoreUrl {
            url: url.to_owned(),
            reason: reason.to_owned(),
        };
        let rest = url
            .strip_prefix("s3://")
            .ok_or_else(|| invalid("only s3://bucket/prefix is supported"))?;
        let (bucket, prefix) = rest.split_once('/').unwrap_or((rest, ""));
        if bucket.is_empty() {
            return Err(invalid("no bucket named"));
        }
        // reqwest takes TLS from the process's rustls provider: ring (see Cargo.toml). An
        // error means one is installed already, which serves as well.
        let _ = rustls::crypto::ring::default_provider().install_default();
        let s3 = AmazonS3Builder::from_env()
            .with_bucket_name(bucket)
            .with_retry(s3_retries())
            .build()
            .map_err(|error| invalid(&error.to_string()))?;
        let prefix = prefix.trim_matches('/');
        let store: Arc<dyn ObjectStore> = if prefix.is_empty() {
            Arc::new(s3)
        } else {
            Arc::new(PrefixStore::new(s3, prefix))
        };
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("covec-object-store")
            .enable_all()
            .build()
            .map_err(|source| StoreError::Io {
                path: PathBuf::from(url),
                source,
            })?;
        Ok(Self::Objects(Objects {
            store,
            runtime: Some(runtime),
        }))
    }

    /// Writes `jobs/<id>/<name>` whole.
    pub fn write(&self, id: &str, name: &str, bytes: &[u8]) -> Result<(), StoreError> {
        match self {
            Self::Files { root } => write_atomic(&job_dir(root, id).join(name), bytes),
            Self::Objects(objects) => {
                let store = objects.store.clone();
                let location = object_path(id, name);
                let payload = PutPayload::from(bytes.to_vec());
                objects.run(async move { store.put(&location, payload).await.map(drop) })
            }
        }
    }

    /// Reads `jobs/<id>/<name>`; `None` when it does not exist.
    pub fn read(&self, id: &str, name: &str) -> Result<Option<Vec<u8>>, StoreError> {
        match self {
            Self::Files { root } => {
                let path = job_dir(root, id).join(name);
                match fs::read(&path) {
                    Ok(bytes) => Ok(Some(bytes)),
                    Err(error) if error.kind() == std::io::ErrorKind::NotFound => Ok(None),
                    Err(error) => Err(io_error(&path)(error)),
                }
            }
            Self::Objects(objects) => {
                let store = objects.store.clone();
                let location = object_path(id, name);
                objects.run(async move {
                    match store.get(&location).await {
                        Ok(found) => Ok(Some(found.bytes().await?.to_vec())),
                        Err(object_store::Error::NotFound { .. }) => Ok(None),
                        Err(error) => Err(error),
                    }
                })
            }
        }
    }

    /// Whether `jobs/<id>/<name>` exists, without reading it.
    pub fn exists(&self, id: &str, name: &str) -> Result<bool, StoreError> {
        match self {
            Self::Files { root } => {
                let path = job_dir(root, id).join(name);
                path.try_exists().map_err(io_error(&path))
            }
            Self::Objects(objects) => {
                let store = objects.store.clone();
                let location = object_path(id, name);
                objects.run(async move {
                    match store.head(&location).await {
                        Ok(_) => Ok(true),
                        Err(object_store::Error::NotFound { .. }) => Ok(false),
                        Err(error) => Err(error),
                    }
                })
            }
        }
    }

    /// Removes every file of a job; missing files are not an error.
    pub fn remove_job(&self, id: &str) -> Result<(), StoreError> {
        match self {
            Self::Files { root } => remove_dir(&job_dir(root, id)),
            Self::Objects(objects) => objects.remove_under(&format!("{JOBS}/{id}"), |_| true),
        }
    }

    /// Removes what a run produced ([`OUTPUT_FOLDERS`], [`OUTPUT_FILES`]), keeping the inputs.
    pub fn remove_outputs(&self, id: &str) -> Result<(), StoreError> {
        match self {
            Self::Files { root } => {
                let dir = job_dir(root, id);
                for folder in OUTPUT_FOLDERS {
                    remove_dir(&dir.join(folder))?;
                }
                for file in OUTPUT_FILES {
                    let path = dir.join(file);
                    match fs::remove_file(&path) {
                        Err(error) if error.kind() != std::io::ErrorKind::NotFound => {
                            return Err(io_error(&path)(error));
                        }
                        _ => {}
                    }
                }
                Ok(())
            }
            Self::Objects(objects) => {
                objects.remove_under(&format!("{JOBS}/{id}"), |name: &str| {
                    OUTPUT_FILES.contains(&name)
                        || OUTPUT_FOLDERS.iter().any(|folder| {
                            name.strip_prefix(folder)
                                .is_some_and(|rest| rest.starts_with('/'))
                        })
                })
            }
        }
    }

    /// Every job folder with the time since anything in it last changed (for the orphan
    /// sweep). Unreadable entries are left out: the sweep only ever removes what it saw.
    pub fn job_ages(&self) -> Result<Vec<(String, Duration)>, StoreError> {
        let now = SystemTime::now();
        let age = |changed: SystemTime| now.duration_since(changed).unwrap_or_default();
        match self {
            Self::Files { root } => {
                let jobs = root.join(JOBS);
                let entries = fs::read_dir(&jobs).map_err(io_error(&jobs))?;
                Ok(entries
                    .flatten()
                    .filter_map(|entry| {
                        let changed = entry.metadata().and_then(|m| m.modified()).ok()?;
                        Some((
                            entry.file_name().to_string_lossy().into_owned(),
                            age(changed),
                        ))
                    })
                    .collect())
            }
            Self::Objects(objects) => {
                let store = objects.store.clone();
                let newest = objects.run(async move {
                    let mut newest = std::collections::BTreeMap::<String, SystemTime>::new();
                    let mut listing = store.list(Some(&ObjectPath::from(JOBS)));
                    while let Some(meta) = listing.next().await {
                        let meta = meta?;
                        let Some(id) = meta.location.parts().nth(1) else {
                            continue;
                        };
                        let changed = SystemTime::from(meta.last_modified);
                        let entry = newest.entry(id.as_ref().to_owned()).or_insert(changed);
                        *entry = (*entry).max(changed);
                    }
                    Ok(newest)
                })?;
                Ok(newest
                    .into_iter()
                    .map(|(id, changed)| (id, age(changed)))
                    .collect())
            }
        }
    }

    /// Proves the storage takes writes (for `/readyz`).
    pub fn check(&self) -> Result<(), StoreError> {
        match self {
            Self::Files { root } => write_atomic(&root.join(READY_CHECK), b"ok"),
            Self::Objects(objects) => {
                let store = objects.store.clone();
                objects.run(async move {
                    store
                        .put(
                            &ObjectPath::from(READY_CHECK),
                            PutPayload::from_static(b"ok"),
                        )
                        .await
                        .map(drop)
                })
            }
        }
    }
}

impl Objects {
    /// Runs one request on the store's runtime and waits for it.
    fn run<T: Send + 'static>(
        &self,
        request: impl Future<Output = object_store::Result<T>> + Send + 'static,
    ) -> Result<T, StoreError> {
        let runtime = self.runtime.as_ref().expect("the runtime lives until drop");
        let (answer, answered) = std::sync::mpsc::channel();
        runtime.spawn(async move {
            let _ = answer.send(request.await);
        });
        answered
            .recv()
            .map_err(|_| StoreError::ObjectStoreStopped)?
            .map_err(StoreError::from)
    }

    /// Deletes the objects under `folder/` whose name below it `selected` picks.
    fn remove_under(
        &self,
        folder: &str,
        selected: impl Fn(&str) -> bool + Send + 'static,
    ) -> Result<(), StoreError> {
        let store = self.store.clone();
        let folder = ObjectPath::from(folder);
        self.run(async move {
            let depth = folder.parts().count();
            let mut names = Vec::new();
            let mut listing = store.list(Some(&folder));
            while let Some(meta) = listing.next().await {
                let location = meta?.location;
                let below: Vec<String> = location
                    .parts()
                    .skip(depth)
                    .map(|part| part.as_ref().to_owned())
                    .collect();
                if selected(&below.join("/")) {
                    names.push(location);
                }
            }
            for location in names {
                match store.delete(&location).await {
                    Ok(()) | Err(object_store::Error::NotFound { .. }) => {}
                    Err(error) => return Err(error),
                }
            }
            Ok(())
        })
    }
}

fn job_dir(root: &Path, id: &str) -> PathBuf {
    root.join(JOBS).join(id)
}

fn object_path(id: &str, name: &str) -> ObjectPath {
    ObjectPath::from(format!("{JOBS}/{id}/{name}"))
}

fn remove_dir(dir: &Path) -> Result<(), StoreError> {
    match fs::remove_dir_all(dir) {
        Err(error) if error.kind() != std::io::ErrorKind::NotFound => Err(io_error(dir)(error)),
        _ => Ok(()),
    }
}

/// Temporary file in the same directory, fsync, rename over the target.
fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), StoreError> {
    let dir = path.parent().expect("artefact paths have a parent");
    fs::create_dir_all(dir).map_err(io_error(dir))?;
    let file_name = path
        .file_name()
        .expect("artefact paths name a file")
        .to_string_lossy();
    let temporary = dir.join(format!(
        ".{file_name}.{}.tmp",
        uuid::Uuid::now_v7().simple()
    ));
    let result = (|| {
        let mut file = fs::File::create(&temporary)?;
        file.write_all(bytes)?;
        file.sync_all()?;
        fs::rename(&temporary, path)
    })();
    if result.is_err() {
        let _ = fs::remove_file(&temporary);
    }
    result.map_err(io_error(path))
}
