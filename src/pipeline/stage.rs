//! What every stage shares: the stage lists ([`PHOTO_STAGES`], [`SIMPLE_STAGES`]), which drive
//! running, progress counting and preview names; progress, previews and cancellation
//! (`RunContext`, `StageRun`); and rendering helpers over the rasteriser (`Canvas`).

use std::cell::Cell;
use std::ops::Range;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use super::params::{Error, Iterations, Mode, Observer, Progress, ResolvedMode};
use crate::render::{Backdrop, Image, PathGrad, Rasterizer, STRIP_ROWS};
use crate::scene::{LayerKind, Path, Scene};

/// What a stage does; [`super::run`] dispatches on it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StageKind {
    /// Working-size target, albedo map and candidate masks; `auto` resolved.
    Decompose,
    /// Masks to organised groups of closed paths with flat fills.
    Init,
    /// Structure loss on the albedo and illumination layers.
    Structure,
    /// Reconstruction loss ‖I − R(A)·R(I)‖² on both layers.
    Reconstruct,
    /// New paths where the error is high, in rounds.
    Refine,
    /// Illumination into shade and light (paper Appendix C).
    Split,
    /// All layers under the SVG model.
    Polish,
}

/// One stage of a run.
#[derive(Clone, Copy, Debug)]
pub struct StageSpec {
    /// What it does.
    pub kind: StageKind,
    /// Its name in progress reports and preview names.
    pub name: &'static str,
    /// The layers it changes.
    pub layers: &'static [LayerKind],
    /// Its iteration count under the given settings (0: a single step).
    pub iterations: fn(&Iterations) -> u64,
    /// Whether a draft follows it (see [`super::Observer::draft`]): after every stage that
    /// changes the picture, but the last, whose scene is the output itself. Not after the
    /// split: the refinement's draft split a copy the same way.
    pub draft: bool,
}

const NONE: fn(&Iterations) -> u64 = |_| 0;
const ALL_LAYERS: &[LayerKind] = &LayerKind::ALL;
const TWO_LAYERS: &[LayerKind] = &[LayerKind::Albedo, LayerKind::Shade];
const ALBEDO: &[LayerKind] = &[LayerKind::Albedo];
const ILLUMINATION: &[LayerKind] = &[LayerKind::Shade];

const DECOMPOSE: StageSpec = StageSpec {
    kind: StageKind::Decompose,
    name: "decompose",
    layers: &[],
    iterations: NONE,
    draft: false,
};
const STRUCTURE: StageSpec = StageSpec {
    kind: StageKind::Structure,
    name: "structure",
    layers: TWO_LAYERS,
    iterations: |it| u64::from(it.structure),
    draft: true,
};
const RECONSTRUCT: StageSpec = StageSpec {
    kind: StageKind::Reconstruct,
    name: "reconstruct",
    layers: TWO_LAYERS,
    iterations: |it| u64::from(it.reconstruction),
    draft: true,
};
const POLISH: StageSpec = StageSpec {
    kind: StageKind::Polish,
    name: "polish",
    layers: ALL_LAYERS,
    iterations: |it| u64::from(it.polish),
    draft: false,
};

/// The photo-mode run (the paper's method). Until the split, the illumination layer lives in
/// `Scene::shade`.
pub const PHOTO_STAGES: &[StageSpec] = &[
    DECOMPOSE,
    StageSpec {
        kind: StageKind::Init,
        name: "init",
        layers: TWO_LAYERS,
        iterations: NONE,
        draft: true,
    },
    STRUCTURE,
    RECONSTRUCT,
    StageSpec {
        kind: StageKind::Refine,
        name: "refine",
        layers: ILLUMINATION,
        iterations: |it| u64::from(it.refine_rounds) * u64::from(it.refine),
        draft: true,
    },
    StageSpec {
        kind: StageKind::Split,
        name: "split",
        layers: &[LayerKind::Shade, LayerKind::Light],
        iterations: NONE,
        draft: false,
    },
    POLISH,
];

/// The simple-mode run (paper Appendix C.2): albedo only.
pub const SIMPLE_STAGES: &[StageSpec] = &[
    DECOMPOSE,
    StageSpec {
        kind: StageKind::Init,
        name: "init",
        layers: ALBEDO,
        iterations: NONE,
        draft: true,
    },
    STRUCTURE,
    RECONSTRUCT,
    StageSpec {
        kind: StageKind::Refine,
        name: "refine",
        layers: ALBEDO,
        iterations: |it| u64::from(it.refine_rounds) * u64::from(it.refine),
        draft: true,
    },
    POLISH,
];

impl Iterations {
    /// Every iteration of a run, summed over the stages.
    pub fn total(&self) -> u64 {
        PHOTO_STAGES
            .iter()
            .map(|spec| (spec.iterations)(self))
            .sum()
    }
}

impl ResolvedMode {
    /// The stages this mode runs, in order.
    pub fn stages(self) -> &'static [StageSpec] {
        match self {
            ResolvedMode::Photo => PHOTO_STAGES,
            ResolvedMode::Simple => SIMPLE_STAGES,
        }
    }
}

