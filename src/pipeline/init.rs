//! The init stage (paper Sec. 4.2): masks → organised back-to-front groups → closed cubic paths
//! with flat fills, within the structure share of the path budget.
//!
//! Photo mode: albedo paths from the albedo masks (the bottom one the full canvas; the others
//! the candidates first in [`perceptual_order`]), filled with
//! the mean albedo of their visible part; illumination paths from region-wise binarisation
//! inside the albedo regions, filled with the mean of image / albedo, clamped to [0, 1]. The
//! illumination layer lives in `Scene::shade` until the split stage moves highlights to
//! `Scene::light`, so the light layer starts empty.
//!
//! Simple mode (paper Appendix C.2): albedo only; segmentation masks and binarisation masks both
//! seed albedo paths, filled with the mean image colour.

use rayon::prelude::*;

use super::decompose::Decomposition;
use super::params::{Params, ResolvedMode};
use super::rank::perceptual_order;
use super::segments::{
    INIT_SEGMENTS_PER_PATH, MAX_TOLERANCE_SCALE, TOLERANCE_STEP, refinement_reserve,
};
use crate::decompose::binarize::binarize;
use crate::decompose::mask::Mask;
use crate::decompose::organize::organize;
use crate::decompose::segment::Candidate;
use crate::decompose::{channel_sums, min_mask_area};
use crate::geom::contour::{simplify_closed, simplify_tolerance};
use crate::perceptual::Grey;
use crate::render::Image;
use crate::scene::{LayerKind, Path, Point, Scene};

/// A structure path and the mask it was built from (the structure loss's target).
#[derive(Clone, Debug)]
pub struct MaskedPath {
    /// Index of the path in its layer's `paths`.
    pub path: usize,
    pub mask: Mask,
}

/// One layer's structure paths as back-to-front groups: masks within a group barely overlap,
/// and a mask contained in another sits in a higher group. Paint order is group by group.
#[derive(Clone, Debug)]
pub struct LayerGroups {
    pub layer: LayerKind,
    pub groups: Vec<Vec<MaskedPath>>,
}

/// How the path budget is shared out.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Budget {
    /// All paths the output may hold (`Params::paths`).
    pub total: usize,
    /// Most albedo structure paths, base path included.
    pub albedo: usize,
    /// Most illumination structure paths (0 in simple mode).
    pub illumination: usize,
}

/// Share of the budget for structure paths, both layers together (LayerVec's 0.4); the rest is
/// left to the refinement stage.
pub const STRUCTURE_SHARE: f32 = 0.4;
/// Share of the structure paths that go to the albedo layer in photo mode. Below half: the
/// albedo map is flat per surface, so a few paths hold it, and the shading
/// inside surfaces needs the rest.
pub const ALBEDO_SHARE: f32 = 0.4;
/// Binarisation levels per albedo region in photo mode (see [`binarize`]).
pub const PHOTO_BINARISATION_LEVELS: u32 = 2;

impl Budget {
    pub fn new(total: usize, mode: ResolvedMode) -> Self {
        let structure = ((total as f32 * STRUCTURE_SHARE) as usize).clamp(1, total);
        let albedo = match mode {
            ResolvedMode::Simple => structure,
            ResolvedMode::Photo => {
                ((structure as f32 * ALBEDO_SHARE).ceil() as usize).clamp(1, structure)
            }
        };
        Self {
            total,
            albedo,
            illumination: structure - albedo,
        }
    }
}

/// Everything the later stages need: the scene so far, the targets, and the structure groups.
#[derive(Clone, Debug)]
pub struct InitState {
    pub scene: Scene,
    /// The image at working size.
    pub target: Image,
    /// Albedo structure paths (in `scene.albedo`).
    pub albedo: LayerGroups,
    /// Illumination structure paths (in `scene.shade`); no groups in simple mode.
    pub illumination: LayerGroups,
    pub mode: ResolvedMode,
    /// Whether the albedo masks are the client's (see `super::keep`).
    pub masks_given: bool,
}

