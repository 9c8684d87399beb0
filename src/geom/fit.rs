//! Few smooth cubics for a closed outline: corners split it into spans, and each span is fitted
//! by Schneider's least-squares cubic fit ("An Algorithm for Automatically Fitting Digitized
//! Curves", Graphics Gems, 1990), split at its worst point until every input point lies within
//! the tolerance of its fitted cubic.
//!
//! Traced pixel boundaries are staircases; [`smooth_closed`] takes the steps out first, so that
//! the fit follows the shape and not the pixel grid.

use crate::scene::Point;

/// How an outline is fitted.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FitSettings {
    /// Largest distance, in pixels, from an input point to the curve at its parameter.
    pub tolerance: f32,
    /// A point turning by more than this (radians), measured over `corner_reach` points on
    /// either side, and more than its neighbours, is a corner: the curve may break there.
    pub corner_angle: f32,
    /// Points on either side over which the turning angle is measured.
    pub corner_reach: usize,
}

impl Default for FitSettings {
    fn default() -> Self {
        Self {
            tolerance: 1.0,
            corner_angle: 70f32.to_radians(),
            corner_reach: 4,
        }
    }
}

/// Fits a closed outline (points in order, the last joining the first) with cubics, returned in
/// [`crate::scene::Path::points`] layout: 3 points per segment, `[P0, C0a, C0b, P1, …]`, the
/// last segment ending at `P0`. Every input point lies within `settings.tolerance` of the curve.
/// Fewer than 3 points give one straight cubic per edge.
pub fn fit_closed(points: &[Point], settings: &FitSettings) -> Vec<Point> {
    fit_closed_with_slack(points, &vec![0.0; points.len()], settings)
}

/// [`fit_closed`] where point `i` may lie up to `settings.tolerance + slack[i]` from the curve,
/// e.g. where nobody will see the outline.
///
/// # Panics
/// If `slack` and `points` differ in length.
pub fn fit_closed_with_slack(
    points: &[Point],
    slack: &[f32],
    settings: &FitSettings,
) -> Vec<Point> {
    assert_eq!(points.len(), slack.len(), "one slack per point");
    let n = points.len();
    if n < 3 {
        return straight_cubics(points);
    }
    let found = corners(points, settings.corner_reach, settings.corner_angle);
    fit_with_corners(points, slack, found, settings)
}

fn fit_with_corners(
    points: &[Point],
    slack: &[f32],
    mut corners: Vec<usize>,
    settings: &FitSettings,
) -> Vec<Point> {
    let n = points.len();
    let smooth_start = corners.is_empty();
    if smooth_start {
        // No corner: start anywhere (point 0) with a tangent continuous through the start.
        corners.push(0);
    }
    let mut out = Vec::new();
    for (k, &first) in corners.iter().enumerate() {
        let next = corners[(k + 1) % corners.len()];
        // A span runs first..=last in unwrapped indices (the whole loop for one corner).
        let last = if next > first { next } else { next + n };
        let span: Vec<Point> = (first..=last).map(|i| points[i % n]).collect();
        let tolerances: Vec<f32> = (first..=last)
            .map(|i| settings.tolerance + slack[i % n].max(0.0))
            .collect();
        let (start_tangent, end_tangent) = if smooth_start {
            let t = centre_tangent(points, 0, settings.corner_reach);
            (t, scale(t, -1.0))
        } else {
            (
                end_tangent_at(&span, false, settings.corner_reach),
                end_tangent_at(&span, true, settings.corner_reach),
            )
        };
        fit_span(&span, &tolerances, start_tangent, end_tangent, &mut out);
    }
    out
}

