//! The perceptual ranking of albedo candidates: which masks get the albedo paths of the budget.
//!
//! The segmentation scores a mask by the squared RGB error a flat colour inside it removes.
//! Squared RGB sees little between skin and a grey wall of the same lightness, so at 64 paths
//! a small face on a large wall got no albedo path and stayed grey, which shade cannot undo.
//! Here candidates are ranked greedily by the perceptual error each would remove: the sum over
//! its pixels of the CIELAB distance (ΔE*ab) from the pixel's albedo to what covers it so far,
//! less the distance to the mask's own mean colour. "What covers it so far" is the masks
//! already taken (smaller ones above larger ones, as `organize` paints them) over the base
//! path, whose fill is the mean of what none of them covers.
//!
//! Why these choices, on `covec eval --faces` at 64 paths:
//! - A sum of distances, not area × the squared distance of the means (tried first): squared
//!   distances let every small high-contrast speck outrank a face of moderate contrast, and
//!   means call a ring with its holes filled (a painted circle round an eye) as useful as the
//!   ring, though filling its inside paints the skin there.
//! - ΔE*ab with lightness at half weight ([`LIGHTNESS_WEIGHT`]), not CIEDE2000: the greedy
//!   scores every candidate at every step, and CIEDE2000 costs about twenty times as much per
//!   pixel.
//! - On a grid of at most [`SAMPLES`] pixels, for the same reason: a sum over a mask's pixels
//!   is a statistic of its area, which a regular grid keeps.

use rayon::prelude::*;

use crate::decompose::segment::Candidate;
use crate::perceptual::lab;
use crate::render::Image;

/// Weight of CIELAB lightness in the distance, against 1 for the two chroma axes: as in
/// CMC l:c = 2:1 (colour acceptability), lightness differences count half. Tried with the
/// albedo map's surfaces as extra candidates (not kept: they put cast shadows in the albedo),
/// weight 0.5 against 1 and 2 gave a mean skin colour error of 1.57 against 1.71 and 2.06 ΔE00.
const LIGHTNESS_WEIGHT: f32 = 0.5;

/// Most pixels the scores are summed over (a regular grid of the canvas).
const SAMPLES: usize = 128 * 128;

/// `candidates` (masks of `albedo`'s canvas) reordered by the perceptual error each removes,
/// greedily (see the module's documentation), for the first `steps` places; the rest follow
/// in their given order. Equal scores keep their order.
///
/// `steps` is how many masks the caller means to take: each greedy step scores every
/// remaining candidate, so ranking all of them would cost as much again as the whole
/// decomposition for places nobody takes.
pub(crate) fn perceptual_order(
    candidates: Vec<Candidate>,
    albedo: &Image,
    steps: usize,
) -> Vec<Candidate> {
    if candidates.len() < 2 || albedo.width * albedo.height == 0 {
        return candidates;
    }
    let mut order = by_eye(&candidates, albedo, steps);
    order.extend(0..candidates.len());
    let mut slots: Vec<Option<Candidate>> = candidates.into_iter().map(Some).collect();
    order.into_iter().filter_map(|k| slots[k].take()).collect()
}

/// The indices of the first `steps` of `candidates` in the greedy perceptual order (see the
/// module's documentation); equal scores keep their order.
fn by_eye(candidates: &[Candidate], albedo: &Image, steps: usize) -> Vec<usize> {
    let (w, h) = (albedo.width, albedo.height);
    let stride = grid_stride(w * h);
    let grid: Vec<usize> = (stride / 2..h)
        .step_by(stride)
        .flat_map(|y| (stride / 2..w).step_by(stride).map(move |x| y * w + x))
        .collect();
    // Per grid point and per candidate on rayon's pool: on one thread this ranking took half
    // of a 256² photo's init stage.
    let colours: Vec<[f32; 3]> = grid
        .par_iter()
        .map(|&i| lab([0, 1, 2].map(|c| albedo.data[3 * i + c])).map(|v| v as f32))
        .map(|c| [c[0] * LIGHTNESS_WEIGHT, c[1], c[2]])
        .collect();
    // Per candidate: its grid points (indices into `grid`) and its own mean colour.
    let points: Vec<Vec<u32>> = candidates
        .par_iter()
        .map(|c| {
            (0..grid.len() as u32)
                .filter(|&g| c.mask.contains_index(grid[g as usize]))
                .collect()
        })
        .collect();
    let own: Vec<[f32; 3]> = points
        .par_iter()
        .map(|p| mean(p.iter().map(|&g| colours[g as usize])))
        .collect();
    let own_error: Vec<f32> = points
        .par_iter()
        .zip(&own)
        .map(|(p, o)| p.iter().map(|&g| distance(colours[g as usize], *o)).sum())
        .collect();
    let areas: Vec<usize> = candidates.iter().map(|c| c.mask.area()).collect();

    // What covers each grid point so far: a taken mask (its colour and area) or the base path.
    let mut painted = vec![[0f32; 3]; grid.len()];
    let mut painted_by = vec![BASE; grid.len()];
    let mut taken = vec![false; candidates.len()];
    let mut order = Vec::with_capacity(candidates.len());
    for _ in 0..steps.min(candidates.len()) {
        let base = mean(
            (0..grid.len())
                .filter(|&g| painted_by[g] == BASE)
                .map(|g| colours[g]),
        );
        let scores: Vec<(usize, f32)> = (0..candidates.len())
            .into_par_iter()
            .filter(|&k| !taken[k])
            .map(|k| {
                // Smaller masks sit above larger ones, so k would repaint only what larger
                // ones hold.
                let covered: f32 = points[k]
                    .iter()
                    .map(|&g| g as usize)
                    .filter(|&g| painted_by[g] > areas[k])
                    .map(|g| {
                        let cover = if painted_by[g] == BASE {
                            base
                        } else {
                            painted[g]
                        };
                        distance(colours[g], cover)
                    })
                    .sum();
                (k, covered - own_error[k])
            })
            .collect();
        let mut best: Option<(usize, f32)> = None;
        for (k, score) in scores {
            if best.is_none_or(|(_, b)| score > b) {
                best = Some((k, score));
            }
        }
        let Some((k, _)) = best else { break };
        taken[k] = true;
        order.push(k);
        for &g in &points[k] {
            let g = g as usize;
            if painted_by[g] > areas[k] {
                painted[g] = own[k];
                painted_by[g] = areas[k];
            }
        }
    }
    order
}

