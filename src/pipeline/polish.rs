//! Final polish (beyond the paper): a short joint optimisation of all three layers under the exact
//! model a browser shows, `clamp01(R(A)·R(S) + R(L))`, with every value in its SVG range, so the
//! file is optimal for what is displayed rather than for the unclamped two-layer model. Its loss
//! adds a gradient-similarity term to the MSE ([`PolishSettings::gradient_similarity`]).

use std::ops::Range;

use rayon::prelude::*;

use super::coarse::PlateauSettings;
use super::descent::{Descent, Objective};
use super::keep::{Held, KeepRun};
use super::params::{Error, ResolvedMode};
use super::stage::{Canvas, IterationSpan, StageRun, hold_albedo_base};
use super::structure::StructureSettings;
use crate::edit::albedo_owner;
use crate::optim::loss::mse;
use crate::optim::{Adam, AdamSettings, Bounds};
use crate::perceptual::GradientSimilarity;
use crate::render::composite::{svg_model, svg_model_backward};
use crate::render::{Image, PathGrad, PixelGrad, Rasterizer};
use crate::scene::{LayerKind, Path, Scene};

/// Settings of the polish.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct PolishSettings {
    /// Adam in photo mode. Default: the paper's point rate (a pixel a step, at each size the
    /// polish runs at) with half its colour and opacity rates: a photo's edges need the full
    /// step to reach them in the polish's few iterations (docs/history.md, "The polish").
    pub photo_adam: AdamSettings,
    /// Adam in simple mode. Default: half the paper's rates. Flat artwork's edges sit where
    /// its colours step, and a pixel a step overshoots them (docs/history.md, "The
    /// polish").
    pub simple_adam: AdamSettings,
    /// When the polish stops early.
    pub plateau: PlateauSettings,
    /// Weight of 1 − GMSM, the mean of GMSD's gradient similarity map
    /// ([`GradientSimilarity`]), beside the MSE: a departure from the paper, whose loss is the
    /// MSE alone (weight 0). The MSE rewards a blurred edge as much as a sharp one a pixel off;
    /// the term asks for the photo's edges where the photo has them. Default 0.01, the weight
    /// that buys the bench photos a clearly lower GMSD for a little MSE. This is
    /// the weight for images of up to 256² pixels at 64 paths; larger images and other budgets
    /// get more ([`PolishSettings::similarity_weight`]). Above 64 paths the fill colours see it
    /// at its weight at 64 paths ([`PolishSettings::similarity_weights`]).
    pub gradient_similarity: f32,
    /// How far the polish may lower an albedo fill's lightness (the mean of its channels) below
    /// its value when the stage began, in photo mode (no limit in simple mode, whose albedo is
    /// the picture); rising is free. Left free, the MSE lowers a surface's fill to the mean of
    /// its lit and darker parts wherever no shade path holds the darker ones, and skin and
    /// shadowed white surfaces went grey in the albedo. Default 0.005, the loosest that keeps
    /// the Cornell scenes' albedo right (docs/history.md, "The polish").
    pub albedo_lightness_drop: f32,
    /// Share of the canvas a fill must own for [`Self::albedo_lightness_drop`] to hold it.
    /// Default 1-30 %. A fill owning more is at low path counts the picture's base tone over
    /// several surfaces, whose mean the MSE rightly asks for; fills under 1 % are at high path
    /// counts pieces of a textured surface (docs/history.md, "The polish").
    pub lightness_floor_share: Range<f32>,
}

/// Side (the square root of the pixel count) up to which the gradient-similarity term has its
/// set weight: the size of the bench photos the weight was chosen on.
const SIMILARITY_REFERENCE_SIDE: f32 = 256.0;

/// How the term's weight grows with the side above [`SIMILARITY_REFERENCE_SIDE`]. The same
/// picture at twice the size has half the gradient per pixel, and where gradients are small
/// against GMSD's constant the term is quadratic in them (exponent 2); where they are large it
/// does not change (0). 1.5: the largest that keeps the MSE of a set of 512² photos no worse
/// than without the growth (docs/history.md, "The polish").
const SIMILARITY_SIZE_EXPONENT: f32 = 1.5;

