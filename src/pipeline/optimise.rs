//! The optimisation stages after the initialisation, as [`super::stage::PHOTO_STAGES`] and
//! [`super::stage::SIMPLE_STAGES`] order them: photo: structure → reconstruct → refine
//! (illumination) → split → polish; simple: structure → reconstruct → refine (albedo) → polish.
//!
//! The structure stage, the first part of the reconstruction, the first refinement rounds and the
//! first part of the polish run on a reduced copy of the scene (see [`super::coarse`]);
//! previews are made at full size ([`Optimisation::coarse_then_fine`]). The reconstruction splits
//! segments up to the segment budget ([`super::segments`]). Every stage's iterations are
//! [`super::descent::Descent`]'s loop.

use super::coarse::{CoarseSettings, PlateauSettings, halvings_of};
use super::init::InitState;
use super::keep::{Keep, KeepRun, KeepSettings};
use super::params::{Error, Params, ResolvedMode};
use super::polish::{self, LightnessFloor, PolishLoss, PolishSettings};
use super::reconstruct::{ReconstructionRun, optimise_reconstruction};
use super::refine::{Growth, RefinePlan, RefineSettings, refine};
use super::segments::SplitPlan;
use super::split::{SplitReport, split_layers};
use super::stage::{Canvas, IterationSpan, StageKind, StageRun};
use super::structure::{
    MaskGroup, Scratch, StructureRun, StructureSettings, optimise_structure, preview_two_layers,
    reconstruction_loss,
};
use crate::imageio::halve_image;
use crate::render::Image;
use crate::scene::{LayerKind, Scene};

/// Settings of every optimisation stage; the defaults are what `covec` runs.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct OptimiseSettings {
    pub structure: StructureSettings,
    pub refine: RefineSettings,
    pub coarse: CoarseSettings,
    pub polish: PolishSettings,
    pub keep: KeepSettings,
}

/// The image loss at the start and end of one stage: the MSE of the two-layer model `R(A)·R(I)`
/// up to the refinement; in the polish, the MSE of the SVG model `clamp01(R(A)·R(S) + R(L))`
/// plus its gradient-similarity term (`PolishSettings::gradient_similarity`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct StageLoss {
    pub stage: &'static str,
    pub before: f32,
    pub after: f32,
}

/// What the optimisation did, for logs and tests.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct OptimiseReport {
    pub losses: Vec<StageLoss>,
    pub split: Option<SplitReport>,
}

/// An initialised scene going through the optimisation stages. In photo mode the illumination
/// layer is `scene.shade` until the split; in simple mode only the albedo layer is used.
pub(crate) struct Optimisation<'a> {
    pub scene: Scene,
    pub report: OptimiseReport,
    /// The structure stage's mask groups, until that stage takes them.
    groups: Vec<MaskGroup>,
    /// What paths are held to after the structure stage (photo mode): at full size, then
    /// halved once, twice, … (at least once).
    keep: Option<Vec<Keep>>,
    target: Image,
    /// The target halved once, twice, … ([`CoarseSettings::halvings`] times; none when the
    /// coarse phase does not apply).
    pyramid: Vec<Image>,
    pub mode: ResolvedMode,
    params: &'a Params,
    settings: &'a OptimiseSettings,
    /// The loss after the last stage run, the next stage's `before`.
    loss: f32,
}

impl<'a> Optimisation<'a> {
    /// Takes over the init stage's scene and mask groups.
    pub fn new(
        init: InitState,
        params: &'a Params,
        settings: &'a OptimiseSettings,
    ) -> Result<Self, Error> {
        let InitState {
            scene,
            target,
            albedo,
            illumination,
            mode,
            masks_given,
        } = init;
        let groups = MaskGroup::from_init(&[albedo, illumination]);
        Self::from_parts(scene, groups, target, mode, masks_given, params, settings)
    }

