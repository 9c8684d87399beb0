//! Image algorithms behind the decompose and init stages: the classical substitutes for the
//! paper's networks, mask preparation, binarisation and organisation. Pure functions of images
//! and masks; the stage that chooses between the client's inputs and these lives in
//! `pipeline::decompose`.
//!
//! | paper (Sec. 4.2) | given by the client | classical substitute here |
//! |---|---|---|
//! | albedo map, Careaga & Aksoy 2024 | the client's albedo map | [`intrinsic`]: illuminant-corrected superpixels grouped into surfaces by chromaticity, highlights joined by the dichromatic model, one lit colour per surface ([`albedo`], the grey Retinex estimate it replaced, stays as a baseline for `covec eval --intrinsic`) |
//! | SAM masks of the albedo map | the client's masks or label map | [`segment`]: Felzenszwalb superpixels merged by Ward's criterion, all scales |
//! | region-wise binarisation | — | [`binarize`] (as in the paper) |
//! | LayerVec mask organisation | — | [`organize`] (as in LayerVec) |

pub mod albedo;
pub mod binarize;
pub mod intrinsic;
pub mod look;
pub mod mask;
pub mod organize;
pub mod segment;

use std::collections::HashMap;
use std::hash::Hash;

use image::{DynamicImage, GrayImage};

use crate::render::Image;
use mask::Mask;
use segment::Candidate;

/// Masks smaller than this many pixels are dropped: 1/2000 of the canvas, at least 8 pixels
/// (LayerVec's SAM setting drops regions under 100 px at 512², about 1/2600).
pub fn min_mask_area(width: usize, height: usize) -> usize {
    (width * height / 2000).max(8)
}

/// Scores client masks by the squared error a flat colour inside them removes (a Ward split
/// against the rest of the canvas), most useful first.
pub fn score_masks(masks: Vec<Mask>, albedo: &Image) -> Vec<Candidate> {
    let n = (albedo.width * albedo.height) as f64;
    let total = channel_sums(albedo, 0..albedo.width * albedo.height);
    let mut out: Vec<Candidate> = masks
        .into_iter()
        .map(|mask| {
            let inside = channel_sums(albedo, mask.indices());
            let (n_in, n_out) = (mask.area() as f64, (n - mask.area() as f64).max(1.0));
            let d2: f64 = (0..3)
                .map(|c| (inside[c] / n_in - (total[c] - inside[c]) / n_out).powi(2))
                .sum();
            Candidate {
                mask,
                gain: (n_in * n_out / n * d2) as f32,
            }
        })
        .collect();
    out.sort_by(|a, b| b.gain.total_cmp(&a.gain));
    out
}

/// Per-channel sums of `image` over the pixel indices `pixels`.
pub fn channel_sums(image: &Image, pixels: impl Iterator<Item = usize>) -> [f64; 3] {
    let mut sum = [0f64; 3];
    for i in pixels {
        for (s, &v) in sum.iter_mut().zip(&image.data[3 * i..3 * i + 3]) {
            *s += f64::from(v);
        }
    }
    sum
}

/// Nearest-neighbour sample of a binary mask at working size (pixel centres).
pub fn sample_mask(mask: &GrayImage, w: usize, h: usize) -> Mask {
    let (mw, mh) = (mask.width() as usize, mask.height() as usize);
    Mask::from_fn(w, h, |x, y| {
        let (sx, sy) = (
            ((x * 2 + 1) * mw / (2 * w)).min(mw - 1),
            ((y * 2 + 1) * mh / (2 * h)).min(mh - 1),
        );
        mask.get_pixel(sx as u32, sy as u32).0[0] > 0
    })
}

/// One mask per distinct value of a label map, in order of first appearance.
pub fn label_masks(labels: &DynamicImage, w: usize, h: usize) -> Vec<Mask> {
    let rgba = labels.to_rgba16();
    let (mw, mh) = (rgba.width() as usize, rgba.height() as usize);
    let values = (0..h).flat_map(|y| (0..w).map(move |x| (x, y))).map(|(x, y)| {
        let (sx, sy) = (
            ((x * 2 + 1) * mw / (2 * w)).min(mw - 1),
            ((y * 2 + 1) * mh / (2 * h)).min(mh - 1),
        );
        rgba.get_pixel(sx as u32, sy as u32).0
    });
    masks_of_values(w, h, values)
}

/// One mask per distinct colour of a map that is flat per surface ([`intrinsic::albedo_map`]):
/// its surfaces, in order of first appearance.
pub fn surface_masks(map: &Image) -> Vec<Mask> {
    let values = map
        .data
        .chunks_exact(3)
        .map(|px| [px[0].to_bits(), px[1].to_bits(), px[2].to_bits()]);
    masks_of_values(map.width, map.height, values)
}

/// One mask per distinct item of `values` (row-major, `w × h` of them), in order of first
/// appearance.
fn masks_of_values<T: Eq + Hash>(w: usize, h: usize, values: impl Iterator<Item = T>) -> Vec<Mask> {
    let mut seen: HashMap<T, usize> = HashMap::new();
    let index: Vec<usize> = values
        .map(|v| {
            let next = seen.len();
            *seen.entry(v).or_insert(next)
        })
        .collect();
    Mask::from_labels(w, h, &index, seen.len())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_flat_map_gives_one_mask_per_surface_colour_in_order_of_first_appearance() {
        // A grey wall with two peach squares apart: two surfaces, the peach in two pieces.
        let (w, h) = (24, 12);
        let peach = |x: usize, y: usize| (2..8).contains(&y) && ((2..8).contains(&x) || (14..20).contains(&x));
        let mut map = Image::filled(w, h, [0.6; 3]);
        for y in 0..h {
            for x in 0..w {
                if peach(x, y) {
                    map.data[3 * (y * w + x)..3 * (y * w + x) + 3].copy_from_slice(&[0.8, 0.6, 0.5]);
                }
            }
        }
        let surfaces = surface_masks(&map);
        assert_eq!(surfaces.len(), 2);
        assert_eq!(surfaces[0].area(), w * h - 72, "the wall, seen first");
        assert_eq!(surfaces[1], Mask::from_fn(w, h, peach));
        assert_eq!(surfaces[1].components(1).len(), 2);
    }
}
