//! Structural optimisation (paper Sec. 4.3): per-layer structure loss, then the shared
//! reconstruction loss ‖I − R(A)·R(I)‖², with one Adam per layer.
//!
//! Until the layer separation, the illumination layer lives in `scene.shade` (both are painted over
//! white and multiplied onto the albedo); its colours may exceed 1 up to
//! [`StructureSettings::illumination_cap`].
//!
//! Paths that keep to objects: after the structure stage, terms added to the
//! reconstruction, refinement and polish losses keep what the init stage built from masks there
//! ([`Keep`]).

use super::coarse::{Plateau, PlateauSettings, halve_mask};
use super::init::LayerGroups;
use super::params::{Error, ResolvedMode};
use super::segments::{SegmentPull, SplitLayer, SplitPlan};
use super::stage::{Canvas, IterationSpan, StageRun, hold_albedo, hold_albedo_base};
use crate::decompose::mask::Mask;
use crate::optim::loss::{mse, overlap_penalty};
use crate::optim::rng::Rng;
use crate::optim::{Adam, AdamSettings, Bounds, reset_grads};
use crate::render::composite::{product, product_backward};
use crate::render::{Image, PathGrad};
use crate::scene::{LayerKind, Path, Scene};

/// One mask group from the initialisation: paths of one layer, painted in this order, each with
/// the mask (working size) it was traced from. Masks within a group are (nearly) disjoint;
/// nested masks go to later groups (LayerVec's back-to-front organisation).
#[derive(Clone, Debug)]
pub struct MaskGroup {
    /// `Albedo`, or `Shade` for the illumination layer.
    pub layer: LayerKind,
    /// Indices into the layer's paths, one per mask.
    pub paths: Vec<usize>,
    pub masks: Vec<Mask>,
}

impl MaskGroup {
    /// The groups of the init stage's layers, in paint order.
    pub fn from_init(layers: &[LayerGroups]) -> Vec<MaskGroup> {
        layers
            .iter()
            .flat_map(|layer| {
                layer.groups.iter().map(|group| MaskGroup {
                    layer: layer.layer,
                    paths: group.iter().map(|m| m.path).collect(),
                    masks: group.iter().map(|m| m.mask.clone()).collect(),
                })
            })
            .collect()
    }
}

/// Settings of the structure and reconstruction stages.
#[derive(Clone, Debug, PartialEq)]
pub struct StructureSettings {
    /// Adam of each layer. Default: points 1.0, colours and opacities 0.01, betas 0.9/0.9.
    pub adam: AdamSettings,
    /// Overlap threshold δ: one layer of 0.3-grey over white gives 0.7 ≥ δ, two give 0.49 < δ.
    /// Default 178/255 (LayerVec).
    pub overlap_delta: f32,
    /// Weight of the overlap term on the *mean* of ReLU(δ − v) over pixels × channels, i.e. the
    /// paper's λ = weight / (3·W·H) on its sum. Default 0.5: a doubly covered pixel then costs
    /// 0.104, a third of what a wrongly covered pixel costs the mask term (~0.36 on average),
    /// so overlaps are discouraged without fighting the masks. The paper's λ = 1e-8 (LayerVec
    /// 2e-7) on a 512² sum is a weight of 0.008 (0.16) here and would barely act.
    pub overlap_weight: f32,
    /// Upper bound of illumination colours. Default 4: enough for highlights on albedo ≥ 0.25.
    pub illumination_cap: f32,
    /// When the reconstruction loop stops early.
    pub plateau: PlateauSettings,
}

impl Default for StructureSettings {
    fn default() -> Self {
        Self {
            adam: AdamSettings::default(),
            overlap_delta: 178.0 / 255.0,
            overlap_weight: 0.5,
            illumination_cap: crate::render::composite::ILLUMINATION_CAP,
            plateau: PlateauSettings::default(),
        }
    }
}

/// Grey translucent fill used to measure overlap within a group (LayerVec: black at alpha 0.3).
const OVERLAP_OPACITY: f32 = 0.3;