    /// Takes over a scene with its structure groups (as the init stage makes them).
    pub fn from_parts(
        scene: Scene,
        groups: Vec<MaskGroup>,
        target: Image,
        mode: ResolvedMode,
        masks_given: bool,
        params: &'a Params,
        settings: &'a OptimiseSettings,
    ) -> Result<Self, Error> {
        let budget = params.paths as usize;
        if scene.path_count() > budget {
            return Err(Error::Internal(format!(
                "the initialisation made {} paths, more than the budget of {budget}",
                scene.path_count()
            )));
        }
        if (target.width, target.height) != (scene.width as usize, scene.height as usize) {
            return Err(Error::Internal(
                "target image and scene sizes differ".into(),
            ));
        }
        let (w, h) = (target.width, target.height);
        let halvings = settings.coarse.halvings(w, h);
        // Photo mode only: simple mode's albedo paths are its objects and shading at once.
        let keep = (mode == ResolvedMode::Photo)
            .then(|| Keep::new(&groups, w, h, &settings.keep, masks_given))
            .filter(|k| k.albedo_weight > 0.0 || k.containment_weight > 0.0)
            .map(|full| {
                let halved = halvings_of(&full, halvings.max(1), Keep::halved);
                std::iter::once(full).chain(halved).collect()
            });
        Ok(Self {
            keep,
            groups,
            pyramid: halvings_of(&target, halvings, halve_image),
            target,
            scene,
            mode,
            params,
            settings,
            report: OptimiseReport::default(),
            loss: 0.0,
        })
    }

    /// Runs one optimisation stage.
    pub fn run_stage(&mut self, kind: StageKind, stage: &StageRun) -> Result<(), Error> {
        match kind {
            StageKind::Structure => self.structure(stage),
            StageKind::Reconstruct => self.reconstruct(stage),
            StageKind::Refine => self.refine(stage),
            StageKind::Split => self.split(stage),
            StageKind::Polish => self.polish(stage),
            StageKind::Decompose | StageKind::Init => Err(Error::Internal(format!(
                "the {} stage runs before the optimisation",
                stage.name()
            ))),
        }
    }

    /// The scene as the SVG model would draw it if the run ended now: before the split (photo
    /// mode), the illumination of a copy split into shade and light; every value in range.
    pub fn draft(&self) -> Scene {
        let mut scene = self.scene.clone();
        if self.mode == ResolvedMode::Photo && self.report.split.is_none() {
            split_layers(&mut scene, &self.target, None);
        }
        polish::into_range(&mut scene);
        scene
    }

    /// A full-size canvas for a stage's loss after it ends: made for the purpose and dropped,
    /// so that no stage's buffers stay alive through the next (its stored signed areas are
    /// some of a job's largest).
    fn canvas(&self) -> Canvas {
        Canvas::new(self.target.width, self.target.height)
    }

    /// How many times the coarse copy is halved (0: no coarse phase).
    fn halvings(&self) -> u32 {
        self.pyramid.len() as u32
    }

    /// Runs `f` on a copy of the scene halved `halvings` (≥ 1) times (against the target at that
    /// size) and scales the result back.
    fn coarse<T>(
        &mut self,
        halvings: u32,
        f: impl FnOnce(&mut Scene, &Image) -> Result<T, Error>,
    ) -> Result<Option<T>, Error> {
        let Some(small_target) = self.pyramid.get((halvings as usize).wrapping_sub(1)) else {
            return Ok(None);
        };
        let (w, h) = (self.target.width as u32, self.target.height as u32);
        let (sw, sh) = (small_target.width as u32, small_target.height as u32);
        let scale = 0.5f32.powi(halvings as i32);
        let mut small = self.scene.rescaled(scale, sw, sh);
        let out = f(&mut small, small_target)?;
        self.scene = small.rescaled(1.0 / scale, w, h);
        Ok(Some(out))
    }

    /// How many of `asked` iterations (or rounds) run coarse: none when the phase does not apply.
    fn coarse_count(&self, asked: u32) -> u32 {
        if !self.pyramid.is_empty() { asked } else { 0 }
    }

