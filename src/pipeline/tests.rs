//! The optimisation stages on a small synthetic scene, initialised by hand from its true layers
//! (so these tests do not depend on the decomposition): losses fall, the split keeps the
//! composite, the budget is exact, runs are deterministic and cancelable.

use std::sync::Mutex;
use std::sync::atomic::AtomicBool;

use image::GrayImage;

use super::coarse::CoarseSettings;
use super::optimise::{Optimisation, OptimiseReport, OptimiseSettings};
use super::stage::{RunContext, StageKind};
use super::structure::MaskGroup;
use super::{Error, Iterations, Observer, Params, Progress, Quiet, ResolvedMode};
use crate::decompose::mask::Mask;
use crate::render::Image;
use crate::scene::{LayerKind, Path, Scene};
use crate::synth::{self, SyntheticScene};

const SIZE: usize = 48;

fn params(paths: u32) -> Params {
    Params {
        paths,
        iterations: Iterations {
            structure: 10,
            reconstruction: 15,
            refine_rounds: 2,
            refine: 15,
            polish: 15,
        },
        ..Params::default()
    }
}

fn to_mask(gray: &GrayImage) -> Mask {
    Mask::from_fn(SIZE, SIZE, |x, y| gray.get_pixel(x as u32, y as u32)[0] > 0)
}

/// Bounding-box rectangle of a mask, `None` if empty.
fn bbox_path(mask: &GrayImage, color: [f32; 3]) -> Option<Path> {
    let (mut x0, mut y0, mut x1, mut y1) = (u32::MAX, u32::MAX, 0, 0);
    for (x, y, v) in mask.enumerate_pixels() {
        if v[0] > 0 {
            (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x + 1), y1.max(y + 1));
        }
    }
    (x0 != u32::MAX).then(|| Path::rect(x0 as f32, y0 as f32, x1 as f32, y1 as f32, color, 1.0))
}

fn mean_over(img: &Image, mask: &GrayImage) -> [f32; 3] {
    let mut sum = [0.0; 3];
    let mut n = 0.0f32;
    for (i, v) in mask.as_raw().iter().enumerate() {
        if *v > 0 {
            for c in 0..3 {
                sum[c] += img.data[3 * i + c];
            }
            n += 1.0;
        }
    }
    sum.map(|s| s / n.max(1.0))
}

/// A rough initialisation: one albedo path per true albedo region (its bounding box, mean image
/// colour) over a full-canvas base, and per region one illumination path on its darker half.
fn hand_init(truth: &SyntheticScene, photo: bool) -> (Scene, Vec<MaskGroup>) {
    let (w, h) = (SIZE as u32, SIZE as u32);
    let mut labels: Vec<[u32; 3]> = Vec::new();
    let mut masks: Vec<GrayImage> = Vec::new();
    for (i, px) in truth.albedo.data.chunks_exact(3).enumerate() {
        let key = [0, 1, 2].map(|c| (px[c] * 1000.0) as u32);
        let k = labels.iter().position(|l| *l == key).unwrap_or_else(|| {
            labels.push(key);
            masks.push(GrayImage::new(w, h));
            labels.len() - 1
        });
        masks[k].as_mut()[i] = 255;
    }
    let mut scene = Scene::new(w, h, w, h);
    let full = GrayImage::from_pixel(w, h, image::Luma([255]));
    scene.albedo.paths.push(Path::rect(
        0.0,
        0.0,
        w as f32,
        h as f32,
        mean_over(&truth.image, &full),
        1.0,
    ));
    let mut groups = vec![MaskGroup {
        layer: LayerKind::Albedo,
        paths: vec![0],
        masks: vec![to_mask(&full)],
    }];
    let mut regions = MaskGroup {
        layer: LayerKind::Albedo,
        paths: vec![],
        masks: vec![],
    };
    let mut shadows = MaskGroup {
        layer: LayerKind::Shade,
        paths: vec![],
        masks: vec![],
    };
    // The most frequent label is the background, covered by the base path.
    let background = (0..masks.len())
        .max_by_key(|&k| masks[k].as_raw().iter().filter(|&&v| v > 0).count())
        .unwrap();
    for (k, mask) in masks.iter().enumerate() {
        if k != background {
            let path = bbox_path(mask, mean_over(&truth.image, mask)).unwrap();
            regions.paths.push(scene.albedo.paths.len());
            regions.masks.push(to_mask(mask));
            scene.albedo.paths.push(path);
        }
        if photo {
            let luma = |i: usize| truth.image.data[3 * i..3 * i + 3].iter().sum::<f32>();
            let inside: Vec<usize> = (0..SIZE * SIZE).filter(|&i| mask.as_raw()[i] > 0).collect();
            let mean = inside.iter().map(|&i| luma(i)).sum::<f32>() / inside.len() as f32;
            let mut dark = GrayImage::new(w, h);
            for &i in &inside {
                if luma(i) <= mean {
                    dark.as_mut()[i] = 255;
                }
            }
            if let Some(path) = bbox_path(&dark, [0.8; 3]) {
                shadows.paths.push(scene.shade.paths.len());
                shadows.masks.push(to_mask(&dark));
                scene.shade.paths.push(path);
            }
        }
    }
    groups.push(regions);
    if photo {
        groups.push(shadows);
    }
    (scene, groups)
}