/// How many times [`simplify_tolerance`] an outline may stray where the image is flat. There a
/// straighter outline costs the loss little, and the optimiser moves it anyway; on an edge it
/// would cost the edge. Under the segment budget ([`super::segments`]) 0.1 and 10× did best
/// (docs/history.md, "Init outlines").
pub const FLAT_TOLERANCE_FACTOR: f32 = 10.0;

/// Luma gradient from which an outline point counts as on an edge and keeps the edge
/// tolerance; below it the tolerance rises linearly to [`FLAT_TOLERANCE_FACTOR`] times at a
/// flat point. Central differences of luma in [0, 1], per [`simplify_tolerance`] pixels (per
/// pixel up to 256 px of long side), so that an image at twice the size gets the same outlines
/// (per pixel lost MSE at 512²: docs/history.md, "Init outlines").
pub const EDGE_CONTRAST: f32 = 0.1;

/// The init outlines' tolerance at each point: [`simplify_tolerance`] on an edge of the image,
/// up to [`FLAT_TOLERANCE_FACTOR`] times that where the image is flat; all of it scaled up as
/// far as the segment budget needs ([`super::segments`]).
pub struct OutlineTolerance {
    /// Factor on every point's tolerance, raised to fit the segment budget.
    scale: f32,
    edge: f32,
    width: usize,
    height: usize,
    /// Per outline point's 4×4 pixel window (see [`OutlineTolerance::at`]), the largest luma
    /// gradient magnitude in it, per `edge` pixels: `(width + 1) × (height + 1)` windows, the
    /// first row and column those of points on the canvas's left and top edges. Taken once:
    /// the segment budget simplifies every outline at each scale it tries, and at 1024² the
    /// windows taken point by point were a fifth of the init stage.
    contrast: Vec<f32>,
}

impl OutlineTolerance {
    pub fn new(image: &Image) -> Self {
        let (w, h) = (image.width, image.height);
        let edge = simplify_tolerance(w, h);
        let luma = Grey::luma(image);
        let at = |x: usize, y: usize| (luma.data[y * w + x] / 255.0) as f32;
        let gradient: Vec<f32> = (0..w * h)
            .into_par_iter()
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let gx = 0.5 * (at((x + 1).min(w - 1), y) - at(x.saturating_sub(1), y));
                let gy = 0.5 * (at(x, (y + 1).min(h - 1)) - at(x, y.saturating_sub(1)));
                edge * gx.hypot(gy)
            })
            .collect();
        // Window k along an axis of n pixels covers pixels k - 2 ..= k + 1 (window 0: points
        // whose pixel to the left or above is -1).
        let window = |k: usize, n: usize| k.saturating_sub(2)..(k + 2).min(n);
        let mut rows = vec![0.0f32; h * (w + 1)];
        rows.par_chunks_mut(w + 1)
            .zip(gradient.par_chunks(w))
            .for_each(|(out, row)| {
                for (k, v) in out.iter_mut().enumerate() {
                    *v = row[window(k, w)].iter().fold(0.0, |m, &g| m.max(g));
                }
            });
        let mut contrast = vec![0.0f32; (h + 1) * (w + 1)];
        contrast
            .par_chunks_mut(w + 1)
            .enumerate()
            .for_each(|(k, out)| {
                for y in window(k, h) {
                    for (v, &r) in out.iter_mut().zip(&rows[y * (w + 1)..(y + 1) * (w + 1)]) {
                        *v = v.max(r);
                    }
                }
            });
        Self {
            scale: 1.0,
            edge,
            width: w,
            height: h,
            contrast,
        }
    }

    /// The tolerance at an outline point (a pixel-edge midpoint, on the canvas), from the
    /// largest gradient in the 4×4 pixels around it: an outline traced a pixel off the edge
    /// still sees the edge.
    pub fn at(&self, p: Point) -> f32 {
        let window = |v: f32, n: usize| ((v - 0.5).floor() as i64 + 1).clamp(0, n as i64) as usize;
        let contrast =
            self.contrast[window(p.y, self.height) * (self.width + 1) + window(p.x, self.width)];
        let flatness = 1.0 - (contrast / EDGE_CONTRAST).min(1.0);
        self.scale * self.edge * (1.0 + (FLAT_TOLERANCE_FACTOR - 1.0) * flatness)
    }
}