/// How the structure stage runs.
pub(crate) struct StructureRun<'a> {
    pub iterations: u32,
    pub settings: &'a StructureSettings,
    /// Seed of the groups' fixed random colours.
    pub seed: u64,
}

/// Runs the structure loss on the albedo and illumination (`scene.shade`) layers, one Adam per
/// layer (geometry and opacity only). Returns the reconstruction loss ‖I − R(A)·R(I)‖² before
/// and after.
pub(crate) fn optimise_structure(
    scene: &mut Scene,
    groups: &[MaskGroup],
    target: &Image,
    run: &StructureRun,
    stage: &StageRun,
) -> Result<[f32; 2], Error> {
    let StructureRun {
        iterations,
        settings,
        seed,
    } = *run;
    let (w, h) = (target.width, target.height);
    let mut canvas = Canvas::new(w, h);
    let mut scratch = Scratch::default();
    let initial = reconstruction_loss(&mut canvas, scene, target, &mut scratch, None);
    let [mut adam_albedo, mut adam_illum] = layer_adams(settings, w, h);
    let prepared = prepare_groups(scene, groups, w, h, seed)?;
    let mut grads_a = Vec::new();
    let mut grads_i = Vec::new();
    for it in 0..iterations {
        let mut loss = 0.0;
        for (kind, adam, grads) in [
            (LayerKind::Albedo, &mut adam_albedo, &mut grads_a),
            (LayerKind::Shade, &mut adam_illum, &mut grads_i),
        ] {
            let paths = &mut scene.layer_mut(kind).paths;
            reset_grads(grads, paths);
            // A group holding only the albedo base trains nothing (its geometry and opacity
            // are held, and this loss leaves colours alone): skip its renders.
            let trainable = |g: &&PreparedGroup| {
                g.layer == kind && !(kind == LayerKind::Albedo && g.paths == [0])
            };
            for group in prepared.iter().filter(trainable) {
                loss += structure_loss(
                    &mut canvas,
                    paths,
                    group,
                    settings,
                    1.0,
                    grads,
                    &mut scratch,
                );
            }
            // The structure loss shapes geometry only; colours are fit by the reconstruction.
            hold_colours(grads);
            if kind == LayerKind::Albedo {
                hold_albedo_base(grads);
            }
            adam.step(paths, grads);
        }
        stage.iteration(it + 1, iterations, Some(loss))?;
    }
    let after = reconstruction_loss(&mut canvas, scene, target, &mut scratch, None);
    Ok([initial, after])
}

/// How one part (coarse or fine) of the reconstruction runs.
pub(crate) struct ReconstructionRun<'a> {
    pub span: IterationSpan,
    pub settings: &'a StructureSettings,
    pub keep: Option<&'a KeepRun<'a>>,
    pub mode: ResolvedMode,
    /// Up to where the loop splits segments ([`super::segments`]).
    pub split: SplitPlan,
}

