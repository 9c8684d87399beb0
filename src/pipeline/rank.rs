//! The perceptual ranking of albedo candidates: which masks get the albedo paths of the budget.
//!
//! The segmentation scores a mask by the squared RGB error a flat colour inside it removes.
//! Squared RGB sees little between skin and a grey wall of the same lightness, so at 64 paths
//! a small face on a large wall got no albedo path and stayed grey, which shade cannot undo.
//! Here candidates are ranked greedily by what a person sees: each step takes the mask whose
//! own colour is farthest, in CIEDE2000, from the colour that would cover it otherwise (the
//! masks already taken, smaller ones above larger ones, over the base path's colour, the mean
//! of what none of them covers), weighted by its area:
//! area × ΔE00², the squared error's form with CIEDE2000 in place of RGB distance. A mask
//! that the taken ones already paint in its own colour drops down the list.

use crate::decompose::segment::Candidate;
use crate::perceptual::{ciede2000, lab};
use crate::render::Image;

/// `candidates` (masks of `albedo`'s canvas) reordered by the perceptual error each removes,
/// greedily (see the module's documentation). Equal scores keep their order.
pub(crate) fn perceptual_order(candidates: Vec<Candidate>, albedo: &Image) -> Vec<Candidate> {
    let n = albedo.width * albedo.height;
    if candidates.len() < 2 || n == 0 {
        return candidates;
    }
    let colours: Vec<[f32; 3]> = albedo
        .data
        .chunks_exact(3)
        .map(|px| lab([px[0], px[1], px[2]]).map(|v| v as f32))
        .collect();
    let areas: Vec<usize> = candidates.iter().map(|c| c.mask.area()).collect();
    let own: Vec<[f64; 3]> = candidates
        .iter()
        .zip(&areas)
        .map(|(c, &area)| {
            colour_sum(&colours, &mut c.mask.indices()).map(|s| s / area.max(1) as f64)
        })
        .collect();
    let (start, members) = holders(&candidates, n);
    // What covers each pixel so far: a taken mask (its colour and area), or the base path,
    // whose fill is the mean of the pixels nothing else covers.
    let mut painted = vec![[0f32; 3]; n];
    let mut painted_by = vec![BASE; n];
    let (mut base_sum, mut base_count) = (colour_sum(&colours, &mut (0..n)), n);
    // Per candidate: the sum of its taken-mask colours, and how many of its pixels show the base.
    let mut covered_sum = vec![[0f64; 3]; candidates.len()];
    let mut on_base = areas.clone();
    let mut taken = vec![false; candidates.len()];
    let mut order = Vec::with_capacity(candidates.len());
    for _ in 0..candidates.len() {
        let base = base_sum.map(|s| s / base_count.max(1) as f64);
        let mut best: Option<(usize, f64)> = None;
        for k in (0..candidates.len()).filter(|&k| !taken[k]) {
            let area = areas[k].max(1) as f64;
            let covered =
                [0, 1, 2].map(|c| (covered_sum[k][c] + on_base[k] as f64 * base[c]) / area);
            let score = area * ciede2000(own[k], covered).powi(2);
            if best.is_none_or(|(_, b)| score > b) {
                best = Some((k, score));
            }
        }
        let Some((k, _)) = best else { break };
        taken[k] = true;
        order.push(k);
        // Smaller masks sit above larger ones (`organize`), so k paints only over larger ones.
        let colour = own[k].map(|v| v as f32);
        for i in candidates[k].mask.indices() {
            if painted_by[i] <= areas[k] {
                continue;
            }
            let holders = &members[start[i]..start[i + 1]];
            if painted_by[i] == BASE {
                (0..3).for_each(|c| base_sum[c] -= f64::from(colours[i][c]));
                base_count -= 1;
                for &m in holders {
                    on_base[m as usize] -= 1;
                    (0..3).for_each(|c| covered_sum[m as usize][c] += f64::from(colour[c]));
                }
            } else {
                for &m in holders {
                    let m = m as usize;
                    (0..3).for_each(|c| {
                        covered_sum[m][c] += f64::from(colour[c]) - f64::from(painted[i][c]);
                    });
                }
            }
            painted[i] = colour;
            painted_by[i] = areas[k];
        }
    }
    let mut slots: Vec<Option<Candidate>> = candidates.into_iter().map(Some).collect();
    order.into_iter().filter_map(|k| slots[k].take()).collect()
}

/// Which candidates hold each pixel, as compressed rows: pixel i's are
/// `members[start[i]..start[i + 1]]`.
fn holders(candidates: &[Candidate], n: usize) -> (Vec<usize>, Vec<u32>) {
    let mut start = vec![0usize; n + 1];
    for c in candidates {
        c.mask.indices().for_each(|i| start[i + 1] += 1);
    }
    for i in 0..n {
        start[i + 1] += start[i];
    }
    let mut members = vec![0u32; start[n]];
    let mut filled = start.clone();
    for (k, c) in candidates.iter().enumerate() {
        for i in c.mask.indices() {
            members[filled[i]] = k as u32;
            filled[i] += 1;
        }
    }
    (start, members)
}

/// The "painted by" of a pixel only the base path covers: larger than any mask.
const BASE: usize = usize::MAX;

fn colour_sum(colours: &[[f32; 3]], pixels: &mut dyn Iterator<Item = usize>) -> [f64; 3] {
    let mut sum = [0f64; 3];
    for i in pixels {
        (0..3).for_each(|c| sum[c] += f64::from(colours[i][c]));
    }
    sum
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
        let order = perceptual_order(candidates, &albedo);
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
        let candidates = [&inner, &red, &dot]
            .into_iter()
            .map(|m| Candidate {
                mask: m.clone(),
                gain: 1.0,
            })
            .collect();
        let order = perceptual_order(candidates, &albedo);
        let areas: Vec<usize> = order.iter().map(|c| c.mask.area()).collect();
        // The inner square is red like the half around it: once that is taken it adds nothing.
        assert_eq!(areas, [red.area(), dot.area(), inner.area()]);
    }
}