/// Counts progress reports and checks they are well formed.
#[derive(Default)]
struct Recorder {
    reports: Mutex<Vec<Progress>>,
    previews: Mutex<Vec<String>>,
}

impl Observer for Recorder {
    fn progress(&self, p: &Progress) {
        assert!(
            p.stage_index < p.stage_count && p.iteration <= p.iterations,
            "{p:?}"
        );
        self.reports.lock().unwrap().push(p.clone());
    }
    fn preview(&self, name: &str, image: &Image) {
        assert_eq!((image.width, image.height), (SIZE, SIZE));
        self.previews.lock().unwrap().push(name.to_string());
    }
}

fn run(
    mode: ResolvedMode,
    params: &Params,
    observer: &dyn Observer,
    cancel: &AtomicBool,
) -> Result<(Scene, OptimiseReport), Error> {
    run_with(mode, params, &CoarseSettings::default(), observer, cancel)
}

/// [`run`] with a coarse-to-fine schedule (the default leaves 48 px at full size): the mode's
/// optimisation stages, with their indices in the whole run.
fn run_with(
    mode: ResolvedMode,
    params: &Params,
    coarse: &CoarseSettings,
    observer: &dyn Observer,
    cancel: &AtomicBool,
) -> Result<(Scene, OptimiseReport), Error> {
    let truth = synth::generate(SIZE, SIZE, 5);
    let (scene, groups) = hand_init(&truth, mode == ResolvedMode::Photo);
    let settings = OptimiseSettings {
        coarse: *coarse,
        ..OptimiseSettings::default()
    };
    let mut optimisation =
        Optimisation::from_parts(scene, groups, truth.image, mode, false, params, &settings)?;
    let context = RunContext::new(observer, cancel, mode.stages());
    for (index, spec) in mode.stages().iter().enumerate() {
        if !matches!(spec.kind, StageKind::Decompose | StageKind::Init) {
            optimisation.run_stage(spec.kind, &context.stage(index)?)?;
        }
    }
    Ok((optimisation.scene, optimisation.report))
}

#[test]
fn photo_stages_lower_the_loss_keep_the_budget_and_preserve_the_split() {
    let recorder = Recorder::default();
    let (scene, report) = run(
        ResolvedMode::Photo,
        &params(20),
        &recorder,
        &AtomicBool::new(false),
    )
    .unwrap();
    let loss = |name: &str| *report.losses.iter().find(|l| l.stage == name).unwrap();
    let (structure, reconstruct) = (loss("structure"), loss("reconstruct"));
    assert!(reconstruct.after < structure.before, "{:?}", report.losses);
    for name in ["reconstruct", "refine", "polish"] {
        let l = loss(name);
        assert!(l.after < l.before, "{name}: {l:?}");
    }
    assert_eq!(scene.path_count(), 20);
    // The albedo base stays an opaque full-canvas rectangle (browsers need the opaque backdrop).
    let base = &scene.albedo.paths[0];
    let canvas = Path::rect(0.0, 0.0, SIZE as f32, SIZE as f32, base.color, 1.0);
    assert_eq!((&base.points, base.opacity), (&canvas.points, 1.0));
    let split = report.split.unwrap();
    assert_eq!(split.shade_paths, scene.shade.paths.len());
    assert!(split.mean_change < 0.03, "{split:?}");
    // Every value is in its SVG range.
    for kind in LayerKind::ALL {
        for p in &scene.layer(kind).paths {
            assert!(
                p.color.iter().all(|c| (0.0..=1.0).contains(c)) && (0.0..=1.0).contains(&p.opacity)
            );
        }
    }
    let reports = recorder.reports.lock().unwrap();
    let expected = 10 + 15 + 2 * 15 + 15;
    assert!(reports.iter().filter(|p| p.loss.is_some()).count() >= expected);
    let previews = recorder.previews.lock().unwrap();
    for name in [
        "03-reconstruct-composite",
        "04-refine-illumination",
        "05-split-light",
        "06-polish-composite",
    ] {
        assert!(
            previews.iter().any(|p| p == name),
            "{name} missing from {previews:?}"
        );
    }
}

