//! Structural optimisation (paper Sec. 4.3): the structure stage's per-layer structure loss,
//! with one Adam per layer, and the two-layer model ‖I − R(A)·R(I)‖² that it and the
//! reconstruction ([`super::reconstruct`]) are measured by.
//!
//! Until the layer separation, the illumination layer lives in `scene.shade` (both are painted over
//! white and multiplied onto the albedo); its colours may exceed 1 up to
//! [`StructureSettings::illumination_cap`].

use super::coarse::{PlateauSettings, halve_mask, halvings_of};
use super::descent::{Descent, Objective};
use super::init::LayerGroups;
use super::params::Error;
use super::stage::{Canvas, StageRun, hold_albedo_base};
use crate::decompose::mask::Mask;
use crate::optim::loss::{mse, overlap_penalty};
use crate::optim::rng::Rng;
use crate::optim::{Adam, AdamSettings, Bounds};
use crate::render::composite::product;
use crate::render::{Image, PathGrad, PixelGrad};
use crate::scene::{LayerKind, Path, Scene};
use rayon::prelude::*;

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

    /// The group with each mask halved `times` times ([`halve_mask`]), on rayon's pool: at
    /// 1024², one by one, the masks held up the other core for about a tenth of a second.
    pub fn halved(&self, times: u32) -> MaskGroup {
        let halved = |m: &Mask| halvings_of(m, times, halve_mask).pop();
        MaskGroup {
            layer: self.layer,
            paths: self.paths.clone(),
            masks: (self.masks.par_iter())
                .map(|m| halved(m).unwrap_or_else(|| m.clone()))
                .collect(),
        }
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
    let descent = Descent {
        iterations,
        plateau: PlateauSettings::never(),
    };
    let structure = |_: &mut Canvas, scene: &Scene, scratch| {
        let groups: Vec<PreparedGroup> = prepare_groups(scene, groups, w, h, seed)?
            .into_iter()
            .filter(trains)
            .collect();
        let workspaces = groups
            .iter()
            .map(|_| (Canvas::new(w, h), Scratch::default()))
            .collect();
        Ok(Structure {
            scratch,
            groups,
            workspaces,
            settings,
        })
    };
    descend_two_layers(
        scene,
        target,
        settings,
        &descent,
        structure,
        |done, loss| stage.iteration(done, iterations, Some(loss)),
    )
}

/// Runs `descent` on the albedo and illumination layers, one Adam each ([`layer_adams`]), and
/// returns the two-layer loss ‖I − R(A)·R(I)‖² before and after. The objective is made once
/// the loss before is known, and takes over its buffers.
pub(crate) fn descend_two_layers<O: Objective<Scene> + AsMut<Scratch>>(
    scene: &mut Scene,
    target: &Image,
    settings: &StructureSettings,
    descent: &Descent,
    objective: impl FnOnce(&mut Canvas, &Scene, Scratch) -> Result<O, Error>,
    report: impl FnMut(u32, f32) -> Result<(), Error>,
) -> Result<[f32; 2], Error> {
    let (w, h) = (target.width, target.height);
    let mut canvas = Canvas::new(w, h);
    let mut scratch = Scratch::default();
    let initial = reconstruction_loss(&mut canvas, scene, target, &mut scratch, None);
    let mut adams = layer_adams(settings, w, h);
    let mut objective = objective(&mut canvas, scene, scratch)?;
    descent.run(&mut canvas, scene, &mut adams, &mut objective, report)?;
    let after = reconstruction_loss(&mut canvas, scene, target, objective.as_mut(), None);
    Ok([initial, after])
}

/// Whether the structure loss of `group` trains anything. A group holding only the albedo
/// base does not (its geometry and opacity are held, and this loss leaves colours alone).
fn trains(group: &PreparedGroup) -> bool {
    !(group.layer == LayerKind::Albedo && group.paths == [0])
}

/// The structure loss of every mask group that [`trains`], on sets 0 (albedo) and 1
/// (illumination).
struct Structure<'a> {
    scratch: Scratch,
    groups: Vec<PreparedGroup>,
    /// A canvas and buffers for each group, so the groups' losses run side by side.
    workspaces: Vec<(Canvas, Scratch)>,
    settings: &'a StructureSettings,
}

impl AsMut<Scratch> for Structure<'_> {
    fn as_mut(&mut self) -> &mut Scratch {
        &mut self.scratch
    }
}

