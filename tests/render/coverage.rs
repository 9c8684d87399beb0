//! The forward's coverage: exact areas for polygons, circles within the flattening bound, and a
//! random scene against tiny-skia's anti-aliased fill.

use crate::render_support;

use covec::geom::bezier;
use covec::geom::bezier::FLATTEN_TOLERANCE;
use covec::render::{Image, MIN_LINES_PER_CUBIC, Rasterizer};
use covec::scene::{Path, Point};
use render_support::*;

const SIZE: usize = 48;

/// Total coverage: the path drawn white, opaque, over black, summed over the red channel.
fn coverage_sum(path: &Path) -> f64 {
    let mut raster = Rasterizer::new();
    let mut image = Image::default();
    let white = Path {
        color: [1.0; 3],
        opacity: 1.0,
        ..path.clone()
    };
    raster.render(&[white], [0.0; 3], SIZE, SIZE, &mut image);
    image.data.chunks_exact(3).map(|p| p[0] as f64).sum()
}

/// Shoelace area of a closed polygon.
fn polygon_area(v: &[Point]) -> f64 {
    let n = v.len();
    (0..n)
        .map(|i| {
            let (a, b) = (v[i], v[(i + 1) % n]);
            a.x as f64 * b.y as f64 - b.x as f64 * a.y as f64
        })
        .sum::<f64>()
        .abs()
        / 2.0
}

#[test]
fn rectangles_have_exact_area() {
    let mut rng = SplitMix64(11);
    for _ in 0..50 {
        let (x0, y0) = (rng.range(1.0, 20.0), rng.range(1.0, 20.0));
        let (x1, y1) = (x0 + rng.range(0.1, 25.0), y0 + rng.range(0.1, 25.0));
        let rect = Path::rect(x0, y0, x1, y1, [1.0; 3], 1.0);
        let area = (x1 - x0) as f64 * (y1 - y0) as f64;
        let sum = coverage_sum(&rect);
        assert!(
            (sum - area).abs() < 1e-3,
            "rect {x0},{y0}-{x1},{y1}: coverage {sum}, area {area}"
        );
    }
    // Clipped by the canvas: only the part inside counts.
    let sum = coverage_sum(&Path::rect(-10.5, -3.25, 10.0, 60.0, [1.0; 3], 1.0));
    assert!(
        (sum - 10.0 * SIZE as f64).abs() < 1e-3,
        "clipped rect: {sum}"
    );
    let everything = coverage_sum(&Path::rect(-100.0, -100.0, 100.0, 100.0, [1.0; 3], 1.0));
    assert!(
        (everything - (SIZE * SIZE) as f64).abs() < 1e-3,
        "canvas-covering rect: {everything}"
    );
}

#[test]
fn triangles_have_exact_area_in_both_orientations() {
    let mut rng = SplitMix64(12);
    for i in 0..100 {
        let mut v: Vec<Point> = (0..3)
            .map(|_| Point::new(rng.range(0.0, 48.0), rng.range(0.0, 48.0)))
            .collect();
        if i % 2 == 1 {
            v.reverse();
        }
        let tri = Path::from_polygon(&v, [1.0; 3], 1.0).expect("three vertices");
        let (sum, area) = (coverage_sum(&tri), polygon_area(&v));
        assert!(
            (sum - area).abs() < 1e-3,
            "triangle {v:?}: coverage {sum}, area {area}"
        );
    }
}

/// A circle of four cubics (the usual kappa = 0.5522847).
fn circle(cx: f32, cy: f32, r: f32) -> Path {
    let k = 0.552_284_8 * r;
    let points = vec![
        Point::new(cx + r, cy),
        Point::new(cx + r, cy + k),
        Point::new(cx + k, cy + r),
        Point::new(cx, cy + r),
        Point::new(cx - k, cy + r),
        Point::new(cx - r, cy + k),
        Point::new(cx - r, cy),
        Point::new(cx - r, cy - k),
        Point::new(cx - k, cy - r),
        Point::new(cx, cy - r),
        Point::new(cx + k, cy - r),
        Point::new(cx + r, cy - k),
    ];
    Path {
        points,
        color: [1.0; 3],
        opacity: 1.0,
    }
}

/// The exact area of a closed cubic path by Green's theorem, `½∮(x dy − y dx)`: the integrand is
/// a degree-5 polynomial in t per segment, so 3-point Gauss-Legendre is exact.
fn bezier_area(path: &Path) -> f64 {
    let nodes = [
        (0.5 - 0.5 * (0.6f64).sqrt(), 5.0 / 18.0),
        (0.5, 8.0 / 18.0),
        (0.5 + 0.5 * (0.6f64).sqrt(), 5.0 / 18.0),
    ];
    let mut area = 0.0;
    for s in 0..path.segment_count() {
        let c = path.segment(s).map(|p| [p.x as f64, p.y as f64]);
        for (t, w) in nodes {
            let u = 1.0 - t;
            let b = [u * u * u, 3.0 * u * u * t, 3.0 * u * t * t, t * t * t];
            let d = [
                -3.0 * u * u,
                3.0 * u * u - 6.0 * u * t,
                6.0 * u * t - 3.0 * t * t,
                3.0 * t * t,
            ];
            let (mut x, mut y, mut dx, mut dy) = (0.0, 0.0, 0.0, 0.0);
            for j in 0..4 {
                x += b[j] * c[j][0];
                y += b[j] * c[j][1];
                dx += d[j] * c[j][0];
                dy += d[j] * c[j][1];
            }
            area += 0.5 * w * (x * dy - y * dx);
        }
    }
    area.abs()
}