/// The init stage.
pub(crate) fn run(
    decomposition: Decomposition,
    params: &Params,
    original: (u32, u32),
) -> InitState {
    let Decomposition {
        target,
        albedo: albedo_map,
        candidates,
        mode,
        masks_given,
        ..
    } = decomposition;
    let (w, h) = (target.width, target.height);
    let budget = Budget::new(params.paths as usize, mode);
    let min_area = min_mask_area(w, h);

    let candidates = match mode {
        ResolvedMode::Photo => perceptual_order(candidates, &albedo_map, budget.albedo),
        ResolvedMode::Simple => candidates,
    };
    let mut albedo_masks = select(&candidates, budget.albedo, true, w, h);
    let mut illumination_masks = Vec::new();
    if budget.albedo > 1 || mode == ResolvedMode::Photo {
        let regions = visible_parts(&albedo_masks, w, h);
        let levels = match mode {
            ResolvedMode::Simple => 1,
            ResolvedMode::Photo => PHOTO_BINARISATION_LEVELS,
        };
        let shadows = sorted(binarize(&target, &regions, min_area, levels));
        match mode {
            ResolvedMode::Simple => {
                let mut all = candidates.clone();
                all.extend(shadows);
                albedo_masks = select(&sorted(all), budget.albedo, true, w, h);
            }
            ResolvedMode::Photo => {
                illumination_masks = select(&shadows, budget.illumination, false, w, h)
            }
        }
    }

    // The outlines at the smallest tolerance (a power of TOLERANCE_STEP) that fits the budget.
    let mut tolerance = OutlineTolerance::new(&target);
    let budget_segments = (INIT_SEGMENTS_PER_PATH * params.paths as f32) as usize;
    let albedo_outlines = outlines(&albedo_masks, w, h, |visible| {
        mean_colour(&albedo_map, visible)
    });
    let illumination_outlines = outlines(&illumination_masks, w, h, |visible| {
        mean_ratio(&target, &albedo_map, visible).map(|c| c.map(|v| v.clamp(0.0, 1.0)))
    });
    let (mut scene, albedo, illumination) = loop {
        let mut scene = Scene::new(w as u32, h as u32, original.0, original.1);
        let albedo = build_layer(LayerKind::Albedo, &albedo_outlines, &mut scene, &tolerance);
        let illumination = build_layer(
            LayerKind::Shade,
            &illumination_outlines,
            &mut scene,
            &tolerance,
        );
        let segments =
            scene.segment_count() + refinement_reserve(params.paths as usize, scene.path_count());
        if segments <= budget_segments || tolerance.scale > MAX_TOLERANCE_SCALE {
            break (scene, albedo, illumination);
        }
        tolerance.scale *= TOLERANCE_STEP;
    };
    if mode == ResolvedMode::Photo {
        fit_illumination_fills(&mut scene, &target, &albedo, &illumination);
    }
    InitState {
        scene,
        target,
        albedo,
        illumination,
        mode,
        masks_given,
    }
}

/// Refits the photo-mode illumination fills so that albedo × illumination matches the target:
/// each illumination fill becomes Σ I·A / Σ A² over its mask's visible part, per channel,
/// clamped to [0, 1] (the paper's fill, mean image / albedo, weighs dark albedo too much).
///
/// The albedo fills stay the map's means. Refitting them as well (alternating least squares)
/// lets a sliver of albedo mask on a cast shadow's edge, under no
/// shade path, take the shadow's colour; the optimiser then grows it over the shadow. Held to
/// the map, shadows stay out of the albedo (docs/history.md, "Init outlines").
fn fit_illumination_fills(
    scene: &mut Scene,
    target: &Image,
    albedo: &LayerGroups,
    illumination: &LayerGroups,
) {
    let (w, h) = (target.width, target.height);
    let albedo_owner = owner_map(albedo, w, h);
    let shade_owner = owner_map(illumination, w, h);
    let albedo_at =
        |i: usize, c: usize| albedo_owner[i].map_or(1.0, |k| scene.albedo.paths[k].color[c]);
    let fitted = least_squares(&shade_owner, scene.shade.paths.len(), target, albedo_at);
    apply(&mut scene.shade.paths, fitted);
}