/// Refits a closed path (in [`crate::scene::Path::points`] layout) with fewer cubics: the curve
/// is sampled about every half pixel, its joints where the tangent turns by more than
/// `settings.corner_angle` stay corners, and the samples are fitted within `settings.tolerance`.
pub fn refit_path(points: &[Point], settings: &FitSettings) -> Vec<Point> {
    let n = points.len() / 3;
    if n < 2 {
        return points.to_vec();
    }
    let segment = |k: usize| {
        [
            points[3 * k],
            points[3 * k + 1],
            points[3 * k + 2],
            points[(3 * k + 3) % points.len()],
        ]
    };
    let mut samples = Vec::new();
    let mut joint_is_corner = Vec::new();
    for k in 0..n {
        let c = segment(k);
        let length = dist(c[0], c[1]) + dist(c[1], c[2]) + dist(c[2], c[3]);
        let steps = ((2.0 * length).ceil() as usize).clamp(1, 256);
        // Tangent in at the joint (end of the previous segment) and out of it.
        let prev = segment((k + n - 1) % n);
        let t_in = normalise(if dist(prev[3], prev[2]) > 1e-4 {
            sub(prev[3], prev[2])
        } else {
            sub(prev[3], prev[0])
        });
        let t_out = normalise(if dist(c[1], c[0]) > 1e-4 {
            sub(c[1], c[0])
        } else {
            sub(c[3], c[0])
        });
        let turn = (t_in.x * t_out.y - t_in.y * t_out.x)
            .atan2(dot(t_in, t_out))
            .abs();
        joint_is_corner.push((samples.len(), turn > settings.corner_angle));
        for j in 0..steps {
            samples.push(crate::geom::bezier::eval(&c, j as f32 / steps as f32));
        }
    }
    let corners: Vec<usize> = joint_is_corner
        .iter()
        .filter(|(_, c)| *c)
        .map(|(i, _)| *i)
        .collect();
    fit_with_corners(&samples, &vec![0.0; samples.len()], corners, settings)
}

/// Circular Gaussian smoothing of a closed polyline (σ in points); σ ≤ 0 returns it unchanged.
pub fn smooth_closed(points: &[Point], sigma: f32) -> Vec<Point> {
    let n = points.len();
    if sigma <= 0.0 || n < 3 {
        return points.to_vec();
    }
    let radius = ((3.0 * sigma).ceil() as usize).min((n - 1) / 2);
    let weights: Vec<f32> = (0..=2 * radius)
        .map(|i| (-((i as f32 - radius as f32).powi(2)) / (2.0 * sigma * sigma)).exp())
        .collect();
    let total: f32 = weights.iter().sum();
    (0..n)
        .map(|i| {
            let (mut x, mut y) = (0.0, 0.0);
            for (k, w) in weights.iter().enumerate() {
                let p = points[(i + n + k - radius) % n];
                x += w * p.x;
                y += w * p.y;
            }
            Point::new(x / total, y / total)
        })
        .collect()
}

/// Indices of corner points, ascending: local maxima (strictly ahead of earlier equal ones) of
/// the turning angle between `p[i] − p[i−reach]` and `p[i+reach] − p[i]` above `min_angle`.
pub fn corners(points: &[Point], reach: usize, min_angle: f32) -> Vec<usize> {
    let n = points.len();
    let reach = reach.clamp(1, (n.max(3) - 1) / 2);
    let angle: Vec<f32> = (0..n)
        .map(|i| {
            let a = points[(i + n - reach) % n];
            let (b, c) = (points[i], points[(i + reach) % n]);
            let (u, v) = (sub(b, a), sub(c, b));
            let cross = u.x * v.y - u.y * v.x;
            let dot = u.x * v.x + u.y * v.y;
            cross.atan2(dot).abs()
        })
        .collect();
    (0..n)
        .filter(|&i| {
            angle[i] > min_angle
                && (1..=reach).all(|d| {
                    let (before, after) = (angle[(i + n - d) % n], angle[(i + d) % n]);
                    angle[i] > before && angle[i] >= after
                })
        })
        .collect()
}

/// Fits `d` (at least 2 points) with cubics from `d[0]` to `d[last]`, each `d[i]` within
/// `tolerance[i]`, appending each segment's first three control points to `out`.
fn fit_span(d: &[Point], tolerance: &[f32], t1: Point, t2: Point, out: &mut Vec<Point>) {
    let last = d.len() - 1;
    if last <= 1 || dist(d[0], d[last]) < 1e-6 && last < 3 {
        push_segment(out, line_cubic(d[0], d[last]));
        return;
    }
    let mut u = chord_parameters(d);
    let mut curve = least_squares_cubic(d, &u, t1, t2);
    // Errors are relative to each point's tolerance: ≤ 1 means within it.
    let (mut error, mut split) = max_error(d, tolerance, &curve, &u);
    if error <= 1.0 {
        push_segment(out, curve);
        return;
    }
    // Close misses are often fixed by better parameters (Schneider's Newton-Raphson step).
    if error <= 4.0 {
        for _ in 0..4 {
            u = reparameterise(d, &curve, &u);
            curve = least_squares_cubic(d, &u, t1, t2);
            (error, split) = max_error(d, tolerance, &curve, &u);
            if error <= 1.0 {
                push_segment(out, curve);
                return;
            }
        }
    }
    let split = split.clamp(1, last - 1);
    let centre = normalise(sub(d[split - 1], d[split + 1]));
    fit_span(&d[..=split], &tolerance[..=split], t1, centre, out);
    fit_span(
        &d[split..],
        &tolerance[split..],
        scale(centre, -1.0),
        t2,
        out,
    );
}