#[test]
fn circles_cover_their_flattened_area_and_the_curve_area_within_the_bound() {
    for (cx, cy, r) in [
        (24.0, 24.0, 20.0),
        (10.3, 31.7, 6.45),
        (30.1, 12.9, 2.2),
        (40.0, 40.0, 15.0),
    ] {
        let c = circle(cx, cy, r);
        // The renderer's own flattening (default tolerance, at least MIN_LINES_PER_CUBIC lines).
        let mut polygon = Vec::new();
        let mut perimeter = 0.0f64;
        for s in 0..c.segment_count() {
            let seg = c.segment(s);
            let n = bezier::lines_for_tolerance(&seg, FLATTEN_TOLERANCE).max(MIN_LINES_PER_CUBIC);
            bezier::flatten_into(&seg, n, &mut polygon);
        }
        for i in 0..polygon.len() {
            let (a, b) = (polygon[i], polygon[(i + 1) % polygon.len()]);
            perimeter += ((b.x - a.x) as f64).hypot((b.y - a.y) as f64);
        }
        let sum = coverage_sum(&c);
        let flat_area = polygon_area(&polygon);
        // Canvas clipping: the (40, 40, 15) circle pokes out of the 48² canvas, so compare its
        // polygon clipped by rendering the same polygon as straight edges.
        let flat_sum = coverage_sum(&Path::from_polygon(&polygon, [1.0; 3], 1.0).expect("polygon"));
        assert!(
            (sum - flat_sum).abs() < 1e-3,
            "circle {r}: coverage {sum}, flattened polygon coverage {flat_sum}"
        );
        if cx + r <= SIZE as f32 && cy + r <= SIZE as f32 && cx >= r && cy >= r {
            assert!(
                (sum - flat_area).abs() < 1e-3,
                "circle {r}: coverage {sum}, polygon area {flat_area}"
            );
            // Each chord is within the tolerance of its arc, so the area between them is at most
            // (2/3)·tolerance·chord (a parabolic segment); summed: (2/3)·tolerance·perimeter.
            let exact = bezier_area(&c);
            let bound = 2.0 / 3.0 * FLATTEN_TOLERANCE as f64 * perimeter;
            eprintln!("circle r={r}: coverage {sum:.4}, curve area {exact:.4}, bound {bound:.3}");
            assert!(
                (sum - exact).abs() <= bound,
                "circle {r}: coverage {sum}, curve area {exact}, bound {bound}"
            );
        }
    }
}

#[test]
fn random_scene_matches_tiny_skia_antialiased_fill() {
    let size = 64;
    let mut rng = SplitMix64(21);
    let paths = mixed_scene(&mut rng, size as f32, 8, 3);
    let ours = render(&mut Rasterizer::new(), &paths, [1.0; 3], size);

    let mut pixmap = tiny_skia::Pixmap::new(size as u32, size as u32).expect("pixmap");
    pixmap.fill(tiny_skia::Color::WHITE);
    for p in &paths {
        let mut pb = tiny_skia::PathBuilder::new();
        pb.move_to(p.points[0].x, p.points[0].y);
        for k in 0..p.segment_count() {
            let c = p.segment(k);
            pb.cubic_to(c[1].x, c[1].y, c[2].x, c[2].y, c[3].x, c[3].y);
        }
        pb.close();
        let mut paint = tiny_skia::Paint::default();
        paint.set_color(
            tiny_skia::Color::from_rgba(p.color[0], p.color[1], p.color[2], p.opacity)
                .expect("colour"),
        );
        paint.anti_alias = true;
        let path = pb.finish().expect("path");
        pixmap.fill_path(
            &path,
            &paint,
            tiny_skia::FillRule::Winding,
            tiny_skia::Transform::identity(),
            None,
        );
    }
    let skia = pixmap.data();
    let mut diff = 0.0f64;
    for i in 0..size * size {
        for c in 0..3 {
            diff += (ours.data[3 * i + c] as f64 - skia[4 * i + c] as f64 / 255.0).abs();
        }
    }
    let mean = diff / (size * size * 3) as f64;
    eprintln!("mean abs difference to tiny-skia: {:.3}/255", mean * 255.0);
    assert!(mean <= 2.0 / 255.0, "mean abs difference {mean}");
}
