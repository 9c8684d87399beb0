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

/// The image loss (MSE against the target) at the start and end of one stage: the two-layer
/// model `R(A)·R(I)` up to the refinement, the SVG model `clamp01(R(A)·R(S) + R(L))` in the polish.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StageLoss {
    pub stage: &'static str,
    pub before: f32,
    pub after: f32,
}

/// What the optimisation did, for logs and tests.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct OptimiseReport {
    pub losses: Vec<StageLoss>,
    pub split: Option<SplitReport>,
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
    let [initial, after_structure, after_reconstruct] = optimise_structure(
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
    report.losses.push(StageLoss {
        stage: "structure",
        before: initial,
        after: after_structure,
    });
    report.losses.push(StageLoss {
        stage: "reconstruct",
        before: after_structure,
        after: after_reconstruct,
    });
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
    let [before, after] = refine(
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
    report.losses.push(StageLoss {
        stage: "refine",
        before,
        after,
    });
    if mode != Mode::Simple {
        ctx.iteration(stage("split"), 0, 1, None)?;
        let split = split_layers(scene, target, ctx, stage("split"));
        ctx.iteration(stage("split"), 1, 1, Some(split.mse_after))?;
        report.split = Some(split);
    }
    let [before, after] = polish::polish(
        scene,
        target,
        it.polish,
        polish::polish_settings(),
        ctx,
        stage("polish"),
    )?;
    report.losses.push(StageLoss {
        stage: "polish",
        before,
        after,
    });
    Ok(report)
}

/// Keeps the albedo layer's first path, the opaque full-canvas base, in place and opaque:
/// browsers must see an opaque backdrop under the blend groups. Its colour stays trainable.
pub(crate) fn hold_albedo_base(grads: &mut [crate::render::PathGrad]) {
    if let Some(base) = grads.first_mut() {
        base.points.iter_mut().for_each(|p| *p = Default::default());
        base.opacity = 0.0;
    }
}
