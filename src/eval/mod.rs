//! Measuring covec: metrics of a scene against its input (MSE, PSNR, SSIM), peak memory, and the
//! `random` baseline (DiffVG-style random paths trained with the reconstruction loss only, on the
//! same engine, budget and total iteration count), so the value of COVec's initialisation and
//! decomposition shows side by side.

pub mod drawn;
pub mod edits;
pub mod faces;
pub mod intrinsic;
pub mod vec;

use std::sync::atomic::AtomicBool;
use std::time::Instant;

use crate::optim::loss::mse;
use crate::optim::rng::Rng;
use crate::optim::{Adam, AdamSettings, Bounds, reset_grads};
use crate::perceptual::{gaussian_kernel, ssim_means};
use crate::pipeline::stage::{Canvas, RunContext, StageKind, StageSpec};
use crate::pipeline::{Error, Observer, Params};
use crate::render::Image;
use crate::scene::{Path, Point, Scene};

/// Image-quality numbers of a reconstruction against its target (values in [0, 1]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Quality {
    /// Mean over pixels × channels of the squared difference.
    pub mse: f32,
    /// 10·log10(1 / MSE), in dB (capped at 100 for identical images).
    pub psnr: f32,
    /// Mean SSIM over the three channels (Gaussian window σ 1.5, 11 × 11, K1 0.01, K2 0.03).
    pub ssim: f32,
    /// GMSD on luma ([`crate::perceptual::gmsd`]): 0 for equal images, lower is better.
    pub gmsd: f32,
    /// MS-SSIM on luma ([`crate::perceptual::ms_ssim`]); `None` under 11 px.
    pub ms_ssim: Option<f32>,
}

/// MSE, PSNR, SSIM, GMSD and MS-SSIM of `reconstruction` against `target` (same size).
pub fn quality(reconstruction: &Image, target: &Image) -> Quality {
    let mse = crate::optim::loss::mse_value(reconstruction, target);
    let psnr = if mse > 1e-10 {
        -10.0 * mse.log10()
    } else {
        100.0
    };
    Quality {
        mse,
        psnr,
        ssim: ssim(reconstruction, target),
        gmsd: crate::perceptual::gmsd(target, reconstruction),
        ms_ssim: crate::perceptual::ms_ssim(target, reconstruction),
    }
}

/// SSIM (Wang et al. 2004) per channel with an 11 × 11 Gaussian window (σ 1.5) over the valid
/// region, averaged over channels; images smaller than the window are compared as one window.
pub fn ssim(a: &Image, b: &Image) -> f32 {
    const C1: f64 = 0.01 * 0.01;
    const C2: f64 = 0.03 * 0.03;
    let (w, h) = (a.width, a.height);
    let radius = 5usize.min((w.min(h).max(1) - 1) / 2);
    let kernel = gaussian_kernel(radius, 1.5);
    let channel = |img: &Image, c: usize| -> Vec<f64> {
        img.data
            .iter()
            .skip(c)
            .step_by(3)
            .map(|&v| f64::from(v))
            .collect()
    };
    let total: f64 = (0..3)
        .map(|c| ssim_means(&channel(a, c), &channel(b, c), w, h, &kernel, C1, C2).ssim)
        .sum();
    (total / 3.0) as f32
}

