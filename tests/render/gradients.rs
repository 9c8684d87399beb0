//! Every analytic gradient of the renderer against central finite differences of its forward.

use crate::render_support;

use covec::render::composite::product;
use covec::render::{Backdrop, Flattening, Image, PathGrad, PixelGrad, Rasterizer};
use covec::scene::Path;
use render_support::*;

/// Steps of the central differences: points move by `H_POINT` px, paints by `H_PAINT` (powers
/// of two, so `v ± h` is exact in f32). Coverage is piecewise quadratic in the points (C¹, with
/// kinks where a vertex or edge crosses a pixel boundary), so the step is small; the forward
/// being differenced is the f64 evaluation of the very same renderer, so rounding stays far
/// below the step.
const H_POINT: f32 = 1.0 / 8192.0;
const H_PAINT: f32 = 1.0 / 1024.0;
const REL_TOL: f64 = 1e-2;
const ABS_TOL: f64 = 1e-4;

/// Which parameter of which path.
#[derive(Clone, Copy, Debug)]
enum Param {
    X(usize),
    Y(usize),
    Color(usize),
    Opacity,
}

fn get(path: &Path, p: Param) -> f32 {
    match p {
        Param::X(i) => path.points[i].x,
        Param::Y(i) => path.points[i].y,
        Param::Color(c) => path.color[c],
        Param::Opacity => path.opacity,
    }
}

fn set(path: &mut Path, p: Param, v: f32) {
    match p {
        Param::X(i) => path.points[i].x = v,
        Param::Y(i) => path.points[i].y = v,
        Param::Color(c) => path.color[c] = v,
        Param::Opacity => path.opacity = v,
    }
}

fn analytic(grad: &PathGrad, p: Param) -> f64 {
    (match p {
        Param::X(i) => grad.points[i].x,
        Param::Y(i) => grad.points[i].y,
        Param::Color(c) => grad.color[c],
        Param::Opacity => grad.opacity,
    }) as f64
}

fn params(path: &Path) -> Vec<Param> {
    let mut v: Vec<Param> = (0..path.points.len())
        .flat_map(|i| [Param::X(i), Param::Y(i)])
        .collect();
    v.extend([
        Param::Color(0),
        Param::Color(1),
        Param::Color(2),
        Param::Opacity,
    ]);
    v
}

/// Compares every gradient of every layer against central differences of `loss`; returns the
/// number of parameters checked.
fn check_all(
    layers: &mut [Vec<Path>],
    grads: &[Vec<PathGrad>],
    mut loss: impl FnMut(&[Vec<Path>]) -> f64,
) -> usize {
    let mut failures = Vec::new();
    let mut checked = 0;
    let mut worst = 0.0f64;
    for l in 0..layers.len() {
        for i in 0..layers[l].len() {
            for p in params(&layers[l][i]) {
                let h = if matches!(p, Param::X(_) | Param::Y(_)) {
                    H_POINT
                } else {
                    H_PAINT
                };
                let v = get(&layers[l][i], p);
                set(&mut layers[l][i], p, v + h);
                let up = loss(layers);
                set(&mut layers[l][i], p, v - h);
                let down = loss(layers);
                set(&mut layers[l][i], p, v);
                let fd = (up - down) / (2.0 * h as f64);
                let an = analytic(&grads[l][i], p);
                let err = (an - fd).abs();
                worst = worst.max(err / fd.abs().max(ABS_TOL / REL_TOL));
                if err > (REL_TOL * fd.abs()).max(ABS_TOL) {
                    failures.push(format!(
                        "layer {l} path {i} {p:?}: analytic {an:.6e}, fd {fd:.6e}"
                    ));
                }
                checked += 1;
            }
        }
    }
    eprintln!("{checked} gradients checked, worst scaled error {worst:.3e}");
    assert!(
        failures.is_empty(),
        "{} of {checked} gradients off:\n{}",
        failures.len(),
        failures.join("\n")
    );
    checked
}

fn target_and_weights(rng: &mut SplitMix64, len: usize) -> (Vec<f32>, Vec<f32>) {
    let target = (0..len).map(|_| rng.uniform()).collect();
    let weights = (0..len).map(|_| rng.range(0.5, 1.5)).collect();
    (target, weights)
}

#[test]
fn single_layer_gradients_match_finite_differences() {
    for (seed, size) in [(1u64, 32usize), (2, 48), (3, 64)] {
        let mut rng = SplitMix64(seed);
        let mut paths = mixed_scene(&mut rng, size as f32, 3, 2);
        let base = [1.0, 1.0, 1.0];
        let (target, weights) = target_and_weights(&mut rng, size * size * 3);
        // Fixed line counts: finite differences must not straddle a change of flattening.
        let mut raster = Rasterizer::with_flattening(Flattening::Fixed(8));
        let image = render(&mut raster, &paths, base, size);
        let (_, d_out) = weighted_sq_loss(&image, &target, &weights);
        let mut grads = zero_grads(&paths);
        raster.backward(&paths, base, &d_out, &mut grads);

        let mut layers = [std::mem::take(&mut paths)];
        check_all(&mut layers, &[grads], |layers| {
            let image = raster.render_f64(&layers[0], base, size, size);
            weighted_sq_loss_f64(&image, &target, &weights)
        });
    }
}

