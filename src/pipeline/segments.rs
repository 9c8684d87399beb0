//! The segment budget (a departure from the paper): paths start with few cubics and
//! the reconstruction splits the ones the loss pulls hardest, so that the scene ends with
//! [`SEGMENTS_PER_PATH`] cubics per path on average and spends them where the image needs them.
//!
//! - **Init.** The init outlines' tolerance ([`super::init::OutlineTolerance`]) is scaled up by
//!   [`TOLERANCE_STEP`] until the init paths, plus [`REGION_PATH_SEGMENTS`] for each path the
//!   refinement will add, fit [`INIT_SEGMENTS_PER_PATH`] per path.
//! - **Reconstruction.** Every [`SPLIT_EVERY`] iterations, the segments with the largest pull
//!   (the gradient magnitude on their control points, summed over the iterations so far) are
//!   halved at t = ½ (de Casteljau: no pixel changes), until the scene holds
//!   [`SEGMENTS_PER_PATH`] per path less the refinement's share. Only the illumination
//!   layer splits. Albedo outlines split where the loss pulls chase the shadows' edges, the
//!   leak `super::stage::hold_albedo` guards against; in simple mode, where the albedo is the
//!   only layer, the emoji's outlines already fit the budget and splits cost GMSD for no MSE
//!   (docs/history.md, "The segment budget").
//!
//! The mean is [`SEGMENTS_PER_PATH`] when the refinement fills the path budget, which it does
//! unless it runs out of error regions.

use super::regions::REGION_PATH_SEGMENTS;
use crate::geom::bezier::split_half;
use crate::optim::Adam;
use crate::render::PathGrad;
use crate::scene::{Path, Point};

/// Mean cubic segments per path the scene ends with.
pub const SEGMENTS_PER_PATH: f32 = 12.0;

/// Mean per path the init outlines start from, leaving the rest to the splits: fewer cost MSE
/// (docs/history.md, "The segment budget"); above 12 nothing is left.
pub const INIT_SEGMENTS_PER_PATH: f32 = 11.5;

/// Factor by which the init tolerance grows per attempt to fit [`INIT_SEGMENTS_PER_PATH`].
pub const TOLERANCE_STEP: f32 = 1.15;

/// The init gives up growing the tolerance past this scale (an image too busy for the budget
/// keeps more segments rather than lose its outlines).
pub const MAX_TOLERANCE_SCALE: f32 = 20.0;

/// Reconstruction iterations between splits: enough for the pull to build up again and for
/// the new points to settle before the next split.
pub const SPLIT_EVERY: u32 = 10;

/// Segments the refinement's new paths will bring, when the scene holds `paths` of `budget`.
pub fn refinement_reserve(budget: usize, paths: usize) -> usize {
    budget.saturating_sub(paths) * REGION_PATH_SEGMENTS
}

/// Segments the reconstruction may split up to, for a path budget.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct SplitPlan {
    pub target: usize,
}

impl SplitPlan {
    /// The plan for a scene holding `paths` of a budget of `budget` paths.
    pub fn new(budget: usize, paths: usize) -> Self {
        let total = (SEGMENTS_PER_PATH * budget as f32) as usize;
        Self {
            target: total.saturating_sub(refinement_reserve(budget, paths)),
        }
    }

    /// How many segments to split after iteration `done` of a loop of `count`, the scene
    /// holding `current`: an equal share of what is left at each split still to come, none in
    /// the last [`SPLIT_EVERY`] iterations (the new points need them).
    pub fn due(&self, done: u32, count: u32, current: usize) -> usize {
        if done == 0 || !done.is_multiple_of(SPLIT_EVERY) || done >= count {
            return 0;
        }
        let splits_left = ((count - 1) / SPLIT_EVERY - done / SPLIT_EVERY + 1) as usize;
        self.target.saturating_sub(current).div_ceil(splits_left)
    }
}

/// Per-segment pull of the loss on a list of paths, summed over iterations.
#[derive(Clone, Debug, Default)]
pub(crate) struct SegmentPull {
    /// `pull[path][segment]`.
    pull: Vec<Vec<f32>>,
}

impl SegmentPull {
    /// Adds one iteration's gradient: each segment gets the gradient magnitude of its two
    /// handles and half of each end point's (end points are shared with the neighbours).
    pub fn add(&mut self, paths: &[Path], grads: &[PathGrad]) {
        self.pull.resize_with(paths.len(), Vec::new);
        let length = |p: Point| p.x.hypot(p.y);
        for ((pull, path), grad) in self.pull.iter_mut().zip(paths).zip(grads) {
            let n = path.segment_count();
            if pull.len() != n {
                *pull = vec![0.0; n];
            }
            let g = &grad.points;
            for (k, s) in pull.iter_mut().enumerate() {
                *s += 0.5 * length(g[3 * k])
                    + length(g[3 * k + 1])
                    + length(g[3 * k + 2])
                    + 0.5 * length(g[(3 * k + 3) % g.len()]);
            }
        }
    }
}

/// One layer's paths with their pull and their Adam, which a split keeps in step.
pub(crate) struct SplitLayer<'a> {
    pub paths: &'a mut Vec<Path>,
    pub pull: &'a mut SegmentPull,
    pub adam: &'a mut Adam,
}

