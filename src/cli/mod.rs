//! The `covec` subcommands: each one's arguments and logic live in its own module.

pub mod batch;
pub mod edit;
pub mod eval;
#[cfg(feature = "service")]
pub mod healthcheck;
pub mod intrinsic;
pub mod io;
pub mod malloc;
#[cfg(feature = "service")]
pub mod openapi;
pub mod reference;
pub mod render;
#[cfg(feature = "service")]
pub mod serve;
pub mod vectorize;

/// `covec vectorize`: one image file, or a batch for a directory or several inputs.
pub fn vectorize(args: &vectorize::Args) -> Result<(), String> {
    match args.inputs.as_slice() {
        [input] if !input.is_dir() => {
            in_pool(|| vectorize::run(input, args)).map_err(|e| e.to_string())
        }
        _ => batch::run(args).map_err(|e| e.to_string()),
    }
}

/// `covec eval`: quality on images, or with `--intrinsic` / `--write-scenes` the
/// decomposition on scenes with known layers, or with `--write-masks` the skin masks alone.
pub fn eval(args: &eval::Args) -> Result<(), String> {
    let result = if let Some(dir) = &args.write_scenes {
        intrinsic::write_scenes(dir, args.scene_size)
    } else if let (Some(dir), Some(faces)) = (&args.write_masks, &args.faces) {
        eval::write_masks(faces, dir)
    } else if args.intrinsic {
        in_pool(|| intrinsic::run(args))
    } else {
        in_pool(|| eval::run(args))
    };
    result.map_err(|e| e.to_string())
}

/// Runs `work` on a thread of rayon's global pool, as a batch and the service run their
/// pipelines. Called from outside the pool, each of a pipeline's parallel loops hands its work
/// to the pool and puts the calling thread to sleep until it is done, thousands of times a
/// run, which cost a large share of the wall time (docs/history.md, "Running in the pool").
fn in_pool<R: Send>(work: impl FnOnce() -> R + Send) -> R {
    rayon::scope(|_| work())
}
