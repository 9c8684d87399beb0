//! What every optimisation stage shares: progress and cancellation ([`StageContext`]) and
//! rendering helpers over the rasteriser ([`Canvas`]).

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use super::{Error, Observer, Progress};
use crate::optim::loss::resize_like;
use crate::render::{Image, PathGrad, Rasterizer};
use crate::scene::{LayerKind, Path, Scene};

/// Progress, previews and cancellation for the stages of one run.
pub struct StageContext<'a> {
    pub observer: &'a dyn Observer,
    pub cancel: &'a AtomicBool,
    /// When the run started; progress reports time elapsed since.
    pub started: Instant,
    /// Number of stages in the whole run, for `Progress::stage_count`.
    pub stage_count: u32,
}

/// One stage's name and 0-based index within the run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Stage {
    pub name: &'static str,
    pub index: u32,
}

/// Iterations (or rounds) `start..start + count` of a loop of `total`: a stage split into a
/// coarse and a fine part reports progress against the whole.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IterationSpan {
    pub start: u32,
    pub count: u32,
    pub total: u32,
}

impl IterationSpan {
    /// All `total` iterations.
    pub fn all(total: u32) -> Self {
        Self {
            start: 0,
            count: total,
            total,
        }
    }
}

impl StageContext<'_> {
    /// Reports one iteration and returns `Err(Canceled)` if the run was canceled.
    pub fn iteration(
        &self,
        stage: Stage,
        iteration: u32,
        iterations: u32,
        loss: Option<f32>,
    ) -> Result<(), Error> {
        self.observer.progress(&Progress {
            stage: stage.name,
            stage_index: stage.index,
            stage_count: self.stage_count,
            iteration,
            iterations,
            loss,
            elapsed: self.started.elapsed(),
        });
        self.check_cancel()
    }

    pub fn check_cancel(&self) -> Result<(), Error> {
        if self.cancel.load(Ordering::Relaxed) {
            Err(Error::Canceled)
        } else {
            Ok(())
        }
    }

    /// Hands a stage-end preview named `NN-stage-what` to the observer.
    pub fn preview(&self, stage: Stage, what: &str, image: &Image) {
        self.observer.preview(
            &format!("{:02}-{}-{}", stage.index, stage.name, what),
            image,
        );
    }
}

/// The rasteriser at one working size, with helpers for the compositing the stages need.
pub struct Canvas {
    pub raster: Rasterizer,
    pub width: usize,
    pub height: usize,
    scratch_black: Image,
    scratch_white: Image,
    scratch_grad: Image,
}

impl Canvas {
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            raster: Rasterizer::new(),
            width,
            height,
            scratch_black: Image::default(),
            scratch_white: Image::default(),
            scratch_grad: Image::default(),
        }
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

    /// Renders `paths` painted over an arbitrary `backdrop` image. "Over" is affine in the
    /// backdrop (`out = C + T·backdrop` per value), so two renders over black and white give it
    /// exactly; this lets a stage paint only the paths it trains on top of a cached render of the
    /// frozen ones.
    pub fn render_over(&mut self, paths: &[Path], backdrop: &Image, out: &mut Image) {
        self.raster.render(
            paths,
            [0.0; 3],
            self.width,
            self.height,
            &mut self.scratch_black,
        );
        self.raster.render(
            paths,
            [1.0; 3],
            self.width,
            self.height,
            &mut self.scratch_white,
        );
        resize_like(out, backdrop);
        for i in 0..out.data.len() {
            let black = self.scratch_black.data[i];
            out.data[i] = black + (self.scratch_white.data[i] - black) * backdrop.data[i];
        }
    }

    /// Backward of [`Canvas::render_over`]: adds dLoss/dparams of `paths` into `grads`.
    pub fn backward_over(
        &mut self,
        paths: &[Path],
        backdrop: &Image,
        d_out: &Image,
        grads: &mut [PathGrad],
    ) {
        resize_like(&mut self.scratch_grad, d_out);
        for i in 0..d_out.data.len() {
            self.scratch_grad.data[i] = d_out.data[i] * (1.0 - backdrop.data[i]);
        }
        self.raster
            .backward(paths, [0.0; 3], &self.scratch_grad, grads);
        for i in 0..d_out.data.len() {
            self.scratch_grad.data[i] = d_out.data[i] * backdrop.data[i];
        }
        self.raster
            .backward(paths, [1.0; 3], &self.scratch_grad, grads);
    }

    /// Coverage in (0, 1] of `path` alone (its opacity ignored) at the pixels it touches, as
    /// `(y * width + x, coverage)` in pixel order: sparse, so many paths' coverages fit in memory.
    pub fn coverage(&mut self, path: &Path) -> Vec<(u32, f32)> {
        let silhouette = Path {
            points: path.points.clone(),
            color: [1.0; 3],
            opacity: 1.0,
        };
        self.raster.render(
            std::slice::from_ref(&silhouette),
            [0.0; 3],
            self.width,
            self.height,
            &mut self.scratch_black,
        );
        self.scratch_black
            .data
            .chunks_exact(3)
            .enumerate()
            .filter(|(_, px)| px[0] > 0.0)
            .map(|(i, px)| (i as u32, px[0].min(1.0)))
            .collect()
    }
}
