//! Outer boundaries of pixel regions, and Douglas-Peucker simplification of closed polygons.
//!
//! A region is a set of pixels; pixel (x, y) covers [x, x+1) × [y, y+1). Its outer boundary is
//! walked along pixel edges ("crack following") with 4-connectivity, and reported as the
//! midpoints of the boundary edges: on a staircase those lie on the true diagonal, so the
//! simplified polygon hugs the region instead of its corners.

use crate::scene::Point;

/// Douglas-Peucker tolerance on an edge, in pixels: 1 px per 256 px of long side, at least 1
/// (LayerVec uses 5 px at 512²; finer keeps small features for the 2-decimal SVG at no path
/// cost).
pub fn simplify_tolerance(width: usize, height: usize) -> f32 {
    (width.max(height) as f32 / 256.0).max(1.0)
}

/// The outer boundary of the 4-connected region containing `start`, clockwise on screen
/// (y down), as midpoints of its boundary pixel edges.
///
/// `start` must be the region's first pixel in raster order (topmost, then leftmost) and
/// `inside(x, y)` must be true for it; `inside` is asked about pixels just outside the canvas
/// too and must answer false there.
pub fn trace_outer_boundary(start: (i64, i64), inside: impl Fn(i64, i64) -> bool) -> Vec<Point> {
    // Directions clockwise on screen: +x, +y, -x, -y.
    const STEPS: [(i64, i64); 4] = [(1, 0), (0, 1), (-1, 0), (0, -1)];
    let (sx, sy) = start;
    debug_assert!(inside(sx, sy) && !inside(sx - 1, sy) && !inside(sx, sy - 1));
    // Walk the top edge of the start pixel first, the region on the right-hand side.
    let mut points = vec![Point::new(sx as f32 + 0.5, sy as f32)];
    let (mut x, mut y, mut dir) = (sx + 1, sy, 0usize);
    // The start vertex touches only the start pixel, so it is reached exactly once: at the end.
    while (x, y) != (sx, sy) {
        let (dx, dy) = STEPS[dir];
        let (rx, ry) = (-dy, dx);
        let pixel_at = |qx: i64, qy: i64| inside(x + qx.min(0), y + qy.min(0));
        let ahead_right = pixel_at(dx + rx, dy + ry);
        let ahead_left = pixel_at(dx - rx, dy - ry);
        dir = if !ahead_right {
            (dir + 1) % 4
        } else if ahead_left {
            (dir + 3) % 4
        } else {
            dir
        };
        let (dx, dy) = STEPS[dir];
        points.push(Point::new(
            x as f32 + dx as f32 * 0.5,
            y as f32 + dy as f32 * 0.5,
        ));
        x += dx;
        y += dy;
    }
    points
}

/// Douglas-Peucker simplification of a closed polygon: every dropped vertex `p` lies within
/// `tolerance(p)` of the kept polygon (a tolerance of its own at each vertex lets an outline be
/// coarser where it matters less). Keeps at least 3 vertices when the input has 3 that are
/// not all the same point.
pub fn simplify_closed(points: &[Point], tolerance: impl Fn(Point) -> f32) -> Vec<Point> {
    let tolerances: Vec<f32> = points.iter().map(|&p| tolerance(p)).collect();
    let n = points.len();
    if n <= 3 {
        return points.to_vec();
    }
    // Split at two extreme vertices so both halves are open chains with distinct ends.
    let far_from = |from: Point| {
        (0..n)
            .max_by(|&i, &j| {
                dist2(points[i], from)
                    .total_cmp(&dist2(points[j], from))
                    .then(j.cmp(&i))
            })
            .unwrap_or(0)
    };
    let a = far_from(points[0]);
    let b = far_from(points[a]);
    let mut keep = vec![false; n];
    keep[a] = true;
    keep[b] = true;
    simplify_chain(points, a, b, &tolerances, &mut keep);
    simplify_chain(points, b, a, &tolerances, &mut keep);
    if keep.iter().filter(|&&k| k).count() < 3 {
        // A sliver: keep the vertex farthest from the a-b line to make a triangle.
        let far = (0..n)
            .max_by(|&i, &j| {
                segment_distance(points[i], points[a], points[b])
                    .total_cmp(&segment_distance(points[j], points[a], points[b]))
                    .then(j.cmp(&i))
            })
            .unwrap_or(0);
        keep[far] = true;
    }
    // Start the output at `a` so the result does not depend on where tracing began.
    (0..n)
        .map(|k| (a + k) % n)
        .filter(|&i| keep[i])
        .map(|i| points[i])
        .collect()
}

