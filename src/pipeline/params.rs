//! Run-wide types shared by every stage, the command line, the service and the editor: what a
//! run is told ([`Params`]) and given ([`Inputs`]), what it reports ([`Progress`] to an
//! [`Observer`]), what it returns ([`Output`]) and how it fails ([`Error`]).

use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::imageio::{InputError, check_aspect};
use crate::output::{self, Artefact};
use crate::scene::Scene;

/// Which variant of the method to run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[cfg_attr(feature = "service", derive(utoipa::ToSchema))]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// Pick `simple` or `photo` from the image itself: `simple` for flat artwork, `photo` for
    /// smooth shading or photographic texture, however much flat background surrounds it.
    #[default]
    Auto,
    /// Albedo + shade + light (the paper's main method).
    Photo,
    /// Albedo only, for emoji, icons and flat artwork (the paper's appendix variant).
    Simple,
}

/// The variant a run actually runs: [`Mode`] with `auto` decided.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResolvedMode {
    /// Albedo + shade + light.
    Photo,
    /// Albedo only.
    Simple,
}

impl ResolvedMode {
    /// `photo` or `simple`, as in [`Mode`]'s serialised form.
    pub fn name(self) -> &'static str {
        match self {
            ResolvedMode::Photo => "photo",
            ResolvedMode::Simple => "simple",
        }
    }
}

impl From<ResolvedMode> for Mode {
    fn from(mode: ResolvedMode) -> Self {
        match mode {
            ResolvedMode::Photo => Mode::Photo,
            ResolvedMode::Simple => Mode::Simple,
        }
    }
}

/// Everything a run can be told. Defaults are the paper's unless noted.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "service", derive(utoipa::ToSchema))]
#[serde(default, deny_unknown_fields)]
pub struct Params {
    /// Total path budget over all layers, base path included. Default 64; range 8-1024.
    #[cfg_attr(feature = "service", schema(minimum = 8, maximum = 1024))]
    pub paths: u32,
    /// Default `auto`.
    pub mode: Mode,
    /// Working size: the long side is scaled down to this (never up). Default 512; range 16-4096.
    #[cfg_attr(feature = "service", schema(minimum = 16, maximum = 4096))]
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
#[cfg_attr(feature = "service", derive(utoipa::ToSchema))]
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
    /// Final joint polish under the exact SVG model. Default 160, of which the first 3/4 run at
    /// reduced size on images of 128 px and more (`CoarseSettings::polish_share`), so 40 at full
    /// size (fewer above 512 px, `CoarseSettings::polish_fine_side`): with a flat albedo map
    /// and split segments much is left to fit jointly.
    pub polish: u32,
}

impl Default for Iterations {
    fn default() -> Self {
        Self {
            structure: 50,
            reconstruction: 50,
            refine_rounds: 5,
            refine: 100,
            polish: 160,
        }
    }
}

/// Ranges [`Params`] must keep. The defaults are what the pipeline supports; a service may
/// configure narrower ones.
#[derive(Clone, Debug, PartialEq)]
pub struct ParamLimits {
    /// Largest `paths`. Default 1024.
    pub max_paths: u32,
    /// Largest `max_size`. Default 4096.
    pub max_size: u32,
    /// Largest [`Iterations::total`]. Default: no limit.
    pub max_iterations: Option<u64>,
}

impl Default for ParamLimits {
    fn default() -> Self {
        Self {
            max_paths: 1024,
            max_size: 4096,
            max_iterations: None,
        }
    }
}

/// Smallest path budget: the albedo base and room for structure and refinement.
pub const MIN_PATHS: u32 = 8;
/// Smallest working size.
pub const MIN_SIZE: u32 = 16;

impl Params {
    /// Refuses values outside `limits`.
    pub fn validate(&self, limits: &ParamLimits) -> Result<(), Error> {
        if !(MIN_PATHS..=limits.max_paths).contains(&self.paths) {
            return Err(Error::Params(format!(
                "`paths` must be within {MIN_PATHS}-{}, not {}",
                limits.max_paths, self.paths
            )));
        }
        if !(MIN_SIZE..=limits.max_size).contains(&self.max_size) {
            return Err(Error::Params(format!(
                "`max_size` must be within {MIN_SIZE}-{}, not {}",
                limits.max_size, self.max_size
            )));
        }
        let total = self.iterations.total();
        if let Some(max) = limits.max_iterations
            && total > max
        {
            return Err(Error::Params(format!(
                "the iteration budget {total} is over the limit of {max}"
            )));
        }
        Ok(())
    }
}