/// Per path and channel, the factor x minimising Σ (I − x·other)² over the path's pixels;
/// `None` where the path owns no pixel.
fn least_squares(
    owner: &[Option<usize>],
    paths: usize,
    target: &Image,
    other: impl Fn(usize, usize) -> f32,
) -> Vec<Option<[f32; 3]>> {
    let mut num = vec![[0f64; 3]; paths];
    let mut den = vec![[0f64; 3]; paths];
    for (i, k) in owner.iter().enumerate() {
        let Some(k) = *k else { continue };
        for c in 0..3 {
            let o = f64::from(other(i, c));
            num[k][c] += f64::from(target.data[3 * i + c]) * o;
            den[k][c] += o * o;
        }
    }
    (0..paths)
        .map(|k| {
            (den[k][0] > 0.0).then(|| [0, 1, 2].map(|c| (num[k][c] / den[k][c].max(1e-9)) as f32))
        })
        .collect()
}

fn apply(paths: &mut [Path], fitted: Vec<Option<[f32; 3]>>) {
    for (path, colour) in paths.iter_mut().zip(fitted) {
        if let Some(colour) = colour {
            path.color = colour.map(|v| v.clamp(0.0, 1.0));
        }
    }
}

/// The path painted last at each pixel (by mask), if any.
fn owner_map(layer: &LayerGroups, w: usize, h: usize) -> Vec<Option<usize>> {
    let mut owner = vec![None; w * h];
    for masked in layer.groups.iter().flatten() {
        for i in masked.mask.indices() {
            owner[i] = Some(masked.path);
        }
    }
    owner
}

fn sorted(mut candidates: Vec<Candidate>) -> Vec<Candidate> {
    // Stable, so equal gains keep their order and runs are reproducible.
    candidates.sort_by(|a, b| b.gain.total_cmp(&a.gain));
    candidates
}

/// Organised groups of the most useful candidates, at most `cap` masks in all; with
/// `with_canvas`, the full canvas is the bottom mask and counts towards `cap`. Candidates that
/// organisation drops as duplicates free their slot for the next ones.
fn select(
    candidates: &[Candidate],
    cap: usize,
    with_canvas: bool,
    w: usize,
    h: usize,
) -> Vec<Vec<Mask>> {
    let mut masks: Vec<Mask> = if with_canvas {
        vec![Mask::full(w, h)]
    } else {
        Vec::new()
    };
    let mut next = 0;
    loop {
        let groups = organize(&masks);
        let kept: usize = groups.iter().map(Vec::len).sum();
        if kept >= cap || next >= candidates.len() {
            let mut budget = cap;
            return groups
                .into_iter()
                .map(|g| {
                    let take = g.len().min(budget);
                    budget -= take;
                    // Within a group keep the earliest-chosen (most useful) masks.
                    let mut g = g;
                    g.sort_unstable();
                    g.truncate(take);
                    g.into_iter().map(|i| masks[i].clone()).collect::<Vec<_>>()
                })
                .filter(|g| !g.is_empty())
                .collect();
        }
        let want = cap - kept;
        let end = (next + want).min(candidates.len());
        masks.extend(candidates[next..end].iter().map(|c| c.mask.clone()));
        next = end;
    }
}

/// Each mask's visible part when the groups are painted bottom to top.
fn visible_parts(groups: &[Vec<Mask>], w: usize, h: usize) -> Vec<Mask> {
    let masks: Vec<&Mask> = groups.iter().flatten().collect();
    let mut owner = vec![usize::MAX; w * h];
    for (k, m) in masks.iter().enumerate() {
        for i in m.indices() {
            owner[i] = k;
        }
    }
    Mask::from_labels(w, h, &owner, masks.len())
}