/// The stages of a run that was asked for `mode`, as far as known before the decompose stage
/// resolves `auto` (counted as photo until then; the stages before the resolution are the same
/// in both lists).
pub(crate) fn provisional_stages(mode: Mode) -> &'static [StageSpec] {
    match mode {
        Mode::Simple => SIMPLE_STAGES,
        Mode::Auto | Mode::Photo => PHOTO_STAGES,
    }
}

/// Progress, previews and cancellation for one run.
pub(crate) struct RunContext<'a> {
    observer: &'a dyn Observer,
    cancel: &'a AtomicBool,
    /// When the run started; progress reports time elapsed since.
    started: Instant,
    /// The run's stages; replaced once when `auto` is resolved.
    stages: Cell<&'static [StageSpec]>,
}

impl<'a> RunContext<'a> {
    pub fn new(
        observer: &'a dyn Observer,
        cancel: &'a AtomicBool,
        stages: &'static [StageSpec],
    ) -> Self {
        Self {
            observer,
            cancel,
            started: Instant::now(),
            stages: Cell::new(stages),
        }
    }

    /// The stages as known so far.
    pub fn stages(&self) -> &'static [StageSpec] {
        self.stages.get()
    }

    /// Replaces the stage list once the mode is known; stages done keep their indices.
    pub fn set_stages(&self, stages: &'static [StageSpec]) {
        self.stages.set(stages);
    }

    /// Stage `index` of the list, unless the run was canceled.
    pub fn stage(&self, index: usize) -> Result<StageRun<'_>, Error> {
        self.check_cancel()?;
        let spec = self.stages().get(index).ok_or_else(|| {
            Error::Internal(format!("stage {index} is past the end of the stage list"))
        })?;
        Ok(StageRun {
            run: self,
            spec,
            index: index as u32,
        })
    }

    fn check_cancel(&self) -> Result<(), Error> {
        if self.cancel.load(Ordering::Relaxed) {
            Err(Error::Canceled)
        } else {
            Ok(())
        }
    }
}

/// One running stage: what it reports goes out under its name and index.
#[derive(Clone, Copy)]
pub(crate) struct StageRun<'a> {
    run: &'a RunContext<'a>,
    spec: &'static StageSpec,
    index: u32,
}

impl StageRun<'_> {
    /// The stage's name.
    pub fn name(&self) -> &'static str {
        self.spec.name
    }

    /// Reports `iteration` of `iterations` and returns `Err(Canceled)` if the run was canceled.
    pub fn iteration(
        &self,
        iteration: u32,
        iterations: u32,
        loss: Option<f32>,
    ) -> Result<(), Error> {
        self.run.observer.progress(&Progress {
            stage: self.spec.name,
            stage_index: self.index,
            stage_count: self.run.stages().len() as u32,
            iteration,
            iterations,
            loss,
            elapsed: self.run.started.elapsed(),
        });
        self.run.check_cancel()
    }

    /// Hands a stage-end preview named `NN-stage-what` to the observer.
    pub fn preview(&self, what: &str, image: &Image) {
        self.preview_as(&format!("{}-{what}", self.spec.name), image);
    }

    /// Whether the observer keeps previews (see [`Observer::wants_previews`]).
    pub fn wants_previews(&self) -> bool {
        self.run.observer.wants_previews()
    }

    /// Hands the observer a draft of the run after this stage, if one follows it
    /// ([`StageSpec::draft`]), made by `make` only if the observer takes drafts (see
    /// [`Observer::draft`]).
    pub fn draft(&self, make: impl FnOnce() -> Scene) {
        if self.spec.draft && self.run.observer.wants_drafts() {
            self.run.observer.draft(self.spec.name, &make());
        }
    }

    /// Hands a preview named `NN-what` to the observer (inputs, masks).
    pub fn preview_as(&self, what: &str, image: &Image) {
        self.run
            .observer
            .preview(&format!("{:02}-{what}", self.index), image);
    }
}

/// Iterations (or rounds) `start..start + count` of a loop of `total`: a stage split into a
/// coarse and a fine part reports progress against the whole.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct IterationSpan {
    pub start: u32,
    pub count: u32,
    pub total: u32,
}

impl IterationSpan {
    /// Whether the span ends before the loop does (a coarse part).
    pub fn ends_early(&self) -> bool {
        self.start + self.count < self.total
    }
}

/// Keeps the albedo layer's first path, the opaque full-canvas base, in place and opaque:
/// browsers must see an opaque backdrop under the blend groups. Its colour stays trainable.
pub(crate) fn hold_albedo_base(grads: &mut [PathGrad]) {
    if let Some(base) = grads.first_mut() {
        base.points.iter_mut().for_each(|p| *p = Default::default());
        base.opacity = 0.0;
    }
}