/// The path budget the set weight was chosen at (also the default budget, `Params::paths`).
const SIMILARITY_REFERENCE_PATHS: f32 = 64.0;

/// How the term's weight grows with the budget's ratio to [`SIMILARITY_REFERENCE_PATHS`],
/// below it and above it. Away from 64 paths the MSE alone left edges that VTracer's files of
/// the same gzip bytes draw better, with MSE to spare: the weight buys GMSD with it.
/// Exponents from `benches/quality/rd.sh` (docs/benchmarks.md, "Rate and distortion against
/// VTracer").
const SIMILARITY_PATHS_EXPONENTS: (f32, f32) = (1.0, 1.3);

/// The largest budget the exponents were measured at; above it the weight stays at its value
/// there, since growing on cost far more MSE than it gave GMSD (docs/benchmarks.md, "Rate
/// and distortion against VTracer").
const SIMILARITY_PATHS_CAP: f32 = 256.0;

/// The gradient-similarity term's weights for one job.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct SimilarityWeights {
    /// In the gradient of the points and opacities.
    pub shapes: f32,
    /// In the gradient of the fill colours (at most `shapes`).
    pub colours: f32,
}

impl PolishSettings {
    /// The Adam settings for a job in `mode`.
    pub(crate) fn adam(&self, mode: ResolvedMode) -> AdamSettings {
        match mode {
            ResolvedMode::Photo => self.photo_adam,
            ResolvedMode::Simple => self.simple_adam,
        }
    }

    /// The gradient-similarity weight for a job whose full-size image has `pixels` pixels and
    /// whose budget is `paths`: the set weight up to [`SIMILARITY_REFERENCE_SIDE`]² at
    /// [`SIMILARITY_REFERENCE_PATHS`], growing with the side above it and with the budget's
    /// distance from it (up to [`SIMILARITY_PATHS_CAP`]). One weight for a job's coarse and
    /// full-size parts, since both fit the same picture.
    pub(crate) fn similarity_weight(&self, pixels: usize, paths: u32) -> f32 {
        let side_ratio = (pixels as f32).sqrt() / SIMILARITY_REFERENCE_SIDE;
        let paths_ratio = (paths as f32).min(SIMILARITY_PATHS_CAP) / SIMILARITY_REFERENCE_PATHS;
        let (below, above) = SIMILARITY_PATHS_EXPONENTS;
        let paths_factor = if paths_ratio < 1.0 {
            paths_ratio.recip().powf(below)
        } else {
            paths_ratio.powf(above)
        };
        self.gradient_similarity * side_ratio.max(1.0).powf(SIMILARITY_SIZE_EXPONENT) * paths_factor
    }

    /// [`Self::similarity_weight`] for the shapes; for the colours, the weight at
    /// [`SIMILARITY_REFERENCE_PATHS`] when the budget is above it. The term asks for the
    /// photo's edges, and grown for large budgets it also pulled fill colours, skin's among
    /// them, away from the photo's to sharpen texture (docs/history.md, "The polish").
    pub(crate) fn similarity_weights(&self, pixels: usize, paths: u32) -> SimilarityWeights {
        let reference = SIMILARITY_REFERENCE_PATHS as u32;
        SimilarityWeights {
            shapes: self.similarity_weight(pixels, paths),
            colours: self.similarity_weight(pixels, paths.min(reference)),
        }
    }
}

impl Default for PolishSettings {
    fn default() -> Self {
        let halved = AdamSettings::default().scaled(0.5);
        Self {
            photo_adam: AdamSettings {
                points: AdamSettings::default().points,
                ..halved
            },
            simple_adam: halved,
            plateau: PlateauSettings::default(),
            gradient_similarity: 0.01,
            albedo_lightness_drop: 0.005,
            lightness_floor_share: 0.01..0.3,
        }
    }
}

