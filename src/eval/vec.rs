//! VeC, the paper's measure of how well paths keep to semantic objects (COVec, Table 1): the
//! share of vector paths with over 85% of their area inside a semantic mask.
//!
//! Written out, as `covec eval --semantic-masks` reports it: a path is a *candidate* of a mask
//! when at least [`CANDIDATE_SHARE`] of its area (its own coverage, opacity and occlusion
//! ignored) lies inside the mask, and *counts* when at least [`INSIDE_SHARE`] does; a mask's
//! score is counted / candidates, and VeC is the mean over the masks that have candidates.
//! The albedo base path (the opaque full canvas) is not a path of any object and is left out
//! by the caller.

use crate::pipeline::stage::Canvas;
use crate::scene::Scene;

/// How well a scene's paths keep to semantic masks.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ObjectScores {
    /// [`vec_score`] over the paths of all three layers but the albedo base.
    pub vec: Option<f32>,
    /// Median over the masks of the best IoU any albedo path (but the base) has with it: the
    /// path built from that mask, when one was.
    pub median_iou: Option<f32>,
}

/// [`ObjectScores`] of `scene` against masks at its working size (`width × height` each).
pub fn object_scores(scene: &Scene, masks: &[Vec<bool>]) -> ObjectScores {
    let mut canvas = Canvas::new(scene.width as usize, scene.height as usize);
    let albedo: Vec<_> = scene
        .albedo
        .paths
        .iter()
        .skip(1)
        .map(|p| canvas.coverage(p))
        .collect();
    let illumination = scene
        .shade
        .paths
        .iter()
        .chain(&scene.light.paths)
        .map(|p| canvas.coverage(p));
    let all: Vec<_> = albedo.iter().cloned().chain(illumination).collect();
    let mut best: Vec<f32> = masks
        .iter()
        .filter(|m| m.iter().any(|&v| v))
        .map(|m| albedo.iter().map(|c| iou(c, m)).fold(0.0, f32::max))
        .collect();
    best.sort_by(f32::total_cmp);
    ObjectScores {
        vec: vec_score(&all, masks),
        median_iou: (!best.is_empty()).then(|| best[best.len() / 2]),
    }
}

/// Share of a path's area inside a mask that makes it one of the mask's candidates.
pub const CANDIDATE_SHARE: f32 = 0.15;
/// Share of a path's area inside a mask that makes it count as keeping to the mask.
pub const INSIDE_SHARE: f32 = 0.85;

/// VeC of paths given as sparse coverages (`(pixel index, coverage)`, as
/// `pipeline` computes them) against binary masks of the same canvas; `None` when no mask has
/// a candidate.
pub fn vec_score(paths: &[Vec<(u32, f32)>], masks: &[Vec<bool>]) -> Option<f32> {
    let scores: Vec<f32> = masks
        .iter()
        .filter_map(|mask| {
            let (mut candidates, mut inside) = (0usize, 0usize);
            for coverage in paths {
                let area: f32 = coverage.iter().map(|&(_, c)| c).sum();
                if area <= 0.0 {
                    continue;
                }
                let within: f32 = coverage
                    .iter()
                    .filter(|&&(i, _)| mask.get(i as usize).copied().unwrap_or(false))
                    .map(|&(_, c)| c)
                    .sum();
                let share = within / area;
                if share >= CANDIDATE_SHARE {
                    candidates += 1;
                    inside += usize::from(share >= INSIDE_SHARE);
                }
            }
            (candidates > 0).then(|| inside as f32 / candidates as f32)
        })
        .collect();
    (!scores.is_empty()).then(|| scores.iter().sum::<f32>() / scores.len() as f32)
}

/// Intersection over union of a path's coverage (weighted) with a mask.
pub fn iou(coverage: &[(u32, f32)], mask: &[bool]) -> f32 {
    let area: f32 = coverage.iter().map(|&(_, c)| c).sum();
    let within: f32 = coverage
        .iter()
        .filter(|&&(i, _)| mask.get(i as usize).copied().unwrap_or(false))
        .map(|&(_, c)| c)
        .sum();
    let mask_area = mask.iter().filter(|&&m| m).count() as f32;
    let union = area + mask_area - within;
    if union > 0.0 { within / union } else { 0.0 }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 10 × 10 canvas; a rectangle [x0, x1) × [y0, y1) as a full-coverage path or a mask.
    fn rect(x0: u32, x1: u32, y0: u32, y1: u32) -> Vec<(u32, f32)> {
        (y0..y1)
            .flat_map(|y| (x0..x1).map(move |x| (y * 10 + x, 1.0)))
            .collect()
    }

    fn mask(x0: u32, x1: u32, y0: u32, y1: u32) -> Vec<bool> {
        let mut m = vec![false; 100];
        for (i, _) in rect(x0, x1, y0, y1) {
            m[i as usize] = true;
        }
        m
    }

    #[test]
    fn a_path_inside_its_mask_counts() {
        let left = mask(0, 5, 0, 10);
        assert_eq!(vec_score(&[rect(1, 4, 1, 9)], &[left]), Some(1.0));
    }

    #[test]
    fn a_straddling_path_is_a_candidate_that_does_not_count() {
        let left = mask(0, 5, 0, 10);
        // Half inside: a candidate, not inside; with an inside path the mask scores 1/2.
        let paths = [rect(3, 7, 0, 10), rect(0, 2, 0, 10)];
        assert_eq!(vec_score(&paths, &[left]), Some(0.5));
        // 10% inside: not even a candidate.
        assert_eq!(vec_score(&[rect(0, 10, 0, 10)], &[mask(0, 1, 0, 10)]), None);
    }

    #[test]
    fn the_score_is_the_mean_over_masks_with_candidates() {
        let (left, right, empty) = (mask(0, 5, 0, 10), mask(5, 10, 0, 10), vec![false; 100]);
        let paths = [rect(0, 5, 0, 10), rect(4, 10, 0, 10)];
        // left: candidates both (100%, 1/6 ≈ 17%), one inside → 1/2; right: one candidate, 5/6
        // inside (83% < 85%) → 0; the empty mask has no candidate and is left out.
        assert_eq!(vec_score(&paths, &[left, right, empty]), Some(0.25));
    }

    #[test]
    fn tiny_and_empty_inputs_are_handled() {
        let left = mask(0, 5, 0, 10);
        assert_eq!(vec_score(&[], std::slice::from_ref(&left)), None);
        assert_eq!(vec_score(&[vec![]], std::slice::from_ref(&left)), None);
        // A one-pixel path inside counts.
        assert_eq!(
            vec_score(&[vec![(0, 0.3)]], std::slice::from_ref(&left)),
            Some(1.0)
        );
        assert_eq!(iou(&rect(0, 5, 0, 10), &left), 1.0);
        assert_eq!(iou(&rect(0, 10, 0, 10), &left), 0.5);
        assert_eq!(iou(&[], &[false; 100]), 0.0);
    }
}