#[test]
fn same_seed_gives_the_same_scene() {
    let cancel = AtomicBool::new(false);
    let a = run(ResolvedMode::Photo, &params(14), &Quiet, &cancel)
        .unwrap()
        .0;
    let b = run(ResolvedMode::Photo, &params(14), &Quiet, &cancel)
        .unwrap()
        .0;
    assert_eq!(
        serde_json::to_vec(&a).unwrap(),
        serde_json::to_vec(&b).unwrap()
    );
}

#[test]
fn simple_mode_grows_the_albedo_only() {
    let (scene, report) = run(
        ResolvedMode::Simple,
        &params(12),
        &Quiet,
        &AtomicBool::new(false),
    )
    .unwrap();
    assert_eq!(scene.albedo.paths.len(), 12);
    assert!(scene.shade.paths.is_empty() && scene.light.paths.is_empty());
    assert!(report.split.is_none());
    let refine = report.losses.iter().find(|l| l.stage == "refine").unwrap();
    assert!(refine.after < refine.before, "{refine:?}");
}

#[test]
fn cancel_stops_the_run() {
    let result = run(
        ResolvedMode::Photo,
        &params(14),
        &Quiet,
        &AtomicBool::new(true),
    );
    assert!(matches!(result, Err(Error::Canceled)));
}

#[test]
fn a_budget_below_the_initialisation_is_an_internal_error() {
    // The init stage keeps to the budget, so more paths than the budget after it is our bug.
    let result = run(
        ResolvedMode::Photo,
        &params(3),
        &Quiet,
        &AtomicBool::new(false),
    );
    assert!(matches!(result, Err(Error::Internal(_))));
}

/// Coarse to fine: the structure, most of the reconstruction and the first refinement round run
/// at 24 px, the rest at 48 px. Same result shape as a run at full size (budget, layers, SVG
/// ranges, full-size previews), a loss within reach of it, and progress that never goes back.
/// "Within reach": the polished loss at most twice the full-size run's. At this size the ratio
/// moves with the seed: 1.24-1.65 over seeds 0-7 with ellipse starts in the refinement,
/// 1.39-1.81 with outline starts (`RefineSettings::outline_vertices`), with or without the
/// polish's lightness floor (`PolishSettings::albedo_lightness_drop`).
#[test]
fn coarse_to_fine_keeps_the_result_shape_and_the_progress_order() {
    let coarse = CoarseSettings {
        min_size: 32,
        ..CoarseSettings::default()
    };
    assert!(coarse.applies(SIZE, SIZE) && !CoarseSettings::default().applies(SIZE, SIZE));
    let recorder = Recorder::default();
    let cancel = AtomicBool::new(false);
    let (scene, report) = run_with(
        ResolvedMode::Photo,
        &params(20),
        &coarse,
        &recorder,
        &cancel,
    )
    .unwrap();
    let (_, fine) = run(ResolvedMode::Photo, &params(20), &Quiet, &cancel).unwrap();
    assert_eq!(scene.path_count(), 20);
    assert_eq!((scene.width, scene.height), (SIZE as u32, SIZE as u32));
    for kind in LayerKind::ALL {
        for p in &scene.layer(kind).paths {
            assert!(
                p.points
                    .iter()
                    .all(|q| q.x.abs() <= 2.0 * SIZE as f32 && q.y.abs() <= 2.0 * SIZE as f32)
            );
        }
    }
    let polish = |r: &OptimiseReport| r.losses.iter().find(|l| l.stage == "polish").unwrap().after;
    assert!(
        polish(&report) < 2.0 * polish(&fine),
        "{:?} vs {:?}",
        report.losses,
        fine.losses
    );
    // Within each stage, reported iterations never decrease across the coarse/fine switch.
    let reports = recorder.reports.lock().unwrap();
    for pair in reports.windows(2) {
        if pair[0].stage == pair[1].stage {
            assert!(pair[1].iteration >= pair[0].iteration, "{:?}", pair);
            assert_eq!(pair[0].iterations, pair[1].iterations);
        }
    }
}
