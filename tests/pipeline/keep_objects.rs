//! Issue 21: paths keep to the objects the client's labels name. A generated scene (64 px) with
//! a small disc (≈ 100 px) painted on its wall runs through the whole pipeline with its true
//! labels as `--labels`: the albedo path of every region must still fit it (IoU ≥ 0.9, the
//! disc's ≥ 0.8), and no shade or light path may have more than 15% of its area outside its
//! parent region (the region holding most of it).

use std::sync::atomic::AtomicBool;

use crate::pipeline_support;

use covec::eval::intrinsic::Truth;
use covec::eval::vec::iou;
use covec::pipeline::{self, Inputs, Masks, Mode, Quiet};
use covec::render::{Image, Rasterizer};
use covec::scene::{Path, Scene};
use covec::synth;
use pipeline_support::quick_params;

const SIZE: usize = 64;
/// Label of the painted disc (the scene's own labels are 0 floor, 1 wall, 2 + k sphere k).
const DISC: u8 = 5;

/// The "sphere" scene with a disc of radius 5.6 px (≈ 100 px) painted on the wall, its label
/// map, and the regions (one per label) as masks.
fn scene_with_disc() -> (Image, image::DynamicImage, Vec<Vec<bool>>) {
    let lit = synth::scenes::scene(0, SIZE);
    let mut truth = Truth::from(lit);
    let objects = truth
        .objects
        .as_mut()
        .expect("generated scenes have labels");
    let (cx, cy) = (12.0f32, 12.0f32);
    for y in 0..SIZE {
        for x in 0..SIZE {
            if (x as f32 + 0.5 - cx).hypot(y as f32 + 0.5 - cy) <= 5.6 {
                let i = y * SIZE + x;
                assert_eq!(objects[i], 1, "the disc lies on the wall");
                objects[i] = DISC;
                truth.image.data[3 * i..3 * i + 3].copy_from_slice(&[0.1, 0.6, 0.2]);
            }
        }
    }
    let masks = truth.object_masks();
    let labels = truth.label_map().expect("labels");
    (truth.image, labels, masks)
}

fn vectorize(image: &Image, labels: image::DynamicImage) -> Scene {
    let params = quick_params(Mode::Photo);
    let inputs = Inputs {
        image: image::DynamicImage::ImageRgb8(synth::to_rgb8(image)),
        albedo: None,
        masks: Masks::Labels(labels),
    };
    pipeline::run(&inputs, &params, &Quiet, &AtomicBool::new(false))
        .expect("the pipeline runs")
        .scene
}

/// The path's own coverage (opacity ignored) as `(pixel, coverage)`.
fn coverage(path: &Path) -> Vec<(u32, f32)> {
    let silhouette = Path {
        color: [1.0; 3],
        opacity: 1.0,
        ..path.clone()
    };
    let mut out = Image::default();
    Rasterizer::new().render(&[silhouette], [0.0; 3], SIZE, SIZE, &mut out);
    (0..SIZE * SIZE)
        .filter(|&i| out.data[3 * i] > 0.0)
        .map(|i| (i as u32, out.data[3 * i].min(1.0)))
        .collect()
}

#[test]
fn albedo_paths_keep_their_regions_and_illumination_paths_their_parents() {
    let (image, labels, masks) = scene_with_disc();
    let scene = vectorize(&image, labels);
    let albedo: Vec<_> = scene.albedo.paths.iter().skip(1).map(coverage).collect();
    let disc = masks.len() - 1;
    for (k, mask) in masks.iter().enumerate() {
        let best = albedo.iter().map(|c| iou(c, mask)).fold(0.0, f32::max);
        let area = mask.iter().filter(|&&m| m).count();
        let bar = if k == disc { 0.8 } else { 0.9 };
        assert!(
            best >= bar,
            "region {k} ({area} px): albedo path IoU {best:.3}"
        );
    }
    let illumination = scene.shade.paths.iter().chain(&scene.light.paths);
    for (n, path) in illumination.enumerate() {
        let c = coverage(path);
        let area: f32 = c.iter().map(|&(_, v)| v).sum();
        if area <= 0.0 {
            continue;
        }
        let inside = |mask: &Vec<bool>| -> f32 {
            c.iter()
                .filter(|&&(i, _)| mask[i as usize])
                .map(|&(_, v)| v)
                .sum()
        };
        let parent = masks.iter().map(inside).fold(0.0, f32::max);
        let outside = 1.0 - parent / area;
        assert!(
            outside <= 0.15,
            "illumination path {n}: {:.0}% outside its parent",
            100.0 * outside
        );
    }
}
