//! Cubic Bézier curves: evaluation, Bernstein weights and flattening at uniform parameters.
//!
//! The renderer flattens every segment at `t_k = k / n`. Because those parameters are fixed for a
//! given render, each flattened vertex is a fixed linear combination of the four control points
//! (`B(t) = Σ_j b_j(t) P_j`), which is how gradients reach the control points exactly.

use std::sync::LazyLock;

use crate::scene::Point;

/// Default flattening tolerance in pixels: the largest distance between a cubic and its
/// flattened polyline. 0.1 px keeps the area error of a typical edge far below what an 8-bit
/// image shows while keeping the number of line pieces (and so the cost) proportional to the
/// perimeter.
pub const FLATTEN_TOLERANCE: f32 = 0.1;

/// Upper bound on the number of lines one cubic is flattened into. Only curves whose control
/// polygon spans thousands of pixels hit it; beyond it the tolerance is no longer guaranteed.
pub const MAX_LINES_PER_CUBIC: u32 = 1024;

/// The cubic Bernstein weights `[(1-t)³, 3(1-t)²t, 3(1-t)t², t³]`.
#[inline]
pub fn bernstein(t: f32) -> [f32; 4] {
    let s = 1.0 - t;
    [s * s * s, 3.0 * s * s * t, 3.0 * s * t * t, t * t * t]
}

/// The point at parameter `t` of the cubic with control points `c`.
#[inline]
pub fn eval(c: &[Point; 4], t: f32) -> Point {
    eval_weighted(c, bernstein(t))
}

/// The point of the cubic with control points `c` whose Bernstein weights are `w`.
#[inline]
pub fn eval_weighted(c: &[Point; 4], w: [f32; 4]) -> Point {
    Point::new(
        w[0] * c[0].x + w[1] * c[1].x + w[2] * c[2].x + w[3] * c[3].x,
        w[0] * c[0].y + w[1] * c[1].y + w[2] * c[2].y + w[3] * c[3].y,
    )
}

/// The cubic's two halves, `t ∈ [0, ½]` and `[½, 1]` (de Casteljau): together they trace the
/// same curve, so splitting a segment changes no pixel.
pub fn split_half(c: &[Point; 4]) -> [[Point; 4]; 2] {
    let mid = |u: Point, v: Point| Point::new(0.5 * (u.x + v.x), 0.5 * (u.y + v.y));
    let (ab, bc, cd) = (mid(c[0], c[1]), mid(c[1], c[2]), mid(c[2], c[3]));
    let (abc, bcd) = (mid(ab, bc), mid(bc, cd));
    let centre = mid(abc, bcd);
    [[c[0], ab, abc, centre], [centre, bcd, cd, c[3]]]
}

/// The number of lines `n` such that the polyline through `B(k/n)`, `k = 0..=n`, stays within
/// `tolerance` pixels of the cubic, clamped to `1..=MAX_LINES_PER_CUBIC`.
///
/// Bound: `B''(t) = 6[(1-t)(P0 - 2P1 + P2) + t(P1 - 2P2 + P3)]`, so `|B''| ≤ 6M` with `M` the
/// larger second difference of the control polygon, and a chord over a parameter interval of
/// length `1/n` deviates from the curve by at most `|B''|max / (8 n²)`. Hence
/// `n = ceil(sqrt(3M / (4 tolerance)))`. Non-finite input gives 1.
pub fn lines_for_tolerance(c: &[Point; 4], tolerance: f32) -> u32 {
    let d1x = c[0].x - 2.0 * c[1].x + c[2].x;
    let d1y = c[0].y - 2.0 * c[1].y + c[2].y;
    let d2x = c[1].x - 2.0 * c[2].x + c[3].x;
    let d2y = c[1].y - 2.0 * c[2].y + c[3].y;
    let m = (d1x * d1x + d1y * d1y).max(d2x * d2x + d2y * d2y).sqrt();
    let n = (0.75 * m / tolerance.max(1e-6)).sqrt().ceil();
    if n.is_finite() {
        (n as u32).clamp(1, MAX_LINES_PER_CUBIC)
    } else {
        1
    }
}

/// The parameter `t_k = k/n` of the `k`-th flattened vertex, computed the one way every user
/// (flattening and gradient chaining) must agree on.
#[inline]
pub fn parameter(k: u32, n: u32) -> f32 {
    k as f32 / n as f32
}

/// Line counts whose vertex weights [`weight_table`] holds: a cubic is flattened into
/// at least 16 lines (the renderer's minimum) and, at the working sizes, rarely more than 64.
/// The table is 2 080 entries of 16 bytes, 32.5 KiB.
const TABLED_LINES: u32 = 64;

