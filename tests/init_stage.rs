//! The init stage: region-wise binarisation, mask organisation, contour → path, path budget.

use std::sync::atomic::AtomicBool;

use covec::decompose::binarize::binarize;
use covec::decompose::mask::Mask;
use covec::decompose::{self, min_mask_area};
use covec::pipeline::init::{self, path_from_mask, simplify_tolerance};
use covec::pipeline::{self, Inputs, Iterations, Masks, Mode, Params, Quiet};
use covec::render::{Image, Rasterizer};
use image::{DynamicImage, GrayImage, RgbImage};

/// A deterministic "photo": smooth shading, several flat-albedo blobs, mild noise.
fn synthetic_photo(w: u32, h: u32) -> RgbImage {
    let mut state = 12345u32;
    let mut noise = move || {
        state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        (state >> 24) as f32 / 255.0 - 0.5
    };
    RgbImage::from_fn(w, h, |x, y| {
        let (fx, fy) = (x as f32 / w as f32, y as f32 / h as f32);
        let albedo = if (fx - 0.35).powi(2) + (fy - 0.4).powi(2) < 0.05 {
            [0.9, 0.3, 0.2]
        } else if fx > 0.6 && fy > 0.55 {
            [0.2, 0.4, 0.85]
        } else if fy < 0.2 {
            [0.3, 0.8, 0.3]
        } else {
            [0.85, 0.85, 0.8]
        };
        let shading = 0.45 + 0.55 * (1.0 - fx * 0.8) * (1.0 - fy * 0.3);
        image::Rgb(
            albedo.map(|a| ((a * shading + 0.03 * noise()).clamp(0.0, 1.0) * 255.0).round() as u8),
        )
    })
}

#[test]
fn region_wise_binarisation_thresholds_each_region_at_its_own_mean() {
    // Left region: 0.2 / 0.4 stripes; right region: 0.6 / 0.8 stripes. A global threshold
    // (0.5) would call the whole left half shadow and nothing on the right.
    let (w, h) = (40usize, 20usize);
    let value = |x: usize, y: usize| match (x < 20, y < 10) {
        (true, true) => 0.2,
        (true, false) => 0.4,
        (false, true) => 0.6,
        (false, false) => 0.8,
    };
    let mut image = Image::filled(w, h, [0.0; 3]);
    for y in 0..h {
        for x in 0..w {
            image.data[3 * (y * w + x)..3 * (y * w + x) + 3].copy_from_slice(&[value(x, y); 3]);
        }
    }
    let regions = [
        Mask::from_fn(w, h, |x, _| x < 20),
        Mask::from_fn(w, h, |x, _| x >= 20),
    ];
    let mut shadows: Vec<Mask> = binarize(&image, &regions, 4)
        .into_iter()
        .map(|c| c.mask)
        .collect();
    shadows.sort_by_key(|m| m.bbox());
    let expected = [
        Mask::from_fn(w, h, |x, y| x < 20 && y < 10),
        Mask::from_fn(w, h, |x, y| x >= 20 && y < 10),
    ];
    assert_eq!(shadows, expected);
}

#[test]
fn a_contained_mask_lands_in_a_higher_group() {
    let (w, h) = (48, 48);
    let square = |x0: u32, x1: u32| {
        GrayImage::from_fn(w, h, |x, y| {
            image::Luma([if (x0..x1).contains(&x) && (x0..x1).contains(&y) {
                255
            } else {
                0
            }])
        })
    };
    let inputs = Inputs {
        image: DynamicImage::ImageRgb8(synthetic_photo(w, h)),
        albedo: None,
        masks: Masks::Binary(vec![square(20, 28), square(4, 44)]),
    };
    let params = Params {
        mode: Mode::Photo,
        ..Params::default()
    };
    let decomposition = decompose::run(&inputs, &params, 16).unwrap();
    let state = init::run(decomposition, &params, (w, h)).unwrap();
    let group_of = |area: usize| {
        state
            .albedo
            .groups
            .iter()
            .position(|g| g.iter().any(|m| m.mask.area() == area))
            .unwrap_or_else(|| panic!("no mask of area {area}"))
    };
    assert_eq!(group_of(48 * 48), 0, "the full canvas is the bottom group");
    assert!(group_of(40 * 40) > group_of(48 * 48));
    assert!(
        group_of(8 * 8) > group_of(40 * 40),
        "the inner square sits above the outer one"
    );
    // Albedo path 0 is the opaque full-canvas base.
    let base = &state.scene.albedo.paths[0];
    assert_eq!(base.opacity, 1.0);
    assert_eq!(state.albedo.groups[0][0].path, 0);
}

#[test]
fn contour_and_douglas_peucker_of_a_disc_render_back_to_the_disc() {
    let (w, h) = (64usize, 64usize);
    let disc = Mask::from_fn(w, h, |x, y| {
        (x as f32 + 0.5 - 30.0).powi(2) + (y as f32 + 0.5 - 33.0).powi(2) <= 20.0f32.powi(2)
    });
    let path =
        path_from_mask(&disc, simplify_tolerance(w, h), [1.0; 3]).expect("a disc gives a path");
    assert!(
        path.segment_count() >= 8,
        "{} segments",
        path.segment_count()
    );
    assert!(
        path.segment_count() < 60,
        "simplified: {} segments",
        path.segment_count()
    );
    let closed_ok = path.segment(path.segment_count() - 1)[3] == path.points[0];
    assert!(closed_ok, "the last segment ends at the start");
    let mut image = Image::default();
    Rasterizer::new().render(&[path], [0.0; 3], w, h, &mut image);
    let (mut inter, mut union) = (0.0f32, 0.0f32);
    for i in 0..w * h {
        let (c, d) = (
            image.data[3 * i],
            if disc.contains_index(i) { 1.0 } else { 0.0 },
        );
        inter += c.min(d);
        union += c.max(d);
    }
    assert!(inter / union >= 0.95, "IoU {}", inter / union);
}

