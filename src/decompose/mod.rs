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
    let mut values: Vec<[u16; 4]> = Vec::new();
    let mut index = vec![0usize; w * h];
    for y in 0..h {
        for x in 0..w {
            let (sx, sy) = (
                ((x * 2 + 1) * mw / (2 * w)).min(mw - 1),
                ((y * 2 + 1) * mh / (2 * h)).min(mh - 1),
            );
            let v = rgba.get_pixel(sx as u32, sy as u32).0;
            index[y * w + x] = match values.iter().position(|&u| u == v) {
                Some(k) => k,
                None => {
                    values.push(v);
                    values.len() - 1
                }
            };
        }
    }
    Mask::from_labels(w, h, &index, values.len())
}