/// Runs the span's iterations of the shared reconstruction loss ‖I − R(A)·R(I)‖² on both
/// layers, one Adam per layer, stopping early once the loss has plateaued, splitting the
/// segments the loss pulls hardest as the plan says. Returns the loss before and after.
/// The albedo layer is held as [`hold_albedo`] says.
pub(crate) fn optimise_reconstruction(
    scene: &mut Scene,
    target: &Image,
    run: &ReconstructionRun,
    stage: &StageRun,
) -> Result<[f32; 2], Error> {
    let ReconstructionRun {
        span,
        settings,
        keep,
        mode,
        split,
    } = *run;
    let (w, h) = (target.width, target.height);
    let mut canvas = Canvas::new(w, h);
    let mut scratch = Scratch::default();
    let initial = reconstruction_loss(&mut canvas, scene, target, &mut scratch, None);
    let [mut adam_albedo, mut adam_illum] = layer_adams(settings, w, h);
    let mut plateau = Plateau::new(settings.plateau);
    let (mut grads_a, mut grads_i) = (Vec::new(), Vec::new());
    // The illumination layer's pull: only it splits (see `super::segments`).
    let mut pull = SegmentPull::default();
    let held = keep.map(|k| {
        (
            k.keep.albedo_groups(scene, k.seed),
            k.keep.parents(&mut canvas, &scene.shade.paths),
        )
    });
    for it in 0..span.count {
        reset_grads(&mut grads_a, &scene.albedo.paths);
        reset_grads(&mut grads_i, &scene.shade.paths);
        let mut loss = reconstruction_loss(
            &mut canvas,
            scene,
            target,
            &mut scratch,
            Some((&mut grads_a, &mut grads_i)),
        );
        if let (Some(k), Some((groups, parents))) = (keep, &held) {
            loss += albedo_term(
                &mut canvas,
                &scene.albedo.paths,
                groups,
                settings,
                k.keep.albedo_weight,
                &mut grads_a,
            );
            loss += containment_term(
                &mut canvas,
                &scene.shade.paths,
                parents,
                k.keep,
                &mut grads_i,
            );
        }
        if plateau.stop_after(loss) {
            break;
        }
        hold_albedo(&mut grads_a, mode);
        adam_albedo.step(&mut scene.albedo.paths, &grads_a);
        adam_illum.step(&mut scene.shade.paths, &grads_i);
        // Once the scene holds its target no split is due, and the pull is not needed.
        let segments = scene.segment_count();
        if segments < split.target {
            pull.add(&scene.shade.paths, &grads_i);
        }
        let due = split.due(it + 1, span.count, segments);
        if due > 0 {
            SplitLayer {
                paths: &mut scene.shade.paths,
                pull: &mut pull,
                adam: &mut adam_illum,
            }
            .split_most_pulled(due);
        }
        stage.iteration(span.start + it + 1, span.total, Some(loss))?;
    }
    let after = reconstruction_loss(&mut canvas, scene, target, &mut scratch, None);
    Ok([initial, after])
}

/// The masks and regions paths are held to in a stage, and how strongly.
pub(crate) struct KeepRun<'a> {
    pub keep: &'a Keep,
    /// Seed of the structure stage's group colours.
    pub seed: u64,
}

/// Zeroes the colour gradients: the paths keep their fills.
fn hold_colours(grads: &mut [PathGrad]) {
    for g in grads {
        g.color = [0.0; 3];
    }
}

/// The albedo and illumination Adams (colours within [0, 1] and [0, illumination cap]).
fn layer_adams(settings: &StructureSettings, w: usize, h: usize) -> [Adam; 2] {
    [
        Adam::new(settings.adam, Bounds::canvas(w, h, 1.0)),
        Adam::new(
            settings.adam,
            Bounds::canvas(w, h, settings.illumination_cap),
        ),
    ]
}

/// Reusable buffers.
#[derive(Default)]
pub(crate) struct Scratch {
    a: Image,
    b: Image,
    c: Image,
    d_c: Image,
    d_a: Image,
    d_b: Image,
}

/// ‖I − R(A)·R(I)‖² (mean); with `grads`, adds its gradient for the albedo and illumination paths.
pub(crate) fn reconstruction_loss(
    canvas: &mut Canvas,
    scene: &Scene,
    target: &Image,
    s: &mut Scratch,
    grads: Option<(&mut Vec<PathGrad>, &mut Vec<PathGrad>)>,
) -> f32 {
    canvas.render_layer(scene, LayerKind::Albedo, &mut s.a);
    canvas.render_layer(scene, LayerKind::Shade, &mut s.b);
    product(&s.a, &s.b, &mut s.c);
    let loss = mse(&s.c, target, &mut s.d_c);
    if let Some((grads_a, grads_i)) = grads {
        product_backward(&s.a, &s.b, &s.d_c, &mut s.d_a, &mut s.d_b);
        canvas.raster.backward(
            &scene.albedo.paths,
            LayerKind::Albedo.base(),
            &s.d_a,
            grads_a,
        );
        canvas
            .raster
            .backward(&scene.shade.paths, LayerKind::Shade.base(), &s.d_b, grads_i);
    }
    loss
}

