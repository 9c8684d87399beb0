//! Losses on rendered images, each returning its value and writing dLoss/dPixel. The compositing
//! models and their backwards are in [`crate::render::composite`].

use std::ops::Range;

use rayon::prelude::*;

use crate::render::Image;
use crate::simd::widest;

/// Values per block of a loss's sum. Blocks are summed in parallel, each in a fixed order in
/// [`LANES`] running sums, and the block sums added in block order, so the value does not
/// depend on the thread count. A 128² canvas (the coarse stages') makes 3 blocks.
const SUM_BLOCK: usize = 1 << 14;
/// Independent running sums within a block, so that each addition need not wait for the last.
const LANES: usize = 8;

/// Sum of squared differences over one block's values, running sum `i % LANES` taking the
/// `i`-th, a whole chunk of [`LANES`] values at a time so that the loop vectorises. With
/// `Some((grad, n))`, also writes the MSE's gradient over `n` values into `grad`.
#[inline(always)]
fn squares(pred: &[f32], target: &[f32], mut grad: Option<(&mut [f32], f32)>) -> f64 {
    let len = pred.len();
    let mut lanes = [0f64; LANES];
    let mut add = |start: usize, d: &[f32]| {
        if let Some((grad, n)) = grad.as_mut() {
            for (g, d) in grad[start..start + d.len()].iter_mut().zip(d) {
                *g = 2.0 * d / *n;
            }
        }
        for (lane, d) in lanes.iter_mut().zip(d) {
            *lane += f64::from(d * d);
        }
    };
    let (pred_chunks, pred_tail) = pred.as_chunks::<LANES>();
    let (target_chunks, target_tail) = target[..len].as_chunks::<LANES>();
    for (k, (p, t)) in pred_chunks.iter().zip(target_chunks).enumerate() {
        let d: [f32; LANES] = std::array::from_fn(|j| p[j] - t[j]);
        add(k * LANES, &d);
    }
    let mut d = [0.0; LANES];
    for (d, (p, t)) in d.iter_mut().zip(pred_tail.iter().zip(target_tail)) {
        *d = p - t;
    }
    add(len - pred_tail.len(), &d[..pred_tail.len()]);
    lanes.iter().sum()
}

/// Mean squared error over pixels × channels; writes dLoss/dPred into `grad` (resized).
pub fn mse(pred: &Image, target: &Image, grad: &mut Image) -> f32 {
    PartialMse::default().update(pred, target, grad, None)
}

/// One block of [`mse`]: writes its gradient, returns its sum of squares.
fn mse_block(grad: &mut [f32], pred: &[f32], target: &[f32], n: f32) -> f64 {
    widest!(squares(pred, target, Some((grad, n))))
}

/// [`mse`] of a prediction that changes in parts (a few paths moving over a fixed backdrop):
/// it keeps the block sums between calls, so a call redoes the value and gradient of the
/// blocks that meet the changed values only. Same value and gradient as [`mse`].
#[derive(Default)]
pub struct PartialMse {
    blocks: Vec<f64>,
    dirty: Vec<bool>,
}

impl PartialMse {
    /// The MSE of `pred` against `target`, writing dLoss/dPred into `grad` (resized).
    /// `changed`: the ranges of `pred.data` that differ from the last call's `pred`, or `None`
    /// for all (as on the first call; a change of size also redoes every block). `grad`, the
    /// same image as last time, keeps its values outside the blocks redone.
    pub fn update(
        &mut self,
        pred: &Image,
        target: &Image,
        grad: &mut Image,
        changed: Option<&[Range<usize>]>,
    ) -> f32 {
        debug_assert_eq!(pred.data.len(), target.data.len());
        resize_like(grad, pred);
        let n = pred.data.len().max(1) as f32;
        let count = pred.data.len().div_ceil(SUM_BLOCK);
        self.dirty.clear();
        match changed {
            Some(ranges) if self.blocks.len() == count => {
                self.dirty.resize(count, false);
                for range in ranges.iter().filter(|r| !r.is_empty()) {
                    self.dirty[range.start / SUM_BLOCK..range.end.div_ceil(SUM_BLOCK)].fill(true);
                }
            }
            _ => {
                self.blocks.clear();
                self.blocks.resize(count, 0.0);
                self.dirty.resize(count, true);
            }
        }
        grad.data
            .par_chunks_mut(SUM_BLOCK)
            .zip(pred.data.par_chunks(SUM_BLOCK))
            .zip(target.data.par_chunks(SUM_BLOCK))
            .zip(self.blocks.par_iter_mut())
            .zip(self.dirty.par_iter())
            .filter(|(_, dirty)| **dirty)
            .for_each(|((((g, p), t), sum), _)| *sum = mse_block(g, p, t, n));
        (self.blocks.iter().sum::<f64>() / f64::from(n)) as f32
    }
}

/// Mean squared error without gradient.
pub fn mse_value(pred: &Image, target: &Image) -> f32 {
    let n = pred.data.len().max(1) as f64;
    let blocks: Vec<f64> = pred
        .data
        .par_chunks(SUM_BLOCK)
        .zip(target.data.par_chunks(SUM_BLOCK))
        .map(|(p, t)| widest!(squares(p, t, None)))
        .collect();
    (blocks.iter().sum::<f64>() / n) as f32
}

