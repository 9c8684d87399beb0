//! The pipeline through its public API: the path budget, refused inputs, the auto mode.
//! (Binarisation, organisation and contour tracing are unit-tested beside their code.)

use std::sync::atomic::AtomicBool;

use covec::pipeline::{self, Inputs, Iterations, Masks, Mode, Params, Quiet, ResolvedMode};
use covec::synth::blobs_photo as synthetic_photo;
use image::{DynamicImage, GrayImage, RgbImage};

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
            if out.mode == ResolvedMode::Simple {
                assert!(out.scene.shade.paths.is_empty() && out.scene.light.paths.is_empty());
            }
        }
    }
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
    let run_at = |image: RgbImage, max_size: u32| {
        let inputs = Inputs {
            image: DynamicImage::ImageRgb8(image),
            albedo: None,
            masks: Masks::None,
        };
        let params = Params {
            max_size,
            ..Params::default()
        };
        let output = pipeline::run(&inputs, &params, &Quiet, &AtomicBool::new(false)).unwrap();
        assert!(
            output.mode_reason.starts_with("auto: "),
            "{}",
            output.mode_reason
        );
        output.mode
    };
    let run = |image: RgbImage| run_at(image, Params::default().max_size);
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
    assert_eq!(run(icon), ResolvedMode::Simple);
    assert_eq!(run(synthetic_photo(64, 48)), ResolvedMode::Photo);
    // A smooth, noiseless gradient (like an upscaled photo) is still a photo.
    let gradient = RgbImage::from_fn(300, 200, |x, y| {
        image::Rgb([(x * 255 / 299) as u8, (y * 255 / 199) as u8, 128])
    });
    assert_eq!(run(gradient), ResolvedMode::Photo);
    // A lit sphere on a flat backdrop: shading, however much of the image is one colour.
    let sphere = covec::synth::lit_sphere(64, [0.8, 0.3, 0.2], [0.55, 0.55, 0.58]);
    assert_eq!(run(sphere), ResolvedMode::Photo);
    // The choice is made on the input's pixels, not on a small working size that blurs an
    // emoji's details into texture.
    let fixture = |name: &str| {
        let path = format!("{}/tests/fixtures/{name}", env!("CARGO_MANIFEST_DIR"));
        image::open(path).unwrap().to_rgb8()
    };
    assert_eq!(
        run_at(fixture("emoji_red-apple.png"), 64),
        ResolvedMode::Simple
    );
    assert_eq!(
        run_at(fixture("photo96_scene_coffee.png"), 32),
        ResolvedMode::Photo
    );
}

/// Keeps every draft a run hands out, with the stage it came after.
#[derive(Default)]
struct Drafts(std::sync::Mutex<Vec<(String, covec::scene::Scene)>>);

impl pipeline::Observer for Drafts {
    fn progress(&self, _: &pipeline::Progress) {}
    fn preview(&self, _: &str, _: &covec::render::Image) {}
    fn draft(&self, stage: &str, scene: &covec::scene::Scene) {
        self.0
            .lock()
            .unwrap()
            .push((stage.to_owned(), scene.clone()));
    }
    fn wants_drafts(&self) -> bool {
        true
    }
}

#[test]
fn drafts_come_after_init_and_the_optimisation_stages_and_leave_the_result_alone() {
    let image = DynamicImage::ImageRgb8(synthetic_photo(64, 48));
    let inputs = Inputs {
        image,
        albedo: None,
        masks: Masks::None,
    };
    let params = Params {
        paths: 16,
        mode: Mode::Photo,
        iterations: Iterations {
            structure: 4,
            reconstruction: 4,
            refine_rounds: 1,
            refine: 4,
            polish: 4,
        },
        ..Params::default()
    };
    let cancel = AtomicBool::new(false);
    let drafts = Drafts::default();
    let with = pipeline::run(&inputs, &params, &drafts, &cancel).unwrap();
    let without = pipeline::run(&inputs, &params, &Quiet, &cancel).unwrap();
    assert_eq!(
        serde_json::to_vec(&with.scene).unwrap(),
        serde_json::to_vec(&without.scene).unwrap(),
        "drafts changed the result"
    );
    let drafts = drafts.0.into_inner().unwrap();
    let stages: Vec<&str> = drafts.iter().map(|(stage, _)| stage.as_str()).collect();
    // Not after the split (the refinement's draft is that picture) nor the polish (the output).
    assert_eq!(stages, ["init", "structure", "reconstruct", "refine"]);
    for (stage, scene) in &drafts {
        // In the SVG model: shade darkens only, every value in range, the picture's size.
        assert_eq!(
            (scene.original_width, scene.original_height),
            (with.scene.original_width, with.scene.original_height)
        );
        assert!(!scene.albedo.paths.is_empty(), "{stage}: no albedo");
        for kind in covec::scene::LayerKind::ALL {
            for path in &scene.layer(kind).paths {
                assert!(
                    path.color.iter().all(|c| (0.0..=1.0).contains(c))
                        && (0.0..=1.0).contains(&path.opacity),
                    "{stage}: {kind:?} path out of range"
                );
            }
        }
        assert!(scene.path_count() <= 16, "{stage}: over the budget");
    }
    // The drafts improve on the whole: the last is nearer the target than the first.
    let target = covec::imageio::to_rgb_image(&inputs.image);
    let error = |scene: &covec::scene::Scene| {
        let picture = covec::render::composite::composite(scene);
        let squares = picture
            .data
            .iter()
            .zip(&target.data)
            .map(|(a, b)| (a - b) * (a - b));
        squares.sum::<f32>() / target.data.len() as f32
    };
    let (first, last) = (error(&drafts[0].1), error(&drafts[drafts.len() - 1].1));
    assert!(last < first, "first draft {first}, last {last}");
}