/// Marks the vertices to keep on the chain from `first` to `last` (indices modulo n, going up):
/// the vertex farthest out of its tolerance, while one is.
fn simplify_chain(
    points: &[Point],
    first: usize,
    last: usize,
    tolerances: &[f32],
    keep: &mut [bool],
) {
    let n = points.len();
    let len = (last + n - first) % n;
    let mut stack = vec![(0usize, len)];
    while let Some((lo, hi)) = stack.pop() {
        if hi <= lo + 1 {
            continue;
        }
        let (p, q) = (points[(first + lo) % n], points[(first + hi) % n]);
        let mut worst = (lo, -1.0f32);
        for k in lo + 1..hi {
            let i = (first + k) % n;
            let d = segment_distance(points[i], p, q) / tolerances[i];
            if d > worst.1 {
                worst = (k, d);
            }
        }
        if worst.1 > 1.0 {
            keep[(first + worst.0) % n] = true;
            stack.push((lo, worst.0));
            stack.push((worst.0, hi));
        }
    }
}

fn dist2(a: Point, b: Point) -> f32 {
    (a.x - b.x).powi(2) + (a.y - b.y).powi(2)
}

/// Distance from `p` to the segment `a`-`b`.
fn segment_distance(p: Point, a: Point, b: Point) -> f32 {
    let (vx, vy) = (b.x - a.x, b.y - a.y);
    let len2 = vx * vx + vy * vy;
    let t = if len2 > 0.0 {
        (((p.x - a.x) * vx + (p.y - a.y) * vy) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    dist2(p, Point::new(a.x + t * vx, a.y + t * vy)).sqrt()
}

/// Twice the signed area of a polygon (positive when clockwise on screen, y down).
pub fn signed_area2(points: &[Point]) -> f32 {
    let n = points.len();
    (0..n)
        .map(|i| {
            let (a, b) = (points[i], points[(i + 1) % n]);
            a.x * b.y - b.x * a.y
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_single_pixel_traces_to_its_four_edge_midpoints() {
        let pts = trace_outer_boundary((2, 3), |x, y| (x, y) == (2, 3));
        assert_eq!(
            pts,
            vec![
                Point::new(2.5, 3.0),
                Point::new(3.0, 3.5),
                Point::new(2.5, 4.0),
                Point::new(2.0, 3.5)
            ]
        );
    }

    #[test]
    fn a_rectangle_simplifies_to_its_sides_with_chamfered_corners() {
        let pts = trace_outer_boundary((1, 1), |x, y| (1..6).contains(&x) && (1..4).contains(&y));
        assert_eq!(pts.len(), 2 * (5 + 3));
        // Edge midpoints cut each corner by a 0.5-px chamfer: 5×3 − 4 × 1/8.
        let simple = simplify_closed(&pts, |_| 0.1);
        assert_eq!(simple.len(), 8, "{simple:?}");
        assert_eq!(signed_area2(&simple), 2.0 * 14.5);
    }

    #[test]
    fn diagonal_neighbours_are_not_followed() {
        // Two pixels touching at a corner: tracing the first must not walk around the second.
        let pts = trace_outer_boundary((0, 0), |x, y| (x, y) == (0, 0) || (x, y) == (1, 1));
        assert_eq!(pts.len(), 4);
    }

    #[test]
    fn each_vertex_keeps_to_its_own_tolerance() {
        // A disc of radius 12: coarse on its left half, fine on its right.
        let inside = |x: i64, y: i64| (x - 20).pow(2) + (y - 20).pow(2) <= 144;
        let pts = trace_outer_boundary((20, 8), inside);
        let tolerance = |p: Point| if p.x < 20.5 { 3.0 } else { 0.3 };
        let simple = simplify_closed(&pts, tolerance);
        let n = simple.len();
        for &p in &pts {
            let nearest = (0..n)
                .map(|i| segment_distance(p, simple[i], simple[(i + 1) % n]))
                .fold(f32::INFINITY, f32::min);
            assert!(nearest <= tolerance(p) + 1e-5, "{p:?} is {nearest} away");
        }
        let left = simple.iter().filter(|p| p.x < 20.0).count();
        let right = simple.iter().filter(|p| p.x > 21.0).count();
        assert!(2 * left < right, "left {left}, right {right}: {simple:?}");
    }
}