/// The overlap term of the structure loss: `weight · mean(ReLU(delta − img))` over pixels ×
/// channels, where `img` is the group rendered in translucent grey over white. Adds
/// dLoss/dPixel into `grad` (resized and zeroed if its size differs).
pub fn overlap_penalty(img: &Image, delta: f32, weight: f32, grad: &mut Image) -> f32 {
    resize_like(grad, img);
    let n = img.data.len().max(1) as f32;
    let mut sum = 0.0f64;
    for (g, &v) in grad.data.iter_mut().zip(&img.data) {
        let excess = delta - v;
        if excess > 0.0 {
            sum += f64::from(excess);
            *g -= weight / n;
        }
    }
    (f64::from(weight) * sum / f64::from(n)) as f32
}

/// Makes `img` the size of `like`, zero-filled when the size changes.
pub fn resize_like(img: &mut Image, like: &Image) {
    if img.width != like.width || img.height != like.height || img.data.len() != like.data.len() {
        *img = Image {
            width: like.width,
            height: like.height,
            data: vec![0.0; like.data.len()],
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(values: &[f32]) -> Image {
        Image {
            width: values.len() / 3,
            height: 1,
            data: values.to_vec(),
        }
    }

    /// Central finite differences of `f` at `x` against `grad`.
    fn check_grad(x: &Image, grad: &Image, f: impl Fn(&Image) -> f32) {
        for i in 0..x.data.len() {
            let h = 1e-3;
            let mut plus = x.clone();
            plus.data[i] += h;
            let mut minus = x.clone();
            minus.data[i] -= h;
            let fd = (f(&plus) - f(&minus)) / (2.0 * h);
            assert!(
                (fd - grad.data[i]).abs() < 2e-3,
                "value {i}: fd {fd} vs analytic {}",
                grad.data[i]
            );
        }
    }

    #[test]
    fn mse_gradient_matches_finite_differences() {
        let pred = image(&[0.1, 0.5, 0.9, 0.3, 0.2, 0.7]);
        let target = image(&[0.2, 0.4, 1.0, 0.0, 0.2, 0.1]);
        let mut grad = Image::default();
        let loss = mse(&pred, &target, &mut grad);
        assert!((loss - mse_value(&pred, &target)).abs() < 1e-7);
        check_grad(&pred, &grad, |p| mse_value(p, &target));
    }

    #[test]
    fn a_partial_mse_is_the_whole_one_after_a_change() {
        let len = 3 * SUM_BLOCK + 4002;
        let value = |i: usize, k: usize| ((i * k) % 997) as f32 / 997.0;
        let mut pred = image(&(0..len).map(|i| value(i, 31)).collect::<Vec<_>>());
        let target = image(&(0..len).map(|i| value(i, 17)).collect::<Vec<_>>());
        let (mut partial, mut grad) = (PartialMse::default(), Image::default());
        partial.update(&pred, &target, &mut grad, None);
        // Change values across a block boundary and in the last block.
        let changed = [SUM_BLOCK - 5..SUM_BLOCK + 7, len - 3..len];
        for range in &changed {
            for i in range.clone() {
                pred.data[i] = 1.0 - pred.data[i];
            }
        }
        let loss = partial.update(&pred, &target, &mut grad, Some(&changed[..]));
        let mut whole = Image::default();
        assert_eq!(loss.to_bits(), mse(&pred, &target, &mut whole).to_bits());
        assert_eq!(grad, whole);
    }

    #[test]
    fn mse_over_several_blocks_is_the_plain_mean() {
        // 3 blocks, the last one short and not a multiple of the lanes.
        let len = 2 * SUM_BLOCK + 4003;
        let value = |i: usize, k: usize| ((i * k) % 997) as f32 / 997.0;
        let pred = image(&(0..len).map(|i| value(i, 31)).collect::<Vec<_>>());
        let target = image(&(0..len).map(|i| value(i, 17)).collect::<Vec<_>>());
        let plain = (0..len)
            .map(|i| f64::from((pred.data[i] - target.data[i]).powi(2)))
            .sum::<f64>()
            / len as f64;
        let mut grad = Image::default();
        let loss = mse(&pred, &target, &mut grad);
        assert!(
            (f64::from(loss) - plain).abs() < 1e-7 * plain,
            "{loss} vs {plain}"
        );
        assert_eq!(loss, mse_value(&pred, &target));
        let n = len as f32;
        assert!(
            (0..len).all(|i| grad.data[i] == 2.0 * (pred.data[i] - target.data[i]) / n),
            "the gradient of a pixel is its own"
        );
    }

    #[test]
    fn overlap_penalty_gradient_matches_finite_differences() {
        // Away from the kink at delta.
        let img = image(&[0.49, 0.7, 1.0, 0.3, 0.65, 0.9]);
        let mut grad = Image::default();
        overlap_penalty(&img, 0.6, 2.0, &mut grad);
        check_grad(&img, &grad, |x| {
            overlap_penalty(x, 0.6, 2.0, &mut Image::default())
        });
    }
}