/// One mask of a layer with its fill and its traced outline (`None`: the full canvas), traced
/// once and simplified at each tolerance the segment budget tries.
struct Outline<'a> {
    mask: &'a Mask,
    colour: [f32; 3],
    boundary: Option<Vec<Point>>,
}

/// The outlines of one layer's organised masks, per group, filled by `fill(visible part)`; a
/// mask with no fill is left out.
fn outlines<'a>(
    groups: &'a [Vec<Mask>],
    w: usize,
    h: usize,
    fill: impl Fn(&Mask) -> Option<[f32; 3]>,
) -> Vec<Vec<Outline<'a>>> {
    let visible = visible_parts(groups, w, h);
    let mut k = 0;
    groups
        .iter()
        .map(|group| {
            group
                .iter()
                .filter_map(|mask| {
                    let part = if visible[k].is_empty() {
                        mask
                    } else {
                        &visible[k]
                    };
                    k += 1;
                    let colour = fill(part).or_else(|| fill(mask))?;
                    Some(Outline {
                        mask,
                        colour,
                        boundary: (mask.area() != w * h).then(|| mask.outer_boundary()),
                    })
                })
                .collect()
        })
        .collect()
}

/// Paths for one layer's outlines at `tolerance`.
fn build_layer(
    layer: LayerKind,
    outlines: &[Vec<Outline>],
    scene: &mut Scene,
    tolerance: &OutlineTolerance,
) -> LayerGroups {
    let (w, h) = (scene.width as usize, scene.height as usize);
    let mut out = LayerGroups {
        layer,
        groups: Vec::new(),
    };
    for group in outlines {
        // Each outline simplified on rayon's pool, then the paths pushed in order.
        let paths: Vec<Option<Path>> = group
            .par_iter()
            .map(|outline| {
                let boundary = outline.boundary.as_deref();
                path_from_outline(boundary, w, h, |p| tolerance.at(p), outline.colour)
            })
            .collect();
        let mut built = Vec::new();
        for (outline, path) in group.iter().zip(paths) {
            let Some(path) = path else { continue };
            let paths = &mut scene.layer_mut(layer).paths;
            paths.push(path);
            built.push(MaskedPath {
                path: paths.len() - 1,
                mask: outline.mask.clone(),
            });
        }
        if !built.is_empty() {
            out.groups.push(built);
        }
    }
    out
}

/// A closed path around a mask's traced outer boundary (Douglas-Peucker simplified to
/// `tolerance` at each point, straight cubics); `None`, the full `w × h` canvas, becomes the
/// exact canvas rectangle.
fn path_from_outline(
    boundary: Option<&[Point]>,
    w: usize,
    h: usize,
    tolerance: impl Fn(Point) -> f32,
    colour: [f32; 3],
) -> Option<Path> {
    let Some(boundary) = boundary else {
        return Some(Path::rect(0.0, 0.0, w as f32, h as f32, colour, 1.0));
    };
    let polygon = simplify_closed(boundary, tolerance);
    if polygon.len() < 3 {
        return None;
    }
    Path::from_polygon(&polygon, colour, 1.0)
}

fn mean_colour(image: &Image, mask: &Mask) -> Option<[f32; 3]> {
    if mask.is_empty() {
        return None;
    }
    let sum = channel_sums(image, mask.indices());
    Some(sum.map(|s| (s / mask.area() as f64) as f32))
}

/// Mean of `numerator / denominator` per channel (denominator floored at 1/255).
fn mean_ratio(numerator: &Image, denominator: &Image, mask: &Mask) -> Option<[f32; 3]> {
    if mask.is_empty() {
        return None;
    }
    let mut sum = [0f64; 3];
    for i in mask.indices() {
        let (n, d) = (
            &numerator.data[3 * i..3 * i + 3],
            &denominator.data[3 * i..3 * i + 3],
        );
        for ((s, &n), &d) in sum.iter_mut().zip(n).zip(d) {
            *s += f64::from(n / d.max(1.0 / 255.0));
        }
    }
    Some(sum.map(|s| (s / mask.area() as f64) as f32))
}

