//! The reconstruction stage (paper Sec. 4.3): the shared loss ‖I − R(A)·R(I)‖² on the albedo
//! and illumination (`scene.shade`) layers, one Adam per layer, splitting the segments the loss
//! pulls hardest ([`super::segments`]), with the kept terms of [`super::keep`].

use super::descent::{Descent, Objective};
use super::keep::{Held, KeepRun};
use super::params::{Error, ResolvedMode};
use super::segments::{SegmentPull, SplitLayer, SplitPlan};
use super::stage::{Canvas, IterationSpan, StageRun, hold_albedo};
use super::structure::{Scratch, StructureSettings, descend_two_layers, reconstruction_loss};
use crate::optim::Adam;
use crate::render::{Image, PathGrad};
use crate::scene::{LayerKind, Scene};

/// How one part (coarse or fine) of the reconstruction runs.
pub(crate) struct ReconstructionRun<'a> {
    pub span: IterationSpan,
    pub settings: &'a StructureSettings,
    pub keep: Option<&'a KeepRun<'a>>,
    pub mode: ResolvedMode,
    /// Up to where the loop splits segments ([`super::segments`]).
    pub split: SplitPlan,
}

/// Runs the span's iterations of the shared reconstruction loss ‖I − R(A)·R(I)‖² on both
/// layers, one Adam per layer, stopping early once the loss has plateaued, splitting the
/// segments the loss pulls hardest as the plan says. Returns the loss before and after.
/// The albedo layer is held as [`hold_albedo`] says.
pub(crate) fn optimise_reconstruction(
    scene: &mut Scene,
    target: &Image,
    run: &ReconstructionRun,
    stage: &StageRun,
) -> Result<[f32; 2], Error> {
    let ReconstructionRun {
        span,
        settings,
        keep,
        mode,
        split,
    } = *run;
    let descent = Descent {
        iterations: span.count,
        plateau: settings.plateau,
    };
    let reconstruction = |canvas: &mut Canvas, scene: &Scene, scratch| {
        Ok(Reconstruction {
            scratch,
            target,
            held: keep.map(|k| k.held(canvas, scene, &[LayerKind::Shade], settings)),
            mode,
            split,
            iterations: span.count,
            pull: SegmentPull::default(),
        })
    };
    descend_two_layers(
        scene,
        target,
        settings,
        &descent,
        reconstruction,
        |done, loss| stage.iteration(span.start + done, span.total, Some(loss)),
    )
}

/// The reconstruction loss with the kept terms, on sets 0 (albedo) and 1 (illumination).
struct Reconstruction<'a> {
    scratch: Scratch,
    target: &'a Image,
    held: Option<Held<'a>>,
    mode: ResolvedMode,
    split: SplitPlan,
    /// Iterations of this part, for the split plan.
    iterations: u32,
    /// The illumination layer's pull: only it splits (see `super::segments`).
    pull: SegmentPull,
}

impl AsMut<Scratch> for Reconstruction<'_> {
    fn as_mut(&mut self) -> &mut Scratch {
        &mut self.scratch
    }
}

impl Objective<Scene> for Reconstruction<'_> {
    fn loss(&mut self, canvas: &mut Canvas, scene: &Scene, grads: &mut [Vec<PathGrad>]) -> f32 {
        let (albedo, illumination) = grads.split_at_mut(1);
        let (grads_a, grads_i) = (&mut albedo[0], &mut illumination[0]);
        let mut loss = reconstruction_loss(
            canvas,
            scene,
            self.target,
            &mut self.scratch,
            Some((&mut *grads_a, &mut *grads_i)),
        );
        if let Some(held) = &self.held {
            loss += held.add_term(canvas, LayerKind::Albedo, &scene.albedo.paths, grads_a);
            loss += held.add_term(canvas, LayerKind::Shade, &scene.shade.paths, grads_i);
        }
        loss
    }

    fn hold(&self, set: usize, grads: &mut [PathGrad]) {
        if set == 0 {
            hold_albedo(grads, self.mode);
        }
    }

    fn stepped(
        &mut self,
        _canvas: &mut Canvas,
        scene: &mut Scene,
        adams: &mut [Adam],
        grads: &[Vec<PathGrad>],
        done: u32,
    ) -> Option<f32> {
        // Once the scene holds its target no split is due, and the pull is not needed.
        let segments = scene.segment_count();
        if segments < self.split.target {
            self.pull.add(&scene.shade.paths, &grads[1]);
        }
        let due = self.split.due(done, self.iterations, segments);
        if due > 0 {
            SplitLayer {
                paths: &mut scene.shade.paths,
                pull: &mut self.pull,
                adam: &mut adams[1],
            }
            .split_most_pulled(due);
        }
        None
    }
}
