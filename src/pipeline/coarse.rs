//! Coarse-to-fine optimisation and early stopping (departures from the paper, for speed).
//!
//! **Coarse to fine.** The early iterations only need the rough geometry: the structure stage,
//! the first part of the reconstruction, the first refinement rounds and the first part of the
//! polish run on a copy of the
//! scene at half the working size (points × ½, target and masks averaged over 2×2 blocks), whose
//! renders cost about a quarter; a large working size is halved more than once
//! ([`CoarseSettings::side`]), and the polish then runs on that copy first and on a half-size
//! one after ([`CoarseSettings::polish_halvings`], [`CoarseSettings::polish_deep_share`]). The
//! geometry is then
//! scaled back and the later iterations run at full size. Each resolution gets its own Adam
//! (moments do not carry over a change of scale).
//!
//! **Early stopping.** A loop stops once its loss has plateaued ([`Plateau`]): when the best
//! loss of the last `window` iterations is less than `min_gain` (relative) below the best loss
//! before them. The reconstruction, the coarse refinement rounds and the polish stop early; the
//! last (full-size) refinement round runs all its iterations: it places the paths the output
//! ends with, and stopping it early broke the edit-faithfulness test (docs/history.md,
//! "Coarse to fine").

use crate::decompose::mask::Mask;

/// When and how much to run coarse.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CoarseSettings {
    /// Images whose long side is under this run at full size throughout. Default 128: below it
    /// a half-size copy no longer holds the features paths start from.
    pub min_size: usize,
    /// Long side the coarse copy may be brought down to: the working size is halved once, and
    /// again while the copy's long side stays at least this (the polish stops at
    /// [`CoarseSettings::polish_halvings`]). Default 256: 512² runs coarse at 256², 1024² at
    /// 256² too, where its coarse iterations cost what they cost at 512²; smaller lost
    /// accuracy (docs/history.md, "Coarse to fine").
    pub side: usize,
    /// Share of the reconstruction iterations run coarse. Default 0.8.
    pub reconstruction_share: f32,
    /// Refinement rounds run at full size, at the end; the earlier ones run coarse. Default 1.
    pub fine_rounds: u32,
    /// Share of the polish iterations run coarse. Default 0.75: a lower error than fewer
    /// full-size iterations in the same time (docs/history.md, "Coarse to fine").
    pub polish_share: f32,
    /// Side above which the polish's full-size iterations shrink in proportion to the side
    /// (the rest run coarse): their cost then grows with the side, not with the pixel count.
    /// Default 512: 512² keeps 40 of 160 at full size, 1024² runs 20 (140 coarse), a small
    /// loss for a cheaper run (docs/history.md, "Coarse to fine").
    pub polish_fine_side: usize,
    /// Most halvings of the polish's last coarse copy. Default 1: the gradient-similarity term
    /// wants the detail a half-size copy keeps (docs/history.md, "Coarse to fine").
    pub polish_halvings: u32,
    /// Share of the polish's coarse iterations run on the smallest copy first, when the other
    /// stages' copy is smaller than the polish's (1024²: 256² against 512²). Default 0.7:
    /// cheaper at no loss of GMSD, where 0.9 lost some (docs/history.md, "Coarse to fine").
    pub polish_deep_share: f32,
}

impl Default for CoarseSettings {
    fn default() -> Self {
        Self {
            min_size: 128,
            side: 256,
            reconstruction_share: 0.8,
            fine_rounds: 1,
            polish_share: 0.75,
            polish_fine_side: 512,
            polish_halvings: 1,
            polish_deep_share: 0.7,
        }
    }
}

impl CoarseSettings {
    /// Whether a `width × height` working image has a coarse phase.
    pub fn applies(&self, width: usize, height: usize) -> bool {
        width.max(height) >= self.min_size
    }

    /// How many of a `width × height` image's `total` polish iterations run coarse (when it
    /// has a coarse phase): [`CoarseSettings::polish_share`] of them, and more above
    /// [`CoarseSettings::polish_fine_side`].
    pub fn polish_coarse(&self, total: u32, width: usize, height: usize) -> u32 {
        let shared = ((total as f32 * self.polish_share).round() as u32).min(total);
        let side = width.max(height);
        if side <= self.polish_fine_side {
            return shared;
        }
        let fine = (total - shared) as usize * self.polish_fine_side / side;
        total - fine as u32
    }

