//! Losses on rendered images, each returning its value and writing dLoss/dPixel, plus the two
//! compositing models with their backward passes:
//! - two-layer model of the structure and refinement stages: `R(A) · R(I)`;
//! - the SVG model of the final file: `clamp01(R(A) · R(S) + R(L))`.

use crate::render::Image;

/// Mean squared error over pixels × channels; writes dLoss/dPred into `grad` (resized).
pub fn mse(pred: &Image, target: &Image, grad: &mut Image) -> f32 {
    debug_assert_eq!(pred.data.len(), target.data.len());
    resize_like(grad, pred);
    let n = pred.data.len().max(1) as f32;
    let mut sum = 0.0f64;
    for ((g, &p), &t) in grad.data.iter_mut().zip(&pred.data).zip(&target.data) {
        let d = p - t;
        sum += f64::from(d * d);
        *g = 2.0 * d / n;
    }
    (sum / f64::from(n)) as f32
}

/// Mean squared error without gradient.
pub fn mse_value(pred: &Image, target: &Image) -> f32 {
    let n = pred.data.len().max(1) as f64;
    let sum: f64 = pred
        .data
        .iter()
        .zip(&target.data)
        .map(|(&p, &t)| f64::from((p - t) * (p - t)))
        .sum();
    (sum / n) as f32
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

/// `out = a · b` per value.
pub fn multiply(a: &Image, b: &Image, out: &mut Image) {
    resize_like(out, a);
    for ((o, &x), &y) in out.data.iter_mut().zip(&a.data).zip(&b.data) {
        *o = x * y;
    }
}

/// Backward of [`multiply`]: `d_a = d_out · b`, `d_b = d_out · a` (either may be skipped).
pub fn multiply_backward(
    d_out: &Image,
    a: &Image,
    b: &Image,
    d_a: Option<&mut Image>,
    d_b: Option<&mut Image>,
) {
    if let Some(d_a) = d_a {
        resize_like(d_a, a);
        for ((d, &g), &y) in d_a.data.iter_mut().zip(&d_out.data).zip(&b.data) {
            *d = g * y;
        }
    }
    if let Some(d_b) = d_b {
        resize_like(d_b, b);
        for ((d, &g), &x) in d_b.data.iter_mut().zip(&d_out.data).zip(&a.data) {
            *d = g * x;
        }
    }
}

/// The SVG model: `out = clamp01(a · s + l)`.
pub fn svg_composite(a: &Image, s: &Image, l: &Image, out: &mut Image) {
    resize_like(out, a);
    for (i, o) in out.data.iter_mut().enumerate() {
        *o = (a.data[i] * s.data[i] + l.data[i]).clamp(0.0, 1.0);
    }
}

/// Backward of [`svg_composite`]; the clamp passes gradient only where `0 < a·s + l < 1`.
pub fn svg_composite_backward(
    d_out: &Image,
    a: &Image,
    s: &Image,
    l: &Image,
    grads: [&mut Image; 3],
) {
    let [d_a, d_s, d_l] = grads;
    for d in [&mut *d_a, &mut *d_s, &mut *d_l] {
        resize_like(d, a);
    }
    for i in 0..a.data.len() {
        let v = a.data[i] * s.data[i] + l.data[i];
        let g = if v > 0.0 && v < 1.0 {
            d_out.data[i]
        } else {
            0.0
        };
        d_a.data[i] = g * s.data[i];
        d_s.data[i] = g * a.data[i];
        d_l.data[i] = g;
    }
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
    fn overlap_penalty_gradient_matches_finite_differences() {
        // Away from the kink at delta.
        let img = image(&[0.49, 0.7, 1.0, 0.3, 0.65, 0.9]);
        let mut grad = Image::default();
        overlap_penalty(&img, 0.6, 2.0, &mut grad);
        check_grad(&img, &grad, |x| {
            overlap_penalty(x, 0.6, 2.0, &mut Image::default())
        });
    }

    #[test]
    fn composite_gradients_match_finite_differences() {
        let a = image(&[0.2, 0.5, 0.9, 0.3, 0.8, 0.6]);
        let s = image(&[0.7, 1.5, 0.4, 0.9, 0.5, 0.3]);
        let l = image(&[0.1, 0.0, 0.3, 0.2, 0.05, 0.9]);
        let target = image(&[0.3, 0.6, 0.5, 0.2, 0.1, 0.4]);
        let loss_of = |a: &Image, s: &Image, l: &Image| {
            let mut out = Image::default();
            svg_composite(a, s, l, &mut out);
            mse_value(&out, &target)
        };
        let mut out = Image::default();
        svg_composite(&a, &s, &l, &mut out);
        let mut d_out = Image::default();
        mse(&out, &target, &mut d_out);
        let (mut d_a, mut d_s, mut d_l) = (Image::default(), Image::default(), Image::default());
        svg_composite_backward(&d_out, &a, &s, &l, [&mut d_a, &mut d_s, &mut d_l]);
        check_grad(&a, &d_a, |x| loss_of(x, &s, &l));
        check_grad(&s, &d_s, |x| loss_of(&a, x, &l));
        check_grad(&l, &d_l, |x| loss_of(&a, &s, x));

        let product_loss = |a: &Image, b: &Image| {
            let mut out = Image::default();
            multiply(a, b, &mut out);
            mse_value(&out, &target)
        };
        multiply(&a, &s, &mut out);
        mse(&out, &target, &mut d_out);
        multiply_backward(&d_out, &a, &s, Some(&mut d_a), Some(&mut d_s));
        check_grad(&a, &d_a, |x| product_loss(x, &s));
        check_grad(&s, &d_s, |x| product_loss(&a, x));
    }
}