#[test]
fn product_composite_gradients_match_finite_differences() {
    let size = 40;
    let mut rng = SplitMix64(7);
    let albedo = mixed_scene(&mut rng, size as f32, 3, 1);
    let mut illum = mixed_scene(&mut rng, size as f32, 2, 1);
    // Illumination may exceed 1 during optimisation.
    for p in &mut illum {
        p.color = p.color.map(|c| 2.0 * c);
    }
    let (target, weights) = target_and_weights(&mut rng, size * size * 3);
    let bases = [[1.0; 3], [1.0; 3]];
    let mut raster = Rasterizer::with_flattening(Flattening::Fixed(6));

    let forward = |layers: &[Vec<Path>], raster: &mut Rasterizer| -> (Image, Image, Image) {
        let a = render(raster, &layers[0], bases[0], size);
        let i = render(raster, &layers[1], bases[1], size);
        let mut v = Image::default();
        product(&a, &i, &mut v);
        (a, i, v)
    };
    let mut layers = [albedo, illum];
    let (a, i, v) = forward(&layers, &mut raster);
    let (_, d_v) = weighted_sq_loss(&v, &target, &weights);
    // Each layer's dL/dPixel is the product's times the other layer.
    let times = |factor| PixelGrad {
        factor: Some(factor),
        ..PixelGrad::of(&d_v)
    };
    let mut grads = [zero_grads(&layers[0]), zero_grads(&layers[1])];
    raster.backward_of(&layers[0], bases[0], times(&i), &mut grads[0]);
    raster.backward_of(&layers[1], bases[1], times(&a), &mut grads[1]);

    check_all(&mut layers, &grads, |layers| {
        let a = raster.render_f64(&layers[0], bases[0], size, size);
        let i = raster.render_f64(&layers[1], bases[1], size, size);
        let v: Vec<f64> = a.iter().zip(&i).map(|(a, i)| a * i).collect();
        weighted_sq_loss_f64(&v, &target, &weights)
    });
}

#[test]
fn deep_overlap_gradients_match_finite_differences() {
    // 600 canvas-wide paths: deep enough that the backward splits each 16-row band into
    // several passes; check a few paths at the bottom, middle and top of the stack.
    let size = 48;
    let mut rng = SplitMix64(9);
    let mut paths: Vec<Path> = (0..600)
        .map(|_| {
            let pts = scribble(
                &mut rng,
                -5.0,
                -5.0,
                size as f32 + 5.0,
                size as f32 + 5.0,
                4,
            );
            paint(&mut rng, pts)
        })
        .collect();
    for p in &mut paths {
        p.opacity *= 0.2;
    }
    let base = [1.0, 1.0, 1.0];
    let (target, weights) = target_and_weights(&mut rng, size * size * 3);
    let mut raster = Rasterizer::with_flattening(Flattening::Fixed(4));
    let image = render(&mut raster, &paths, base, size);
    let (_, d_out) = weighted_sq_loss(&image, &target, &weights);
    let mut grads = zero_grads(&paths);
    raster.backward(&paths, base, &d_out, &mut grads);

    let picked = [0usize, 300, 599];
    let mut layers = [picked.iter().map(|&i| paths[i].clone()).collect::<Vec<_>>()];
    let picked_grads = [picked.iter().map(|&i| grads[i].clone()).collect::<Vec<_>>()];
    check_all(&mut layers, &picked_grads, |layers| {
        let mut scene = paths.clone();
        for (k, &i) in picked.iter().enumerate() {
            scene[i] = layers[0][k].clone();
        }
        let image = raster.render_f64(&scene, base, size, size);
        weighted_sq_loss_f64(&image, &target, &weights)
    });
}