/// The lowest lightness each albedo fill may take in the polish
/// ([`PolishSettings::albedo_lightness_drop`]), one per albedo path, taken when the stage begins
/// so that its coarse and full-size parts share it.
pub(crate) struct LightnessFloor(Vec<f32>);

impl LightnessFloor {
    /// The floor for a job in `mode`: none in simple mode; none for a fill that owns (holds at
    /// the top of the albedo layer, as an edit's silhouettes do) a share of the canvas outside
    /// [`PolishSettings::lightness_floor_share`].
    pub(crate) fn new(
        scene: &Scene,
        settings: &PolishSettings,
        mode: ResolvedMode,
    ) -> Option<Self> {
        (mode == ResolvedMode::Photo).then(|| {
            let (width, height) = (scene.width as usize, scene.height as usize);
            let mut owned = vec![0usize; scene.albedo.paths.len()];
            for index in albedo_owner(&mut Rasterizer::new(), scene, width, height)
                .into_iter()
                .flatten()
            {
                owned[index] += 1;
            }
            let canvas = (width * height) as f32;
            let floor = scene.albedo.paths.iter().zip(owned).map(|(path, area)| {
                if settings
                    .lightness_floor_share
                    .contains(&(area as f32 / canvas))
                {
                    lightness(path.color) - settings.albedo_lightness_drop
                } else {
                    f32::NEG_INFINITY
                }
            });
            Self(floor.collect())
        })
    }

    /// Lifts each fill below its floor by the difference, on every channel (its hue kept, up
    /// to the clamp to 1).
    fn apply(&self, paths: &mut [Path]) {
        for (path, &floor) in paths.iter_mut().zip(&self.0) {
            let lift = floor - lightness(path.color);
            if lift > 0.0 {
                path.color
                    .iter_mut()
                    .for_each(|c| *c = (*c + lift).min(1.0));
            }
        }
    }
}

fn lightness(color: [f32; 3]) -> f32 {
    color.iter().sum::<f32>() / 3.0
}

/// Files hold [0, 1] values: brings any illumination colour (and every point and opacity) into
/// its SVG range.
pub(crate) fn into_range(scene: &mut Scene) {
    let bounds = Bounds::canvas(scene.width as usize, scene.height as usize, 1.0);
    for kind in LayerKind::ALL {
        for path in &mut scene.layer_mut(kind).paths {
            bounds.project(path);
        }
    }
}

/// The SVG model's loss against the target ([`PolishLoss`], made for this target).
pub(crate) fn model_loss(
    canvas: &mut Canvas,
    scene: &Scene,
    target: &Image,
    loss: &PolishLoss,
) -> f32 {
    SvgModel::new(target.width, target.height).render(canvas, scene, (target, loss))
}

/// Runs up to the span's iterations of joint steps (from [`into_range`]) and returns the loss of
/// the SVG model before and after. A coarse part (one that ends early) makes no previews.
/// `loss` is made for `target`.
pub(crate) fn polish(
    scene: &mut Scene,
    (target, loss_of): (&Image, &PolishLoss),
    span: IterationSpan,
    (settings, mode, floor): (&PolishSettings, ResolvedMode, Option<&LightnessFloor>),
    keep: Option<(&KeepRun, &StructureSettings)>,
    stage: &StageRun,
) -> Result<[f32; 2], Error> {
    let (w, h) = (target.width, target.height);
    let mut canvas = Canvas::new(w, h);
    let mut adams: Vec<Adam> = LayerKind::ALL
        .iter()
        .map(|_| Adam::new(settings.adam(mode), Bounds::canvas(w, h, 1.0)))
        .collect();
    into_range(scene);
    let mut model = SvgModel::new(w, h);
    let initial = model.render(&mut canvas, scene, (target, loss_of));
    let held = keep.map(|(k, structure)| {
        k.held(
            &mut canvas,
            scene,
            &[LayerKind::Shade, LayerKind::Light],
            structure,
        )
    });
    let mut objective = Joint {
        target: (target, loss_of),
        model,
        loss: initial,
        held,
        floor,
    };
    let descent = Descent {
        iterations: span.count,
        plateau: settings.plateau,
    };
    descent.run(
        &mut canvas,
        scene,
        &mut adams,
        &mut objective,
        |done, loss| stage.iteration(span.start + done, span.total, Some(loss)),
    )?;
    let Joint { model, loss, .. } = objective;
    if !span.ends_early() {
        stage.preview("composite", &model.composite);
        for (k, kind) in LayerKind::ALL.into_iter().enumerate() {
            stage.preview(kind.name(), &model.layers[k]);
        }
    }
    Ok([initial, loss])
}

