-- Bounded records (issue 20): ended jobs' records are deleted after the record retention and
-- Idempotency-Keys expire; each query on them reads one of these indexes, so nothing walks
-- every record. The times are the record's own (Unix ms, as the service writes them).
CREATE INDEX jobs_by_completion ON jobs (((record ->> 'completed_at')::bigint))
    WHERE status IN ('succeeded', 'failed', 'canceled') AND NOT deleted;
CREATE INDEX jobs_results_due ON jobs (((record ->> 'expires_at')::bigint))
    WHERE record ->> 'data_removed' = 'false' AND NOT deleted;
CREATE INDEX jobs_keys_by_age ON jobs (((record ->> 'created_at')::bigint))
    WHERE idempotency_key IS NOT NULL;

-- A deleted record's id and owner, kept for a while after: what tells `410 Gone` for an
-- expired job from `404` for an id that never existed.
CREATE TABLE expired_jobs (
    id text PRIMARY KEY,
    owner text,
    expired_at bigint NOT NULL
);
CREATE INDEX expired_jobs_by_age ON expired_jobs (expired_at);