/// Previews the two-layer composite and both layers; returns the reconstruction loss.
pub(crate) fn preview_two_layers(
    canvas: &mut Canvas,
    scene: &Scene,
    target: &Image,
    stage: &StageRun,
) -> f32 {
    let mut s = Scratch::default();
    let loss = reconstruction_loss(canvas, scene, target, &mut s, None);
    stage.preview("composite", &s.c);
    stage.preview("albedo", &s.a);
    stage.preview("illumination", &s.b);
    loss
}

/// A mask group ready for the loss: fixed random colours per path and the coloured mask target.
pub(crate) struct PreparedGroup {
    pub layer: LayerKind,
    pub paths: Vec<usize>,
    colors: Vec<[f32; 3]>,
    target: Image,
}

pub(crate) fn prepare_groups(
    scene: &Scene,
    groups: &[MaskGroup],
    w: usize,
    h: usize,
    seed: u64,
) -> Result<Vec<PreparedGroup>, Error> {
    let mut rng = Rng::new(seed, 0x5354_5255);
    let mut prepared = Vec::with_capacity(groups.len());
    for group in groups {
        let layer_len = scene.layer(group.layer).paths.len();
        if group.paths.len() != group.masks.len() {
            return Err(Error::Internal(
                "a mask group needs one mask per path".into(),
            ));
        }
        let mut target = Image::filled(w, h, [0.0; 3]);
        let mut colors = Vec::with_capacity(group.paths.len());
        for (&index, mask) in group.paths.iter().zip(&group.masks) {
            if index >= layer_len {
                return Err(Error::Internal(format!(
                    "mask group refers to missing path {index}"
                )));
            }
            if mask.width() != w || mask.height() != h {
                return Err(Error::Internal(
                    "mask size differs from the working size".into(),
                ));
            }
            let color = [
                rng.range(0.2, 1.0),
                rng.range(0.2, 1.0),
                rng.range(0.2, 1.0),
            ];
            for i in mask.indices() {
                for c in 0..3 {
                    let v = &mut target.data[3 * i + c];
                    *v = (*v + color[c]).min(1.0);
                }
            }
            colors.push(color);
        }
        prepared.push(PreparedGroup {
            layer: group.layer,
            paths: group.paths.clone(),
            colors,
            target,
        });
    }
    Ok(prepared)
}

/// Mask term + overlap term of one group; adds `scale` × its point and opacity gradients into
/// `grads`.
pub(crate) fn structure_loss(
    canvas: &mut Canvas,
    paths: &[Path],
    group: &PreparedGroup,
    settings: &StructureSettings,
    scale: f32,
    grads: &mut [PathGrad],
    s: &mut Scratch,
) -> f32 {
    let colored: Vec<Path> = group
        .paths
        .iter()
        .zip(&group.colors)
        .map(|(&i, &color)| Path {
            points: paths[i].points.clone(),
            color,
            opacity: paths[i].opacity,
        })
        .collect();
    let mut local = crate::render::PathGrad::zeros_like(&colored);
    canvas.render(&colored, [0.0; 3], &mut s.a);
    let mask_loss = mse(&s.a, &group.target, &mut s.d_a);
    canvas
        .raster
        .backward(&colored, [0.0; 3], &s.d_a, &mut local);

    let grey: Vec<Path> = colored
        .iter()
        .map(|p| Path {
            points: p.points.clone(),
            color: [0.0; 3],
            opacity: OVERLAP_OPACITY,
        })
        .collect();
    canvas.render(&grey, [1.0; 3], &mut s.b);
    s.d_b.data.iter_mut().for_each(|v| *v = 0.0);
    let overlap = overlap_penalty(
        &s.b,
        settings.overlap_delta,
        settings.overlap_weight,
        &mut s.d_b,
    );
    let mut grey_grads = crate::render::PathGrad::zeros_like(&grey);
    canvas
        .raster
        .backward(&grey, [1.0; 3], &s.d_b, &mut grey_grads);

    for ((&i, g), gg) in group.paths.iter().zip(&local).zip(&grey_grads) {
        let out = &mut grads[i];
        for ((o, a), b) in out.points.iter_mut().zip(&g.points).zip(&gg.points) {
            o.x += scale * (a.x + b.x);
            o.y += scale * (a.y + b.y);
        }
        out.opacity += scale * g.opacity;
    }
    mask_loss + overlap
}