/// `bernstein(parameter(k, n))` for `n = 1..=TABLED_LINES`, `k = 0..n`: entry `n(n−1)/2 + k`.
static WEIGHT_TABLE: LazyLock<Vec<[f32; 4]>> = LazyLock::new(|| {
    (1..=TABLED_LINES)
        .flat_map(|n| (0..n).map(move |k| bernstein(parameter(k, n))))
        .collect()
});

/// The table of the weights of the `n` flattened vertices `B(t_k)`, `k = 0..n`, if `n` is one
/// of the common counts: the renderer needs them at every vertex of every render and its
/// backward. Read it with [`weight`].
pub fn weight_table(n: u32) -> Option<&'static [[f32; 4]]> {
    (1..=TABLED_LINES).contains(&n).then(|| {
        let start = (n * (n - 1) / 2) as usize;
        &WEIGHT_TABLE[start..start + n as usize]
    })
}

/// Exactly `bernstein(parameter(k, n))`: from `table` ([`weight_table`] of `n`) when there is one.
#[inline]
pub fn weight(table: Option<&[[f32; 4]]>, k: u32, n: u32) -> [f32; 4] {
    match table {
        Some(table) => table[k as usize],
        None => bernstein(parameter(k, n)),
    }
}

/// Appends the flattened vertices `B(t_k)` for `k = 0..n` (the end point `B(1)` is left out: in
/// a closed path it is the next segment's start). `B(0)` is the start point itself.
pub fn flatten_into(c: &[Point; 4], n: u32, out: &mut Vec<Point>) {
    out.push(c[0]);
    for k in 1..n {
        out.push(eval(c, parameter(k, n)));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_halves_trace_the_whole() {
        let c = [
            Point::new(0.0, 0.0),
            Point::new(3.0, 9.0),
            Point::new(7.0, -4.0),
            Point::new(10.0, 2.0),
        ];
        let [first, second] = split_half(&c);
        for i in 0..=10 {
            let t = i as f32 / 10.0;
            let whole = eval(&c, t);
            let half = if t <= 0.5 {
                eval(&first, 2.0 * t)
            } else {
                eval(&second, 2.0 * t - 1.0)
            };
            assert!((whole.x - half.x).abs() < 1e-4 && (whole.y - half.y).abs() < 1e-4);
        }
    }

    fn arc() -> [Point; 4] {
        // A quarter circle of radius 10 (the usual 4-cubic circle's kappa).
        let k = 10.0 * 0.552_284_8;
        [
            Point::new(10.0, 0.0),
            Point::new(10.0, k),
            Point::new(k, 10.0),
            Point::new(0.0, 10.0),
        ]
    }

    #[test]
    fn bernstein_weights_partition_unity() {
        for i in 0..=10 {
            let w = bernstein(i as f32 / 10.0);
            assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        }
        assert_eq!(eval(&arc(), 0.0), arc()[0]);
        assert_eq!(eval(&arc(), 1.0), arc()[3]);
    }

    #[test]
    fn flattening_meets_the_tolerance() {
        let c = arc();
        for tol in [1.0, 0.1, 0.01] {
            let n = lines_for_tolerance(&c, tol);
            let mut pts = Vec::new();
            flatten_into(&c, n, &mut pts);
            pts.push(c[3]);
            // Distance from densely sampled curve points to their chord.
            let mut worst = 0.0f32;
            for k in 0..n as usize {
                let (a, b) = (pts[k], pts[k + 1]);
                for j in 0..=20 {
                    let t = (k as f32 + j as f32 / 20.0) / n as f32;
                    let p = eval(&c, t);
                    let (dx, dy) = (b.x - a.x, b.y - a.y);
                    let d =
                        ((p.x - a.x) * dy - (p.y - a.y) * dx).abs() / (dx * dx + dy * dy).sqrt();
                    worst = worst.max(d);
                }
            }
            assert!(
                worst <= tol,
                "tolerance {tol}: deviation {worst} with {n} lines"
            );
        }
    }

    #[test]
    fn straight_and_degenerate_cubics_take_one_line() {
        let line = [
            Point::new(0.0, 0.0),
            Point::new(1.0, 1.0),
            Point::new(2.0, 2.0),
            Point::new(3.0, 3.0),
        ];
        assert_eq!(lines_for_tolerance(&line, 0.1), 1);
        let bad = [Point::new(f32::NAN, 0.0); 4];
        assert_eq!(lines_for_tolerance(&bad, 0.1), 1);
    }
}