/// The step of the scoring grid: every pixel up to [`SAMPLES`], then every 2nd, 3rd, ... in
/// each direction.
fn grid_stride(pixels: usize) -> usize {
    (1..).find(|s| pixels / (s * s) <= SAMPLES).unwrap_or(1)
}

/// The "painted by" of a point only the base path covers: larger than any mask.
const BASE: usize = usize::MAX;

/// The Euclidean distance of two colours in CIELAB, lightness already weighted.
fn distance(a: [f32; 3], b: [f32; 3]) -> f32 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn mean(colours: impl Iterator<Item = [f32; 3]>) -> [f32; 3] {
    let (mut sum, mut n) = ([0f64; 3], 0usize);
    for c in colours {
        (0..3).for_each(|k| sum[k] += f64::from(c[k]));
        n += 1;
    }
    sum.map(|s| (s / n.max(1) as f64) as f32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::decompose::mask::Mask;

    /// A grey wall with a white suit below and a small skin-coloured face: in squared RGB the
    /// darker-grey patch of the wall outranks the face; perceptually the face comes first.
    #[test]
    fn a_small_face_on_a_grey_wall_outranks_a_grey_patch() {
        let (w, h) = (48usize, 48usize);
        let wall = [0.62, 0.6, 0.6];
        let skin = [0.78, 0.58, 0.5];
        let patch = [0.56, 0.54, 0.54];
        let face = Mask::from_fn(w, h, |x, y| (18..26).contains(&x) && (8..18).contains(&y));
        let grey = Mask::from_fn(w, h, |x, y| x >= 32 && y < 24);
        let suit = Mask::from_fn(w, h, |_, y| y >= 30);
        let colour = |i: usize| {
            let (x, y) = (i % w, i / w);
            if suit.contains(x, y) {
                [0.95; 3]
            } else if face.contains(x, y) {
                skin
            } else if grey.contains(x, y) {
                patch
            } else {
                wall
            }
        };
        let albedo = Image {
            width: w,
            height: h,
            data: (0..w * h).flat_map(colour).collect(),
        };
        let rgb_gain = |m: &Mask, c: [f32; 3]| {
            let d2: f32 = (0..3).map(|k| (c[k] - wall[k]).powi(2)).sum();
            m.area() as f32 * d2
        };
        assert!(
            rgb_gain(&grey, patch) > rgb_gain(&face, skin),
            "the setting: squared RGB prefers the patch"
        );
        let candidates = vec![
            Candidate {
                mask: suit.clone(),
                gain: 3.0,
            },
            Candidate {
                mask: grey.clone(),
                gain: 2.0,
            },
            Candidate {
                mask: face.clone(),
                gain: 1.0,
            },
        ];
        let order = perceptual_order(candidates, &albedo, 3);
        let areas: Vec<usize> = order.iter().map(|c| c.mask.area()).collect();
        assert_eq!(
            areas,
            [suit.area(), face.area(), grey.area()],
            "suit, face, patch"
        );
    }

    #[test]
    fn a_mask_already_painted_in_its_colour_drops_down() {
        let (w, h) = (32usize, 32usize);
        let red = Mask::from_fn(w, h, |x, _| x < 16);
        let inner = Mask::from_fn(w, h, |x, y| x < 12 && y < 12);
        let dot = Mask::from_fn(w, h, |x, y| (24..28).contains(&x) && (24..28).contains(&y));
        let albedo = Image {
            width: w,
            height: h,
            data: (0..w * h)
                .flat_map(|i| {
                    let (x, y) = (i % w, i / w);
                    if red.contains(x, y) {
                        [0.8, 0.1, 0.1]
                    } else if dot.contains(x, y) {
                        [0.1, 0.1, 0.8]
                    } else {
                        [0.9; 3]
                    }
                })
                .collect(),
        };
        let candidates: Vec<Candidate> = [&inner, &red, &dot]
            .into_iter()
            .map(|m| Candidate {
                mask: m.clone(),
                gain: 1.0,
            })
            .collect();
        // The inner square is red like the half around it: once that is taken it adds nothing.
        assert_eq!(
            by_eye(&candidates, &albedo, 3),
            [1, 2, 0],
            "red, dot, inner"
        );
        // Past the steps asked for, the given order.
        let areas: Vec<usize> = perceptual_order(candidates, &albedo, 1)
            .iter()
            .map(|c| c.mask.area())
            .collect();
        assert_eq!(areas, [red.area(), inner.area(), dot.area()]);
    }
}