// ---- Paths that keep to objects ----
//
// - **Albedo paths keep their masks**: the structure loss of the albedo mask groups (the
//   structure stage's mask and overlap terms, same fixed colours) stays on, weighted (see
//   `KeepSettings`), in every later stage that moves albedo geometry (reconstruct, polish).
// - **Illumination paths keep one parent region**: the albedo regions (visible parts of the
//   albedo masks, a partition of the canvas) label every pixel; each shade or light path's
//   parent is the region holding most of its area when a stage starts (for a structure path,
//   the region it was binarised in; for a new path, the region its error region lies in), and
//   its coverage outside the parent costs a weight per pixel (mean over the canvas, as the
//   image loss is) in the reconstruction, the refinement's training and the polish.
// - Photo mode only; by default on the client's masks only (on covec's own segmentation
//   both terms cost bench MSE and did not raise VeC).
/// How strongly paths are held to their masks and regions; 0 turns a term off.
#[derive(Clone, Debug, PartialEq)]
pub struct KeepSettings {
    /// Weight of the albedo groups' structure loss after the structure stage, when the masks
    /// are the client's. Default 1: a path edge moved off its mask costs about what the mask
    /// term costs in the structure stage, several times what a typical colour error costs the
    /// image loss.
    pub given_albedo_weight: f32,
    /// The same for covec's own segmentation.
    pub own_albedo_weight: f32,
    /// Weight of an illumination path's coverage outside its parent region, per pixel (mean),
    /// when the masks are the client's.
    pub given_containment_weight: f32,
    /// The same for covec's own segmentation.
    pub own_containment_weight: f32,
}

impl Default for KeepSettings {
    fn default() -> Self {
        Self {
            given_albedo_weight: 1.0,
            own_albedo_weight: 0.0,
            given_containment_weight: 0.1,
            own_containment_weight: 0.0,
        }
    }
}

/// The masks and regions at one working size, and the weights of this run.
pub(crate) struct Keep {
    /// Weight of the albedo groups' structure loss.
    pub albedo_weight: f32,
    /// Weight of the illumination paths' containment term.
    pub containment_weight: f32,
    groups: Vec<MaskGroup>,
    /// Albedo region of each pixel (an index in paint order of the albedo masks).
    region: Vec<u32>,
    width: usize,
    height: usize,
}

impl Keep {
    /// From the init stage's mask groups (working size), with the weights for the client's
    /// masks or covec's own.
    pub fn new(
        groups: &[MaskGroup],
        width: usize,
        height: usize,
        settings: &KeepSettings,
        masks_given: bool,
    ) -> Self {
        let albedo: Vec<MaskGroup> = groups
            .iter()
            .filter(|g| g.layer == LayerKind::Albedo)
            .cloned()
            .collect();
        let (albedo_weight, containment_weight) = if masks_given {
            (
                settings.given_albedo_weight,
                settings.given_containment_weight,
            )
        } else {
            (settings.own_albedo_weight, settings.own_containment_weight)
        };
        Self::from_groups(albedo, width, height, [albedo_weight, containment_weight])
    }

    fn from_groups(
        groups: Vec<MaskGroup>,
        width: usize,
        height: usize,
        [albedo_weight, containment_weight]: [f32; 2],
    ) -> Self {
        let mut region = vec![0u32; width * height];
        for (k, mask) in groups.iter().flat_map(|g| &g.masks).enumerate() {
            for i in mask.indices() {
                region[i] = k as u32;
            }
        }
        Self {
            albedo_weight,
            containment_weight,
            groups,
            region,
            width,
            height,
        }
    }

