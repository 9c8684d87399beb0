//! The memory backend: job records and the queue in this process, jobs run here, artefacts
//! in the data directory. Nothing survives a restart; for trials, and for the service tests
//! where a database adds nothing. The same answers as the embedded backend's SQLite records,
//! kept in one map under one lock.

use std::collections::{BTreeMap, HashMap};
use std::sync::{Mutex, MutexGuard};

use crate::service::model::{JobRecord, Status, Webhook, now_ms};
use crate::service::store::{LocalRecords, Records, Recovered, StoreError};

#[derive(Default)]
pub struct Memory {
    rows: Mutex<Rows>,
}

#[derive(Default)]
struct Rows {
    /// Every record by id (ids sort by creation), with whether it is a tombstone.
    jobs: BTreeMap<String, (JobRecord, bool)>,
    /// Expired jobs' owners and when they expired (Unix ms), by id.
    expired: HashMap<String, (Option<String>, u64)>,
}

impl Memory {
    fn rows(&self) -> MutexGuard<'_, Rows> {
        self.rows
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner())
    }
}

impl Rows {
    /// The records that are not tombstones.
    fn live(&self) -> impl DoubleEndedIterator<Item = &JobRecord> {
        self.jobs
            .values()
            .filter(|(_, deleted)| !deleted)
            .map(|(record, _)| record)
    }
}

impl Records for Memory {
    /// Unless the job is a tombstone.
    fn save(&self, record: &JobRecord) -> Result<(), StoreError> {
        let mut rows = self.rows();
        match rows.jobs.get_mut(&record.id) {
            Some((_, true)) => {}
            Some((stored, false)) => *stored = record.clone(),
            None => {
                rows.jobs.insert(record.id.clone(), (record.clone(), false));
            }
        }
        Ok(())
    }

    fn save_webhook(&self, record: &JobRecord) -> Result<(), StoreError> {
        self.save(record)
    }

    fn tombstone(&self, id: &str) -> Result<(), StoreError> {
        if let Some((_, deleted)) = self.rows().jobs.get_mut(id) {
            *deleted = true;
        }
        Ok(())
    }

    fn get(&self, id: &str) -> Result<Option<JobRecord>, StoreError> {
        Ok(match self.rows().jobs.get(id) {
            Some((record, false)) => Some(record.clone()),
            _ => None,
        })
    }

    fn idempotent(
        &self,
        owner: &Option<String>,
        key: &str,
        created_since: u64,
    ) -> Result<Option<JobRecord>, StoreError> {
        let rows = self.rows();
        let newest = rows.live().rev().find(|record| {
            record.owner == *owner
                && record.created_at >= created_since
                && record.idempotency.as_ref().is_some_and(|i| i.key == key)
        });
        Ok(newest.cloned())
    }

    fn drop_idempotency_keys(&self, created_before: u64) -> Result<usize, StoreError> {
        let mut dropped = 0;
        for (record, _) in self.rows().jobs.values_mut() {
            if record.created_at < created_before && record.idempotency.take().is_some() {
                dropped += 1;
            }
        }
        Ok(dropped)
    }

    fn results_due(&self, now: u64, limit: usize) -> Result<Vec<String>, StoreError> {
        let rows = self.rows();
        let due = rows
            .live()
            .filter(|record| !record.data_removed && record.expires_at.is_some_and(|at| at <= now));
        Ok(due.take(limit).map(|record| record.id.clone()).collect())
    }

    fn expire_records(
        &self,
        ended_before: u64,
        expired_before: u64,
        limit: usize,
    ) -> Result<Vec<String>, StoreError> {
        let mut rows = self.rows();
        let ended = rows.live().filter(|record| {
            record.status.is_terminal() && record.completed_at.is_some_and(|at| at < ended_before)
        });
        let ids: Vec<String> = ended.take(limit).map(|record| record.id.clone()).collect();
        let now = now_ms();
        for id in &ids {
            if let Some((record, _)) = rows.jobs.remove(id) {
                rows.expired.insert(id.clone(), (record.owner, now));
            }
        }
        rows.expired.retain(|_, (_, at)| *at >= expired_before);
        Ok(ids)
    }

    fn expired_owner(&self, id: &str) -> Result<Option<Option<String>>, StoreError> {
        Ok(self.rows().expired.get(id).map(|(owner, _)| owner.clone()))
    }

    fn list_ids(
        &self,
        owner: &Option<String>,
        status: Option<Status>,
        before: &str,
        limit: usize,
    ) -> Result<Vec<String>, StoreError> {
        let rows = self.rows();
        let older = rows.jobs.range(..before.to_owned()).rev();
        let ids = older
            .filter(|(_, (record, deleted))| {
                !deleted
                    && record.owner == *owner
                    && status.is_none_or(|status| record.status == status)
            })
            .take(limit)
            .map(|(id, _)| id.clone());
        Ok(ids.collect())
    }

    fn has_record(&self, id: &str) -> Result<bool, StoreError> {
        Ok(matches!(self.rows().jobs.get(id), Some((_, false))))
    }

    fn check(&self) -> Result<(), StoreError> {
        Ok(())
    }
}

impl LocalRecords for Memory {
    /// Nothing to recover but what this process wrote (nothing, at start); a record is never
    /// unreadable.
    fn recover(&self) -> Result<Recovered, StoreError> {
        let mut rows = self.rows();
        rows.jobs.retain(|_, (_, deleted)| !*deleted);
        let live = rows.live().filter(|record| !record.status.is_terminal());
        Ok(Recovered {
            records: live.cloned().collect(),
            quarantined: Vec::new(),
        })
    }

    fn webhooks_pending(&self) -> Result<Vec<JobRecord>, StoreError> {
        let rows = self.rows();
        let pending = rows
            .live()
            .filter(|record| record.webhook.as_ref().is_some_and(Webhook::unfinished));
        Ok(pending.cloned().collect())
    }
}