/// What the reconstruction stage may change in the albedo layer: the base's geometry and
/// opacity never ([`hold_albedo_base`]); in photo mode no path's colour or opacity either (a
/// documented departure, docs/design.md). Left free there, `A·S` lets an albedo path darken or fade
/// to explain a shadow or a shading gradient before the illumination paths have taken their
/// shape, and that lighting stays in the albedo. Geometry still trains so edges follow the
/// image; the polish stage, with all three layers in place, frees the fills again (on the
/// generated scenes that halves the albedo error of three of them, and on the bench photos
/// it recovers most of the reconstruction).
pub(crate) fn hold_albedo(grads: &mut [PathGrad], mode: ResolvedMode) {
    hold_albedo_base(grads);
    if mode == ResolvedMode::Photo {
        for g in grads {
            (g.color, g.opacity) = ([0.0; 3], 0.0);
        }
    }
}

/// The rasteriser at one working size, with helpers for the compositing the stages need.
pub(crate) struct Canvas {
    pub raster: Rasterizer,
    pub width: usize,
    pub height: usize,
    scratch: Image,
    marks: Vec<bool>,
}

impl Canvas {
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            raster: Rasterizer::new(),
            width,
            height,
            scratch: Image::default(),
            marks: Vec::new(),
        }
    }

    /// Marks in `marks` the strips `paths` can paint (see [`Rasterizer::mark_strips`]).
    pub fn mark_strips(&mut self, paths: &[Path], marks: &mut Vec<bool>) {
        self.raster
            .mark_strips(paths, self.width, self.height, marks);
    }

    /// [`Canvas::render_over`] of the strips `strips` marks only, the rest of `out` (already
    /// the canvas's size) left as it is (see [`Rasterizer::render_over_strips`]).
    pub fn render_over_strips(
        &mut self,
        paths: &[Path],
        backdrop: &Image,
        strips: &[bool],
        out: &mut Image,
    ) {
        self.raster
            .render_over_strips(paths, Backdrop::Image(backdrop), strips, out);
    }

    /// Renders `paths` over a flat `base`.
    pub fn render(&mut self, paths: &[Path], base: [f32; 3], out: &mut Image) {
        self.raster
            .render(paths, base, self.width, self.height, out);
    }

    /// Renders one layer of `scene` over its base colour.
    pub fn render_layer(&mut self, scene: &Scene, kind: LayerKind, out: &mut Image) {
        self.render(&scene.layer(kind).paths, kind.base(), out);
    }

    /// Renders `paths` painted over a `backdrop` image: lets a stage paint only the paths it
    /// trains on top of a cached render of the frozen ones.
    pub fn render_over(&mut self, paths: &[Path], backdrop: &Image, out: &mut Image) {
        self.raster.render_over(
            paths,
            Backdrop::Image(backdrop),
            self.width,
            self.height,
            out,
        );
    }

    /// Backward of [`Canvas::render_over`]: adds dLoss/dparams of `paths` into `grads`.
    pub fn backward_over(
        &mut self,
        paths: &[Path],
        backdrop: &Image,
        d_out: &Image,
        grads: &mut [PathGrad],
    ) {
        self.raster
            .backward_over(paths, Backdrop::Image(backdrop), d_out, grads);
    }

    /// Coverage in (0, 1] of `path` alone (its opacity ignored) at the pixels it touches, as
    /// `(y * width + x, coverage)` in pixel order: sparse, so many paths' coverages fit in memory.
    pub fn coverage(&mut self, path: &Path) -> Vec<(u32, f32)> {
        let silhouette = [Path {
            points: path.points.clone(),
            color: [1.0; 3],
            opacity: 1.0,
        }];
        // Only the strips the path meets: elsewhere a whole render is all zero.
        self.marks.clear();
        self.raster
            .mark_strips(&silhouette, self.width, self.height, &mut self.marks);
        self.scratch.resize(self.width, self.height);
        self.raster.render_over_strips(
            &silhouette,
            Backdrop::Color([0.0; 3]),
            &self.marks,
            &mut self.scratch,
        );
        let data = &self.scratch.data;
        strip_ranges(&self.marks, self.width, self.height)
            .flat_map(|values| values.start / 3..values.end / 3)
            .filter(|&i| data[3 * i] > 0.0)
            .map(|i| (i as u32, data[3 * i].min(1.0)))
            .collect()
    }
}

/// The ranges of an image's `data` (3 values a pixel, `width × height`) that the marked strips
/// ([`STRIP_ROWS`] rows each) hold, in order, neighbouring strips joined.
pub(crate) fn strip_ranges(
    marks: &[bool],
    width: usize,
    height: usize,
) -> impl Iterator<Item = Range<usize>> + '_ {
    let strip = 3 * STRIP_ROWS * width;
    let end = 3 * width * height;
    marks
        .chunk_by(|a, b| a == b)
        .scan(0, move |start, run| {
            let range = *start..(*start + run.len() * strip).min(end);
            *start += run.len() * strip;
            Some((run[0], range))
        })
        .filter(|(marked, _)| *marked)
        .map(|(_, range)| range)
}