#[cfg(test)]
mod tests {
    use image::{DynamicImage, GrayImage};

    use super::*;
    use crate::decompose::min_mask_area;
    use crate::pipeline::decompose;
    use crate::pipeline::params::{Inputs, Masks, Mode};
    use crate::render::Rasterizer;
    use crate::synth::blobs_photo;

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
            image: DynamicImage::ImageRgb8(blobs_photo(w, h)),
            albedo: None,
            masks: Masks::Binary(vec![square(20, 28), square(4, 44)]),
        };
        let params = Params {
            mode: Mode::Photo,
            ..Params::default()
        };
        let state = run(decompose::run(&inputs, &params), &params, (w, h));
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
        let boundary = disc.outer_boundary();
        let tolerance = |_| simplify_tolerance(w, h);
        let path = path_from_outline(Some(&boundary), w, h, tolerance, [1.0; 3])
            .expect("a disc gives a path");
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
    fn outlines_are_coarser_where_the_image_is_flat() {
        let (w, h) = (32usize, 32usize);
        // Black left half, white right half.
        let data = (0..w * h)
            .flat_map(|i| [if i % w < 16 { 0.0 } else { 1.0 }; 3])
            .collect();
        let image = Image {
            width: w,
            height: h,
            data,
        };
        let tolerance = OutlineTolerance::new(&image);
        let edge = simplify_tolerance(w, h);
        assert_eq!(tolerance.at(Point::new(16.0, 10.5)), edge, "on the edge");
        assert_eq!(
            tolerance.at(Point::new(17.5, 3.0)),
            edge,
            "a pixel off the edge"
        );
        let flat = edge * FLAT_TOLERANCE_FACTOR;
        assert_eq!(tolerance.at(Point::new(4.0, 10.5)), flat, "in the black");
        assert_eq!(tolerance.at(Point::new(28.0, 31.0)), flat, "in the white");
        let disc = Mask::from_fn(w, h, |x, y| {
            (x as f32 + 0.5 - 7.0).powi(2) + (y as f32 + 0.5 - 16.0).powi(2) <= 25.0
        });
        let segments = |tolerance: &dyn Fn(Point) -> f32| {
            path_from_outline(Some(&disc.outer_boundary()), w, h, tolerance, [1.0; 3])
                .expect("a disc gives a path")
                .segment_count()
        };
        let (coarse, fine) = (segments(&|p| tolerance.at(p)), segments(&|_| edge));
        assert!(coarse < fine, "flat {coarse} segments, edge-only {fine}");
    }

    #[test]
    fn an_image_at_twice_the_size_gets_outlines_at_twice_the_size() {
        // A grey ramp of 0.04 per pixel at 256² (below the edge contrast), flat around it.
        let ramp = |size: usize| {
            let scale = size as f32 / 256.0;
            let luma = |x: usize| (0.2 + 0.04 * (x as f32 / scale - 100.0)).clamp(0.2, 0.84);
            let data = (0..size * size).flat_map(|i| [luma(i % size); 3]).collect();
            OutlineTolerance::new(&Image {
                width: size,
                height: size,
                data,
            })
        };
        let small = ramp(256).at(Point::new(108.0, 50.5));
        let large = ramp(512).at(Point::new(216.0, 101.0));
        assert!(small > 1.5 && small < 7.0, "partly flat: {small}");
        assert!(
            (large - 2.0 * small).abs() < 1e-3,
            "{large} against {small}"
        );
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
            image: DynamicImage::ImageRgb8(blobs_photo(w, h)),
            albedo: None,
            masks: Masks::Binary(vec![mask]),
        };
        let params = Params {
            mode: Mode::Photo,
            ..Params::default()
        };
        let decomposition = decompose::run(&inputs, &params);
        assert!(min_mask_area(64, 64) > 4);
        assert_eq!(decomposition.candidates.len(), 1, "the speck is dropped");
        let ring = &decomposition.candidates[0].mask;
        assert!(ring.contains(30, 30), "the hole is filled");
    }
}
