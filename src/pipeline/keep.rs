//! Paths that keep to objects: after the structure stage, terms added to the reconstruction,
//! refinement and polish losses keep what the init stage built from masks there.
//!
//! - **Albedo paths keep their masks**: the structure loss of the albedo mask groups (the
//!   structure stage's mask and overlap terms, same fixed colours) stays on, weighted (see
//!   `KeepSettings`), in every later stage that moves albedo geometry (reconstruct, polish).
//! - **Illumination paths keep one parent region**: the albedo regions (visible parts of the
//!   albedo masks, a partition of the canvas) label every pixel; each shade or light path's
//!   parent is the region holding most of its area when a stage starts (for a structure path,
//!   the region it was binarised in; for a new path, the region its error region lies in), and
//!   its coverage outside the parent costs a weight per pixel (mean over the canvas, as the
//!   image loss is) in the reconstruction, the refinement's training and the polish.
//! - Photo mode only; by default on the client's masks only (on covec's own segmentation
//!   both terms cost bench MSE and did not raise VeC).

use super::stage::Canvas;
use super::structure::{
    MaskGroup, PreparedGroup, Scratch, StructureSettings, prepare_groups, structure_loss,
};
use crate::render::{Image, PathGrad};
use crate::scene::{LayerKind, Path, Scene};

/// The masks and regions paths are held to in a stage, and how strongly.
pub(crate) struct KeepRun<'a> {
    pub keep: &'a Keep,
    /// Seed of the structure stage's group colours.
    pub seed: u64,
}

impl<'a> KeepRun<'a> {
    /// What a loop over `scene` holds its paths to: the albedo groups, and the parents of the
    /// paths of each of the `illumination` layers (as they are now).
    pub fn held(
        &self,
        canvas: &mut Canvas,
        scene: &Scene,
        illumination: &[LayerKind],
        structure: &'a StructureSettings,
    ) -> Held<'a> {
        Held {
            keep: self.keep,
            structure,
            groups: self.keep.albedo_groups(scene, self.seed),
            parents: illumination
                .iter()
                .map(|&kind| (kind, self.keep.parents(canvas, &scene.layer(kind).paths)))
                .collect(),
        }
    }
}

/// The kept terms of one loop, ready to add to a layer's gradient.
pub(crate) struct Held<'a> {
    keep: &'a Keep,
    structure: &'a StructureSettings,
    groups: Vec<PreparedGroup>,
    parents: Vec<(LayerKind, Vec<u32>)>,
}

impl Held<'_> {
    /// Adds layer `kind`'s kept term into `grads` (the albedo groups' structure loss, or the
    /// containment of an illumination layer's paths); returns the term.
    pub fn add_term(
        &self,
        canvas: &mut Canvas,
        kind: LayerKind,
        paths: &[Path],
        grads: &mut [PathGrad],
    ) -> f32 {
        match kind {
            LayerKind::Albedo => albedo_term(
                canvas,
                paths,
                &self.groups,
                self.structure,
                self.keep.albedo_weight,
                grads,
            ),
            LayerKind::Shade | LayerKind::Light => {
                let parents = self.parents.iter().find(|(k, _)| *k == kind);
                parents.map_or(0.0, |(_, parents)| {
                    containment_term(canvas, paths, parents, self.keep, grads)
                })
            }
        }
    }
}

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

    /// The same at half size ([`MaskGroup::halved`]).
    pub fn halved(&self) -> Self {
        let groups = self.groups.iter().map(|g| g.halved(1)).collect();
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
        prepare_groups(scene, &self.groups, self.width, self.height, seed)
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
fn albedo_term(
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
