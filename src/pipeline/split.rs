//! Layer separation (paper Appendix C): the illumination layer (held in `scene.shade`) splits into
//! shade paths (max colour ≤ 1, kept as they are) and light paths (max colour > 1), which keep
//! their shapes, get opacity 1 and the mean of the residual `I − R(A)·R(S)` over their area.

use super::stage::{Canvas, StageRun};
use crate::optim::loss::mse_value;
use crate::render::Image;
use crate::render::composite::{product, svg_model};
use crate::scene::{LayerKind, Path, Scene};

/// How the separation went, for logs and tests.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SplitReport {
    pub shade_paths: usize,
    pub light_paths: usize,
    /// MSE against the target of the two-layer composite before and of the SVG model after.
    pub mse_before: f32,
    pub mse_after: f32,
    /// Mean absolute difference between the two composites.
    pub mean_change: f32,
}

/// Splits the illumination layer in place (paper rule, no tolerance); hands the result's
/// previews to `previews`' stage, if any.
pub(crate) fn split_layers(
    scene: &mut Scene,
    target: &Image,
    previews: Option<&StageRun>,
) -> SplitReport {
    let (w, h) = (target.width, target.height);
    let mut canvas = Canvas::new(w, h);
    // Full-size images live only while they are needed: they are a job's largest buffers.
    let (mut albedo, mut before) = (Image::default(), Image::default());
    canvas.render_layer(scene, LayerKind::Albedo, &mut albedo);
    {
        let mut illumination = Image::default();
        canvas.render_layer(scene, LayerKind::Shade, &mut illumination);
        product(&albedo, &illumination, &mut before);
    }

    let (shade, lights): (Vec<Path>, Vec<Path>) = std::mem::take(&mut scene.shade.paths)
        .into_iter()
        .partition(|p| p.color.iter().all(|&c| c <= 1.0));
    scene.shade.paths = shade;
    let mut shaded = Image::default();
    canvas.render_layer(scene, LayerKind::Shade, &mut shaded);
    let mut residual_base = Image::default();
    product(&albedo, &shaded, &mut residual_base);

    scene.light.paths = lights
        .into_iter()
        .map(|path| {
            let coverage = canvas.coverage(&path);
            let area: f32 = coverage.iter().map(|&(_, a)| a).sum();
            let mut color = [0.0; 3];
            for &(p, a) in &coverage {
                let p = p as usize;
                for c in 0..3 {
                    color[c] += a * (target.data[3 * p + c] - residual_base.data[3 * p + c]);
                }
            }
            let color = color.map(|c| {
                if area > 0.0 {
                    (c / area).clamp(0.0, 1.0)
                } else {
                    0.0
                }
            });
            Path {
                points: path.points,
                color,
                opacity: 1.0,
            }
        })
        .collect();
    drop(residual_base);

    let mut light = Image::default();
    canvas.render_layer(scene, LayerKind::Light, &mut light);
    let mut after = Image::default();
    svg_model(&albedo, &shaded, &light, &mut after);
    let mean_change = before
        .data
        .iter()
        .zip(&after.data)
        .map(|(a, b)| (a.clamp(0.0, 1.0) - b).abs())
        .sum::<f32>()
        / after.data.len().max(1) as f32;
    if let Some(stage) = previews {
        stage.preview("composite", &after);
        stage.preview("albedo", &albedo);
        stage.preview("shade", &shaded);
        stage.preview("light", &light);
    }
    SplitReport {
        shade_paths: scene.shade.paths.len(),
        light_paths: scene.light.paths.len(),
        mse_before: mse_value(&before, target),
        mse_after: mse_value(&after, target),
        mean_change,
    }
}