/// The SVG model's loss on all three layers (sets 0, 1, 2), with the kept terms in the
/// gradient only. Each step's render gives the next iteration's loss.
struct Joint<'a> {
    target: (&'a Image, &'a PolishLoss),
    model: SvgModel,
    /// The loss of the current values.
    loss: f32,
    held: Option<Held<'a>>,
    floor: Option<&'a LightnessFloor>,
}

impl Objective<Scene> for Joint<'_> {
    fn loss(&mut self, _: &mut Canvas, _: &Scene, _: &mut [Vec<PathGrad>]) -> f32 {
        self.loss
    }

    fn gradient(&mut self, canvas: &mut Canvas, scene: &Scene, grads: &mut [Vec<PathGrad>]) {
        let SvgModel {
            others: [shade, light],
            layers,
            d_composite,
            d_composite_colours,
            ..
        } = &mut self.model;
        let apart = self.target.1.colours_apart();
        let [a, s, l] = &*layers;
        svg_model_backward(a, s, l, d_composite);
        if apart {
            svg_model_backward(a, s, l, d_composite_colours);
        }
        // A × S + L: the albedo's gradient is the composite's times the shade, the shade's
        // times the albedo, the light's the composite's.
        let grad = |factor| PixelGrad {
            d: &*d_composite,
            colour: apart.then_some(&*d_composite_colours),
            factor,
        };
        let d_layers = [grad(Some(s)), grad(Some(a)), grad(None)];
        let held = &self.held;
        [canvas, shade, light]
            .into_par_iter()
            .zip(grads.par_iter_mut())
            .zip(d_layers)
            .zip(LayerKind::ALL.par_iter())
            .for_each(|(((canvas, grads), grad), &kind)| {
                let paths = &scene.layer(kind).paths;
                canvas.raster.backward_of(paths, kind.base(), grad, grads);
                if let Some(held) = held {
                    held.add_term(canvas, kind, paths, grads);
                }
            });
    }

    fn hold(&self, set: usize, grads: &mut [PathGrad]) {
        if set == 0 {
            hold_albedo_base(grads);
        }
    }

    fn stepped(
        &mut self,
        canvas: &mut Canvas,
        scene: &mut Scene,
        _adams: &mut [Adam],
        _grads: &[Vec<PathGrad>],
        _done: u32,
    ) -> Option<f32> {
        if let Some(floor) = self.floor {
            floor.apply(&mut scene.albedo.paths);
        }
        self.loss = self.model.render(canvas, scene, self.target);
        Some(self.loss)
    }
}

/// MSE + weight × (1 − GMSM) against one target, whose gradient magnitudes it computes once.
/// It does not borrow the target, so that a stage can keep it while it runs its coarse part.
pub(crate) struct PolishLoss {
    similarity: Option<(GradientSimilarity, SimilarityWeights)>,
}

impl PolishLoss {
    /// `weights` are [`PolishSettings::similarity_weights`] for the job.
    pub(crate) fn new(target: &Image, weights: SimilarityWeights) -> Self {
        Self {
            similarity: (weights.shapes > 0.0).then(|| (GradientSimilarity::new(target), weights)),
        }
    }

    /// Whether the colours take a gradient of their own ([`SimilarityWeights::colours`]).
    fn colours_apart(&self) -> bool {
        self.similarity
            .as_ref()
            .is_some_and(|(_, weights)| weights.colours < weights.shapes)
    }

