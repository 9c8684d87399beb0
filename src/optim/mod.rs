//! Optimisation building blocks: Adam over paths with per-group settings, projection of every
//! value back into its valid range after each step, losses with their gradients, and a small
//! seeded random generator.
//!
//! The stages in [`crate::pipeline`] combine these with the rasteriser; nothing here renders.

pub mod loss;
pub mod rng;

use crate::render::PathGrad;
use crate::scene::{Path, Point};

/// Adam settings of one parameter group (points, colours or opacities).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroupSettings {
    /// Step size. Points are in pixels, colours and opacities in [0, 1] units.
    pub lr: f32,
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
}

impl GroupSettings {
    /// LayerVec's Adam (betas 0.9/0.9, eps 1e-6), which COVec is built on, with learning rate `lr`.
    pub const fn layervec(lr: f32) -> Self {
        Self {
            lr,
            beta1: 0.9,
            beta2: 0.9,
            eps: 1e-6,
        }
    }
}

/// Adam settings per parameter group.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamSettings {
    /// Default: lr 1.0 (the paper's point learning rate).
    pub points: GroupSettings,
    /// Default: lr 0.01 (the paper's colour learning rate).
    pub color: GroupSettings,
    /// Default: lr 0.01, as colours (DiffVG peers optimise RGBA as one tensor).
    pub opacity: GroupSettings,
}

impl Default for AdamSettings {
    fn default() -> Self {
        Self {
            points: GroupSettings::layervec(1.0),
            color: GroupSettings::layervec(0.01),
            opacity: GroupSettings::layervec(0.01),
        }
    }
}

impl AdamSettings {
    /// The same settings with every learning rate multiplied by `factor`.
    pub fn scaled(self, factor: f32) -> Self {
        let scale = |g: GroupSettings| GroupSettings {
            lr: g.lr * factor,
            ..g
        };
        Self {
            points: scale(self.points),
            color: scale(self.color),
            opacity: scale(self.opacity),
        }
    }
}

/// Where values must lie after every step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds {
    /// Upper bound of colour channels (lower bound 0): 1 for albedo, shade and light; larger for
    /// the illumination layer, whose values above 1 mark highlights.
    pub color_max: f32,
    /// Canvas size: points are kept within `[-margin, width + margin] × [-margin, height + margin]`
    /// so no path drifts away for good.
    pub width: f32,
    pub height: f32,
    pub margin: f32,
}

impl Bounds {
    /// Bounds for a canvas with colours in `[0, color_max]` and a 1-pixel margin.
    pub fn canvas(width: usize, height: usize, color_max: f32) -> Self {
        Self {
            color_max,
            width: width as f32,
            height: height as f32,
            margin: 1.0,
        }
    }

    /// Moves every value of `path` into range.
    pub fn project(&self, path: &mut Path) {
        for c in &mut path.color {
            *c = c.clamp(0.0, self.color_max);
        }
        path.opacity = path.opacity.clamp(0.0, 1.0);
        for p in &mut path.points {
            p.x = p.x.clamp(-self.margin, self.width + self.margin);
            p.y = p.y.clamp(-self.margin, self.height + self.margin);
        }
    }
}

/// First and second moment estimates of one path's parameters.
#[derive(Clone, Debug)]
struct Moments {
    points: Vec<[f32; 4]>,
    color: [[f32; 2]; 3],
    opacity: [f32; 2],
}

/// Adam over a list of paths, one moment state per path (in the order given to [`Adam::step`]).
/// Each parameter group has its own settings; the step is followed by projection into [`Bounds`].
#[derive(Clone, Debug)]
pub struct Adam {
    settings: AdamSettings,
    bounds: Bounds,
    moments: Vec<Moments>,
    steps: i32,
}

impl Adam {
    pub fn new(settings: AdamSettings, bounds: Bounds) -> Self {
        Self {
            settings,
            bounds,
            moments: Vec::new(),
            steps: 0,
        }
    }

