//! Fewer cubics per closed path by merging neighbouring segments (issue 12).
//!
//! A merge replaces two adjacent cubics by one from the first's start to the second's end,
//! keeping the outer tangent directions and fitting the two handle lengths by least squares
//! (Schneider, "An Algorithm for Automatically Fitting Digitized Curves", Graphics Gems 1990)
//! to samples of the *original* path, so errors do not pile up over repeated merges. Its cost
//! is the area between the merged cubic and the original curve (mean distance × length): about
//! how many pixels change. Each path is merged greedily, cheapest joint first; [`merge_paths`]
//! then takes the globally cheapest merges until the paths hold at most the allowed mean.

use crate::geom::bezier::{bernstein, eval};
use crate::scene::Point;

/// Samples per original segment (the merged fit and its cost are measured on them).
const SAMPLES_PER_SEGMENT: usize = 12;
/// Fewest segments a merged path keeps.
pub const MIN_SEGMENTS: usize = 2;
/// Newton-Raphson reparameterisation rounds per merge fit.
const REPARAMETERISE_ROUNDS: usize = 2;

/// Merges segments of the closed paths (each in [`crate::scene::Path::points`] layout: 3 points
/// per segment) until they hold at most `max_mean` segments per path on average, taking the
/// merges that change the least weighted area first. `weight(i, p, n)` weighs the area at point
/// `p` of path `i`'s original outline, `n` the unit normal there (e.g. the contrast across the
/// outline: a hidden or low-contrast stretch may move freely). Paths are changed in place;
/// returns the segments removed.
pub fn merge_paths(
    paths: &mut [&mut Vec<Point>],
    weight: impl Fn(usize, Point, Point) -> f32,
    max_mean: f32,
) -> usize {
    let total: usize = paths.iter().map(|p| p.len() / 3).sum();
    let allowed = (max_mean * paths.len() as f32).floor() as usize;
    if total <= allowed {
        return 0;
    }
    let weight = &weight;
    let weighted = |i: usize| move |p: Point, n: Point| weight(i, p, n);
    // Each path's greedy merge sequence, as running-maximum costs (so that taking the globally
    // cheapest steps takes every path's steps in order).
    let mut steps: Vec<(f32, usize, usize)> = Vec::new();
    for (i, path) in paths.iter().enumerate() {
        let mut running = 0f32;
        for (k, cost) in greedy(path, usize::MAX, weighted(i))
            .1
            .into_iter()
            .enumerate()
        {
            running = running.max(cost);
            steps.push((running, i, k));
        }
    }
    steps.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let mut count = vec![0usize; paths.len()];
    let needed = total - allowed;
    for &(_, i, _) in steps.iter().take(needed) {
        count[i] += 1;
    }
    let mut removed = 0;
    for (i, (path, &n)) in paths.iter_mut().zip(&count).enumerate() {
        if n > 0 {
            let (merged, costs) = greedy(path, n, weighted(i));
            removed += costs.len();
            **path = merged;
        }
    }
    removed
}

