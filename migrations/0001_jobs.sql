-- Job records, the queue and its leases (covec serve/worker --database-url; issue 14).
-- `record` is the job's JSON record; the columns beside it are what the queue works on and
-- win over the same fields in the JSON (src/service/store/postgres.rs).
CREATE TABLE jobs (
    id text PRIMARY KEY,
    owner text,
    status text NOT NULL,
    record jsonb NOT NULL,
    idempotency_key text,
    cancel_requested boolean NOT NULL DEFAULT false,
    deleted boolean NOT NULL DEFAULT false,
    attempts integer NOT NULL DEFAULT 0,
    -- The claim of the worker running the job, and until when it holds unless renewed.
    lease_owner text,
    lease_expires_at timestamptz,
    -- Set on every change: API replicas follow jobs by it.
    updated_at timestamptz NOT NULL DEFAULT clock_timestamp()
);

-- One live job per (owner, Idempotency-Key); a deleted job frees its key.
CREATE UNIQUE INDEX jobs_idempotency ON jobs (coalesce(owner, ''), idempotency_key)
    WHERE idempotency_key IS NOT NULL AND NOT deleted;
CREATE INDEX jobs_by_owner ON jobs (coalesce(owner, ''), id);
CREATE INDEX jobs_by_owner_status ON jobs (coalesce(owner, ''), status, id);
-- The queue, oldest first, and the running jobs whose leases the reaper checks.
CREATE INDEX jobs_active ON jobs (status, id) WHERE status IN ('queued', 'running');
CREATE INDEX jobs_by_update ON jobs (updated_at);

CREATE FUNCTION jobs_touch() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN
    NEW.updated_at := clock_timestamp();
    RETURN NEW;
END
$$;
CREATE TRIGGER jobs_touch BEFORE UPDATE ON jobs FOR EACH ROW EXECUTE FUNCTION jobs_touch();