    /// One step on `paths` with gradients `grads` (same shapes), then projection.
    /// Moment state is kept per index; if a path changes shape its state restarts.
    pub fn step(&mut self, paths: &mut [Path], grads: &[PathGrad]) {
        self.steps += 1;
        let t = self.steps;
        let s = self.settings;
        self.moments.truncate(paths.len());
        for (i, (path, grad)) in paths.iter_mut().zip(grads).enumerate() {
            if i == self.moments.len() || self.moments[i].points.len() != path.points.len() {
                let fresh = Moments {
                    points: vec![[0.0; 4]; path.points.len()],
                    color: [[0.0; 2]; 3],
                    opacity: [0.0; 2],
                };
                if i == self.moments.len() {
                    self.moments.push(fresh);
                } else {
                    self.moments[i] = fresh;
                }
            }
            let m = &mut self.moments[i];
            for ((p, g), mv) in path.points.iter_mut().zip(&grad.points).zip(&mut m.points) {
                let mut xy = [mv[0], mv[1]];
                let mut vv = [mv[2], mv[3]];
                p.x -= adam_update(&s.points, t, &mut xy[0], &mut vv[0], g.x);
                p.y -= adam_update(&s.points, t, &mut xy[1], &mut vv[1], g.y);
                *mv = [xy[0], xy[1], vv[0], vv[1]];
            }
            for c in 0..3 {
                let [mut m1, mut v1] = m.color[c];
                path.color[c] -= adam_update(&s.color, t, &mut m1, &mut v1, grad.color[c]);
                m.color[c] = [m1, v1];
            }
            let [mut m1, mut v1] = m.opacity;
            path.opacity -= adam_update(&s.opacity, t, &mut m1, &mut v1, grad.opacity);
            m.opacity = [m1, v1];
            self.bounds.project(path);
        }
    }
}

impl Adam {
    /// Keeps path `path`'s moments in step with a split of its segment `k` into two (the new
    /// points, the middle end point and its two handles, start with zero moments).
    pub fn split_segment(&mut self, path: usize, k: usize) {
        if let Some(m) = self.moments.get_mut(path) {
            let at = (3 * k + 3).min(m.points.len());
            m.points.splice(at..at, [[0.0; 4]; 3]);
        }
    }
}

/// Updates one parameter's moments with gradient `g` and returns the step to subtract.
fn adam_update(s: &GroupSettings, t: i32, m: &mut f32, v: &mut f32, g: f32) -> f32 {
    let g = if g.is_finite() { g } else { 0.0 };
    *m = s.beta1 * *m + (1.0 - s.beta1) * g;
    *v = s.beta2 * *v + (1.0 - s.beta2) * g * g;
    let m_hat = *m / (1.0 - s.beta1.powi(t));
    let v_hat = *v / (1.0 - s.beta2.powi(t));
    s.lr * m_hat / (v_hat.sqrt() + s.eps)
}

/// Zero gradients for `paths`, reusing `grads`' allocations.
pub fn reset_grads(grads: &mut Vec<PathGrad>, paths: &[Path]) {
    grads.resize_with(paths.len(), PathGrad::default);
    for (g, p) in grads.iter_mut().zip(paths) {
        g.points.clear();
        g.points.resize(p.points.len(), Point::default());
        g.color = [0.0; 3];
        g.opacity = 0.0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Adam on f(c) = Σ (c - target)² for a path's colour converges and respects the bounds.
    #[test]
    fn adam_minimises_a_quadratic_within_bounds() {
        let mut paths = vec![Path::rect(0.0, 0.0, 4.0, 4.0, [0.5; 3], 0.5)];
        let target = [0.2, 0.9, 1.7]; // 1.7 is out of range: the result must stop at 1.
        let settings = AdamSettings::default().scaled(2.0);
        let mut adam = Adam::new(settings, Bounds::canvas(8, 8, 1.0));
        let mut grads = Vec::new();
        for _ in 0..500 {
            reset_grads(&mut grads, &paths);
            for c in 0..3 {
                grads[0].color[c] = 2.0 * (paths[0].color[c] - target[c]);
            }
            grads[0].opacity = 2.0 * (paths[0].opacity - 2.0);
            adam.step(&mut paths, &grads);
        }
        let c = paths[0].color;
        assert!(
            (c[0] - 0.2).abs() < 0.02 && (c[1] - 0.9).abs() < 0.02,
            "{c:?}"
        );
        assert_eq!(c[2], 1.0);
        assert_eq!(paths[0].opacity, 1.0);
    }

    #[test]
    fn projection_keeps_points_near_the_canvas() {
        let mut path = Path::rect(-50.0, 0.0, 100.0, 4.0, [3.0, -1.0, 0.5], 1.5);
        Bounds::canvas(10, 10, 2.0).project(&mut path);
        assert_eq!(path.color, [2.0, 0.0, 0.5]);
        assert_eq!(path.opacity, 1.0);
        assert!(path.points.iter().all(|p| (-1.0..=11.0).contains(&p.x)));
    }
}
