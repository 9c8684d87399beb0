//! The whole pipeline on a synthetic scene with known albedo, shading and highlight: the albedo
//! layer must be well closer to the true albedo than the input is, and the light layer must sit on the
//! highlight. Also: byte-identical SVG for the same seed.

use std::sync::atomic::AtomicBool;

use crate::pipeline_support;

use covec::pipeline::{self, Inputs, Masks, Mode, Quiet};
use covec::render::Image;
use covec::render::Rasterizer;
use covec::render::composite::composite;
use covec::scene::{LayerKind, Scene};
use covec::svg::{SvgOptions, to_svg};
use covec::synth::{self, SyntheticScene, scale_invariant_mse};
use pipeline_support::quick_params;

const SIZE: usize = 64;

fn vectorize(truth: &SyntheticScene) -> Scene {
    let inputs = Inputs {
        image: image::DynamicImage::ImageRgb8(synth::to_rgb8(&truth.image)),
        albedo: None,
        masks: Masks::None,
    };
    pipeline::run(
        &inputs,
        &quick_params(Mode::Photo),
        &Quiet,
        &AtomicBool::new(false),
    )
    .unwrap()
    .scene
}

fn render_layer(scene: &Scene, kind: LayerKind) -> Image {
    let mut out = Image::default();
    Rasterizer::new().render(&scene.layer(kind).paths, kind.base(), SIZE, SIZE, &mut out);
    out
}

#[test]
fn albedo_beats_the_input_and_light_sits_on_the_highlight() {
    let truth = synth::generate(SIZE, SIZE, 11);
    let scene = vectorize(&truth);
    assert_eq!(scene.path_count(), 32);

    let albedo = render_layer(&scene, LayerKind::Albedo);
    let albedo_error = scale_invariant_mse(&albedo, &truth.albedo);
    let input_error = scale_invariant_mse(&truth.image, &truth.albedo);
    // Issue 11: seeds 0-15 give 0.07-0.62x; the Retinex map this replaced gave about 0.8x.
    assert!(
        albedo_error < 0.75 * input_error,
        "albedo layer {albedo_error} vs input {input_error}"
    );

    assert!(!scene.light.paths.is_empty(), "no light paths");
    let light = render_layer(&scene, LayerKind::Light);
    let highlight = truth.highlight_pixels(0.2);
    let mut on = 0.0;
    let mut off = 0.0;
    for p in 0..SIZE * SIZE {
        let v: f32 = light.data[3 * p..3 * p + 3].iter().sum::<f32>() / 3.0;
        if highlight.binary_search(&p).is_ok() {
            on += v
        } else {
            off += v
        }
    }
    let (on, off) = (
        on / highlight.len() as f32,
        off / (SIZE * SIZE - highlight.len()) as f32,
    );
    assert!(
        on > 0.05 && on > 3.0 * off,
        "light on the highlight {on}, elsewhere {off}"
    );

    // And the whole is a good reconstruction.
    let mse = covec::eval::quality(&composite(&scene), &truth.image).mse;
    assert!(mse < 0.01, "MSE {mse}");
}

#[test]
fn same_seed_gives_byte_identical_svg() {
    let truth = synth::generate(SIZE, SIZE, 4);
    let a = to_svg(&vectorize(&truth), &SvgOptions::default());
    let b = to_svg(&vectorize(&truth), &SvgOptions::default());
    assert!(a == b, "SVGs differ");
}