/// Merges the cheapest joint of `points` up to `limit` times (and never below
/// [`MIN_SEGMENTS`]); returns the merged path and each merge's cost in order.
fn greedy(
    points: &[Point],
    limit: usize,
    weight: impl Fn(Point, Point) -> f32,
) -> (Vec<Point>, Vec<f32>) {
    let n = points.len() / 3;
    let segment = |k: usize| {
        [
            points[3 * k],
            points[3 * k + 1],
            points[3 * k + 2],
            points[(3 * k + 3) % points.len()],
        ]
    };
    // Original samples, SAMPLES_PER_SEGMENT per segment starting at its start point, and the
    // weight of each.
    let samples: Vec<Point> = (0..n)
        .flat_map(|k| {
            let c = segment(k);
            (0..SAMPLES_PER_SEGMENT).map(move |j| eval(&c, j as f32 / SAMPLES_PER_SEGMENT as f32))
        })
        .collect();
    let count = samples.len();
    let weights: Vec<f32> = (0..count)
        .map(|i| {
            let along = sub(samples[(i + 1) % count], samples[(i + count - 1) % count]);
            let along = normalise(along);
            weight(samples[i], Point::new(along.y, -along.x))
        })
        .collect();
    // Current segments: the cubic, the first original segment it covers and how many.
    let mut current: Vec<([Point; 4], usize, usize)> = (0..n).map(|k| (segment(k), k, 1)).collect();
    let mut costs = Vec::new();
    // Cost and fit of merging current[j] with its successor, cached until either changes.
    let mut cache: Vec<Option<(f32, [Point; 4])>> = vec![None; n];
    while costs.len() < limit && current.len() > MIN_SEGMENTS {
        let m = current.len();
        for j in 0..m {
            if cache[j].is_none() {
                let (a, b) = (&current[j], &current[(j + 1) % m]);
                cache[j] = Some(merge_cost(&samples, &weights, a.1, a.2 + b.2, &a.0, &b.0));
            }
        }
        let Some((j, (cost, merged))) = cache
            .iter()
            .enumerate()
            .filter_map(|(j, c)| c.map(|c| (j, c)))
            .min_by(|a, b| a.1.0.total_cmp(&b.1.0))
        else {
            break;
        };
        let next = (j + 1) % m;
        current[j].0 = merged;
        current[j].2 += current[next].2;
        current.remove(next);
        cache.remove(next);
        let m = m - 1;
        let j = if next == 0 { j - 1 } else { j };
        cache[j] = None;
        cache[(j + m - 1) % m] = None;
        costs.push(cost);
    }
    let mut out = Vec::with_capacity(3 * current.len());
    for (c, _, _) in &current {
        out.extend_from_slice(&c[..3]);
    }
    (out, costs)
}

/// The one cubic from `a[0]` to `b[3]` along `a`'s start tangent and `b`'s end tangent closest
/// to the samples of `covered` original segments from `first` on (wrapping), and its cost: the
/// weighted area between the two.
fn merge_cost(
    samples: &[Point],
    weights: &[f32],
    first: usize,
    covered: usize,
    a: &[Point; 4],
    b: &[Point; 4],
) -> (f32, [Point; 4]) {
    let count = samples.len();
    let range = first * SAMPLES_PER_SEGMENT..=(first + covered) * SAMPLES_PER_SEGMENT;
    let d: Vec<Point> = range.clone().map(|i| samples[i % count]).collect();
    let weight: Vec<f32> = range.map(|i| weights[i % count]).collect();
    // The span's ends are the current ends (equal to the samples there).
    let (start, end) = (a[0], b[3]);
    let t1 = tangent(a[0], a[1], a[3]);
    let t2 = tangent(b[3], b[2], b[0]);
    let mut u = chord_parameters(&d);
    let mut curve = fit_handles(&d, &u, start, end, t1, t2);
    for _ in 0..REPARAMETERISE_ROUNDS {
        u = reparameterise(&d, &curve, &u);
        curve = fit_handles(&d, &u, start, end, t1, t2);
    }
    let mut area = 0.0;
    for w in 1..d.len() {
        let step = dist(d[w], d[w - 1]);
        area += weight[w] * step * dist(eval(&curve, u[w]), d[w]);
    }
    (area, curve)
}

/// Unit direction from `at` towards `handle`, or towards `far` if the handle sits on `at`.
fn tangent(at: Point, handle: Point, far: Point) -> Point {
    let t = if dist(at, handle) > 1e-4 {
        sub(handle, at)
    } else {
        sub(far, at)
    };
    normalise(t)
}

/// Parameters in [0, 1] proportional to the length along the polyline.
fn chord_parameters(d: &[Point]) -> Vec<f32> {
    let mut u = Vec::with_capacity(d.len());
    let mut total = 0.0;
    u.push(0.0);
    for w in d.windows(2) {
        total += dist(w[0], w[1]);
        u.push(total);
    }
    let last = (d.len() - 1).max(1) as f32;
    u.iter_mut().enumerate().for_each(|(i, v)| {
        *v = if total > 0.0 {
            *v / total
        } else {
            i as f32 / last
        }
    });
    u
}