    /// The polish's coarse parts, `(iterations, halvings)` in turn, for `coarse` coarse
    /// iterations of an image halved `halvings` times for the other stages.
    pub fn polish_parts(&self, coarse: u32, halvings: u32) -> Vec<(u32, u32)> {
        let last = halvings.min(self.polish_halvings);
        if halvings <= last {
            return vec![(coarse, last)];
        }
        let deep = ((coarse as f32 * self.polish_deep_share).round() as u32).min(coarse);
        vec![(deep, halvings), (coarse - deep, last)]
    }

    /// How many times a `width × height` working image is halved for its coarse phase (0: it
    /// has none).
    pub fn halvings(&self, width: usize, height: usize) -> u32 {
        if !self.applies(width, height) {
            return 0;
        }
        let mut long = width.max(height).div_ceil(2);
        let mut halvings = 1;
        while long.div_ceil(2) >= self.side {
            long = long.div_ceil(2);
            halvings += 1;
        }
        halvings
    }
}

/// `value` halved once, twice, … `times` times: `halve` applied to the last each time.
pub fn halvings_of<T>(value: &T, times: u32, halve: impl Fn(&T) -> T) -> Vec<T> {
    let mut out: Vec<T> = Vec::new();
    for _ in 0..times {
        let halved = halve(out.last().unwrap_or(value));
        out.push(halved);
    }
    out
}

/// The mask at half size: a pixel is in when at least half of its 2×2 block is.
pub fn halve_mask(mask: &Mask) -> Mask {
    let (w, h) = (mask.width(), mask.height());
    Mask::from_fn(w.div_ceil(2), h.div_ceil(2), |x, y| {
        let inside = [(0, 0), (1, 0), (0, 1), (1, 1)]
            .iter()
            .filter(|&&(dx, dy)| {
                let (px, py) = (2 * x + dx, 2 * y + dy);
                px < w && py < h && mask.contains(px, py)
            })
            .count();
        inside >= 2
    })
}

/// The plateau test of early stopping.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlateauSettings {
    /// Iterations compared. Default 10.
    pub window: u32,
    /// Smallest relative gain over the window that keeps a loop going. Default 0.002 (0.2%).
    pub min_gain: f32,
    /// Iterations always run. Default 20.
    pub min_iterations: u32,
}

impl Default for PlateauSettings {
    fn default() -> Self {
        Self {
            window: 10,
            min_gain: 0.002,
            min_iterations: 20,
        }
    }
}

impl PlateauSettings {
    /// Never stops early.
    pub fn never() -> Self {
        Self {
            min_gain: 0.0,
            ..Self::default()
        }
    }
}

/// Tracks one loop's loss and says when it has plateaued.
#[derive(Clone, Debug)]
pub struct Plateau {
    settings: PlateauSettings,
    /// Best loss so far after each iteration (non-increasing).
    best: Vec<f32>,
}

impl Plateau {
    pub fn new(settings: PlateauSettings) -> Self {
        Self {
            settings,
            best: Vec::new(),
        }
    }