impl SplitLayer<'_> {
    /// Halves the `count` segments with the largest pull (each at most once); each half keeps
    /// half its segment's pull. Ties go to the earlier path and segment. A segment the loss
    /// does not pull (a held path) is never split.
    pub fn split_most_pulled(&mut self, count: usize) {
        let mut ranked: Vec<(f32, usize, usize)> = Vec::new();
        for (p, (path, pull)) in self.paths.iter().zip(&self.pull.pull).enumerate() {
            if pull.len() == path.segment_count() {
                let pulled = pull.iter().enumerate().filter(|&(_, &s)| s > 0.0);
                ranked.extend(pulled.map(|(k, &s)| (s, p, k)));
            }
        }
        ranked.sort_by(|a, b| b.0.total_cmp(&a.0).then((a.1, a.2).cmp(&(b.1, b.2))));
        ranked.truncate(count);
        // From each path's last segment backwards, so that the indices still to split stay
        // valid.
        ranked.sort_by_key(|&(_, p, k)| std::cmp::Reverse((p, k)));
        for (_, p, k) in ranked {
            split_segment(&mut self.paths[p], k);
            self.adam.split_segment(p, k);
            let pull = &mut self.pull.pull[p];
            pull[k] *= 0.5;
            pull.insert(k + 1, pull[k]);
        }
    }
}

/// Replaces segment `k` of `path` by its two halves.
fn split_segment(path: &mut Path, k: usize) {
    let [first, second] = split_half(&path.segment(k));
    path.points[3 * k + 1] = first[1];
    path.points[3 * k + 2] = first[2];
    path.points
        .splice(3 * k + 3..3 * k + 3, [second[0], second[1], second[2]]);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optim::AdamSettings;
    use crate::optim::Bounds;

    fn path(points: &[(f32, f32)]) -> Path {
        Path {
            points: points.iter().map(|&(x, y)| Point::new(x, y)).collect(),
            color: [0.5; 3],
            opacity: 1.0,
        }
    }

    #[test]
    fn a_split_keeps_the_curve_and_the_other_segments() {
        let mut p = path(&[
            (0.0, 0.0),
            (3.0, 9.0),
            (7.0, -4.0),
            (10.0, 2.0),
            (8.0, 8.0),
            (2.0, 8.0),
        ]);
        let [first, second] = split_half(&p.segment(0));
        let last = p.segment(1);
        split_segment(&mut p, 0);
        assert_eq!(p.segment_count(), 3);
        assert_eq!(
            [p.segment(0), p.segment(1), p.segment(2)],
            [first, second, last]
        );
    }

    #[test]
    fn the_most_pulled_segments_split_first() {
        // Two triangles; the loss pulls the second path's middle segment hardest.
        let triangle = [
            (0.0, 0.0),
            (1.0, 0.0),
            (2.0, 0.0),
            (3.0, 0.0),
            (3.0, 1.0),
            (3.0, 2.0),
            (3.0, 3.0),
            (2.0, 2.0),
            (1.0, 1.0),
        ];
        let mut paths = vec![path(&triangle), path(&triangle)];
        let mut grads = vec![PathGrad::default(); 2];
        for (g, p) in grads.iter_mut().zip(&paths) {
            g.points = vec![Point::new(0.1, 0.0); p.points.len()];
        }
        grads[1].points[4] = Point::new(0.0, 5.0);
        let mut pull = SegmentPull::default();
        pull.add(&paths, &grads);
        let mut adam = Adam::new(AdamSettings::default(), Bounds::canvas(8, 8, 1.0));
        adam.step(&mut paths, &[PathGrad::default(), PathGrad::default()]);
        let before = paths[1].segment(1);
        SplitLayer {
            paths: &mut paths,
            pull: &mut pull,
            adam: &mut adam,
        }
        .split_most_pulled(1);
        assert_eq!(paths[0].segment_count(), 3);
        assert_eq!(paths[1].segment_count(), 4);
        let halves = [paths[1].segment(1), paths[1].segment(2)];
        assert_eq!(halves, split_half(&before));
        // More splits asked for than segments pulled: an unpulled path stays as it is.
        let mut held = vec![path(&triangle)];
        let mut pull = SegmentPull::default();
        pull.add(
            &held,
            &[PathGrad {
                points: vec![Point::default(); 9],
                ..PathGrad::default()
            }],
        );
        SplitLayer {
            paths: &mut held,
            pull: &mut pull,
            adam: &mut adam,
        }
        .split_most_pulled(5);
        assert_eq!(held[0].segment_count(), 3);
    }

    #[test]
    fn the_plan_spreads_the_splits_and_keeps_the_last_iterations() {
        let plan = SplitPlan { target: 100 };
        // A loop of 50: splits after 10, 20, 30 and 40, the last one for all that is left.
        assert_eq!(plan.due(10, 50, 60), 10);
        assert_eq!(plan.due(11, 50, 60), 0);
        assert_eq!(plan.due(40, 50, 90), 10);
        assert_eq!(plan.due(50, 50, 90), 0);
        assert_eq!(plan.due(20, 50, 120), 0);
        // 12 per path for 64 paths, 20 to come from the refinement at 6 each.
        assert_eq!(SplitPlan::new(64, 44).target, 768 - 120);
    }
}
