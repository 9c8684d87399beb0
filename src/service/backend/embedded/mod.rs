//! The embedded backend: job records in SQLite in the data directory ([`Sqlite`]), artefacts
//! there or in an object store, and every job run in this process ([`Local`]).
//!
//! Records go through rusqlite rather than sqlx: every access is a short synchronous statement,
//! so an async driver buys nothing, and rusqlite links the system libsqlite3 (no bundled C
//! build, no proc macros), which keeps the build quick.

mod sqlite;

pub use sqlite::Sqlite;