#[test]
fn the_path_budget_is_never_exceeded() {
    let image = DynamicImage::ImageRgb8(synthetic_photo(64, 48));
    for mode in [Mode::Photo, Mode::Simple, Mode::Auto] {
        for paths in [8u32, 9, 13, 64, 200, 1024] {
            // No optimisation iterations and no refinement rounds: the output is the init scene.
            let params = Params {
                paths,
                mode,
                iterations: Iterations {
                    structure: 0,
                    reconstruction: 0,
                    refine_rounds: 0,
                    refine: 0,
                    polish: 0,
                },
                ..Params::default()
            };
            let inputs = Inputs {
                image: image.clone(),
                albedo: None,
                masks: Masks::None,
            };
            let out = pipeline::run(&inputs, &params, &Quiet, &AtomicBool::new(false)).unwrap();
            let count = out.scene.path_count();
            assert!(count <= paths as usize, "{mode:?} {paths}: {count} paths");
            assert!(
                count as f32 <= (0.4 * paths as f32).max(1.0),
                "init keeps to the structure share: {count} of {paths}"
            );
            assert!(count >= 1, "the base path is always there");
            if out.mode == Mode::Simple {
                assert!(out.scene.shade.paths.is_empty() && out.scene.light.paths.is_empty());
            }
        }
    }
}

#[test]
fn tiny_masks_are_dropped_and_holes_filled() {
    let (w, h) = (64u32, 64u32);
    // A ring (hole inside) plus a 2×2 speck far away.
    let mask = GrayImage::from_fn(w, h, |x, y| {
        let r2 = (x as i32 - 30).pow(2) + (y as i32 - 30).pow(2);
        let ring = (100..400).contains(&r2);
        let speck = x >= 60 && y >= 60 && x < 62 && y < 62;
        image::Luma([if ring || speck { 255 } else { 0 }])
    });
    let inputs = Inputs {
        image: DynamicImage::ImageRgb8(synthetic_photo(w, h)),
        albedo: None,
        masks: Masks::Binary(vec![mask]),
    };
    let params = Params {
        mode: Mode::Photo,
        ..Params::default()
    };
    let decomposition = decompose::run(&inputs, &params, 16).unwrap();
    assert!(min_mask_area(64, 64) > 4);
    assert_eq!(decomposition.candidates.len(), 1, "the speck is dropped");
    let ring = &decomposition.candidates[0].mask;
    assert!(ring.contains(30, 30), "the hole is filled");
}

#[test]
fn bad_masks_and_parameters_are_refused() {
    let image = DynamicImage::ImageRgb8(synthetic_photo(64, 48));
    let wrong_aspect = Inputs {
        image: image.clone(),
        albedo: None,
        masks: Masks::Binary(vec![GrayImage::new(64, 64)]),
    };
    let err = pipeline::run(
        &wrong_aspect,
        &Params::default(),
        &Quiet,
        &AtomicBool::new(false),
    )
    .err()
    .unwrap();
    assert!(err.to_string().contains("aspect ratio"), "{err}");
    let inputs = Inputs {
        image,
        albedo: None,
        masks: Masks::None,
    };
    let err = pipeline::run(
        &inputs,
        &Params {
            paths: 7,
            ..Params::default()
        },
        &Quiet,
        &AtomicBool::new(false),
    )
    .err()
    .unwrap();
    assert!(err.to_string().contains("8-1024"), "{err}");
    let canceled = pipeline::run(&inputs, &Params::default(), &Quiet, &AtomicBool::new(true))
        .err()
        .unwrap();
    assert!(matches!(canceled, pipeline::Error::Canceled));
}

#[test]
fn auto_mode_tells_flat_artwork_from_photos() {
    let run = |image: RgbImage| {
        let inputs = Inputs {
            image: DynamicImage::ImageRgb8(image),
            albedo: None,
            masks: Masks::None,
        };
        pipeline::run(&inputs, &Params::default(), &Quiet, &AtomicBool::new(false))
            .unwrap()
            .mode
    };
    // An icon: a few flat shapes on white (anti-aliased edges do not matter).
    let icon = RgbImage::from_fn(64, 64, |x, y| {
        let r2 = (x as i32 - 32).pow(2) + (y as i32 - 32).pow(2);
        image::Rgb(if r2 < 100 {
            [40, 40, 40]
        } else if r2 < 700 {
            [250, 200, 30]
        } else {
            [255, 255, 255]
        })
    });
    assert_eq!(run(icon), Mode::Simple);
    assert_eq!(run(synthetic_photo(64, 48)), Mode::Photo);
    // A smooth, noiseless gradient (like an upscaled photo) is still a photo.
    let gradient = RgbImage::from_fn(300, 200, |x, y| {
        image::Rgb([(x * 255 / 299) as u8, (y * 255 / 199) as u8, 128])
    });
    assert_eq!(run(gradient), Mode::Photo);
}