    /// The loss of `composite` against `target` (the one the loss was made for); writes
    /// dLoss/dComposite into `grad` and, when [`Self::colours_apart`], the colours' own into
    /// `grad_colours` (both resized).
    fn of(&self, composite: &Image, target: &Image, [grad, grad_colours]: [&mut Image; 2]) -> f32 {
        let loss = mse(composite, target, grad);
        let Some((similarity, weights)) = &self.similarity else {
            return loss;
        };
        let apart = self.colours_apart();
        if apart {
            grad_colours.clone_from(grad);
        }
        let term = similarity.add_loss(composite, weights.shapes, grad);
        if apart {
            // grad = MSE′ + shapes · term′, so MSE′ + colours · term′ is this blend of the two.
            let share = weights.colours / weights.shapes;
            for (c, &g) in grad_colours.data.iter_mut().zip(&grad.data) {
                *c += share * (g - *c);
            }
        }
        loss + term
    }
}

/// The three layers, the SVG composite and its loss gradient, as last rendered.
struct SvgModel {
    /// The shade's and the light's canvases (the albedo's is the caller's), so the layers
    /// render, and their backwards run, side by side: at the polish's coarse sizes one
    /// layer's strips are too few to keep every thread busy.
    others: [Canvas; 2],
    layers: [Image; 3],
    composite: Image,
    d_composite: Image,
    /// The colours' own gradient, when [`PolishLoss::colours_apart`].
    d_composite_colours: Image,
}

impl SvgModel {
    fn new(width: usize, height: usize) -> Self {
        Self {
            others: std::array::from_fn(|_| Canvas::new(width, height)),
            layers: Default::default(),
            composite: Image::default(),
            d_composite: Image::default(),
            d_composite_colours: Image::default(),
        }
    }