/// The cubic from `first` to `last` with handles along `t1`, `t2` whose lengths minimise the
/// squared distances to `d[i]` at parameters `u[i]`; thirds of the chord when the system is
/// singular or a handle comes out backwards (Schneider's heuristic).
fn fit_handles(
    d: &[Point],
    u: &[f32],
    first: Point,
    last: Point,
    t1: Point,
    t2: Point,
) -> [Point; 4] {
    let (mut c00, mut c01, mut c11, mut x0, mut x1) = (0.0f64, 0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for (&p, &t) in d.iter().zip(u) {
        let b = bernstein(t);
        let a1 = scale(t1, b[1]);
        let a2 = scale(t2, b[2]);
        c00 += f64::from(dot(a1, a1));
        c01 += f64::from(dot(a1, a2));
        c11 += f64::from(dot(a2, a2));
        let base = Point::new(
            first.x * (b[0] + b[1]) + last.x * (b[2] + b[3]),
            first.y * (b[0] + b[1]) + last.y * (b[2] + b[3]),
        );
        let r = sub(p, base);
        x0 += f64::from(dot(a1, r));
        x1 += f64::from(dot(a2, r));
    }
    let det = c00 * c11 - c01 * c01;
    let chord = dist(first, last);
    let (mut alpha1, mut alpha2) = if det.abs() > 1e-12 {
        (
            ((x0 * c11 - x1 * c01) / det) as f32,
            ((c00 * x1 - c01 * x0) / det) as f32,
        )
    } else {
        (0.0, 0.0)
    };
    let floor = 1e-6 * chord;
    if !(alpha1 > floor && alpha2 > floor && alpha1.is_finite() && alpha2.is_finite()) {
        alpha1 = chord / 3.0;
        alpha2 = chord / 3.0;
    }
    [
        first,
        add(first, scale(t1, alpha1)),
        add(last, scale(t2, alpha2)),
        last,
    ]
}

/// One Newton-Raphson step per point towards the parameter of the closest curve point.
fn reparameterise(d: &[Point], c: &[Point; 4], u: &[f32]) -> Vec<f32> {
    let d1: [Point; 3] = [0, 1, 2].map(|i| scale(sub(c[i + 1], c[i]), 3.0));
    let d2: [Point; 2] = [0, 1].map(|i| scale(sub(d1[i + 1], d1[i]), 2.0));
    d.iter()
        .zip(u)
        .map(|(&p, &t)| {
            let q = eval(c, t);
            let s = 1.0 - t;
            let q1 = add(
                add(scale(d1[0], s * s), scale(d1[1], 2.0 * s * t)),
                scale(d1[2], t * t),
            );
            let q2 = add(scale(d2[0], s), scale(d2[1], t));
            let r = sub(q, p);
            let denominator = dot(q1, q1) + dot(r, q2);
            if denominator.abs() < 1e-12 {
                t
            } else {
                (t - dot(r, q1) / denominator).clamp(0.0, 1.0)
            }
        })
        .collect()
}

fn add(a: Point, b: Point) -> Point {
    Point::new(a.x + b.x, a.y + b.y)
}
fn sub(a: Point, b: Point) -> Point {
    Point::new(a.x - b.x, a.y - b.y)
}
fn scale(a: Point, s: f32) -> Point {
    Point::new(a.x * s, a.y * s)
}
fn dot(a: Point, b: Point) -> f32 {
    a.x * b.x + a.y * b.y
}
fn dist(a: Point, b: Point) -> f32 {
    (a.x - b.x).hypot(a.y - b.y)
}
fn normalise(a: Point) -> Point {
    let len = a.x.hypot(a.y);
    if len > 0.0 { scale(a, 1.0 / len) } else { a }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Path;

    fn polygon(count: usize, radius: impl Fn(f32) -> f32) -> Vec<Point> {
        let vertices: Vec<Point> = (0..count)
            .map(|i| {
                let a = std::f32::consts::TAU * i as f32 / count as f32;
                Point::new(50.0 + radius(a) * a.cos(), 50.0 + radius(a) * a.sin())
            })
            .collect();
        Path::from_polygon(&vertices, [0.0; 3], 1.0).unwrap().points
    }

    /// Largest distance from the dense samples of `a` to the closest sample of `b`.
    fn distance(a: &[Point], b: &[Point]) -> f32 {
        let sample = |p: &[Point]| -> Vec<Point> {
            let n = p.len() / 3;
            (0..n)
                .flat_map(|k| {
                    let c = [
                        p[3 * k],
                        p[3 * k + 1],
                        p[3 * k + 2],
                        p[(3 * k + 3) % p.len()],
                    ];
                    (0..64).map(move |j| eval(&c, j as f32 / 64.0))
                })
                .collect()
        };
        let (a, b) = (sample(a), sample(b));
        a.iter()
            .map(|&p| b.iter().map(|&q| dist(p, q)).fold(f32::MAX, f32::min))
            .fold(0.0, f32::max)
    }

    #[test]
    fn a_polygonal_circle_becomes_a_few_cubics_that_keep_its_shape() {
        let original = polygon(48, |_| 30.0);
        let mut merged = original.clone();
        let removed = merge_paths(&mut [&mut merged], |_, _, _| 1.0, 4.0);
        assert_eq!(removed, 44);
        assert_eq!(merged.len() / 3, 4);
        assert!(
            distance(&original, &merged) < 0.5,
            "{}",
            distance(&original, &merged)
        );
        assert!(distance(&merged, &original) < 0.5);
    }

    #[test]
    fn a_square_with_many_edges_keeps_its_corners() {
        let mut vertices = Vec::new();
        for i in 0..8 {
            let t = i as f32 * 5.0;
            vertices.push(Point::new(10.0 + t, 10.0));
        }
        for i in 0..8 {
            vertices.push(Point::new(50.0, 10.0 + i as f32 * 5.0));
        }
        for i in 0..8 {
            vertices.push(Point::new(50.0 - i as f32 * 5.0, 50.0));
        }
        for i in 0..8 {
            vertices.push(Point::new(10.0, 50.0 - i as f32 * 5.0));
        }
        let original = Path::from_polygon(&vertices, [0.0; 3], 1.0).unwrap().points;
        let mut merged = original.clone();
        merge_paths(&mut [&mut merged], |_, _, _| 1.0, 4.0);
        for corner in [(10.0, 10.0), (50.0, 10.0), (50.0, 50.0), (10.0, 50.0)] {
            assert!(
                merged.contains(&Point::new(corner.0, corner.1)),
                "{corner:?}"
            );
        }
        assert!(distance(&original, &merged) < 1e-3);
    }

    /// The mean bound holds over all paths, and the merges go where they change least: the
    /// smooth circle gives up its segments before the wiggly outline, unless weighted up.
    #[test]
    fn merges_go_to_the_path_they_change_least() {
        let circle = polygon(40, |_| 30.0);
        let wiggly = polygon(40, |a| 30.0 + 6.0 * (8.0 * a).sin());
        let (mut a, mut b) = (circle.clone(), wiggly.clone());
        merge_paths(&mut [&mut a, &mut b], |_, _, _| 1.0, 24.0);
        assert_eq!((a.len() + b.len()) / 3, 48);
        assert!(a.len() < b.len(), "{} {}", a.len() / 3, b.len() / 3);
        // A weight moves merges away from a path.
        let (mut a, mut b) = (circle.clone(), wiggly.clone());
        merge_paths(
            &mut [&mut a, &mut b],
            |i, _, _| if i == 0 { 1e6 } else { 1.0 },
            24.0,
        );
        assert!(a.len() > circle.len() / 2, "{}", a.len() / 3);
        // Under the bound nothing changes.
        let mut c = circle.clone();
        assert_eq!(merge_paths(&mut [&mut c], |_, _, _| 1.0, 40.0), 0);
        assert_eq!(c, circle);
    }
}