fn push_segment(out: &mut Vec<Point>, c: [Point; 4]) {
    out.extend_from_slice(&c[..3]);
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
    if total > 0.0 {
        u.iter_mut().for_each(|v| *v /= total);
    } else {
        let n = (d.len() - 1) as f32;
        u.iter_mut()
            .enumerate()
            .for_each(|(i, v)| *v = i as f32 / n);
    }
    u
}

/// The cubic from `d[0]` to `d[last]` with handles along `t1`, `t2` whose lengths minimise the
/// squared distances to `d[i]` at parameters `u[i]`; falls back to thirds of the chord when
/// the system is singular or a handle comes out backwards (Schneider's heuristic).
fn least_squares_cubic(d: &[Point], u: &[f32], t1: Point, t2: Point) -> [Point; 4] {
    let (first, last) = (d[0], d[d.len() - 1]);
    let (mut c00, mut c01, mut c11, mut x0, mut x1) = (0.0f64, 0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for (&p, &t) in d.iter().zip(u) {
        let b = crate::geom::bezier::bernstein(t);
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

/// The largest ratio of the distance from `d[i]` to the curve at `u[i]` to `tolerance[i]`, and
/// where it occurs.
fn max_error(d: &[Point], tolerance: &[f32], c: &[Point; 4], u: &[f32]) -> (f32, usize) {
    let mut worst = (0.0f32, d.len() / 2);
    for (i, (&p, &t)) in d.iter().zip(u).enumerate() {
        let e = dist(crate::geom::bezier::eval(c, t), p) / tolerance[i].max(1e-6);
        if e > worst.0 {
            worst = (e, i);
        }
    }
    worst
}

/// One Newton-Raphson step per point towards the parameter of the closest curve point.
fn reparameterise(d: &[Point], c: &[Point; 4], u: &[f32]) -> Vec<f32> {
    let d1: [Point; 3] = [0, 1, 2].map(|i| scale(sub(c[i + 1], c[i]), 3.0));
    let d2: [Point; 2] = [0, 1].map(|i| scale(sub(d1[i + 1], d1[i]), 2.0));
    d.iter()
        .zip(u)
        .map(|(&p, &t)| {
            let q = crate::geom::bezier::eval(c, t);
            let s = 1.0 - t;
            let q1 = add(
                add(scale(d1[0], s * s), scale(d1[1], 2.0 * s * t)),
                scale(d1[2], t * t),
            );
            let q2 = add(scale(d2[0], s), scale(d2[1], t));
            let r = sub(q, p);
            let numerator = dot(r, q1);
            let denominator = dot(q1, q1) + dot(r, q2);
            if denominator.abs() < 1e-12 {
                t
            } else {
                (t - numerator / denominator).clamp(0.0, 1.0)
            }
        })
        .collect()
}

/// Unit tangent pointing into the span at its start (`at_end` false) or out of it backwards at
/// its end, from the point `reach` steps in (or the far end of a short span).
fn end_tangent_at(span: &[Point], at_end: bool, reach: usize) -> Point {
    let last = span.len() - 1;
    let k = reach.clamp(1, last.max(1));
    let t = if at_end {
        sub(span[last - k.min(last)], span[last])
    } else {
        sub(span[k.min(last)], span[0])
    };
    let t = normalise(t);
    if dot(t, t) > 0.0 {
        t
    } else if at_end {
        normalise(sub(span[0], span[last]))
    } else {
        normalise(sub(span[last], span[0]))
    }
}

/// Unit tangent of a closed polyline at `i` (forward direction), from the points `reach` away.
fn centre_tangent(points: &[Point], i: usize, reach: usize) -> Point {
    let n = points.len();
    let reach = reach.clamp(1, (n - 1) / 2);
    normalise(sub(points[(i + reach) % n], points[(i + n - reach) % n]))
}

fn line_cubic(a: Point, b: Point) -> [Point; 4] {
    let third = scale(sub(b, a), 1.0 / 3.0);
    [a, add(a, third), sub(b, third), b]
}

fn straight_cubics(points: &[Point]) -> Vec<Point> {
    let mut out = Vec::with_capacity(3 * points.len());
    for (i, &a) in points.iter().enumerate() {
        push_segment(&mut out, line_cubic(a, points[(i + 1) % points.len()]));
    }
    out
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
    use crate::geom::bezier::eval;

    /// Distance from `p` to the closed curve, by dense sampling.
    fn distance_to_curve(points: &[Point], p: Point) -> f32 {
        let n = points.len() / 3;
        let mut best = f32::MAX;
        for k in 0..n {
            let c = [
                points[3 * k],
                points[3 * k + 1],
                points[3 * k + 2],
                points[(3 * k + 3) % points.len()],
            ];
            for j in 0..=200 {
                best = best.min(dist(eval(&c, j as f32 / 200.0), p));
            }
        }
        best
    }

    fn circle(radius: f32, count: usize) -> Vec<Point> {
        (0..count)
            .map(|i| {
                let a = std::f32::consts::TAU * i as f32 / count as f32;
                Point::new(50.0 + radius * a.cos(), 50.0 + radius * a.sin())
            })
            .collect()
    }

    #[test]
    fn a_circle_takes_a_few_smooth_cubics_within_the_tolerance() {
        let points = circle(30.0, 188);
        let settings = FitSettings::default();
        assert!(corners(&points, settings.corner_reach, settings.corner_angle).is_empty());
        let fitted = fit_closed(&points, &settings);
        let segments = fitted.len() / 3;
        assert!((2..=6).contains(&segments), "{segments} segments");
        for &p in &points {
            assert!(distance_to_curve(&fitted, p) <= settings.tolerance + 1e-3);
        }
    }

    #[test]
    fn a_square_breaks_at_its_four_corners() {
        let mut points = Vec::new();
        for i in 0..40 {
            points.push(Point::new(10.0 + i as f32, 10.0));
        }
        for i in 0..40 {
            points.push(Point::new(50.0, 10.0 + i as f32));
        }
        for i in 0..40 {
            points.push(Point::new(50.0 - i as f32, 50.0));
        }
        for i in 0..40 {
            points.push(Point::new(10.0, 50.0 - i as f32));
        }
        let settings = FitSettings::default();
        assert_eq!(
            corners(&points, 4, settings.corner_angle),
            vec![0, 40, 80, 120]
        );
        let fitted = fit_closed(&points, &settings);
        assert_eq!(fitted.len() / 3, 4);
        for corner in [(10.0, 10.0), (50.0, 10.0), (50.0, 50.0), (10.0, 50.0)] {
            assert!(fitted.contains(&Point::new(corner.0, corner.1)));
        }
    }

    /// A wiggly outline needs more segments at a tighter tolerance, and always meets it.
    #[test]
    fn tighter_tolerances_cost_segments_and_hold_the_bound() {
        let points: Vec<Point> = (0..400)
            .map(|i| {
                let a = std::f32::consts::TAU * i as f32 / 400.0;
                let r = 40.0 + 6.0 * (7.0 * a).sin() + 2.0 * (23.0 * a).cos();
                Point::new(60.0 + r * a.cos(), 60.0 + r * a.sin())
            })
            .collect();
        let mut last = 0;
        for tolerance in [4.0, 1.0, 0.25] {
            let settings = FitSettings {
                tolerance,
                ..FitSettings::default()
            };
            let fitted = fit_closed(&points, &settings);
            for &p in &points {
                assert!(
                    distance_to_curve(&fitted, p) <= tolerance + 1e-3,
                    "{tolerance}"
                );
            }
            assert!(fitted.len() / 3 > last, "{tolerance}: {}", fitted.len() / 3);
            last = fitted.len() / 3;
        }
    }

    #[test]
    fn smoothing_takes_the_steps_out_of_a_staircase() {
        // A 45° staircase of unit steps: smoothed points lie near the diagonal.
        let mut points = Vec::new();
        for i in 0..30 {
            points.push(Point::new(i as f32, i as f32));
            points.push(Point::new(i as f32 + 1.0, i as f32));
        }
        for i in (0..30).rev() {
            points.push(Point::new(i as f32 - 20.0, i as f32 + 20.0));
        }
        let smooth = smooth_closed(&points, 1.0);
        for p in &smooth[5..50] {
            assert!((p.x - p.y - 0.5).abs() < 0.1, "{p:?}");
        }
    }
}
