//! The paper's claim for editing (Sec. 5.2, Appendix D): with the lighting in its own layers, a
//! recolour by reference reproduces the true edit better than an albedo-only vectorisation does.
//! Ground truth: a synthetic scene whose albedo region is recoloured under the same shading and
//! highlight.

use std::sync::atomic::AtomicBool;

use crate::pipeline_support;

use covec::edit::{ReferenceParams, recolor_by_reference};
use covec::pipeline::{self, Inputs, Masks, Mode, Quiet};
use covec::render::Image;
use covec::render::composite::composite;
use covec::scene::{LayerKind, Scene};
use covec::synth::{self, SyntheticScene};
use pipeline_support::quick_params;

const SIZE: usize = 64;

fn vectorize(truth: &SyntheticScene, mode: Mode) -> Scene {
    let params = quick_params(mode);
    let inputs = Inputs {
        image: image::DynamicImage::ImageRgb8(synth::to_rgb8(&truth.image)),
        albedo: None,
        masks: Masks::None,
    };
    pipeline::run(&inputs, &params, &Quiet, &AtomicBool::new(false))
        .unwrap()
        .scene
}

/// The scene's image with the albedo of its largest disc replaced by `colour`, lighting kept.
fn recoloured(truth: &SyntheticScene, colour: [f32; 3]) -> Image {
    let at = 3 * ((SIZE * 38 / 100) * SIZE + SIZE * 35 / 100);
    let old: [f32; 3] = truth.albedo.data[at..at + 3].try_into().unwrap();
    let mut image = truth.image.clone();
    for (i, a) in truth.albedo.data.chunks_exact(3).enumerate() {
        if a == old {
            for c in 0..3 {
                let j = 3 * i + c;
                image.data[j] =
                    (colour[c] * truth.shading.data[j] + truth.highlight.data[j]).clamp(0.0, 1.0);
            }
        }
    }
    image
}

fn mse(a: &Image, b: &Image) -> f32 {
    a.data
        .iter()
        .zip(&b.data)
        .map(|(x, y)| (x - y).powi(2))
        .sum::<f32>()
        / a.data.len() as f32
}

/// Only 8-bit images reach covec, so the reference is quantised like the original.
fn quantised(image: &Image) -> Image {
    Image {
        data: image
            .data
            .iter()
            .map(|v| (v * 255.0).round() / 255.0)
            .collect(),
        ..image.clone()
    }
}

#[test]
fn three_layer_edits_follow_the_true_edit_better_than_albedo_only() {
    let truth = synth::generate(SIZE, SIZE, 11);
    let original = quantised(&truth.image);
    let target = quantised(&recoloured(&truth, [0.25, 0.45, 0.9]));
    let photo = vectorize(&truth, Mode::Photo);
    let simple = vectorize(&truth, Mode::Simple);
    assert_eq!(photo.path_count(), simple.path_count(), "same budget");

    let mut curve = Vec::new();
    for k in [1, 2, 4, 8, 16] {
        let params = ReferenceParams {
            k,
            ..ReferenceParams::default()
        };
        let error = |scene: &Scene| {
            let edit = recolor_by_reference(scene, &original, &target, &params).unwrap();
            let albedo = edit
                .changed
                .iter()
                .filter(|c| c.path.layer == LayerKind::Albedo);
            assert!((1..=k).contains(&albedo.count()), "k = {k}");
            mse(&composite(&edit.scene), &target)
        };
        curve.push((k, error(&photo), error(&simple)));
    }
    println!("K  photo-MSE  simple-MSE\n{curve:#?}");
    // The bar is K ≤ 4. Before reference edits refit the edited object's own shade and
    // light paths, the photo model lost narrowly at K = 1 (0.0076 vs 0.0071): its albedo splits
    // the edited disc into more paths, so one path covers less of it. From K = 8 simple mode
    // recolours most of its albedo paths and both errors are about each mode's own fit of the
    // picture (0.00037 and 0.00034 at 32 paths, where the polish weighs edges more than at 64
    // since cf4147c; photo mode won at every K before that).
    for &(k, photo_error, simple_error) in curve.iter().filter(|(k, ..)| *k <= 4) {
        assert!(
            photo_error < simple_error,
            "K = {k}: photo {photo_error} vs simple {simple_error}"
        );
    }
}
