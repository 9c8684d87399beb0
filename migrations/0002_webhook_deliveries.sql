-- Which API replica delivers a job's webhook events, and until when its claim holds unless
-- renewed (issue 14): deliveries of a replica that stopped or was killed are taken over by
-- another once the claim expires. A row lives from admission until every event the job asked
-- for is delivered or given up (or the job is gone).
CREATE TABLE webhook_deliveries (
    job_id text PRIMARY KEY,
    replica text NOT NULL,
    lease_expires_at timestamptz NOT NULL
);
CREATE INDEX webhook_deliveries_by_replica ON webhook_deliveries (replica);
CREATE INDEX webhook_deliveries_by_expiry ON webhook_deliveries (lease_expires_at);
