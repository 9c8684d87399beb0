//! The COVec pipeline as named stages: decompose → init → optimise → refine → split → polish → emit.
//!
//! [`run`] is the one entry point the CLI and the service call. Stages report progress through an
//! [`Observer`], check `cancel` every iteration, and hand each stage's previews to the observer
//! as soon as the stage ends.

pub mod coarse;
pub mod init;
pub mod optimise;
pub mod polish;
pub mod refine;
pub mod regions;
pub mod split;
pub mod stage;
pub mod structure;

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use crate::decompose;
use crate::render::composite::svg_model;
use crate::render::{Image, Rasterizer};
use crate::scene::{LayerKind, Scene};

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
///
/// Stages: decompose → init (each between [`Stages::begin`] and [`Stages::end`]), then the
/// optimisation stages of [`optimise::optimise`], which report every iteration themselves.
pub fn run(
    inputs: &Inputs,
    params: &Params,
    observer: &dyn Observer,
    cancel: &AtomicBool,
) -> Result<Output, Error> {
    params.validate()?;
    let started = Instant::now();
    let stage_names = |mode| -> &'static [&'static str] {
        match mode {
            Mode::Simple => &SIMPLE_STAGES,
            _ => &PHOTO_STAGES,
        }
    };
    // `auto` is resolved by the decompose stage; until then, count the photo stages.
    let mut stages = Stages::new(stage_names(params.mode), observer, cancel);
    let original = (inputs.image.width(), inputs.image.height());

    stages.begin()?;
    let decomposition = decompose::run(inputs, params, SEGMENT_CANDIDATES)?;
    observer.preview("00-input", &decomposition.target);
    observer.preview("00-albedo-map", &decomposition.albedo);
    stages.end();
    stages.set_names(stage_names(decomposition.mode));

    stages.begin()?;
    let state = init::run(decomposition, params, original)?;
    preview_init(&state, observer);
    stages.end();

    let init::InitState {
        mut scene,
        target,
        albedo,
        illumination,
        mode,
        ..
    } = state;
    let groups = structure::MaskGroup::from_init(&[albedo, illumination]);
    let ctx = stage::StageContext {
        observer,
        cancel,
        started,
        stage_count: 2 + optimise::stage_names(mode).len() as u32,
    };
    optimise::optimise(&mut scene, &groups, &target, mode, params, &ctx, 2)?;
    Ok(Output { mode, scene })
}

/// All stages of a photo-mode run, for progress reports.
const PHOTO_STAGES: [&str; 7] = [
    "decompose",
    "init",
    "structure",
    "reconstruct",
    "refine",
    "split",
    "polish",
];
/// All stages of a simple-mode run.
const SIMPLE_STAGES: [&str; 6] = [
    "decompose",
    "init",
    "structure",
    "reconstruct",
    "refine",
    "polish",
];

/// How many segmentation masks the decompose stage offers the init stage to choose from.
const SEGMENT_CANDIDATES: usize = 128;

impl Params {
    /// Refuses values outside their documented ranges.
    pub fn validate(&self) -> Result<(), Error> {
        if !(8..=1024).contains(&self.paths) {
            return Err(Error::Params(format!(
                "paths must be within 8-1024, not {}",
                self.paths
            )));
        }
        if !(16..=4096).contains(&self.max_size) {
            return Err(Error::Params(format!(
                "max_size must be within 16-4096, not {}",
                self.max_size
            )));
        }
        Ok(())
    }
}

/// Progress bookkeeping for [`run`]: one report when a stage begins and one when it ends.
pub struct Stages<'a> {
    names: &'static [&'static str],
    index: usize,
    started: Instant,
    observer: &'a dyn Observer,
    cancel: &'a AtomicBool,
}

