//! The optimisation stages after the initialisation, in order:
//! photo: structure → reconstruct → refine (illumination) → split → polish;
//! simple: structure → reconstruct → refine (albedo) → polish.
//!
//! The structure stage, the first part of the reconstruction and the first refinement rounds run
//! on a half-size copy of the scene (see [`super::coarse`]); previews are made at full size.

use super::coarse::{CoarseSettings, PlateauSettings, halve_image, halve_mask, rescaled};
use super::refine::{Growth, RefineSettings, refine};
use super::split::{SplitReport, split_layers};
use super::stage::{Canvas, IterationSpan, Stage, StageContext};
use super::structure::{
    MaskGroup, Scratch, StructureSettings, optimise_reconstruction, optimise_structure,
    preview_two_layers, reconstruction_loss,
};
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
    optimise_with(
        scene,
        groups,
        target,
        mode,
        params,
        &CoarseSettings::default(),
        ctx,
        first_stage,
    )
}

/// [`optimise`] with the given coarse-to-fine schedule.
#[allow(clippy::too_many_arguments)]
pub fn optimise_with(
    scene: &mut Scene,
    groups: &[MaskGroup],
    target: &Image,
    mode: Mode,
    params: &Params,
    coarse: &CoarseSettings,
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
    let refine_settings = RefineSettings::default();
    let mut report = OptimiseReport::default();
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
    let (w, h) = (target.width, target.height);
    let coarse_applies = coarse.applies(w, h);
    // Coarse phase: structure, the first part of the reconstruction, the first refinement rounds.
    let coarse_reconstruction = if coarse_applies {
        ((it.reconstruction as f32 * coarse.reconstruction_share).round() as u32)
            .min(it.reconstruction)
    } else {
        0
    };
    let coarse_rounds = if coarse_applies {
        it.refine_rounds.saturating_sub(coarse.fine_rounds)
    } else {
        0
    };
    let (half_w, half_h) = (w.div_ceil(2), h.div_ceil(2));
    let small_target = coarse_applies.then(|| halve_image(target));
    let mut canvas = Canvas::new(w, h);
    let mut scratch = Scratch::default();

    let structure_losses = if let Some(small_target) = &small_target {
        let mut small = rescaled(scene, 0.5, half_w as u32, half_h as u32);
        let small_groups: Vec<MaskGroup> = groups
            .iter()
            .map(|g| MaskGroup {
                masks: g.masks.iter().map(halve_mask).collect(),
                ..g.clone()
            })
            .collect();
        let losses = optimise_structure(
            &mut small,
            &small_groups,
            small_target,
            it.structure,
            &structure,
            params.seed,
            ctx,
            stage("structure"),
        )?;
        *scene = rescaled(&small, 2.0, w as u32, h as u32);
        losses
    } else {
        optimise_structure(
            scene,
            groups,
            target,
            it.structure,
            &structure,
            params.seed,
            ctx,
            stage("structure"),
        )?
    };
    let after_structure = preview_two_layers(&mut canvas, scene, target, ctx, stage("structure"));
    report.losses.push(StageLoss {
        stage: "structure",
        before: structure_losses[0],
        after: after_structure,
    });

    let reconstruction = |start: u32, count: u32| IterationSpan {
        start,
        count,
        total: it.reconstruction,
    };
    if let Some(small_target) = &small_target {
        let mut small = rescaled(scene, 0.5, half_w as u32, half_h as u32);
        optimise_reconstruction(
            &mut small,
            small_target,
            reconstruction(0, coarse_reconstruction),
            &structure,
            ctx,
            stage("reconstruct"),
        )?;
        *scene = rescaled(&small, 2.0, w as u32, h as u32);
    }
    optimise_reconstruction(
        scene,
        target,
        reconstruction(
            coarse_reconstruction,
            it.reconstruction - coarse_reconstruction,
        ),
        &structure,
        ctx,
        stage("reconstruct"),
    )?;
    let after_reconstruct = if it.reconstruction > 0 {
        preview_two_layers(&mut canvas, scene, target, ctx, stage("reconstruct"))
    } else {
        reconstruction_loss(&mut canvas, scene, target, &mut scratch, None)
    };
    report.losses.push(StageLoss {
        stage: "reconstruct",
        before: after_structure,
        after: after_reconstruct,
    });

    let rounds = |start: u32, count: u32| IterationSpan {
        start,
        count,
        total: it.refine_rounds,
    };
    // Early stopping in the coarse rounds only (see `super::coarse`).
    let fine_refine = RefineSettings {
        plateau: PlateauSettings::never(),
        ..refine_settings.clone()
    };
    let refine_stage = |scene: &mut Scene, target: &Image, span: IterationSpan| {
        let coarse_span = span.start + span.count < span.total;
        refine(
            scene,
            target,
            growth,
            budget,
            span,
            it.refine,
            if coarse_span {
                &refine_settings
            } else {
                &fine_refine
            },
            params.seed,
            ctx,
            stage("refine"),
        )
    };
    if let Some(small_target) = &small_target {
        let mut small = rescaled(scene, 0.5, half_w as u32, half_h as u32);
        refine_stage(&mut small, small_target, rounds(0, coarse_rounds))?;
        *scene = rescaled(&small, 2.0, w as u32, h as u32);
    }
    let [_, after] = refine_stage(
        scene,
        target,
        rounds(coarse_rounds, it.refine_rounds - coarse_rounds),
    )?;
    report.losses.push(StageLoss {
        stage: "refine",
        before: after_reconstruct,
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
