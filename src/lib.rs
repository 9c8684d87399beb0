//! covec: photographs to layered, editable SVG (albedo × shade + light), after the COVec paper
//! (*Clair Obscur: an Illumination-Aware Method for Real-World Image Vectorization*, CVPR 2026).
//!
//! ```no_run
//! let image = covec::imageio::decode_image(&std::fs::read("photo.jpg")?, &Default::default())?;
//! let inputs = covec::Inputs { image, albedo: None, masks: covec::Masks::None };
//! let output = covec::vectorize(&inputs, &covec::Params::default())?;
//! std::fs::write("photo.svg", covec::svg::to_svg(&output.scene, &Default::default()))?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! One [`Scene`] model feeds the differentiable [`render`]er, the [`svg`] writer and the
//! [`edit`]or. The [`pipeline`] turns an image into a scene in named stages; [`output`] names the
//! files made from a scene; with the `service` feature (on by default), `service` serves it all
//! over HTTP. `default-features = false` gives the library alone, without the command line's and
//! the service's dependencies.

#![warn(missing_docs)]

pub(crate) mod decompose;
pub mod edit;
pub mod eval;
pub mod geom;
pub mod imageio;
pub mod opaque;
pub(crate) mod optim;
pub mod output;
pub mod pdf;
pub mod perceptual;
pub mod pipeline;
pub mod render;
pub mod scene;
#[cfg(feature = "service")]
pub mod service;
mod simd;
pub mod svg;
pub mod synth;
#[cfg(feature = "service")]
pub mod web;

use std::sync::atomic::AtomicBool;

pub use pipeline::{
    Error, Inputs, Iterations, Masks, Mode, Observer, Output, Params, Progress, Quiet,
    ResolvedMode, run,
};
pub use scene::{Layer, LayerKind, Path, Point, Scene};

/// Vectorises `inputs` with no progress reports and no way to cancel: [`run`] for scripts.
pub fn vectorize(inputs: &Inputs, params: &Params) -> Result<Output, Error> {
    run(inputs, params, &Quiet, &AtomicBool::new(false))
}
