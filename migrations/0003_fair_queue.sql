-- Fair scheduling (issue 20): whose turn a job takes (`client`: the API key's identity, an
-- X-Client-Key's, or '' for anonymous requests) and how soon it is wanted (`priority`), beside
-- the record as the queue's other columns are; and when each client last had a job started.
-- The rule that reads them is src/service/fair.rs's, in Postgres::claim.
ALTER TABLE jobs ADD COLUMN client text NOT NULL DEFAULT '';
ALTER TABLE jobs ADD COLUMN priority text NOT NULL DEFAULT 'interactive';
UPDATE jobs SET client = coalesce(owner, '');

-- A client's queued and running jobs (its limits, and the running count the rule orders by).
CREATE INDEX jobs_active_by_client ON jobs (client, status)
    WHERE status IN ('queued', 'running') AND NOT deleted;

CREATE TABLE queue_clients (
    client text PRIMARY KEY,
    last_served timestamptz NOT NULL
);