    /// Runs a stage of `total` iterations (or rounds) coarse to fine: each of `coarse`'s
    /// `(count, halvings)` parts in turn on the copy halved that many times (none when the
    /// coarse phase does not apply), then the rest at full size. `part` runs one part with the
    /// kept terms at its size; returns the fine part's result.
    fn coarse_then_fine<T>(
        &mut self,
        total: u32,
        coarse: &[(u32, u32)],
        mut part: impl FnMut(&mut Scene, &Image, Part) -> Result<T, Error>,
    ) -> Result<T, Error> {
        let keep = self.keep.take();
        let seed = self.params.seed;
        let span = |start: u32, count: u32| IterationSpan {
            start,
            count,
            total,
        };
        let mut start = 0;
        let coarse_parts = coarse.iter().try_for_each(|&(count, halvings)| {
            let count = self.coarse_count(count);
            if count == 0 {
                return Ok(());
            }
            let reduced = keep_run(&keep, halvings, seed);
            self.coarse(halvings, |small, small_target| {
                let coarse = Part {
                    span: span(start, count),
                    keep: reduced.as_ref(),
                    coarse: true,
                };
                part(small, small_target, coarse)
            })?;
            start += count;
            Ok(())
        });
        let full = keep_run(&keep, 0, seed);
        let fine = Part {
            span: span(start, total - start),
            keep: full.as_ref(),
            coarse: false,
        };
        let fine = coarse_parts.and_then(|_| part(&mut self.scene, &self.target, fine));
        self.keep = keep;
        fine
    }

    fn record(&mut self, stage: &StageRun, before: f32, after: f32) {
        self.report.losses.push(StageLoss {
            stage: stage.name(),
            before,
            after,
        });
        self.loss = after;
    }

    fn structure(&mut self, stage: &StageRun) -> Result<(), Error> {
        let run = StructureRun {
            iterations: self.params.iterations.structure,
            settings: &self.settings.structure,
            seed: self.params.seed,
        };
        // Taken for good: no later stage reads the masks, and at full size they are a large
        // share of a job's memory.
        let groups = std::mem::take(&mut self.groups);
        let halvings = self.halvings();
        let coarse = self.coarse(halvings, |small, small_target| {
            let small_groups: Vec<MaskGroup> = groups.iter().map(|g| g.halved(halvings)).collect();
            optimise_structure(small, &small_groups, small_target, &run, stage)
        });
        let losses = match coarse {
            Ok(Some(losses)) => Ok(losses),
            Ok(None) => optimise_structure(&mut self.scene, &groups, &self.target, &run, stage),
            Err(error) => Err(error),
        };
        drop(groups);
        let losses = losses?;
        let after = preview_two_layers(&mut self.canvas(), &self.scene, &self.target, stage);
        self.record(stage, losses[0], after);
        Ok(())
    }

    fn reconstruct(&mut self, stage: &StageRun) -> Result<(), Error> {
        let total = self.params.iterations.reconstruction;
        let coarse_count =
            ((total as f32 * self.settings.coarse.reconstruction_share).round() as u32).min(total);
        let split = SplitPlan::new(self.params.paths as usize, self.scene.path_count());
        let (settings, mode) = (&self.settings.structure, self.mode);
        let halvings = self.halvings();
        self.coarse_then_fine(total, &[(coarse_count, halvings)], |scene, target, part| {
            let run = ReconstructionRun {
                span: part.span,
                settings,
                keep: part.keep,
                mode,
                split,
            };
            optimise_reconstruction(scene, target, &run, stage)
        })?;
        let after = if total > 0 {
            preview_two_layers(&mut self.canvas(), &self.scene, &self.target, stage)
        } else {
            let mut scratch = Scratch::default();
            reconstruction_loss(
                &mut self.canvas(),
                &self.scene,
                &self.target,
                &mut scratch,
                None,
            )
        };
        self.record(stage, self.loss, after);
        Ok(())
    }

