//! The layer composites and the renderer's handling of bad paths.

use covec::render::composite::{product, svg_model, svg_model_backward};
use covec::render::{Image, PathError, PathGrad, Rasterizer, check_path};
use covec::scene::{Path, Point};

fn image(values: &[f32]) -> Image {
    Image {
        width: values.len() / 3,
        height: 1,
        data: values.to_vec(),
    }
}

#[test]
fn product_of_two_images() {
    let (a, b) = (
        image(&[0.5, 1.0, 0.2, 0.0, 0.3, 1.0]),
        image(&[2.0, 0.5, 4.0, 1.0, 1.0, 0.25]),
    );
    let mut v = Image::default();
    product(&a, &b, &mut v);
    assert_eq!(v.data, vec![1.0, 0.5, 0.8, 0.0, 0.3, 0.25]);
}

#[test]
fn svg_model_clamps_and_passes_no_gradient_where_clamped() {
    // a·s + l = 0.25 (inside), 1.0 (at the bound: inside), 1.5 (clamped), -0.5 (clamped).
    let a = image(&[0.5, 1.0, 1.0, 0.5, 0.0, 0.0]);
    let s = image(&[0.5, 1.0, 1.0, -1.0, 0.0, 0.0]);
    let l = image(&[0.0, 0.0, 0.5, 0.0, 0.3, 0.0]);
    let mut out = Image::default();
    svg_model(&a, &s, &l, &mut out);
    assert_eq!(out.data, vec![0.25, 1.0, 1.0, 0.0, 0.3, 0.0]);
    let mut g = image(&[1.0; 6]);
    svg_model_backward(&a, &s, &l, &mut g);
    // The light's gradient; the albedo's is g·s and the shade's g·a.
    assert_eq!(g.data, vec![1.0, 1.0, 0.0, 0.0, 1.0, 1.0]);
}

#[test]
fn malformed_paths_are_reported_and_paint_nothing() {
    let good = Path::rect(2.0, 2.0, 6.0, 6.0, [0.0; 3], 1.0);
    let short = Path {
        points: vec![Point::new(1.0, 1.0); 4],
        ..good.clone()
    };
    let mut nan = good.clone();
    nan.points[2].x = f32::NAN;
    let mut bad_paint = good.clone();
    bad_paint.opacity = f32::INFINITY;
    assert_eq!(check_path(&good), Ok(()));
    assert_eq!(check_path(&short), Err(PathError::PointCount(4)));
    assert_eq!(check_path(&nan), Err(PathError::NonFinitePoint(2)));
    assert_eq!(check_path(&bad_paint), Err(PathError::NonFinitePaint));

    let mut raster = Rasterizer::new();
    let mut out = Image::default();
    let paths = [short, nan, bad_paint];
    raster.render(&paths, [1.0; 3], 8, 8, &mut out);
    assert!(out.data.iter().all(|&v| v == 1.0));
    let mut grads = PathGrad::zeros_like(&paths);
    raster.backward(&paths, [1.0; 3], &Image::filled(8, 8, [1.0; 3]), &mut grads);
    assert_eq!(grads, PathGrad::zeros_like(&paths));

    // Far-away and huge coordinates are fine.
    let huge = Path::rect(-1e30, -1e30, 1e30, 1e30, [0.0; 3], 1.0);
    raster.render(&[huge], [1.0; 3], 8, 8, &mut out);
    assert!(out.data.iter().all(|&v| v == 0.0));
    raster.render(&[good], [1.0; 3], 0, 0, &mut out);
    assert!(out.data.is_empty());
}