/// Peak resident memory of this process in bytes (`VmHWM`), if the platform reports it.
pub fn peak_memory_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Resets the peak-memory mark so the next [`peak_memory_bytes`] measures from now (Linux ≥ 4.0;
/// returns false where unsupported, in which case the peak covers the whole process).
pub fn reset_peak_memory() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

/// The random baseline's one stage.
const RANDOM_STAGES: &[StageSpec] = &[StageSpec {
    kind: StageKind::Reconstruct,
    name: "random",
    layers: &[crate::scene::LayerKind::Albedo],
    iterations: |it| it.total(),
    draft: false,
}];

/// The `random` baseline: an opaque full-canvas path of the mean colour plus `params.paths − 1`
/// DiffVG-style random paths (1-3 cubic segments with points within 5% of the canvas around a
/// random centre, random colour and opacity), all trained with the reconstruction loss for
/// as many iterations as covec's stages together ([`crate::Iterations::total`]). Albedo layer
/// only; same engine and Adam as covec. Progress is reported as one stage, `random`.
pub fn random_baseline(
    target: &Image,
    params: &Params,
    observer: &dyn Observer,
    cancel: &AtomicBool,
) -> Result<Scene, Error> {
    let (w, h) = (target.width, target.height);
    if params.paths < 1 {
        return Err(Error::Params("the budget must be at least one path".into()));
    }
    let mut rng = Rng::new(params.seed, 0x5241_4E44);
    let n = (w * h).max(1) as f32;
    let mut mean = [0.0f32; 3];
    for px in target.data.chunks_exact(3) {
        for c in 0..3 {
            mean[c] += px[c] / n;
        }
    }
    let mut scene = Scene::new(w as u32, h as u32, w as u32, h as u32);
    scene
        .albedo
        .paths
        .push(Path::rect(0.0, 0.0, w as f32, h as f32, mean, 1.0));
    let spread = 0.05 * w.max(h) as f32;
    for _ in 1..params.paths {
        let center = Point::new(rng.range(0.0, w as f32), rng.range(0.0, h as f32));
        let segments = 1 + (rng.next_u64() % 3) as usize;
        let points = (0..3 * segments)
            .map(|_| {
                let x = (center.x + rng.range(-spread, spread)).clamp(0.0, w as f32);
                let y = (center.y + rng.range(-spread, spread)).clamp(0.0, h as f32);
                Point::new(x, y)
            })
            .collect();
        let color = [rng.unit(), rng.unit(), rng.unit()];
        scene.albedo.paths.push(Path {
            points,
            color,
            opacity: rng.range(0.5, 1.0),
        });
    }
    let iterations = u32::try_from(params.iterations.total()).unwrap_or(u32::MAX);
    let context = RunContext::new(observer, cancel, RANDOM_STAGES);
    let stage = context.stage(0)?;
    let mut canvas = Canvas::new(w, h);
    let mut adam = Adam::new(AdamSettings::default(), Bounds::canvas(w, h, 1.0));
    let (mut render, mut d_render) = (Image::default(), Image::default());
    let mut grads = Vec::new();
    let started = Instant::now();
    for it in 0..iterations {
        canvas.render(&scene.albedo.paths, [1.0; 3], &mut render);
        let loss = mse(&render, target, &mut d_render);
        reset_grads(&mut grads, &scene.albedo.paths);
        canvas
            .raster
            .backward(&scene.albedo.paths, [1.0; 3], &d_render, &mut grads);
        adam.step(&mut scene.albedo.paths, &grads);
        stage.iteration(it + 1, iterations, Some(loss))?;
    }
    tracing::debug!(
        seconds = started.elapsed().as_secs_f32(),
        "random baseline done"
    );
    Ok(scene)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ssim_is_one_for_identical_images_and_drops_with_noise() {
        let scene = crate::synth::generate(32, 32, 2);
        assert!((ssim(&scene.image, &scene.image) - 1.0).abs() < 1e-6);
        let mut noisy = scene.image.clone();
        let mut rng = Rng::new(1, 1);
        noisy
            .data
            .iter_mut()
            .for_each(|v| *v = (*v + rng.range(-0.2, 0.2)).clamp(0.0, 1.0));
        let s = ssim(&noisy, &scene.image);
        assert!(s < 0.9 && s > 0.0, "{s}");
        let q = quality(&noisy, &scene.image);
        assert!(q.psnr > 10.0 && q.psnr < 30.0, "{q:?}");
    }

    /// For flat images SSIM reduces to the luminance term (2·μx·μy + C1) / (μx² + μy² + C1).
    #[test]
    fn ssim_of_flat_images_matches_the_closed_form() {
        let a = Image::filled(20, 16, [0.2, 0.5, 0.9]);
        let b = Image::filled(20, 16, [0.4, 0.5, 0.3]);
        let c1 = 1e-4f64;
        let expected: f64 = [(0.2, 0.4), (0.5, 0.5), (0.9, 0.3)]
            .iter()
            .map(|&(x, y): &(f64, f64)| (2.0 * x * y + c1) / (x * x + y * y + c1))
            .sum::<f64>()
            / 3.0;
        assert!((f64::from(ssim(&a, &b)) - expected).abs() < 1e-5);
    }

    #[test]
    fn peak_memory_is_reported() {
        assert!(peak_memory_bytes().unwrap_or(1) > 0);
    }
}
