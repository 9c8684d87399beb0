//! The HTTP service, on the backend COVEC_TEST_BACKEND names (service_support): the API, jobs, edits, downloads, faults, fair scheduling, hardening, records, the object store, webhooks, the PostgreSQL backend's own tests, the documented and generated clients, `covec healthcheck`.
//! One binary for the area: one link of the dependency tree serves every test in it.

mod service_support;

mod api;
mod downloads;
mod edits;
mod fair;
mod faults;
mod generated_clients;
mod hardening;
mod healthcheck;
mod jobs;
mod pg;
mod readme_clients;
mod records;
mod s3;
mod webhooks;