#[test]
fn an_image_backdrop_is_the_affine_blend_of_black_and_white() {
    // "Over" is affine in what lies below: out = C + T·backdrop, with C the render over black
    // and T = (render over white) − C. The one-pass render and backward over an image must
    // agree with that blend and with its backward (d·(1 − backdrop) over black, d·backdrop over
    // white).
    let size = 40;
    let mut rng = SplitMix64(21);
    let paths = mixed_scene(&mut rng, size as f32, 5, 2);
    let backdrop = Image {
        width: size,
        height: size,
        data: (0..size * size * 3).map(|_| rng.uniform()).collect(),
    };
    let mut raster = Rasterizer::new();
    let mut over = Image::default();
    raster.render_over(&paths, Backdrop::Image(&backdrop), size, size, &mut over);
    let black = render(&mut raster, &paths, [0.0; 3], size);
    let white = render(&mut raster, &paths, [1.0; 3], size);
    for i in 0..over.data.len() {
        let blend = black.data[i] + (white.data[i] - black.data[i]) * backdrop.data[i];
        assert!((over.data[i] - blend).abs() < 1e-5, "value {i}");
    }

    let (target, weights) = target_and_weights(&mut rng, size * size * 3);
    let (_, d_out) = weighted_sq_loss(&over, &target, &weights);
    let mut grads = zero_grads(&paths);
    raster.backward_over(&paths, Backdrop::Image(&backdrop), &d_out, &mut grads);
    let mut blended = zero_grads(&paths);
    let mut part = d_out.clone();
    for (v, (&d, &b)) in part
        .data
        .iter_mut()
        .zip(d_out.data.iter().zip(&backdrop.data))
    {
        *v = d * (1.0 - b);
    }
    raster.backward(&paths, [0.0; 3], &part, &mut blended);
    for (v, (&d, &b)) in part
        .data
        .iter_mut()
        .zip(d_out.data.iter().zip(&backdrop.data))
    {
        *v = d * b;
    }
    raster.backward(&paths, [1.0; 3], &part, &mut blended);
    for (g, e) in grads.iter().zip(&blended) {
        let close = |a: f32, b: f32| (a - b).abs() <= 1e-3 * (1.0 + b.abs());
        assert!(
            close(g.opacity, e.opacity),
            "{} vs {}",
            g.opacity,
            e.opacity
        );
        for c in 0..3 {
            assert!(
                close(g.color[c], e.color[c]),
                "{:?} vs {:?}",
                g.color,
                e.color
            );
        }
        for (p, q) in g.points.iter().zip(&e.points) {
            assert!(close(p.x, q.x) && close(p.y, q.y), "{p:?} vs {q:?}");
        }
    }
}

#[test]
fn a_backward_with_the_colours_apart_is_two_backwards_in_one() {
    // The colours' gradient from the second dL/dPixel, the points' and opacities' from the
    // first, bit for bit as two separate backwards give them.
    let size = 40;
    let mut rng = SplitMix64(33);
    let paths = mixed_scene(&mut rng, size as f32, 6, 2);
    let base = [0.9, 1.0, 0.8];
    let mut raster = Rasterizer::new();
    let image = render(&mut raster, &paths, base, size);
    let mut d = [0, 1].map(|_| {
        let (target, weights) = target_and_weights(&mut rng, size * size * 3);
        weighted_sq_loss(&image, &target, &weights).1
    });
    // Rows the shapes' gradient leaves out still count for the colours.
    d[0].data[..3 * size * 20].fill(0.0);
    let [d_out, d_colour] = &d;

    let mut apart = zero_grads(&paths);
    let grad = PixelGrad {
        colour: Some(d_colour),
        ..PixelGrad::of(d_out)
    };
    raster.backward_of(&paths, base, grad, &mut apart);
    let (mut shapes, mut colours) = (zero_grads(&paths), zero_grads(&paths));
    raster.backward(&paths, base, d_out, &mut shapes);
    raster.backward(&paths, base, d_colour, &mut colours);
    for ((g, s), c) in apart.iter().zip(&shapes).zip(&colours) {
        assert_eq!(g.points, s.points);
        assert_eq!(g.opacity.to_bits(), s.opacity.to_bits());
        assert_eq!(g.color.map(f32::to_bits), c.color.map(f32::to_bits));
    }
    assert!(colours.iter().any(|c| c.color != [0.0; 3]));
}

#[test]
fn a_backward_with_a_factor_is_the_backward_of_the_product() {
    // dL/dPixel times a factor image, value by value, bit for bit as the backward of that
    // product made as an image; with the colours apart, both are multiplied.
    let size = 40;
    let mut rng = SplitMix64(35);
    let paths = mixed_scene(&mut rng, size as f32, 6, 2);
    let base = [1.0; 3];
    let mut raster = Rasterizer::new();
    let image = render(&mut raster, &paths, base, size);
    let [d_out, d_colour, factor] = [0, 1, 2].map(|_| {
        let (target, weights) = target_and_weights(&mut rng, size * size * 3);
        weighted_sq_loss(&image, &target, &weights).1
    });
    let times = |d: &Image| {
        let mut out = Image::default();
        product(d, &factor, &mut out);
        out
    };
    let (d_product, colour_product) = (times(&d_out), times(&d_colour));

    let mut scaled = zero_grads(&paths);
    let grad = PixelGrad {
        d: &d_out,
        colour: Some(&d_colour),
        factor: Some(&factor),
    };
    raster.backward_of(&paths, base, grad, &mut scaled);
    let mut expected = zero_grads(&paths);
    let grad = PixelGrad {
        colour: Some(&colour_product),
        ..PixelGrad::of(&d_product)
    };
    raster.backward_of(&paths, base, grad, &mut expected);
    for (g, e) in scaled.iter().zip(&expected) {
        assert_eq!(g.points, e.points);
        assert_eq!(g.opacity.to_bits(), e.opacity.to_bits());
        assert_eq!(g.color.map(f32::to_bits), e.color.map(f32::to_bits));
    }
    assert!(scaled.iter().any(|g| g.color != [0.0; 3]));
}
