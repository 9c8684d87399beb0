//! Where to add paths: connected regions of high reconstruction error (LIVE / LayerVec), and the
//! initial shape of a path for a region (an ellipse with the region's centroid and second moments,
//! or the region's simplified outline).

use crate::decompose::mask::Mask;
use crate::geom::contour::simplify_closed;
use crate::scene::{Path, Point};

/// Pixels of one connected region, as indices `y * width + x`.
#[derive(Clone, Debug, PartialEq)]
pub struct Region {
    pub pixels: Vec<usize>,
}

/// Per-pixel error below this (Σ over channels of squared differences) is ignored. LayerVec: 0.025.
pub const ERROR_FLOOR: f32 = 0.025;
/// Number of quantile edges used to bin the error, ends included: 4 gives three bins (terciles of
/// the error above the floor). LayerVec uses 139, which fragments a photo's error into specks
/// that new paths start as; terciles give regions a path can cover (docs/history.md,
/// "Refinement regions").
const QUANTILE_EDGES: usize = 4;

/// Up to `count` largest connected regions of similar, high error. The error (`width × height`
/// values) is split into quantile bins; each bin's 4-connected components are ranked by size over
/// all bins (LayerVec's `select_mask_by_conn_area`, with coarser bins, see [`QUANTILE_EDGES`]).
/// Pixels below [`ERROR_FLOOR`] never count.
pub fn high_error_regions(error: &[f32], width: usize, height: usize, count: usize) -> Vec<Region> {
    if count == 0 {
        return Vec::new();
    }
    let mut values: Vec<f32> = error
        .iter()
        .copied()
        .filter(|&e| e >= ERROR_FLOOR)
        .collect();
    if values.is_empty() {
        return Vec::new();
    }
    values.sort_by(f32::total_cmp);
    let mut edges: Vec<f32> = (1..QUANTILE_EDGES - 1)
        .map(|k| values[((values.len() - 1) * k) / (QUANTILE_EDGES - 1)])
        .collect();
    edges.dedup();
    // Bin 0 = below the floor; bins 1.. by quantile.
    let bins: Vec<u16> = error
        .iter()
        .map(|&e| {
            if e < ERROR_FLOOR {
                0
            } else {
                1 + edges.partition_point(|&q| q <= e) as u16
            }
        })
        .collect();

    let mut seen = vec![false; error.len()];
    let mut regions = Vec::new();
    let mut stack = Vec::new();
    for start in 0..error.len() {
        if seen[start] || bins[start] == 0 {
            continue;
        }
        let bin = bins[start];
        let mut pixels = Vec::new();
        seen[start] = true;
        stack.push(start);
        while let Some(p) = stack.pop() {
            pixels.push(p);
            let (x, y) = (p % width, p / width);
            let mut visit = |q: usize| {
                if !seen[q] && bins[q] == bin {
                    seen[q] = true;
                    stack.push(q);
                }
            };
            if x > 0 {
                visit(p - 1);
            }
            if x + 1 < width {
                visit(p + 1);
            }
            if y > 0 {
                visit(p - width);
            }
            if y + 1 < height {
                visit(p + width);
            }
        }
        regions.push(Region { pixels });
    }
    // Largest first; ties by first pixel so the order is deterministic.
    regions.sort_by(|a, b| {
        b.pixels
            .len()
            .cmp(&a.pixels.len())
            .then(a.pixels[0].cmp(&b.pixels[0]))
    });
    regions.truncate(count);
    regions
}

/// Number of cubic segments of a new region path: enough to bend around an irregular region.
pub const REGION_PATH_SEGMENTS: usize = 6;

/// Regions of fewer pixels, holes filled, have no [`outline`]: their boundary is a few pixel
/// steps.
const MIN_OUTLINE_PIXELS: usize = 12;

/// Douglas-Peucker tolerance (pixels) [`outline`] starts from, and its growth per try.
const OUTLINE_TOLERANCE: (f32, f32) = (0.75, 1.5);