    /// Records the loss of one more iteration; true when the loop should stop.
    pub fn stop_after(&mut self, loss: f32) -> bool {
        let best = self.best.last().map_or(loss, |&b| b.min(loss));
        self.best.push(best);
        let t = self.best.len();
        let window = self.settings.window as usize;
        if t < (self.settings.min_iterations as usize).max(window + 1) {
            return false;
        }
        let before = self.best[t - 1 - window];
        before - best < self.settings.min_gain * before
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imageio::halve_image;
    use crate::render::Image;

    #[test]
    fn the_full_size_polish_shrinks_with_the_side_above_512() {
        let settings = CoarseSettings::default();
        assert_eq!(settings.polish_coarse(160, 256, 256), 120);
        assert_eq!(settings.polish_coarse(160, 512, 384), 120);
        assert_eq!(settings.polish_coarse(160, 1024, 768), 140);
        assert_eq!(settings.polish_coarse(160, 2048, 2048), 150);
    }

    #[test]
    fn the_polish_starts_on_the_smallest_copy_when_the_other_stages_use_one() {
        let settings = CoarseSettings::default();
        assert_eq!(settings.polish_parts(120, 1), [(120, 1)]);
        assert_eq!(settings.polish_parts(140, 2), [(98, 2), (42, 1)]);
        assert_eq!(settings.polish_parts(150, 3), [(105, 3), (45, 1)]);
    }

    #[test]
    fn a_steady_descent_runs_on_and_a_flat_tail_stops() {
        let settings = PlateauSettings::default();
        let mut plateau = Plateau::new(settings);
        // 5% less per iteration: never plateaus.
        let mut loss = 1.0f32;
        for _ in 0..100 {
            assert!(!plateau.stop_after(loss));
            loss *= 0.95;
        }
        let mut plateau = Plateau::new(settings);
        let mut stopped_at = None;
        for t in 0..100 {
            // Descends for 30 iterations, then noise around a floor.
            let loss = if t < 30 {
                1.0 - 0.02 * t as f32
            } else {
                0.4 + 1e-4 * (t % 3) as f32
            };
            if plateau.stop_after(loss) {
                stopped_at = Some(t);
                break;
            }
        }
        // The floor is reached at t = 30; at t = 40 the last 10 iterations gained nothing.
        assert_eq!(stopped_at, Some(40));
    }

    #[test]
    fn never_means_never() {
        let mut plateau = Plateau::new(PlateauSettings::never());
        assert!((0..200).all(|_| !plateau.stop_after(1.0)));
    }

    #[test]
    fn never_stops_before_the_minimum() {
        let mut plateau = Plateau::new(PlateauSettings::default());
        for _ in 0..19 {
            assert!(!plateau.stop_after(1.0));
        }
        assert!(plateau.stop_after(1.0));
    }

    #[test]
    fn halving_averages_blocks_and_keeps_the_mask_majority() {
        let mut image = Image::filled(3, 2, [0.0; 3]);
        image.data[0] = 1.0; // red of (0, 0)
        image.data[3 * 2] = 0.8; // red of (2, 0)
        let half = halve_image(&image);
        assert_eq!((half.width, half.height), (2, 1));
        assert_eq!(half.pixel(0, 0)[0], 0.25);
        // (2, 0) and (2, 1) repeated over the overhang: (0.8 + 0.8 + 0 + 0) / 4.
        assert!((half.pixel(1, 0)[0] - 0.4).abs() < 1e-6);

        let mask = Mask::from_fn(4, 4, |x, y| x < 2 || (x == 2 && y == 0));
        let half = halve_mask(&mask);
        assert!(half.contains(0, 0) && half.contains(0, 1));
        assert!(!half.contains(1, 0), "one of four is not a majority");
    }

    #[test]
    fn large_images_are_halved_down_towards_the_coarse_side() {
        let coarse = CoarseSettings::default();
        assert_eq!(coarse.halvings(100, 64), 0);
        assert_eq!(coarse.halvings(256, 256), 1);
        assert_eq!(coarse.halvings(512, 384), 1);
        assert_eq!(coarse.halvings(1000, 700), 1);
        assert_eq!(coarse.halvings(1023, 700), 2);
        assert_eq!(coarse.halvings(1024, 1024), 2);
        assert_eq!(coarse.halvings(2048, 1536), 3);
        let image = Image::filled(5, 3, [0.5; 3]);
        let halved = halvings_of(&image, 2, halve_image);
        assert_eq!((halved[0].width, halved[0].height), (3, 2));
        assert_eq!((halved[1].width, halved[1].height), (2, 1));
    }

    #[test]
    fn rescaling_there_and_back_keeps_the_scene() {
        let mut scene = crate::scene::Scene::new(64, 64, 64, 64);
        scene.shade.paths.push(crate::scene::Path::rect(
            3.0, 5.0, 17.0, 33.0, [0.5; 3], 0.7,
        ));
        let coarse = scene.rescaled(0.5, 32, 32);
        assert_eq!(
            coarse.shade.paths[0].points[0],
            crate::scene::Point::new(1.5, 2.5)
        );
        assert_eq!(coarse.rescaled(2.0, 64, 64), scene);
    }
}
