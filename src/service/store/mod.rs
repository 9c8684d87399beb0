//! Persistence: job records behind the [`Records`] seam (each backend's in its folder under
//! `service/backend/`); artefacts as files in the data directory or as objects in an
//! S3-compatible bucket ([`Artefacts`]).
//!
//! Every record access is a short synchronous call made from a worker thread or a
//! `spawn_blocking` task. The databases hold one JSON record per job keyed by id, with the
//! columns their queries read beside it (written from the record on every save).
//!
//! Artefacts live under `jobs/<id>/` and are written whole or not at all (see [`Artefacts`]),
//! so a crash never leaves a half-written file under a served name.

use std::collections::BTreeMap;
use std::fs;
use std::path::Path;
use std::time::Duration;

use sha2::{Digest, Sha256};

mod artefacts;
mod error;
mod records;

use std::sync::Arc;

use super::model::{JobRecord, Status, is_job_id};
use artefacts::Artefacts;

pub use error::{StoreError, io_error, retry_transient, with_sources};
pub use records::{LocalRecords, Records, Recovered};

pub struct Store {
    artefacts: Artefacts,
    records: Arc<dyn Records>,
}

impl Store {
    /// Opens (creating if needed) the data directory; artefacts go there or, given
    /// `object_store` (`s3://bucket/prefix`), to that bucket; records go to `records`.
    pub fn open(
        root: &Path,
        object_store: Option<&str>,
        records: Arc<dyn Records>,
    ) -> Result<Self, StoreError> {
        fs::create_dir_all(root).map_err(io_error(root))?;
        let artefacts = Artefacts::open(root, object_store)?;
        Ok(Self { artefacts, records })
    }

    /// Writes a job's record, unless the job was deleted: a tombstone is final, so a worker
    /// finishing or a cancel racing a DELETE cannot bring the record back.
    ///
    /// On the shared backend only a job no worker holds is written, and its webhook deliveries
    /// are kept.
    pub fn save(&self, record: &JobRecord) -> Result<(), StoreError> {
        self.records.save(record)
    }

    /// Writes a job's webhook deliveries: its whole record on the embedded backend, only that
    /// field on the shared one (where a worker may be writing the rest).
    pub fn save_webhook(&self, record: &JobRecord) -> Result<(), StoreError> {
        self.records.save_webhook(record)
    }

    /// Marks a job deleted for good (its row goes at the next start, when no one can still be
    /// writing it). The commit point of a DELETE: until it is written nothing else changes.
    pub fn tombstone(&self, id: &str) -> Result<(), StoreError> {
        self.records.tombstone(id)
    }

    /// The record of job `id`, if it has one. An unreadable row is moved to the quarantine
    /// (as at start) and answered [`StoreError::CorruptRecord`].
    pub fn get(&self, id: &str) -> Result<Option<JobRecord>, StoreError> {
        self.records.get(id)
    }

    /// The newest job of `owner` holding Idempotency-Key `key` created at or after
    /// `created_since` (Unix ms): keys older than that have expired.
    pub fn idempotent(
        &self,
        owner: &Option<String>,
        key: &str,
        created_since: u64,
    ) -> Result<Option<JobRecord>, StoreError> {
        self.records.idempotent(owner, key, created_since)
    }

    /// Removes the Idempotency-Keys of jobs created before `created_before` (Unix ms) from
    /// their records; returns how many.
    pub fn drop_idempotency_keys(&self, created_before: u64) -> Result<usize, StoreError> {
        self.records.drop_idempotency_keys(created_before)
    }

    /// Up to `limit` ids of jobs whose results were due for removal at `now` (Unix ms) and are
    /// not removed yet.
    pub fn results_due(&self, now: u64, limit: usize) -> Result<Vec<String>, StoreError> {
        self.records.results_due(now, limit)
    }

    /// Deletes up to `limit` records of jobs that ended before `ended_before` (Unix ms),
    /// leaving each an entry in `expired_jobs` (its id and owner: what tells `410 Gone` from
    /// `404`), and the entries written before `expired_before`; returns the deleted jobs' ids.
    pub fn expire_records(
        &self,
        ended_before: u64,
        expired_before: u64,
        limit: usize,
    ) -> Result<Vec<String>, StoreError> {
        self.records
            .expire_records(ended_before, expired_before, limit)
    }

    /// The owner of job `id` if its record was deleted by [`Store::expire_records`] (and its
    /// entry is still kept).
    pub fn expired_owner(&self, id: &str) -> Result<Option<Option<String>>, StoreError> {
        self.records.expired_owner(id)
    }

    /// Up to `limit` ids of `owner`'s jobs (with `status` if given) strictly older than
    /// `before`, newest first; one index range scan.
    pub fn list_ids(
        &self,
        owner: &Option<String>,
        status: Option<Status>,
        before: Option<&str>,
        limit: usize,
    ) -> Result<Vec<String>, StoreError> {
        // Ids are `job_<hex>`: every one sorts before "k".
        let before = before.unwrap_or("k");
        self.records.list_ids(owner, status, before, limit)
    }