/// The outer boundary of the region with its holes filled, as a polygon of at most
/// `max_vertices` vertices (at least 3): simplified at a tolerance that grows from
/// [`OUTLINE_TOLERANCE`] until it fits. Filled, a pocket of background that meets the outside
/// only at a pixel corner is inside, so the outline does not wind into it (docs/history.md,
/// "Refinement regions"). `None` below [`MIN_OUTLINE_PIXELS`] pixels.
pub fn outline(region: &Region, width: usize, max_vertices: usize) -> Option<Vec<Point>> {
    // The region on a mask of its bounding box, so that the work is its size, not the canvas's.
    let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
    for &p in &region.pixels {
        let (x, y) = (p % width, p / width);
        (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
    }
    let box_width = x1.checked_sub(x0)? + 1;
    let mut inside = vec![false; box_width * (y1 - y0 + 1)];
    for &p in &region.pixels {
        inside[(p / width - y0) * box_width + p % width - x0] = true;
    }
    let mask = Mask::from_fn(box_width, y1 - y0 + 1, |x, y| inside[y * box_width + x]).fill_holes();
    if mask.area() < MIN_OUTLINE_PIXELS {
        return None;
    }
    let offset = |p: Point| Point::new(p.x + x0 as f32, p.y + y0 as f32);
    let boundary: Vec<Point> = mask.outer_boundary().into_iter().map(offset).collect();
    let (mut tolerance, growth) = OUTLINE_TOLERANCE;
    loop {
        let polygon = simplify_closed(&boundary, |_| tolerance);
        if polygon.len() <= max_vertices.max(3) {
            return (polygon.len() >= 3).then_some(polygon);
        }
        tolerance *= growth;
    }
}

/// A closed path approximating the region: the ellipse with the region's centroid and covariance
/// (a uniform ellipse of semi-axes a, b has variances a²/4, b²/4), at least `min_radius` wide.
pub fn ellipse_for_pixels(
    weighted: impl Iterator<Item = (f32, f32, f32)>,
    min_radius: f32,
) -> Option<Ellipse> {
    let (mut sw, mut sx, mut sy, mut sxx, mut syy, mut sxy) =
        (0.0f64, 0.0f64, 0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for (x, y, w) in weighted {
        let (x, y, w) = (f64::from(x), f64::from(y), f64::from(w));
        sw += w;
        sx += w * x;
        sy += w * y;
        sxx += w * x * x;
        syy += w * y * y;
        sxy += w * x * y;
    }
    if sw <= 0.0 {
        return None;
    }
    let (cx, cy) = (sx / sw, sy / sw);
    // Pixel centres: add the 1/12 variance of a unit box.
    let vxx = sxx / sw - cx * cx + 1.0 / 12.0;
    let vyy = syy / sw - cy * cy + 1.0 / 12.0;
    let vxy = sxy / sw - cx * cy;
    let tr = vxx + vyy;
    let det = vxx * vyy - vxy * vxy;
    let disc = (tr * tr / 4.0 - det).max(0.0).sqrt();
    let (l1, l2) = (tr / 2.0 + disc, (tr / 2.0 - disc).max(0.0));
    let angle = 0.5 * (2.0 * vxy).atan2(vxx - vyy);
    let min_radius = f64::from(min_radius);
    Some(Ellipse {
        center: Point::new(cx as f32, cy as f32),
        radii: [
            (2.0 * l1.sqrt()).max(min_radius) as f32,
            (2.0 * l2.sqrt()).max(min_radius) as f32,
        ],
        angle: angle as f32,
    })
}

/// An ellipse: centre, semi-axes and rotation of the first axis (radians).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ellipse {
    pub center: Point,
    pub radii: [f32; 2],
    pub angle: f32,
}

impl Ellipse {
    /// The region's ellipse, pixel centres at +0.5.
    pub fn of_region(region: &Region, width: usize, min_radius: f32) -> Option<Self> {
        ellipse_for_pixels(
            region
                .pixels
                .iter()
                .map(|&p| ((p % width) as f32 + 0.5, (p / width) as f32 + 0.5, 1.0)),
            min_radius,
        )
    }

    /// A closed path of `segments` cubics on the ellipse (the standard 4/3·tan(φ/4) handles).
    pub fn to_path(self, segments: usize, color: [f32; 3], opacity: f32) -> Path {
        let step = std::f32::consts::TAU / segments as f32;
        let kappa = 4.0 / 3.0 * (step / 4.0).tan();
        let (sin, cos) = self.angle.sin_cos();
        let u = Point::new(cos * self.radii[0], sin * self.radii[0]);
        let v = Point::new(-sin * self.radii[1], cos * self.radii[1]);
        let at = |t: f32| {
            let (s, c) = t.sin_cos();
            (
                Point::new(
                    self.center.x + u.x * c + v.x * s,
                    self.center.y + u.y * c + v.y * s,
                ),
                Point::new(-u.x * s + v.x * c, -u.y * s + v.y * c),
            )
        };
        let mut points = Vec::with_capacity(3 * segments);
        for k in 0..segments {
            let (p0, d0) = at(k as f32 * step);
            let (p1, d1) = at((k + 1) as f32 * step);
            points.push(p0);
            points.push(Point::new(p0.x + kappa * d0.x, p0.y + kappa * d0.y));
            points.push(Point::new(p1.x - kappa * d1.x, p1.y - kappa * d1.y));
        }
        Path {
            points,
            color,
            opacity,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regions_are_connected_and_ranked_by_size() {
        let (w, h) = (10, 6);
        let mut error = vec![0.0f32; w * h];
        for y in 0..3 {
            for x in 0..4 {
                error[y * w + x] = 0.5; // 12 px
            }
        }
        for y in 4..6 {
            for x in 7..9 {
                error[y * w + x] = 0.5; // 4 px, same bin, not connected
            }
        }
        error[5 * w] = 0.01; // below the floor
        let regions = high_error_regions(&error, w, h, 5);
        assert_eq!(regions.len(), 2);
        assert_eq!(regions[0].pixels.len(), 12);
        assert_eq!(regions[1].pixels.len(), 4);
        assert_eq!(high_error_regions(&error, w, h, 1).len(), 1);
    }

    #[test]
    fn an_l_shaped_region_outline_keeps_its_notch() {
        // An L: a 12×4 bar along the top and a 4×12 bar down the left, 20×20 canvas.
        let w = 20;
        let pixels: Vec<usize> = (2..14)
            .flat_map(|y| (3..15).map(move |x| (x, y)))
            .filter(|&(x, y)| y < 6 || x < 7)
            .map(|(x, y)| y * w + x)
            .collect();
        let region = Region { pixels };
        let polygon = outline(&region, w, 10).unwrap();
        assert!((3..=10).contains(&polygon.len()), "{polygon:?}");
        // Every vertex on the L's boundary, and a vertex in the notch's corner (7, 6).
        assert!(
            polygon.iter().any(|p| (p.x - 7.0).hypot(p.y - 6.0) < 1.0),
            "{polygon:?}"
        );
        // Fewer vertices allowed: still a polygon, at most that many.
        assert!(outline(&region, w, 4).unwrap().len() <= 4);
        assert_eq!(
            outline(
                &Region {
                    pixels: vec![0, 1, 2]
                },
                w,
                10
            ),
            None
        );
    }

    #[test]
    fn ellipse_of_a_square_region_matches_its_extent() {
        let w = 20;
        let pixels: Vec<usize> = (5..15)
            .flat_map(|y| (2..12).map(move |x| y * w + x))
            .collect();
        let e = Ellipse::of_region(&Region { pixels }, w, 1.0).unwrap();
        assert!((e.center.x - 7.0).abs() < 1e-4 && (e.center.y - 10.0).abs() < 1e-4);
        // A 10×10 square has variance 100/12; 2σ ≈ 5.77.
        assert!(
            (e.radii[0] - 5.77).abs() < 0.05 && (e.radii[1] - 5.77).abs() < 0.05,
            "{e:?}"
        );
        let path = e.to_path(6, [1.0; 3], 1.0);
        assert_eq!(path.segment_count(), 6);
        assert!(
            path.points
                .iter()
                .all(|p| (p.x - 7.0).hypot(p.y - 10.0) < 7.0)
        );
    }
}
