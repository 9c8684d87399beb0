//! Final polish (beyond the paper): a short joint optimisation of all three layers under the exact
//! model a browser shows, `clamp01(R(A)·R(S) + R(L))`, with every value in its SVG range, so the
//! file is optimal for what is displayed rather than for the unclamped two-layer model.

use super::coarse::{Plateau, PlateauSettings};
use super::params::Error;
use super::stage::{Canvas, StageRun, hold_albedo_base};
use crate::geom::merge::merge_paths;
use crate::optim::loss::mse;
use crate::optim::{Adam, AdamSettings, Bounds, reset_grads};
use crate::render::Image;
use crate::render::composite::render_layers;
use crate::render::composite::{svg_model, svg_model_backward};
use crate::scene::{LayerKind, Point, Scene};

/// Settings of the polish.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct PolishSettings {
    /// Default: half the paper's rates, since the layers are already close.
    pub adam: AdamSettings,
    /// When the polish stops early.
    pub plateau: PlateauSettings,
    /// Before the polish, neighbouring cubics are merged (least area changed first) until the
    /// scene holds at most this many per path on average; the polish then retrains them.
    /// `None` keeps every segment.
    pub max_mean_segments: Option<f32>,
}

/// Default of [`PolishSettings::max_mean_segments`] (issue 12's bar).
pub const MAX_MEAN_SEGMENTS: f32 = 12.0;

impl Default for PolishSettings {
    fn default() -> Self {
        Self {
            adam: AdamSettings::default().scaled(0.5),
            plateau: PlateauSettings::default(),
            max_mean_segments: Some(MAX_MEAN_SEGMENTS),
        }
    }
}

/// Runs up to `iterations` joint steps and returns the MSE of the SVG model before and after.
pub(crate) fn polish(
    scene: &mut Scene,
    target: &Image,
    iterations: u32,
    settings: &PolishSettings,
    stage: &StageRun,
) -> Result<[f32; 2], Error> {
    let (w, h) = (target.width, target.height);
    if let Some(max_mean) = settings.max_mean_segments {
        merge_segments(scene, max_mean);
    }
    let mut canvas = Canvas::new(w, h);
    let mut adams: Vec<Adam> = LayerKind::ALL
        .iter()
        .map(|_| Adam::new(settings.adam, Bounds::canvas(w, h, 1.0)))
        .collect();
    // Files hold [0, 1] values: bring any illumination colour into range first.
    for kind in LayerKind::ALL {
        for path in &mut scene.layer_mut(kind).paths {
            Bounds::canvas(w, h, 1.0).project(path);
        }
    }
    let mut layers = [Image::default(), Image::default(), Image::default()];
    let mut d_layers = [Image::default(), Image::default(), Image::default()];
    let (mut composite, mut d_composite) = (Image::default(), Image::default());
    let mut grads = Vec::new();
    let initial = render_all(
        &mut canvas,
        scene,
        target,
        &mut layers,
        &mut composite,
        &mut d_composite,
    );
    let mut loss = initial;
    let mut plateau = Plateau::new(settings.plateau);
    for it in 0..iterations {
        if plateau.stop_after(loss) {
            break;
        }
        let [d_a, d_s, d_l] = &mut d_layers;
        svg_model_backward(
            &layers[0],
            &layers[1],
            &layers[2],
            &d_composite,
            d_a,
            d_s,
            d_l,
        );
        for (k, kind) in LayerKind::ALL.into_iter().enumerate() {
            let paths = &mut scene.layer_mut(kind).paths;
            reset_grads(&mut grads, paths);
            canvas
                .raster
                .backward(paths, kind.base(), &d_layers[k], &mut grads);
            if kind == LayerKind::Albedo {
                hold_albedo_base(&mut grads);
            }
            adams[k].step(paths, &grads);
        }
        loss = render_all(
            &mut canvas,
            scene,
            target,
            &mut layers,
            &mut composite,
            &mut d_composite,
        );
        stage.iteration(it + 1, iterations, Some(loss))?;
    }
    stage.preview("composite", &composite);
    for (k, kind) in LayerKind::ALL.into_iter().enumerate() {
        stage.preview(kind.name(), &layers[k]);
    }
    Ok([initial, loss])
}

/// Renders the three layers and the SVG composite; returns the MSE and writes its gradient.
fn render_all(
    canvas: &mut Canvas,
    scene: &Scene,
    target: &Image,
    layers: &mut [Image; 3],
    composite: &mut Image,
    d_composite: &mut Image,
) -> f32 {
    for (k, kind) in LayerKind::ALL.into_iter().enumerate() {
        canvas.render_layer(scene, kind, &mut layers[k]);
    }
    svg_model(&layers[0], &layers[1], &layers[2], composite);
    mse(composite, target, d_composite)
}

/// Least weight of an outline point in the merge (in colour units): where a path's outline
/// shows no contrast, its geometry still counts a little.
pub const MERGE_CONTRAST_FLOOR: f32 = 0.02;
/// How far either side of an outline the contrast across it is read, in pixels.
const CONTRAST_REACH: f32 = 1.5;

/// Merges segments over all layers' paths down to `max_mean` per path (see
/// [`crate::geom::merge`]). An outline point weighs by the contrast across it in its layer's
/// render (mean |inside − outside| over RGB, plus [`MERGE_CONTRAST_FLOOR`]): outlines hidden
/// under later paths or between near-equal colours give up their segments first.
fn merge_segments(scene: &mut Scene, max_mean: f32) {
    let layers = render_layers(scene);
    let Scene {
        albedo,
        shade,
        light,
        ..
    } = scene;
    let layer_of: Vec<usize> = [albedo.paths.len(), shade.paths.len(), light.paths.len()]
        .iter()
        .enumerate()
        .flat_map(|(k, &n)| std::iter::repeat_n(k, n))
        .collect();
    let mut points: Vec<&mut Vec<Point>> = albedo
        .paths
        .iter_mut()
        .chain(shade.paths.iter_mut())
        .chain(light.paths.iter_mut())
        .map(|p| &mut p.points)
        .collect();
    let contrast = |i: usize, p: Point, n: Point| {
        let image = &layers[layer_of[i]];
        let at = |s: f32| {
            let x = (p.x + s * n.x).floor().clamp(0.0, (image.width - 1) as f32) as usize;
            let y = (p.y + s * n.y)
                .floor()
                .clamp(0.0, (image.height - 1) as f32) as usize;
            image.pixel(x, y)
        };
        let (a, b) = (at(CONTRAST_REACH), at(-CONTRAST_REACH));
        MERGE_CONTRAST_FLOOR + (0..3).map(|c| (a[c] - b[c]).abs()).sum::<f32>() / 3.0
    };
    merge_paths(&mut points, contrast, max_mean);
}
