//! Shared by the tests that run the whole pipeline on a 64 px synthetic scene: one small,
//! quick budget, so their runs stay comparable.

use covec::pipeline::{Iterations, Mode, Params};

/// 32 paths and a few iterations per stage: seconds per run at 64 px, enough for the layers
/// to settle on a synthetic scene.
pub fn quick_params(mode: Mode) -> Params {
    Params {
        paths: 32,
        mode,
        iterations: Iterations {
            structure: 20,
            reconstruction: 30,
            refine_rounds: 3,
            refine: 30,
            polish: 20,
        },
        ..Params::default()
    }
}
