//! The `covec` subcommands: each one's arguments and logic live in its own module.

pub mod batch;
pub mod edit;
pub mod eval;
pub mod healthcheck;
pub mod intrinsic;
pub mod io;
pub mod openapi;
pub mod reference;
pub mod render;
pub mod serve;
pub mod vectorize;