    /// The same at half size (masks sampled as [`halve_mask`] does).
    pub fn halved(&self) -> Self {
        let groups: Vec<MaskGroup> = self
            .groups
            .iter()
            .map(|g| MaskGroup {
                masks: g.masks.iter().map(halve_mask).collect(),
                ..g.clone()
            })
            .collect();
        Self::from_groups(
            groups,
            self.width.div_ceil(2),
            self.height.div_ceil(2),
            [self.albedo_weight, self.containment_weight],
        )
    }

    /// Whether pixel `i` is inside region `parent`.
    fn inside(&self, parent: u32, i: usize) -> bool {
        self.region[i] == parent
    }

    /// The albedo groups ready for the structure loss (colours seeded as in the structure stage).
    pub fn albedo_groups(&self, scene: &Scene, seed: u64) -> Vec<PreparedGroup> {
        super::structure::prepare_groups(scene, &self.groups, self.width, self.height, seed)
            .unwrap_or_default()
            .into_iter()
            .filter(|g| g.paths != [0])
            .collect()
    }

    /// Each path's parent: the region holding most of its coverage.
    pub fn parents(&self, canvas: &mut Canvas, paths: &[Path]) -> Vec<u32> {
        paths
            .iter()
            .map(|p| {
                let mut share = std::collections::BTreeMap::new();
                for (i, c) in canvas.coverage(p) {
                    *share.entry(self.region[i as usize]).or_insert(0.0f32) += c;
                }
                share
                    .into_iter()
                    .max_by(|a, b| a.1.total_cmp(&b.1))
                    .map_or(0, |(k, _)| k)
            })
            .collect()
    }
}

/// Adds `weight` × the albedo groups' structure loss gradient (geometry and opacity) into
/// `grads`; returns the weighted loss.
pub(crate) fn albedo_term(
    canvas: &mut Canvas,
    paths: &[Path],
    groups: &[PreparedGroup],
    structure: &StructureSettings,
    weight: f32,
    grads: &mut [PathGrad],
) -> f32 {
    if weight <= 0.0 {
        return 0.0;
    }
    let mut scratch = Scratch::default();
    groups
        .iter()
        .map(|g| weight * structure_loss(canvas, paths, g, structure, weight, grads, &mut scratch))
        .sum()
}

/// Adds the containment term of `paths` (each with its parent region) into `grads`: `weight` ×
/// the mean over pixels of the paths' silhouettes outside their parents. Returns the term.
pub(crate) fn containment_term(
    canvas: &mut Canvas,
    paths: &[Path],
    parents: &[u32],
    keep: &Keep,
    grads: &mut [PathGrad],
) -> f32 {
    let weight = keep.containment_weight;
    if weight <= 0.0 || paths.is_empty() {
        return 0.0;
    }
    let n = (3 * keep.region.len()) as f32;
    let mut distinct: Vec<u32> = parents.to_vec();
    distinct.sort_unstable();
    distinct.dedup();
    let (mut render, mut d_out) = (Image::default(), Image::default());
    let mut loss = 0.0;
    for parent in distinct {
        let members: Vec<usize> = (0..paths.len()).filter(|&k| parents[k] == parent).collect();
        let silhouettes: Vec<Path> = members
            .iter()
            .map(|&k| Path {
                points: paths[k].points.clone(),
                color: [1.0; 3],
                opacity: 1.0,
            })
            .collect();
        canvas.render(&silhouettes, [0.0; 3], &mut render);
        d_out.resize(render.width, render.height);
        for i in 0..keep.region.len() {
            let outside = if keep.inside(parent, i) {
                0.0
            } else {
                weight / n
            };
            for c in 0..3 {
                d_out.data[3 * i + c] = outside;
                loss += outside * render.data[3 * i + c];
            }
        }
        let mut local = PathGrad::zeros_like(&silhouettes);
        canvas
            .raster
            .backward(&silhouettes, [0.0; 3], &d_out, &mut local);
        for (&k, g) in members.iter().zip(&local) {
            for (o, a) in grads[k].points.iter_mut().zip(&g.points) {
                o.x += a.x;
                o.y += a.y;
            }
        }
    }
    loss
}
