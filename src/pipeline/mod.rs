//! The COVec pipeline as named stages: decompose → init → structure → reconstruct → refine →
//! split → polish (simple mode: no split), listed once in [`stage::PHOTO_STAGES`] and
//! [`stage::SIMPLE_STAGES`].
//!
//! [`run`] is the one entry point the CLI and the service call. Stages report progress through an
//! [`Observer`], check `cancel` every iteration, and hand each stage's previews to the observer
//! as soon as the stage ends. The run-wide types are in [`params`]; the stage modules are the
//! crate's own.

pub(crate) mod coarse;
pub(crate) mod decompose;
pub(crate) mod descent;
pub(crate) mod init;
pub(crate) mod keep;
pub(crate) mod optimise;
pub mod params;
pub(crate) mod polish;
pub(crate) mod rank;
pub(crate) mod reconstruct;
pub(crate) mod refine;
pub(crate) mod regions;
pub(crate) mod segments;
pub(crate) mod split;
pub mod stage;
pub(crate) mod structure;
#[cfg(test)]
mod tests;

use std::sync::atomic::AtomicBool;

pub use params::{
    Error, Inputs, Iterations, MIN_PATHS, MIN_SIZE, Masks, Mode, Observer, Output, ParamLimits,
    Params, Progress, Quiet, ResolvedMode,
};

use crate::render::Image;
use crate::render::composite::{composite_layers, render_layers};
use crate::scene::LayerKind;
use decompose::Decomposition;
use init::InitState;
use optimise::{Optimisation, OptimiseReport, OptimiseSettings};
use stage::{RunContext, StageKind, StageRun};

/// Runs the whole pipeline. CPU-bound: call it from a worker thread (it uses the current rayon
/// pool inside), never from an async task.
pub fn run(
    inputs: &Inputs,
    params: &Params,
    observer: &dyn Observer,
    cancel: &AtomicBool,
) -> Result<Output, Error> {
    run_with(
        inputs,
        params,
        &OptimiseSettings::default(),
        observer,
        cancel,
    )
    .map(|(output, _)| output)
}

/// Where a run is between stages.
enum Work<'a> {
    Start,
    Decomposed(Decomposition),
    Optimising(Box<Optimisation<'a>>),
}

/// [`run`] with the given optimisation settings; also returns what the optimisation did.
pub(crate) fn run_with(
    inputs: &Inputs,
    params: &Params,
    settings: &OptimiseSettings,
    observer: &dyn Observer,
    cancel: &AtomicBool,
) -> Result<(Output, OptimiseReport), Error> {
    params.validate(&ParamLimits::default())?;
    inputs.check()?;
    let context = RunContext::new(observer, cancel, stage::provisional_stages(params.mode));
    let mut work = Work::Start;
    let mut mode_reason = String::new();
    let mut index = 0;
    while index < context.stages().len() {
        let stage = context.stage(index)?;
        work = match (context.stages()[index].kind, work) {
            (StageKind::Decompose, Work::Start) => {
                stage.iteration(0, 1, None)?;
                let decomposition = decompose::run(inputs, params);
                stage.preview_as("input", &decomposition.target);
                stage.preview_as("albedo-map", &decomposition.albedo);
                context.set_stages(decomposition.mode.stages());
                tracing::info!(
                    mode = decomposition.mode.name(),
                    reason = %decomposition.mode_reason,
                    "mode chosen"
                );
                mode_reason = decomposition.mode_reason.clone();
                stage.iteration(1, 1, None)?;
                Work::Decomposed(decomposition)
            }
            (StageKind::Init, Work::Decomposed(decomposition)) => {
                stage.iteration(0, 1, None)?;
                let original = (inputs.image.width(), inputs.image.height());
                let state = init::run(decomposition, params, original);
                preview_init(&state, &stage);
                let optimisation = Box::new(Optimisation::new(state, params, settings)?);
                stage.draft(|| optimisation.draft());
                stage.iteration(1, 1, None)?;
                Work::Optimising(optimisation)
            }
            (kind, Work::Optimising(mut optimisation)) => {
                optimisation.run_stage(kind, &stage)?;
                stage.draft(|| optimisation.draft());
                Work::Optimising(optimisation)
            }
            (kind, _) => {
                return Err(Error::Internal(format!(
                    "stage {kind:?} is out of order in the stage list"
                )));
            }
        };
        index += 1;
    }
    match work {
        Work::Optimising(optimisation) => {
            let Optimisation {
                scene,
                report,
                mode,
                ..
            } = *optimisation;
            Ok((
                Output {
                    scene,
                    mode,
                    mode_reason,
                },
                report,
            ))
        }
        _ => Err(Error::Internal(
            "the stage list ended before the optimisation".into(),
        )),
    }
}

/// Previews of the init stage: masks overlaid on the target, each layer, and the composite.
fn preview_init(state: &InitState, stage: &StageRun) {
    if !stage.wants_previews() {
        return;
    }
    stage.preview_as("masks-albedo", &mask_overlay(&state.target, &state.albedo));
    if state.mode == ResolvedMode::Photo {
        stage.preview_as(
            "masks-illumination",
            &mask_overlay(&state.target, &state.illumination),
        );
    }
    let layers = render_layers(&state.scene);
    for (kind, image) in LayerKind::ALL.iter().zip(&layers) {
        stage.preview(kind.name(), image);
    }
    stage.preview("composite", &composite_layers(&layers));
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