    /// Whether a live or quarantined record exists for `id` (what the orphan sweep keeps).
    fn has_record(&self, id: &str) -> Result<bool, StoreError> {
        self.records.has_record(id)
    }

    /// Removes job directories that no record owns (an upload interrupted by a crash, a refused
    /// submission whose clean-up failed, a deleted job whose files could not be removed then)
    /// and that were last changed more than `min_age` ago: a submission being admitted writes
    /// its files before its record. `keep` says whether a directory is a live job's.
    /// Returns how many were removed.
    pub fn sweep_orphans(&self, min_age: Duration, keep: impl Fn(&str) -> bool) -> usize {
        let ages = match self.artefacts.job_ages() {
            Ok(ages) => ages,
            Err(error) => {
                tracing::warn!(%error, "listing job folders for the orphan sweep");
                return 0;
            }
        };
        let mut removed = 0;
        for (id, age) in ages {
            if age < min_age || keep(&id) || !matches!(self.has_record(&id), Ok(false)) {
                continue;
            }
            match self.artefacts.remove_job(&id) {
                Ok(()) => removed += 1,
                Err(error) => {
                    tracing::warn!(dir = %id, %error, "removing an orphaned job directory")
                }
            }
        }
        removed
    }

    /// Writes `jobs/<id>/<name>` whole or not at all.
    pub fn write_artefact(&self, id: &str, name: &str, bytes: &[u8]) -> Result<(), StoreError> {
        self.artefacts.write(id, name, bytes)
    }

    /// Records the SHA-256 of files stored together under `jobs/<id>/<folder>/` (an edit's
    /// files; a job's own results have theirs in its record), by file name, for
    /// [`Store::folder_digest`] to check them by when they are served.
    pub fn write_folder_digests(
        &self,
        id: &str,
        folder: &str,
        digests: &BTreeMap<String, String>,
    ) -> Result<(), StoreError> {
        let json = serde_json::to_vec(digests).expect("digests serialise");
        self.write_artefact(id, &format!("{folder}/{FOLDER_DIGESTS}"), &json)
    }

    /// The digest [`Store::write_folder_digests`] recorded for `jobs/<id>/<name>`; `None` when
    /// its folder has none (a name at the job's top level, a preview, an edit stored before
    /// edits had digests). Digests that do not parse are [`StoreError::CorruptRecord`].
    pub fn folder_digest(&self, id: &str, name: &str) -> Result<Option<String>, StoreError> {
        let Some((folder, file)) = name.rsplit_once('/') else {
            return Ok(None);
        };
        let path = format!("{folder}/{FOLDER_DIGESTS}");
        let Some(json) = self.read_artefact(id, &path)? else {
            return Ok(None);
        };
        let digests: BTreeMap<String, String> =
            serde_json::from_slice(&json).map_err(|error| StoreError::CorruptRecord {
                id: format!("{id}/{path}"),
                reason: error.to_string(),
            })?;
        Ok(digests.get(file).cloned())
    }

    /// Reads `jobs/<id>/<name>`; `None` when it does not exist.
    pub fn read_artefact(&self, id: &str, name: &str) -> Result<Option<Vec<u8>>, StoreError> {
        self.artefacts.read(id, name)
    }

    /// Whether `jobs/<id>/<name>` exists, without reading it.
    pub fn has_artefact(&self, id: &str, name: &str) -> Result<bool, StoreError> {
        self.artefacts.exists(id, name)
    }

    /// Removes every file of a job; missing files are not an error.
    pub fn remove_artefacts(&self, id: &str) -> Result<(), StoreError> {
        self.artefacts.remove_job(id)
    }

    /// Removes what a run produced (previews and results), keeping the inputs for a re-run.
    pub fn remove_outputs(&self, id: &str) -> Result<(), StoreError> {
        self.artefacts.remove_outputs(id)
    }

    /// Checks that the artefact storage accepts writes and the database answers (for `/readyz`).
    pub fn check(&self) -> Result<(), StoreError> {
        self.artefacts.check()?;
        self.records.check()
    }
}

/// A stored record, if it parses and is the record of the row it is in.
pub fn parse_record(id: &str, json: &str) -> Result<JobRecord, StoreError> {
    let corrupt = |reason: String| StoreError::CorruptRecord {
        id: id.to_owned(),
        reason,
    };
    let record: JobRecord =
        serde_json::from_str(json).map_err(|error| corrupt(error.to_string()))?;
    if record.id != id || !is_job_id(id) {
        return Err(corrupt(format!("it holds the record of `{}`", record.id)));
    }
    Ok(record)
}

/// The file in a folder of a job that holds its other files' digests.
const FOLDER_DIGESTS: &str = "checksums.json";

/// SHA-256 of a stored file in hex, recorded when it is written and checked when it is served.
pub fn digest(bytes: &[u8]) -> String {
    super::model::hex(&Sha256::digest(bytes))
}