impl<'a> Stages<'a> {
    pub fn new(
        names: &'static [&'static str],
        observer: &'a dyn Observer,
        cancel: &'a AtomicBool,
    ) -> Self {
        Self {
            names,
            index: 0,
            started: Instant::now(),
            observer,
            cancel,
        }
    }

    /// Replaces the list of stage names (once the mode is known); the stages done keep their
    /// indices.
    pub fn set_names(&mut self, names: &'static [&'static str]) {
        self.names = names;
    }

    /// Starts the next stage, unless the run was canceled.
    pub fn begin(&mut self) -> Result<(), Error> {
        if self.cancel.load(Ordering::Relaxed) {
            return Err(Error::Canceled);
        }
        self.report(0, 1, None);
        Ok(())
    }

    /// Reports progress `iteration / iterations` within the current stage; `Err(Canceled)` if
    /// the run was canceled.
    pub fn iteration(
        &self,
        iteration: u32,
        iterations: u32,
        loss: Option<f32>,
    ) -> Result<(), Error> {
        if self.cancel.load(Ordering::Relaxed) {
            return Err(Error::Canceled);
        }
        self.report(iteration, iterations, loss);
        Ok(())
    }

    /// Ends the current stage.
    pub fn end(&mut self) {
        self.report(1, 1, None);
        self.index += 1;
    }

    fn report(&self, iteration: u32, iterations: u32, loss: Option<f32>) {
        self.observer.progress(&Progress {
            stage: self.names[self.index],
            stage_index: self.index as u32,
            stage_count: self.names.len() as u32,
            iteration,
            iterations,
            loss,
            elapsed: self.started.elapsed(),
        });
    }
}

/// Previews of the init stage: masks overlaid on the target, each layer, and the composite.
fn preview_init(state: &init::InitState, observer: &dyn Observer) {
    observer.preview(
        "01-masks-albedo",
        &mask_overlay(&state.target, &state.albedo),
    );
    if state.mode != Mode::Simple {
        observer.preview(
            "01-masks-illumination",
            &mask_overlay(&state.target, &state.illumination),
        );
    }
    let layers = render_layers(&state.scene);
    for (kind, image) in LayerKind::ALL.iter().zip(&layers) {
        observer.preview(&format!("01-init-{}", kind.name()), image);
    }
    observer.preview("01-init-composite", &composite_layers(&layers));
}

/// Each mask's visible part tinted with a colour of its own, half over the target.
fn mask_overlay(target: &Image, layer: &init::LayerGroups) -> Image {
    let mut out = target.clone();
    for (k, masked) in layer.groups.iter().flatten().enumerate() {
        // Golden-angle hues: neighbours in paint order get well-separated colours.
        let hue = (k as f32 * 0.618_034).fract() * 6.0;
        let tint = [0.0f32, 2.0, 4.0].map(|offset| {
            let d = ((hue - offset + 9.0) % 6.0 - 3.0).abs();
            (d - 1.0).clamp(0.0, 1.0)
        });
        for i in masked.mask.indices() {
            for (c, &t) in tint.iter().enumerate() {
                out.data[3 * i + c] = 0.5 * target.data[3 * i + c] + 0.5 * t;
            }
        }
    }
    out
}

/// Each layer rendered over its base colour (white, white, black).
pub fn render_layers(scene: &Scene) -> [Image; 3] {
    let mut rasterizer = Rasterizer::new();
    LayerKind::ALL.map(|kind| {
        let mut image = Image::default();
        let (w, h) = (scene.width as usize, scene.height as usize);
        rasterizer.render(&scene.layer(kind).paths, kind.base(), w, h, &mut image);
        image
    })
}

/// clamp01(albedo · shade + light), as the SVG's blend modes show it.
pub fn composite_layers([albedo, shade, light]: &[Image; 3]) -> Image {
    let mut out = Image::default();
    svg_model(albedo, shade, light, &mut out);
    out
}

/// The scene as shown: its three layers rendered and composited.
pub fn composite(scene: &Scene) -> Image {
    composite_layers(&render_layers(scene))
}