impl Objective<Scene> for Structure<'_> {
    fn loss(&mut self, _: &mut Canvas, scene: &Scene, grads: &mut [Vec<PathGrad>]) -> f32 {
        let settings = self.settings;
        let parts: Vec<GroupLoss> = self
            .groups
            .par_iter()
            .zip(self.workspaces.par_iter_mut())
            .map(|(group, (canvas, scratch))| {
                let paths = &scene.layer(group.layer).paths;
                group_loss(canvas, paths, group, settings, scratch)
            })
            .collect();
        // Summed in the sets' order, each set's groups in turn, as one thread would.
        let mut loss = 0.0;
        for (kind, grads) in [LayerKind::Albedo, LayerKind::Shade].into_iter().zip(grads) {
            for (group, part) in self.groups.iter().zip(&parts) {
                if group.layer == kind {
                    loss += part.add_to(group, 1.0, grads);
                }
            }
        }
        loss
    }

    fn hold(&self, set: usize, grads: &mut [PathGrad]) {
        // The structure loss shapes geometry only; colours are fit by the reconstruction.
        hold_colours(grads);
        if set == 0 {
            hold_albedo_base(grads);
        }
    }
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

/// Reusable buffers of a two-factor model `C = A·B` and its gradients.
#[derive(Default)]
pub(crate) struct Scratch {
    /// A second canvas, made on first use, on which `B` renders (and its backward runs)
    /// beside `A` on the caller's: one layer's strips are too few to keep every thread busy
    /// at the coarse sizes.
    second: Option<Canvas>,
    pub a: Image,
    pub b: Image,
    pub c: Image,
    pub d_c: Image,
    pub d_a: Image,
    pub d_b: Image,
}

/// ‖I − R(A)·R(I)‖² (mean); with `grads`, adds its gradient for the albedo and illumination paths.
pub(crate) fn reconstruction_loss(
    canvas: &mut Canvas,
    scene: &Scene,
    target: &Image,
    s: &mut Scratch,
    grads: Option<(&mut Vec<PathGrad>, &mut Vec<PathGrad>)>,
) -> f32 {
    let size = (canvas.width, canvas.height);
    let second = match &mut s.second {
        Some(second) if (second.width, second.height) == size => second,
        slot => slot.insert(Canvas::new(size.0, size.1)),
    };
    rayon::join(
        || canvas.render_layer(scene, LayerKind::Albedo, &mut s.a),
        || second.render_layer(scene, LayerKind::Shade, &mut s.b),
    );
    product(&s.a, &s.b, &mut s.c);
    let loss = mse(&s.c, target, &mut s.d_c);
    if let Some((grads_a, grads_i)) = grads {
        // Each layer's gradient is the product's times the other layer.
        let times = |factor| PixelGrad {
            factor: Some(factor),
            ..PixelGrad::of(&s.d_c)
        };
        rayon::join(
            || {
                let (paths, base) = (&scene.albedo.paths, LayerKind::Albedo.base());
                canvas.raster.backward_of(paths, base, times(&s.b), grads_a)
            },
            || {
                let (paths, base) = (&scene.shade.paths, LayerKind::Shade.base());
                second.raster.backward_of(paths, base, times(&s.a), grads_i)
            },
        );
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
    group_loss(canvas, paths, group, settings, s).add_to(group, scale, grads)
}

/// One group's structure loss and its gradients for the group's paths, in its order.
struct GroupLoss {
    loss: f32,
    /// Of the mask term.
    mask: Vec<PathGrad>,
    /// Of the overlap term.
    overlap: Vec<PathGrad>,
}

impl GroupLoss {
    /// Adds `scale` × the gradients into the layer's `grads`; returns the loss.
    fn add_to(&self, group: &PreparedGroup, scale: f32, grads: &mut [PathGrad]) -> f32 {
        for ((&i, g), gg) in group.paths.iter().zip(&self.mask).zip(&self.overlap) {
            let out = &mut grads[i];
            for ((o, a), b) in out.points.iter_mut().zip(&g.points).zip(&gg.points) {
                o.x += scale * (a.x + b.x);
                o.y += scale * (a.y + b.y);
            }
            out.opacity += scale * g.opacity;
        }
        self.loss
    }
}

fn group_loss(
    canvas: &mut Canvas,
    paths: &[Path],
    group: &PreparedGroup,
    settings: &StructureSettings,
    s: &mut Scratch,
) -> GroupLoss {
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
    GroupLoss {
        loss: mask_loss + overlap,
        mask: local,
        overlap: grey_grads,
    }
}
