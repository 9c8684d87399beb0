//! The optimisation stages after the initialisation, in order:
//! photo: structure → reconstruct → refine (illumination) → split → polish;
//! simple: structure → reconstruct → refine (albedo) → polish.

use super::refine::{Growth, RefineSettings, refine};
use super::split::{SplitReport, split_layers};
use super::stage::{Stage, StageContext};
use super::structure::{MaskGroup, StructureSettings, optimise_structure};
use super::{Error, Mode, Params, polish};
use crate::render::Image;
use crate::scene::{LayerKind, Scene};

/// Stage names of the optimisation for a resolved mode (`Photo` or `Simple`).
pub fn stage_names(mode: Mode) -> &'static [&'static str] {
    match mode {
        Mode::Simple => &["structure", "reconstruct", "refine", "polish"],
        _ => &["structure", "reconstruct", "refine", "split", "polish"],
    }
}

/// Loss at the end of each stage (NaN for stages that did not run), for logs and tests.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct OptimiseReport {
    pub reconstruct_loss: f32,
    pub refine_loss: f32,
    pub split: Option<SplitReport>,
    pub polish_loss: f32,
}

/// Runs the optimisation stages on an initialised scene. In photo mode the illumination layer is
/// `scene.shade` until the split; in simple mode only the albedo layer is used. `first_stage` is
/// the run-wide index of the first stage here (stages before it: decompose, init, ...).
pub fn optimise(
    scene: &mut Scene,
    groups: &[MaskGroup],
    target: &Image,
    mode: Mode,
    params: &Params,
    ctx: &StageContext,
    first_stage: u32,
) -> Result<OptimiseReport, Error> {
    let names = stage_names(mode);
    let stage = |name: &'static str| Stage {
        name,
        index: first_stage + names.iter().position(|&n| n == name).unwrap_or(0) as u32,
    };
    let budget = params.paths as usize;
    if scene.path_count() > budget {
        return Err(Error::Params(format!(
            "the initialisation made {} paths, more than the budget of {budget}",
            scene.path_count()
        )));
    }
    if (target.width, target.height) != (scene.width as usize, scene.height as usize) {
        return Err(Error::Params("target image and scene sizes differ".into()));
    }
    let it = &params.iterations;
    let structure = StructureSettings::default();
    let mut report = OptimiseReport::default();
    report.reconstruct_loss = optimise_structure(
        scene,
        groups,
        target,
        it.structure,
        it.reconstruction,
        &structure,
        params.seed,
        ctx,
        [stage("structure"), stage("reconstruct")],
    )?;
    let growth = match mode {
        Mode::Simple => Growth {
            layer: LayerKind::Albedo,
            color_max: 1.0,
        },
        _ => Growth {
            layer: LayerKind::Shade,
            color_max: structure.illumination_cap,
        },
    };
    report.refine_loss = refine(
        scene,
        target,
        growth,
        budget,
        it.refine_rounds,
        it.refine,
        &RefineSettings::default(),
        params.seed,
        ctx,
        stage("refine"),
    )?;
    if mode != Mode::Simple {
        ctx.iteration(stage("split"), 0, 1, None)?;
        let split = split_layers(scene, target, ctx, stage("split"));
        ctx.iteration(stage("split"), 1, 1, Some(split.mse_after))?;
        report.split = Some(split);
    }
    report.polish_loss = polish::polish(
        scene,
        target,
        it.polish,
        polish::polish_settings(),
        ctx,
        stage("polish"),
    )?;
    Ok(report)
}
