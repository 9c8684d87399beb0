//! The command line: batches, `covec init`, the fuzz targets' regressions, the documentation's defaults.
//! One binary for the area: one link of the dependency tree serves every test in it.

mod batch;
mod docs_defaults;
mod fuzz_regressions;
mod init;