/// Decoded inputs of one run (see [`crate::imageio`] for decoding with limits).
pub struct Inputs {
    /// The photograph or artwork to vectorise.
    pub image: image::DynamicImage,
    /// An albedo map (same aspect ratio as the image), e.g. from an intrinsic-decomposition network.
    pub albedo: Option<image::DynamicImage>,
    /// Segmentation masks, e.g. from SAM.
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

impl Inputs {
    /// Refuses inputs that cannot be used together: an empty image, or an albedo map, mask or
    /// label map without the image's aspect ratio. Every caller (CLI, service, [`super::run`])
    /// checks through here, so the rule is the same everywhere.
    pub fn check(&self) -> Result<(), InputError> {
        let image = (self.image.width(), self.image.height());
        if image.0 == 0 || image.1 == 0 {
            return Err(InputError::Empty {
                width: image.0,
                height: image.1,
            });
        }
        if let Some(albedo) = &self.albedo {
            check_aspect("the albedo map", (albedo.width(), albedo.height()), image)?;
        }
        match &self.masks {
            Masks::None => {}
            Masks::Binary(masks) => {
                for (k, mask) in masks.iter().enumerate() {
                    check_aspect(&format!("mask {}", k + 1), mask.dimensions(), image)?;
                }
            }
            Masks::Labels(labels) => {
                check_aspect("the label map", (labels.width(), labels.height()), image)?;
            }
        }
        Ok(())
    }
}

/// One progress report.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Progress {
    /// The stage's name, e.g. `refine`.
    pub stage: &'static str,
    /// 0-based index of the stage among `stage_count`.
    pub stage_index: u32,
    /// Stages of the whole run (known once `auto` is resolved; counted as photo before).
    pub stage_count: u32,
    /// Iterations done within the stage.
    pub iteration: u32,
    /// Iterations of the stage.
    pub iterations: u32,
    /// The stage's current loss, where it has one.
    pub loss: Option<f32>,
    /// Time since the run started.
    pub elapsed: Duration,
}

impl Progress {
    /// How much of the run is done, in [0, 1]: the stages before this one, and the share of
    /// this one's iterations done.
    pub fn fraction(&self) -> f32 {
        // A stage of no iterations is done as soon as it reports.
        let within = if self.iterations == 0 {
            1.0
        } else {
            (self.iteration as f32 / self.iterations as f32).min(1.0)
        };
        ((self.stage_index as f32 + within) / self.stage_count.max(1) as f32).clamp(0.0, 1.0)
    }
}

/// Receives progress and previews while a run goes on. Called from worker threads.
pub trait Observer: Sync {
    /// A progress report: at least one when each stage begins and ends.
    fn progress(&self, progress: &Progress);
    /// A stage's preview image, named e.g. `01-init-composite`; PNG-encode it as needed.
    fn preview(&self, name: &str, image: &crate::render::Image);
    /// Whether previews are kept at all: when not, images drawn only to be previewed (the
    /// init stage's masks and layers) are not drawn.
    fn wants_previews(&self) -> bool {
        true
    }
    /// A draft after `stage`: the whole layered scene as the run has it, in the SVG model's
    /// layers and ranges (the final one comes in [`Output`]). One after the init stage and one
    /// after each later stage that changes the picture but the last (the stage list says which:
    /// `StageSpec::draft`), so a front end has a result to show at once.
    fn draft(&self, _stage: &str, _scene: &Scene) {}
    /// Whether the observer takes drafts: when not, none is made (making one copies the scene
    /// and, before the split, splits the copy).
    fn wants_drafts(&self) -> bool {
        false
    }
}

/// An observer that ignores everything.
pub struct Quiet;

impl Observer for Quiet {
    fn progress(&self, _: &Progress) {}
    fn preview(&self, _: &str, _: &crate::render::Image) {}
    fn wants_previews(&self) -> bool {
        false
    }
}

/// What a run produces.
pub struct Output {
    /// The layered vector scene.
    pub scene: Scene,
    /// The mode actually run (`auto` resolved).
    pub mode: ResolvedMode,
    /// Why that mode, one sentence: the request, or what `auto` saw in the image (flat
    /// artwork; smooth shading or photographic texture).
    pub mode_reason: String,
}

impl Output {
    /// The files of a finished run (layered SVG, per-layer SVGs, JSON scene), in the order to
    /// write them; see [`crate::output`].
    pub fn artefacts(&self) -> Vec<Artefact> {
        output::artefacts(&self.scene, output::RESULT_FILES)
    }
}

/// Why a run stopped without a scene.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The inputs cannot be used: the caller's mistake.
    #[error("invalid input: {0}")]
    Input(#[from] InputError),
    /// A parameter is out of range: the caller's mistake.
    #[error("invalid parameters: {0}")]
    Params(String),
    /// The run was canceled through its cancel flag.
    #[error("canceled")]
    Canceled,
    /// A broken invariant inside covec: a bug, never the caller's mistake.
    #[error("internal error: {0}")]
    Internal(String),
}