    /// Renders the three layers (the albedo on `canvas`) and the SVG composite; returns the
    /// loss and writes its gradient.
    fn render(
        &mut self,
        canvas: &mut Canvas,
        scene: &Scene,
        (target, loss): (&Image, &PolishLoss),
    ) -> f32 {
        let [shade, light] = &mut self.others;
        [canvas, shade, light]
            .into_par_iter()
            .zip(self.layers.par_iter_mut())
            .zip(LayerKind::ALL.par_iter())
            .for_each(|((canvas, layer), &kind)| canvas.render_layer(scene, kind, layer));
        let [a, s, l] = &self.layers;
        svg_model(a, s, l, &mut self.composite);
        let grads = [&mut self.d_composite, &mut self.d_composite_colours];
        loss.of(&self.composite, target, grads)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_similarity_weight_grows_only_above_the_reference_size() {
        let settings = PolishSettings::default();
        let set = settings.gradient_similarity;
        assert_eq!(settings.similarity_weight(64 * 64, 64), set);
        assert_eq!(settings.similarity_weight(256 * 256, 64), set);
        let at_512 = settings.similarity_weight(512 * 512, 64);
        assert!((at_512 / set - 2f32.powf(1.5)).abs() < 1e-5, "{at_512}");
    }

    #[test]
    fn the_similarity_weight_grows_away_from_the_reference_budget() {
        let settings = PolishSettings::default();
        let set = settings.gradient_similarity;
        let ratio = |paths| settings.similarity_weight(256 * 256, paths) / set;
        assert!((ratio(8) - 8.0).abs() < 1e-4, "{}", ratio(8));
        assert!((ratio(32) - 2.0).abs() < 1e-5, "{}", ratio(32));
        assert!((ratio(256) - 4f32.powf(1.3)).abs() < 1e-4, "{}", ratio(256));
        assert!(ratio(128) > 1.0 && ratio(128) < ratio(256));
        assert_eq!(ratio(1024), ratio(256));
    }

    #[test]
    fn the_colours_see_the_similarity_weight_of_the_reference_budget_at_most() {
        let settings = PolishSettings::default();
        for pixels in [256 * 256, 512 * 512] {
            for paths in [8, 64] {
                let weights = settings.similarity_weights(pixels, paths);
                assert_eq!(weights.colours, weights.shapes);
            }
            let at_64 = settings.similarity_weight(pixels, 64);
            let weights = settings.similarity_weights(pixels, 256);
            assert_eq!(weights.colours, at_64);
            assert!(weights.shapes > at_64);
        }
    }

    #[test]
    fn with_the_colours_apart_their_gradient_takes_the_term_at_its_own_weight() {
        let mut rng = 7u32;
        let mut image = |size: usize| {
            let data = (0..size * size * 3)
                .map(|_| {
                    rng = rng.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                    (rng >> 8) as f32 / (1 << 24) as f32
                })
                .collect();
            Image {
                width: size,
                height: size,
                data,
            }
        };
        let (target, composite) = (image(24), image(24));
        let weights = SimilarityWeights {
            shapes: 0.4,
            colours: 0.1,
        };
        let apart = PolishLoss::new(&target, weights);
        let (mut grad, mut grad_colours) = (Image::default(), Image::default());
        let loss = apart.of(&composite, &target, [&mut grad, &mut grad_colours]);
        let reference = |weight: f32| {
            let loss = PolishLoss::new(
                &target,
                SimilarityWeights {
                    shapes: weight,
                    colours: weight,
                },
            );
            let mut grad = Image::default();
            let value = loss.of(&composite, &target, [&mut grad, &mut Image::default()]);
            (value, grad)
        };
        let ((shapes_loss, shapes), (_, colours)) = (reference(0.4), reference(0.1));
        assert_eq!(loss, shapes_loss);
        assert_eq!(grad.data, shapes.data);
        for (a, b) in grad_colours.data.iter().zip(&colours.data) {
            assert!((a - b).abs() <= 1e-6 * (1.0 + b.abs()), "{a} vs {b}");
        }
    }

    #[test]
    fn the_lightness_floor_lifts_only_fills_of_its_share_that_fell_below_it_in_photo_mode() {
        let settings = PolishSettings::default();
        let drop = settings.albedo_lightness_drop;
        // On 20×20: a base owning 74 % of the canvas, a square owning 25 %, a pixel (0.25 %).
        let mut scene = Scene::new(20, 20, 20, 20);
        scene.albedo.paths = vec![
            Path::rect(0.0, 0.0, 20.0, 20.0, [0.6, 0.5, 0.4], 1.0),
            Path::rect(0.0, 0.0, 10.0, 10.0, [0.6, 0.5, 0.4], 1.0),
            Path::rect(15.0, 15.0, 16.0, 16.0, [0.6, 0.5, 0.4], 1.0),
        ];
        assert!(LightnessFloor::new(&scene, &settings, ResolvedMode::Simple).is_none());
        let floor = LightnessFloor::new(&scene, &settings, ResolvedMode::Photo).unwrap();
        // Every fill darkened by 0.1 on each channel: only the square is lifted, its hue kept.
        let darker = [0.5, 0.4, 0.3];
        scene.albedo.paths.iter_mut().for_each(|p| p.color = darker);
        floor.apply(&mut scene.albedo.paths);
        let [r, g, b] = scene.albedo.paths[1].color;
        assert!(
            (lightness([r, g, b]) - (0.5 - drop)).abs() < 1e-6,
            "{r} {g} {b}"
        );
        assert!(
            (r - g - 0.1).abs() < 1e-6 && (g - b - 0.1).abs() < 1e-6,
            "hue kept"
        );
        assert_eq!(scene.albedo.paths[0].color, darker);
        assert_eq!(scene.albedo.paths[2].color, darker);
        // Lightened: left as it is.
        scene.albedo.paths[1].color = [1.0, 0.95, 0.95];
        floor.apply(&mut scene.albedo.paths);
        assert_eq!(scene.albedo.paths[1].color, [1.0, 0.95, 0.95]);
    }
}
