//! The one optimisation loop every stage runs: per iteration, the loss and its gradient, the
//! plateau test ([`Plateau`]), the stage's holds on the gradient, one Adam step per trained path
//! set, the stage's own work after the step, and a progress report.
//!
//! A stage configures it: what is optimised (a [`Trainable`]: the scene's layers, or the
//! refinement's new paths, with one [`Adam`] per set, i.e. the learning rates and bounds), the
//! loss and holds (an [`Objective`]), and the schedule and stop ([`Descent`]). The coarse-to-fine
//! split of a stage is the caller's: it runs the loop once per part.
//!
//! The loop owns nothing but the gradients and the plateau test; the canvas it renders on is
//! the caller's, lent to the objective at each call.

use super::coarse::{Plateau, PlateauSettings};
use super::params::Error;
use super::stage::Canvas;
use crate::optim::{Adam, reset_grads};
use crate::render::PathGrad;
use crate::scene::{LayerKind, Path, Scene};

/// What a loop trains: numbered sets of paths, each stepped by its own Adam.
pub(crate) trait Trainable {
    fn paths(&self, set: usize) -> &[Path];
    fn paths_mut(&mut self, set: usize) -> &mut [Path];
}

/// The scene's layers in [`LayerKind::ALL`] order: set 0 is the albedo, 1 the shade (the
/// illumination before the split), 2 the light.
impl Trainable for Scene {
    fn paths(&self, set: usize) -> &[Path] {
        &self.layer(LayerKind::ALL[set]).paths
    }

    fn paths_mut(&mut self, set: usize) -> &mut [Path] {
        &mut self.layer_mut(LayerKind::ALL[set]).paths
    }
}

/// Loose paths (the refinement's new ones): one set.
impl Trainable for [Path] {
    fn paths(&self, _set: usize) -> &[Path] {
        self
    }

    fn paths_mut(&mut self, _set: usize) -> &mut [Path] {
        self
    }
}

/// A stage's loss over a [`Trainable`], and what it does around each step.
pub(crate) trait Objective<M: Trainable + ?Sized> {
    /// The loss at the model's current values. `grads` (one per set, zeroed) may receive the
    /// gradient here already, when computing it with the loss costs less than apart.
    fn loss(&mut self, canvas: &mut Canvas, model: &M, grads: &mut [Vec<PathGrad>]) -> f32;

    /// Adds the gradient of the last [`Objective::loss`] into `grads` if that did not: called
    /// only when the loop goes on to a step.
    fn gradient(&mut self, _canvas: &mut Canvas, _model: &M, _grads: &mut [Vec<PathGrad>]) {}

    /// Zeroes what set `set` must not change, before its step.
    fn hold(&self, _set: usize, _grads: &mut [PathGrad]) {}

    /// Runs after each step (`done` iterations done); returns the loss to report for the
    /// iteration when it is not the one before the step.
    fn stepped(
        &mut self,
        _canvas: &mut Canvas,
        _model: &mut M,
        _adams: &mut [Adam],
        _grads: &[Vec<PathGrad>],
        _done: u32,
    ) -> Option<f32> {
        None
    }
}

/// How long a loop runs and when it stops early.
pub(crate) struct Descent {
    /// At most this many iterations.
    pub iterations: u32,
    /// The early stop; [`PlateauSettings::never`] runs every iteration.
    pub plateau: PlateauSettings,
}

impl Descent {
    /// Runs the loop on `model`, one Adam per set (`adams[k]` steps set `k`). `report` gets the
    /// iterations done and the iteration's loss after each step; an error from it ends the loop.
    pub fn run<M: Trainable + ?Sized>(
        &self,
        canvas: &mut Canvas,
        model: &mut M,
        adams: &mut [Adam],
        objective: &mut impl Objective<M>,
        mut report: impl FnMut(u32, f32) -> Result<(), Error>,
    ) -> Result<(), Error> {
        let mut grads: Vec<Vec<PathGrad>> = adams.iter().map(|_| Vec::new()).collect();
        let mut plateau = Plateau::new(self.plateau);
        for it in 0..self.iterations {
            for (set, grads) in grads.iter_mut().enumerate() {
                reset_grads(grads, model.paths(set));
            }
            let loss = objective.loss(canvas, model, &mut grads);
            if plateau.stop_after(loss) {
                break;
            }
            objective.gradient(canvas, model, &mut grads);
            for (set, (adam, grads)) in adams.iter_mut().zip(&mut grads).enumerate() {
                objective.hold(set, grads);
                adam.step(model.paths_mut(set), grads);
            }
            let reported = objective.stepped(canvas, model, adams, &grads, it + 1);
            report(it + 1, reported.unwrap_or(loss))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optim::{AdamSettings, Bounds};

    /// Σ (colour − 0.25)² over one path's channels, its gradient given with the loss.
    struct ToGrey;

    impl Objective<[Path]> for ToGrey {
        fn loss(&mut self, _: &mut Canvas, paths: &[Path], grads: &mut [Vec<PathGrad>]) -> f32 {
            let color = paths[0].color;
            grads[0][0].color = color.map(|c| 2.0 * (c - 0.25));
            color.iter().map(|c| (c - 0.25) * (c - 0.25)).sum()
        }
    }

    #[test]
    fn the_loop_descends_reports_each_step_and_stops_on_a_plateau() {
        let mut paths = [Path::rect(0.0, 0.0, 4.0, 4.0, [1.0, 0.0, 0.5], 1.0)];
        let adam = || {
            [Adam::new(
                AdamSettings::default(),
                Bounds::canvas(8, 8, 1.0),
            )]
        };
        let mut canvas = Canvas::new(8, 8);
        let mut reported = Vec::new();
        let descent = Descent {
            iterations: 2000,
            plateau: PlateauSettings::default(),
        };
        let mut report = |done, loss| {
            reported.push((done, loss));
            Ok(())
        };
        descent
            .run(
                &mut canvas,
                &mut paths[..],
                &mut adam(),
                &mut ToGrey,
                &mut report,
            )
            .unwrap();
        let steps = reported.len() as u32;
        assert!(steps < 2000, "stopped on the plateau");
        assert!(reported.iter().map(|r| r.0).eq(1..=steps));
        let color = paths[0].color;
        assert!(color.iter().all(|c| (c - 0.25).abs() < 0.05), "{color:?}");

        let never = Descent {
            iterations: 50,
            plateau: PlateauSettings::never(),
        };
        let mut count = 0;
        never
            .run(
                &mut canvas,
                &mut paths[..],
                &mut adam(),
                &mut ToGrey,
                |_, _| {
                    count += 1;
                    Ok(())
                },
            )
            .unwrap();
        assert_eq!(count, 50);
    }
}
