//! The COVec pipeline as named stages: decompose → init → optimise → refine → split → polish → emit.
//!
//! [`run`] is the one entry point the CLI and the service call. Stages report progress through an
//! [`Observer`], check `cancel` every iteration, and hand each stage's previews to the observer
//! as soon as the stage ends.

use std::sync::atomic::AtomicBool;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::render::Image;
use crate::scene::Scene;

/// Which variant of the method to run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// Pick `simple` or `photo` from the image itself.
    #[default]
    Auto,
    /// Albedo + shade + light (the paper's main method).
    Photo,
    /// Albedo only, for emoji, icons and flat artwork (the paper's appendix variant).
    Simple,
}

/// Everything a run can be told. Defaults are the paper's unless noted.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Params {
    /// Total path budget over all layers, base path included. Default 64; range 8-1024.
    pub paths: u32,
    /// Default `auto`.
    pub mode: Mode,
    /// Working size: the long side is scaled down to this (never up). Default 512.
    pub max_size: u32,
    /// Seed for every random choice. Default 0.
    pub seed: u64,
    /// Iteration counts per stage.
    pub iterations: Iterations,
}

impl Default for Params {
    fn default() -> Self {
        Self {
            paths: 64,
            mode: Mode::Auto,
            max_size: 512,
            seed: 0,
            iterations: Iterations::default(),
        }
    }
}

/// Iterations per stage (paper Sec. 4.3-4.4 and Appendix C).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Iterations {
    /// Structure-loss iterations. Default 50.
    pub structure: u32,
    /// Reconstruction-loss iterations after the structure stage. Default 50.
    pub reconstruction: u32,
    /// Path-addition rounds of the refinement. Default 5.
    pub refine_rounds: u32,
    /// Iterations per refinement round. Default 100.
    pub refine: u32,
    /// Final joint polish under the exact SVG model. Default 50.
    pub polish: u32,
}

impl Default for Iterations {
    fn default() -> Self {
        Self {
            structure: 50,
            reconstruction: 50,
            refine_rounds: 5,
            refine: 100,
            polish: 50,
        }
    }
}

/// One progress report.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Progress {
    pub stage: &'static str,
    /// 0-based index of the stage among `stage_count`.
    pub stage_index: u32,
    pub stage_count: u32,
    pub iteration: u32,
    pub iterations: u32,
    pub loss: Option<f32>,
    pub elapsed: Duration,
}

/// Receives progress and previews while a run goes on. Called from worker threads.
pub trait Observer: Sync {
    fn progress(&self, progress: &Progress);
    /// A stage's preview image, named e.g. `01-init-composite`; PNG-encode it as needed.
    fn preview(&self, name: &str, image: &Image);
}

/// An observer that ignores everything.
pub struct Quiet;

impl Observer for Quiet {
    fn progress(&self, _: &Progress) {}
    fn preview(&self, _: &str, _: &Image) {}
}

/// Decoded inputs of one run (see [`crate::imageio`] for decoding with limits).
pub struct Inputs {
    pub image: image::DynamicImage,
    /// An albedo map (same aspect ratio as the image), e.g. from an intrinsic-decomposition network.
    pub albedo: Option<image::DynamicImage>,
    pub masks: Masks,
}

/// Segmentation masks supplied by the client, e.g. from SAM.
pub enum Masks {
    /// None given: covec segments the albedo map itself.
    None,
    /// Binary masks (0 / 255), one per segment; may overlap and need not cover the image.
    Binary(Vec<image::GrayImage>),
    /// One label map: each distinct value is a segment.
    Labels(image::DynamicImage),
}

/// What a run produces.
pub struct Output {
    pub scene: Scene,
    /// The mode actually run (`auto` resolved).
    pub mode: Mode,
}

/// Why a run stopped without a scene.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("invalid input: {0}")]
    Input(String),
    #[error("invalid parameters: {0}")]
    Params(String),
    #[error("canceled")]
    Canceled,
}

/// Runs the whole pipeline. CPU-bound: call it from a worker thread (it uses the current rayon
/// pool inside), never from an async task.
pub fn run(
    inputs: &Inputs,
    params: &Params,
    observer: &dyn Observer,
    cancel: &AtomicBool,
) -> Result<Output, Error> {
    let _ = (inputs, params, observer, cancel);
    todo!("pipeline::run: initialisation lands with issue 3, optimisation with issue 4")
}
