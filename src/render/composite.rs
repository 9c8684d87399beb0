//! Per-pixel composites of rendered layers, with their backwards.
//!
//! - [`product`]: `A · I`, the optimisation-time model (albedo times illumination).
//! - [`svg_model`]: `clamp01(A · S + L)`, exactly what a browser shows for the albedo layer, a
//!   `mix-blend-mode: multiply` shade group and a `plus-lighter` light group (all in sRGB values,
//!   no gamma), so the final polish optimises what users see.
//! - [`render_layers`], [`composite`]: a whole scene rendered as shown, for previews and
//!   measurements.
//!
//! The loops run on rayon's pool in chunks of [`CHUNK`] values. Every value is computed alone,
//! so the results do not depend on the thread count.
//!
//! # Panics
//! Every function here panics if its images differ in size (a programming error).

use std::ops::Range;

use rayon::prelude::*;

use super::{Image, Rasterizer};
use crate::scene::{LayerKind, Scene};
use crate::simd::widest;

/// Upper bound for illumination colours during optimisation: the product model lets shading
/// brighten albedo up to 4× (highlights over dark albedo estimates). The optimiser projects
/// illumination colours into `[0, ILLUMINATION_CAP]` after each step; nothing here clamps.
pub const ILLUMINATION_CAP: f32 = 4.0;

/// Values per rayon task. These loops are memory-bound and run once or twice per iteration
/// over the whole canvas on the pipeline's own thread: at 1024² the polish's `svg_model` and
/// its backward alone took a tenth of the CPU time, on one core. 32 Ki values (128 KiB per
/// image) keep a task's overhead, a few µs, small against its traffic, and still split a 256²
/// image six ways.
const CHUNK: usize = 1 << 15;

fn check_same(images: &[&Image]) {
    let (w, h) = (images[0].width, images[0].height);
    for im in images {
        assert!(
            im.width == w && im.height == h && im.data.len() == w * h * 3,
            "composite: image sizes differ ({}×{} vs {w}×{h})",
            im.width,
            im.height
        );
    }
}

/// `out = a · b` per channel (`out` is resized).
pub fn product(a: &Image, b: &Image, out: &mut Image) {
    check_same(&[a, b]);
    out.resize(a.width, a.height);
    product_range(a, b, out, 0..a.data.len());
}

/// [`product`] of the values `range` of `data` only; `out` (already the size of `a`) keeps
/// the rest.
pub fn product_range(a: &Image, b: &Image, out: &mut Image, range: Range<usize>) {
    check_same(&[a, b, out]);
    let (a, b) = (&a.data[range.clone()], &b.data[range.clone()]);
    out.data[range]
        .par_chunks_mut(CHUNK)
        .zip(a.par_chunks(CHUNK).zip(b.par_chunks(CHUNK)))
        .for_each(|(o, (a, b))| {
            widest!(for ((o, &x), &y) in o.iter_mut().zip(a).zip(b) {
                *o = x * y;
            })
        });
}

/// `out = clamp01(a · s + l)` per channel: albedo, shade (multiply) and light (plus-lighter).
pub fn svg_model(a: &Image, s: &Image, l: &Image, out: &mut Image) {
    check_same(&[a, s, l]);
    out.resize(a.width, a.height);
    out.data
        .par_chunks_mut(CHUNK)
        .zip(a.data.par_chunks(CHUNK).zip(s.data.par_chunks(CHUNK)))
        .zip(l.data.par_chunks(CHUNK))
        .for_each(|((o, (a, s)), l)| {
            widest!(
                for ((o, (&a, &s)), &l) in o.iter_mut().zip(a.iter().zip(s)).zip(l) {
                    *o = (a * s + l).clamp(0.0, 1.0);
                }
            )
        });
}

/// Backward of [`svg_model`]: turns `d_out` into `g`, where `g = d_out` if `0 ≤ a·s + l ≤ 1`
/// and 0 where the clamp is active. Then the light's gradient is `g`, the albedo's `g·s` and
/// the shade's `g·a`: [`PixelGrad`](super::PixelGrad)s with a factor, so no full-size image
/// is made for them. The bounds count as inside, so a pixel sitting exactly at white (the
/// common `1 · 1 + 0`) can still be pulled back into range.
pub fn svg_model_backward(a: &Image, s: &Image, l: &Image, d_out: &mut Image) {
    check_same(&[a, s, l, d_out]);
    d_out
        .data
        .par_chunks_mut(CHUNK)
        .zip(a.data.par_chunks(CHUNK).zip(s.data.par_chunks(CHUNK)))
        .zip(l.data.par_chunks(CHUNK))
        .for_each(|((d_out, (a, s)), l)| {
            widest!(
                for ((d_out, (&a, &s)), &l) in d_out.iter_mut().zip(a.iter().zip(s)).zip(l) {
                    if !(0.0..=1.0).contains(&(a * s + l)) {
                        *d_out = 0.0;
                    }
                }
            )
        });
}

/// Each layer of `scene` rendered over its base colour (white, white, black), in
/// [`LayerKind::ALL`] order.
pub fn render_layers(scene: &Scene) -> [Image; 3] {
    let mut rasterizer = Rasterizer::new();
    LayerKind::ALL.map(|kind| {
        let mut image = Image::default();
        let (w, h) = (scene.width as usize, scene.height as usize);
        rasterizer.render(&scene.layer(kind).paths, kind.base(), w, h, &mut image);
        image
    })
}

/// [`svg_model`] of three rendered layers.
pub fn composite_layers([albedo, shade, light]: &[Image; 3]) -> Image {
    let mut out = Image::default();
    svg_model(albedo, shade, light, &mut out);
    out
}

/// The scene as a browser shows it: its three layers rendered and composited.
pub fn composite(scene: &Scene) -> Image {
    composite_layers(&render_layers(scene))
}