    fn refine(&mut self, stage: &StageRun) -> Result<(), Error> {
        let it = &self.params.iterations;
        let growth = match self.mode {
            ResolvedMode::Simple => Growth {
                layer: LayerKind::Albedo,
                color_max: 1.0,
                outline: false,
            },
            ResolvedMode::Photo => Growth {
                layer: LayerKind::Shade,
                color_max: self.settings.structure.illumination_cap,
                outline: true,
            },
        };
        let coarse_rounds = it
            .refine_rounds
            .saturating_sub(self.settings.coarse.fine_rounds);
        // Early stopping in the coarse rounds only (see `super::coarse`).
        let fine_settings = RefineSettings {
            plateau: PlateauSettings::never(),
            ..self.settings.refine.clone()
        };
        let (budget, seed) = (self.params.paths as usize, self.params.seed);
        let coarse_settings = &self.settings.refine;
        let coarse = (coarse_rounds, self.halvings());
        let fine = self.coarse_then_fine(it.refine_rounds, &[coarse], |scene, target, part| {
            let plan = RefinePlan {
                growth,
                keep: part.keep,
                budget,
                rounds: part.span,
                iterations: it.refine,
                settings: if part.coarse {
                    coarse_settings
                } else {
                    &fine_settings
                },
                seed,
            };
            refine(scene, target, &plan, stage)
        });
        let [_, after] = fine?;
        self.record(stage, self.loss, after);
        Ok(())
    }

    fn split(&mut self, stage: &StageRun) -> Result<(), Error> {
        stage.iteration(0, 1, None)?;
        let split = split_layers(&mut self.scene, &self.target, Some(stage));
        stage.iteration(1, 1, Some(split.mse_after))?;
        self.report.split = Some(split);
        Ok(())
    }

    fn polish(&mut self, stage: &StageRun) -> Result<(), Error> {
        let total = self.params.iterations.polish;
        let coarse = &self.settings.coarse;
        let coarse_count =
            self.coarse_count(coarse.polish_coarse(total, self.target.width, self.target.height));
        let polish_parts = coarse.polish_parts(coarse_count, self.halvings());
        let (settings, structure) = (&self.settings.polish, &self.settings.structure);
        let mode = self.mode;
        let weights =
            settings.similarity_weights(self.target.width * self.target.height, self.params.paths);
        let full_loss = PolishLoss::new(&self.target, weights);
        let floor = LightnessFloor::new(&self.scene, settings, mode);
        // The stage's loss before: the SVG model at full size, before any coarse iteration
        // (without one, the fine polish's first loss is that number).
        let before = (coarse_count > 0).then(|| {
            polish::into_range(&mut self.scene);
            polish::model_loss(&mut self.canvas(), &self.scene, &self.target, &full_loss)
        });
        let fine = self.coarse_then_fine(total, &polish_parts, |scene, target, part| {
            let coarse_loss;
            let loss = if part.coarse {
                coarse_loss = PolishLoss::new(target, weights);
                &coarse_loss
            } else {
                &full_loss
            };
            let keep = part.keep.map(|r| (r, structure));
            polish::polish(
                scene,
                (target, loss),
                part.span,
                (settings, mode, floor.as_ref()),
                keep,
                stage,
            )
        });
        let [initial, after] = fine?;
        self.record(stage, before.unwrap_or(initial), after);
        Ok(())
    }
}

/// One part of a stage split coarse to fine.
struct Part<'k> {
    span: IterationSpan,
    /// The kept terms at the part's size.
    keep: Option<&'k KeepRun<'k>>,
    /// Whether the part runs on the coarse copy.
    coarse: bool,
}

/// The kept terms on the copy halved `halvings` times (0: at full size).
fn keep_run(keep: &Option<Vec<Keep>>, halvings: u32, seed: u64) -> Option<KeepRun<'_>> {
    keep.as_ref()?
        .get(halvings as usize)
        .map(|keep| KeepRun { keep, seed })
}
