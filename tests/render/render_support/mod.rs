//! Shared helpers for the renderer tests: a seeded RNG and random scenes.
#![allow(dead_code)]

use covec::render::{Image, PathGrad, Rasterizer};
use covec::scene::{Path, Point};

/// SplitMix64 (the generator of shared/notes/diffvg-bench.md).
pub struct SplitMix64(pub u64);

impl SplitMix64 {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1), an exact f32.
    pub fn uniform(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.uniform()
    }
}

/// A smooth star-shaped closed path of `segments` cubics around `(cx, cy)` (not
/// self-intersecting), radius jittered in `[0.7 r, 1.1 r]`.
pub fn blob(rng: &mut SplitMix64, cx: f32, cy: f32, r: f32, segments: usize) -> Vec<Point> {
    let n = segments;
    let anchors: Vec<(f32, f32)> = (0..n)
        .map(|k| {
            let a = (k as f32 + rng.range(-0.2, 0.2)) / n as f32 * std::f32::consts::TAU;
            (a, r * rng.range(0.7, 1.1))
        })
        .collect();
    let handle = 4.0 / 3.0 * (std::f32::consts::PI / (2.0 * n as f32)).tan();
    let mut pts = Vec::with_capacity(3 * n);
    for k in 0..n {
        let (a0, r0) = anchors[k];
        let (a1, r1) = anchors[(k + 1) % n];
        let p0 = (cx + r0 * a0.cos(), cy + r0 * a0.sin());
        let p1 = (cx + r1 * a1.cos(), cy + r1 * a1.sin());
        // Tangents perpendicular to the radius, scaled for a circle-like arc.
        let t0 = (-a0.sin() * r0 * handle, a0.cos() * r0 * handle);
        let t1 = (-a1.sin() * r1 * handle, a1.cos() * r1 * handle);
        pts.push(Point::new(p0.0, p0.1));
        pts.push(Point::new(p0.0 + t0.0, p0.1 + t0.1));
        pts.push(Point::new(p1.0 - t1.0, p1.1 - t1.1));
    }
    pts
}

/// A closed path of `segments` cubics with every point uniform in the box (self-intersecting).
pub fn scribble(
    rng: &mut SplitMix64,
    x0: f32,
    y0: f32,
    x1: f32,
    y1: f32,
    segments: usize,
) -> Vec<Point> {
    (0..3 * segments)
        .map(|_| Point::new(rng.range(x0, x1), rng.range(y0, y1)))
        .collect()
}

/// Random paints: colours in [0, 1], opacity in [0.3, 0.95].
pub fn paint(rng: &mut SplitMix64, points: Vec<Point>) -> Path {
    let color = [rng.uniform(), rng.uniform(), rng.uniform()];
    Path {
        points,
        color,
        opacity: rng.range(0.3, 0.95),
    }
}

/// A mixed scene on a `size`² canvas: `blobs` blobs and `scribbles` self-intersecting paths,
/// some partly off the canvas.
pub fn mixed_scene(rng: &mut SplitMix64, size: f32, blobs: usize, scribbles: usize) -> Vec<Path> {
    let mut paths = Vec::new();
    for _ in 0..blobs {
        let (cx, cy) = (rng.range(-0.1, 1.1) * size, rng.range(-0.1, 1.1) * size);
        let r = rng.range(0.1, 0.4) * size;
        let segs = 4 + (rng.next_u64() % 5) as usize;
        let pts = blob(rng, cx, cy, r, segs);
        paths.push(paint(rng, pts));
    }
    for _ in 0..scribbles {
        let pts = scribble(rng, -0.1 * size, -0.1 * size, 1.1 * size, 1.1 * size, 4);
        paths.push(paint(rng, pts));
    }
    paths
}

pub fn render(raster: &mut Rasterizer, paths: &[Path], base: [f32; 3], size: usize) -> Image {
    let mut out = Image::default();
    raster.render(paths, base, size, size, &mut out);
    out
}

/// `0.5 Σ w (I − T)²` in f64 and its gradient dL/dI.
pub fn weighted_sq_loss(image: &Image, target: &[f32], weights: &[f32]) -> (f64, Image) {
    let mut loss = 0.0f64;
    let mut grad = Image {
        width: image.width,
        height: image.height,
        data: vec![0.0; image.data.len()],
    };
    for i in 0..image.data.len() {
        let d = image.data[i] as f64 - target[i] as f64;
        loss += 0.5 * weights[i] as f64 * d * d;
        grad.data[i] = (weights[i] as f64 * d) as f32;
    }
    (loss, grad)
}

/// `0.5 Σ w (I − T)²` of an f64 render.
pub fn weighted_sq_loss_f64(image: &[f64], target: &[f32], weights: &[f32]) -> f64 {
    let mut loss = 0.0f64;
    for i in 0..image.len() {
        let d = image[i] - target[i] as f64;
        loss += 0.5 * weights[i] as f64 * d * d;
    }
    loss
}

pub fn zero_grads(paths: &[Path]) -> Vec<PathGrad> {
    PathGrad::zeros_like(paths)
}
