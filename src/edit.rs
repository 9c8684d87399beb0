//! Illumination-aware recolouring: change albedo paths and keep the lighting: the shade and
//! light layers, less (in a reference edit) the colour an object left in its own shade paths.
//!
//! Two kinds of edit, both cheap (no optimisation) and both returning a new [`Scene`] with the
//! list of paths they changed:
//! - [`recolor_by_reference`]: paper Appendix D, from an edited copy of the original image;
//! - [`recolor_paths`]: set colours of named paths, or of the albedo path under a point.

use image::DynamicImage;

use crate::decompose::mask::Mask;
use crate::decompose::min_mask_area;
use crate::geom::contour::{simplify_closed, simplify_tolerance};
use crate::imageio::{InputError, check_aspect, resize_rgb};
use crate::render::composite::{composite, composite_layers, render_layers};
use crate::render::{Image, Rasterizer};
use crate::scene::{LayerKind, Path, PathId, Point, Scene};

/// Thresholds of the reference edit (paper Appendix D). Colours are in [0, 1].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "service", derive(utoipa::ToSchema))]
#[serde(default, deny_unknown_fields)]
pub struct ReferenceParams {
    /// Number of albedo paths to recolour or add at most (the paper's K; photo mode adds paths
    /// where it splits one); the object's own shade and light paths are refit with them.
    /// Default 4.
    #[cfg_attr(feature = "service", schema(minimum = 1))]
    pub k: usize,
    /// A pixel is edited when its mean absolute channel difference exceeds τ. Default 0.05.
    pub tau: f32,
    /// A path is spatially relevant when its IoU with the edit region exceeds γ. Default 0.01.
    pub gamma: f32,
    /// A path is kept only when its mean colour changes by at least δ (L2 over RGB).
    /// The paper prints `≤ δ` but says the test keeps regions that "actually change colour";
    /// covec implements that intent. Default 0.05.
    pub delta: f32,
    /// Added to the mean shade before dividing, against division by zero. Default 0.01.
    pub epsilon: f32,
}

impl Default for ReferenceParams {
    fn default() -> Self {
        Self {
            k: 4,
            tau: 0.05,
            gamma: 0.01,
            delta: 0.05,
            epsilon: 0.01,
        }
    }
}

/// One direct change: a path (by id, or the albedo path under a point) and its new fill.
#[derive(Clone, Debug, PartialEq)]
pub struct ColorChange {
    /// The path to change.
    pub target: Target,
    /// Its new fill, in [0, 1].
    pub color: [f32; 3],
    /// New opacity, if it changes too.
    pub opacity: Option<f32>,
}

/// Which path a [`ColorChange`] applies to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Target {
    /// The path with this id.
    Path(PathId),
    /// The topmost albedo path covering this point (working-canvas coordinates).
    AlbedoAt(Point),
}

/// A path the edit changed, with its fill before and after; a path the edit added has
/// `old_opacity` 0 (it painted nothing) and the colour that showed there as `old_color`.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Changed {
    /// Which path.
    #[serde(serialize_with = "serialize_id")]
    pub path: PathId,
    /// Fill before the edit.
    pub old_color: [f32; 3],
    /// Fill after the edit.
    pub new_color: [f32; 3],
    /// Opacity before the edit.
    pub old_opacity: f32,
    /// Opacity after the edit.
    pub new_opacity: f32,
}

fn serialize_id<S: serde::Serializer>(id: &PathId, s: S) -> Result<S::Ok, S::Error> {
    s.collect_str(id)
}

/// The new scene (the original is untouched) and what changed.
#[derive(Clone, Debug)]
pub struct Edit {
    /// The edited scene.
    pub scene: Scene,
    /// Every path whose fill changed.
    pub changed: Vec<Changed>,
}

/// Why an edit was refused; each is the caller's mistake.
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum EditError {
    /// No path has this id.
    #[error("unknown path id `{0}`")]
    UnknownPath(String),
    /// No albedo path covers the point `(x, y)`.
    #[error("no albedo path covers the point ({x}, {y})")]
    #[allow(missing_docs)]
    NothingAt { x: f32, y: f32 },
    /// A colour channel outside [0, 1].
    #[error("colour {0:?} is not in [0, 1]")]
    BadColor([f32; 3]),
    /// An opacity outside [0, 1].
    #[error("opacity {0} is not in [0, 1]")]
    BadOpacity(f32),
    /// Original and reference images of different sizes (at working size).
    #[error(
        "the reference image is {actual_width}×{actual_height}, the original {expected_width}×{expected_height}"
    )]
    #[allow(missing_docs)]
    SizeMismatch {
        expected_width: usize,
        expected_height: usize,
        actual_width: usize,
        actual_height: usize,
    },
    /// `k` of zero paths.
    #[error("k must be at least 1")]
    ZeroK,
    /// A reference or original image that does not fit the scene ([`recolor_by_reference_images`]).
    #[error(transparent)]
    Input(#[from] InputError),
}

/// Sets the fills of the given paths; everything else, shade and light included, is kept.
pub fn recolor_paths(scene: &Scene, changes: &[ColorChange]) -> Result<Edit, EditError> {
    let mut edited = scene.clone();
    let mut changed = Vec::with_capacity(changes.len());
    for change in changes {
        if !change.color.iter().all(|c| (0.0..=1.0).contains(c)) {
            return Err(EditError::BadColor(change.color));
        }
        if let Some(o) = change.opacity.filter(|o| !(0.0..=1.0).contains(o)) {
            return Err(EditError::BadOpacity(o));
        }
        let id = match change.target {
            Target::Path(id) => id,
            Target::AlbedoAt(p) => {
                albedo_path_at(&edited, p).ok_or(EditError::NothingAt { x: p.x, y: p.y })?
            }
        };
        let path = edited
            .path_mut(id)
            .ok_or_else(|| EditError::UnknownPath(id.to_string()))?;
        changed.push(set_fill(
            id,
            path,
            change.color,
            change.opacity.unwrap_or(path.opacity),
        ));
    }
    Ok(Edit {
        scene: edited,
        changed,
    })
}

/// [`recolor_by_reference`] from the images as given, at any size with the scene's aspect
/// ratio: both are resized to the working canvas; without `original`, the scene's own
/// rendering stands in for it (and so counts vectorisation error as edits too).
pub fn recolor_by_reference_images(
    scene: &Scene,
    reference: &DynamicImage,
    original: Option<&DynamicImage>,
    params: &ReferenceParams,
) -> Result<Edit, EditError> {
    let reference_size = (reference.width(), reference.height());
    check_aspect(
        "the reference image",
        reference_size,
        (scene.original_width, scene.original_height),
    )?;
    let (w, h) = (scene.width, scene.height);
    let original = match original {
        Some(original) => {
            check_aspect(
                "the original image",
                (original.width(), original.height()),
                reference_size,
            )?;
            resize_rgb(original, w, h)
        }
        None => composite(scene),
    };
    recolor_by_reference(scene, &original, &resize_rgb(reference, w, h), params)
}

/// Recolours up to `k` albedo paths so the scene follows `reference`, an edited copy of
/// `original` (paper Appendix D). Both images are at the scene's working size.
///
/// Where the scene has a shade layer, the new albedo colour is the reference colour, less the
/// mean light under the path, divided by the mean shade under it (the paper divides only; with
/// `I = A·S + L` the light must come off first), so the lighting stays; otherwise it is the
/// reference colour.
///
/// Departures:
/// - a path's support S_n is the part of its silhouette no later albedo path covers (what the
///   path paints), not the whole silhouette as in the paper. Under a stack of opaque paths the
///   silhouette of the full-canvas base holds every edit, so with the paper's rule an edit of
///   one object that is large enough recolours the base, and with it the background;
/// - where the scene has a shade layer, a path that paints outside the edit region too (by at
///   least the smallest mask the pipeline makes, [`min_mask_area`], more than [`RIM`] pixels
///   from it) is split, not recoloured: the edit adds albedo paths
///   over its parts inside the region (traced from them, right above it: [`insert_splits`]),
///   coloured from the means there, and keeps the path. One albedo path can hold a red hat and the pink curtain beside it, told apart only
///   by shade paths: recoloured whole, the curtain turned blue with the hat. Each added path
///   counts as one of the `k` and is listed in `changed` with `old_opacity` 0. Simple
///   mode's albedo paths are the image's own colour regions, and split there, the objects
///   measured came out further from the reference (`docs/benchmarks.md`), so they are
///   recoloured whole;
/// - the object's own shade and light paths are refit too ([`refit_illumination`]).
pub fn recolor_by_reference(
    scene: &Scene,
    original: &Image,
    reference: &Image,
    params: &ReferenceParams,
) -> Result<Edit, EditError> {
    if params.k == 0 {
        return Err(EditError::ZeroK);
    }
    let (width, height) = (scene.width as usize, scene.height as usize);
    for image in [original, reference] {
        if (image.width, image.height) != (width, height) {
            return Err(EditError::SizeMismatch {
                expected_width: width,
                expected_height: height,
                actual_width: image.width,
                actual_height: image.height,
            });
        }
    }
    let edit_region: Vec<bool> = original
        .data
        .chunks_exact(3)
        .zip(reference.data.chunks_exact(3))
        .map(|(a, b)| (0..3).map(|c| (a[c] - b[c]).abs()).sum::<f32>() / 3.0 > params.tau)
        .collect();

    let mut rasterizer = Rasterizer::new();
    // Rendered once: the edit keeps them until the refit, which starts from them.
    let layers = render_layers(scene);
    let [_, shade_layer, light_layer] = &layers;
    let shade = (!scene.shade.paths.is_empty()).then_some(shade_layer);
    let light = (!scene.light.paths.is_empty()).then_some(light_layer);

    struct Candidate {
        index: usize,
        area: usize,
        reference_mean: [f32; 3],
        shade_mean: Option<[f32; 3]>,
        light_mean: [f32; 3],
    }
    let owner = albedo_owner(&mut rasterizer, scene, width, height);
    let mut candidates = Vec::new();
    for index in 0..scene.albedo.paths.len() {
        let mask: Vec<bool> = owner.iter().map(|&o| o == Some(index)).collect();
        let area = mask.iter().filter(|&&m| m).count();
        if area == 0 {
            continue;
        }
        let intersection = mask
            .iter()
            .zip(&edit_region)
            .filter(|&(&m, &e)| m && e)
            .count();
        let union = mask
            .iter()
            .zip(&edit_region)
            .filter(|&(&m, &e)| m || e)
            .count();
        if (intersection as f32 / union as f32) <= params.gamma {
            continue;
        }
        let original_mean = masked_mean(original, &mask, area);
        let reference_mean = masked_mean(reference, &mask, area);
        let change = (0..3)
            .map(|c| (original_mean[c] - reference_mean[c]).powi(2))
            .sum::<f32>()
            .sqrt();
        if change < params.delta {
            continue;
        }
        let shade_mean = shade.map(|s| masked_mean(s, &mask, area));
        let light_mean = light.map_or([0.0; 3], |l| masked_mean(l, &mask, area));
        candidates.push(Candidate {
            index,
            area,
            reference_mean,
            shade_mean,
            light_mean,
        });
    }
    // Largest first; ties keep paint order so the result is deterministic.
    candidates.sort_by(|a, b| b.area.cmp(&a.area).then(a.index.cmp(&b.index)));
    let colour = |reference: [f32; 3], shade: Option<[f32; 3]>, light: [f32; 3]| {
        std::array::from_fn(|i| match shade {
            Some(s) => ((reference[i] - light[i]) / (s[i] + params.epsilon)).clamp(0.0, 1.0),
            None => reference[i],
        })
    };
    let mut edited = scene.clone();
    let mut changed = Vec::new();
    let mut splits = Vec::new();
    let mut edited_paths = Vec::new();
    // Albedo paths recoloured or added so far, against `k`.
    let mut used = 0;
    let min_part = min_mask_area(width, height);
    let near_edit = widened(&edit_region, width, height, RIM);
    for c in &candidates {
        if used == params.k {
            break;
        }
        edited_paths.push(c.index);
        let inside: Vec<bool> = owner
            .iter()
            .zip(&edit_region)
            .map(|(&o, &e)| e && o == Some(c.index))
            .collect();
        let area = inside.iter().filter(|&&i| i).count();
        let beyond_rim = owner
            .iter()
            .zip(&near_edit)
            .filter(|&(&o, &near)| !near && o == Some(c.index))
            .count();
        if shade.is_none() || beyond_rim < min_part {
            let id = PathId {
                layer: LayerKind::Albedo,
                index: c.index,
            };
            let color = colour(c.reference_mean, c.shade_mean, c.light_mean);
            let path = &mut edited.albedo.paths[c.index];
            changed.push(set_fill(id, path, color, path.opacity));
            used += 1;
            continue;
        }
        let color = colour(
            masked_mean(reference, &inside, area),
            shade.map(|s| masked_mean(s, &inside, area)),
            light.map_or([0.0; 3], |l| masked_mean(l, &inside, area)),
        );
        let opacity = scene.albedo.paths[c.index].opacity;
        // A pixel wider wherever that cannot reach outside the edit: the traced outline runs
        // through the edge pixels' middles, and the path under it would show at its edge.
        let grown = widened(&inside, width, height, 1);
        let indices: Vec<usize> = (0..inside.len())
            .filter(|&i| grown[i] && (edit_region[i] || owner[i].is_some_and(|o| o > c.index)))
            .collect();
        let tolerance = simplify_tolerance(width, height);
        let paths: Vec<Path> = Mask::from_indices(width, height, &indices)
            .fill_holes()
            .components(min_part)
            .iter()
            .take(params.k - used)
            .filter_map(|part| {
                let outline = simplify_closed(&part.outer_boundary(), |_| tolerance);
                Path::from_polygon(&outline, color, opacity)
            })
            .collect();
        used += paths.len();
        splits.push(Split {
            index: c.index,
            paths,
        });
    }
    insert_splits(&mut edited.albedo.paths, &splits, &mut changed);
    let object: Vec<bool> = owner
        .iter()
        .zip(&edit_region)
        .map(|(o, &e)| e && o.is_some_and(|i| edited_paths.contains(&i)))
        .collect();
    let target = edited_target(composite_layers(&layers), original, reference);
    let [_, shade, light] = layers;
    changed.extend(refit_illumination(
        &mut rasterizer,
        &mut edited,
        &object,
        &target,
        [shade, light],
    ));
    Ok(Edit {
        scene: edited,
        changed,
    })
}

/// How far (px, in x and in y) an albedo path may paint beyond the edit region and still be
/// recoloured whole: a fitted outline overshoots its object by about a pixel, and its
/// anti-aliased edge by another. Split for that rim, the disc of
/// `tests/pipeline/edit_synthetic.rs` came out worse than recoloured whole
/// (`docs/benchmarks.md`, edit leakage).
const RIM: usize = 2;

/// `region` (a `width`-wide mask) widened by `reach` pixels in x and in y (a square).
fn widened(region: &[bool], width: usize, height: usize, reach: usize) -> Vec<bool> {
    let mut rows = vec![false; region.len()];
    for y in 0..height {
        for x in 0..width {
            let span = x.saturating_sub(reach)..(x + reach + 1).min(width);
            rows[y * width + x] = span.into_iter().any(|sx| region[y * width + sx]);
        }
    }
    let mut out = vec![false; region.len()];
    for y in 0..height {
        let span = y.saturating_sub(reach)..(y + reach + 1).min(height);
        for x in 0..width {
            out[y * width + x] = span.clone().any(|sy| rows[sy * width + x]);
        }
    }
    out
}

/// The paths a reference edit adds over the edited part of the albedo path at `index`.
struct Split {
    index: usize,
    paths: Vec<Path>,
}

/// Inserts each split's paths right above the path they split, so that the albedo paths above
/// it still paint over them as they did over it (traced with holes filled, they cover those
/// paths' pixels too); renumbers the albedo entries of `changed` to the new ids, and lists the
/// added paths, each with `old_opacity` 0 and the split path's colour as `old_color`.
fn insert_splits(albedo: &mut Vec<Path>, splits: &[Split], changed: &mut Vec<Changed>) {
    if splits.is_empty() {
        return;
    }
    let mut new_index = Vec::with_capacity(albedo.len());
    let mut added = Vec::new();
    for (index, path) in std::mem::take(albedo).into_iter().enumerate() {
        new_index.push(albedo.len());
        let old_color = path.color;
        albedo.push(path);
        for path in splits
            .iter()
            .filter(|s| s.index == index)
            .flat_map(|s| &s.paths)
        {
            added.push(Changed {
                path: PathId {
                    layer: LayerKind::Albedo,
                    index: albedo.len(),
                },
                old_color,
                new_color: path.color,
                old_opacity: 0.0,
                new_opacity: path.opacity,
            });
            albedo.push(path.clone());
        }
    }
    for c in changed.iter_mut() {
        c.path.index = new_index[c.path.index];
    }
    changed.extend(added);
}

/// Share of an illumination path's paint that may fall outside the edited object for the
/// reference edit to recolour the path with it. At half rather than a quarter, objects came
/// closer to the reference for a little more change outside them (`docs/benchmarks.md`, edit
/// leakage): a path left as it was keeps the old hue on the object's part of it.
const OWN_PATH_OUTSIDE: f64 = 0.5;

/// Passes of the illumination refit over the object's own paths.
const REFIT_ROUNDS: usize = 3;

/// What the edited render should show: `target`, the unedited render, plus the edit
/// (`reference − original`), so the refit transfers the edit rather than the photo's detail
/// the scene never held.
fn edited_target(mut target: Image, original: &Image, reference: &Image) -> Image {
    for ((t, &o), &r) in target
        .data
        .iter_mut()
        .zip(&original.data)
        .zip(&reference.data)
    {
        *t = (*t + r - o).clamp(0.0, 1.0);
    }
    target
}

/// Recolours the object's own shade and light paths (those painting almost only inside
/// `object`) so the edited scene follows `target`, by least squares on each path's colour in
/// turn. The decomposition leaves colour texture and part of a surface's colour in the shade
/// (a red cap's shade is reddish): a new albedo alone under it cannot reach the new colour,
/// and where it would need a channel above 1 it is clamped. Departure from the paper, which
/// recolours albedo paths only; paths that reach outside the object are kept, so the edit
/// still keeps to it. `[shade, light]` are those layers rendered, as yet unedited.
fn refit_illumination(
    rasterizer: &mut Rasterizer,
    edited: &mut Scene,
    object: &[bool],
    target: &Image,
    [mut shade, mut light]: [Image; 2],
) -> Vec<Changed> {
    let (width, height) = (edited.width as usize, edited.height as usize);
    let Some(bounds) = pixel_bounds(object, width) else {
        return Vec::new();
    };
    let mut albedo = Image::default();
    let base = LayerKind::Albedo.base();
    rasterizer.render(&edited.albedo.paths, base, width, height, &mut albedo);
    // Each own path's paint weight per pixel (coverage × opacity × what later paths let
    // through), which does not depend on colours: the layer rendered black over black with
    // this path white.
    let mut own = Vec::new();
    let mut scratch = Image::default();
    for kind in [LayerKind::Shade, LayerKind::Light] {
        let paths = &edited.layer(kind).paths;
        for index in 0..paths.len() {
            // Outside the object's bounds a path paints nothing inside it: no probe needed.
            if !reaches(&paths[index], bounds) {
                continue;
            }
            let probe: Vec<Path> = paths
                .iter()
                .enumerate()
                .map(|(i, p)| Path {
                    color: [if i == index { 1.0 } else { 0.0 }; 3],
                    ..p.clone()
                })
                .collect();
            rasterizer.render(&probe, [0.0; 3], width, height, &mut scratch);
            let weights: Vec<(usize, f32)> = scratch
                .data
                .chunks_exact(3)
                .enumerate()
                .filter(|(_, px)| px[0] > 0.0)
                .map(|(p, px)| (p, px[0]))
                .collect();
            let total: f64 = weights.iter().map(|&(_, w)| f64::from(w)).sum();
            let outside: f64 = weights
                .iter()
                .filter(|&&(p, _)| !object[p])
                .map(|&(_, w)| f64::from(w))
                .sum();
            if total > 0.0 && outside <= OWN_PATH_OUTSIDE * total {
                own.push((PathId { layer: kind, index }, weights));
            }
        }
    }
    let before: Vec<(PathId, [f32; 3])> = own
        .iter()
        .map(|(id, _)| (*id, edited.layer(id.layer).paths[id.index].color))
        .collect();
    for _ in 0..REFIT_ROUNDS {
        for (id, weights) in &own {
            let path = &mut edited.layer_mut(id.layer).paths[id.index];
            for c in 0..3 {
                // d(render)/d(colour) is w·A for a shade path, w for a light path.
                let (mut gr, mut gg) = (0f64, 0f64);
                for &(p, w) in weights {
                    let i = 3 * p + c;
                    let g = match id.layer {
                        LayerKind::Shade => w * albedo.data[i],
                        _ => w,
                    };
                    let shown = albedo.data[i] * shade.data[i] + light.data[i];
                    gr += f64::from(g) * f64::from(target.data[i] - shown);
                    gg += f64::from(g) * f64::from(g);
                }
                if gg <= 0.0 {
                    continue;
                }
                let old = path.color[c];
                let new = (f64::from(old) + gr / gg).clamp(0.0, 1.0) as f32;
                let layer = if id.layer == LayerKind::Shade {
                    &mut shade
                } else {
                    &mut light
                };
                for &(p, w) in weights {
                    layer.data[3 * p + c] += w * (new - old);
                }
                path.color[c] = new;
            }
        }
    }
    before
        .into_iter()
        .filter_map(|(id, old_color)| {
            let path = &edited.layer(id.layer).paths[id.index];
            (path.color != old_color).then_some(Changed {
                path: id,
                old_color,
                new_color: path.color,
                old_opacity: path.opacity,
                new_opacity: path.opacity,
            })
        })
        .collect()
}

/// `[x0, y0, x1, y1]`: the box of the pixels (each `[x, x + 1] × [y, y + 1]`) set in `mask`, a
/// `width`-wide mask; `None` when none is.
fn pixel_bounds(mask: &[bool], width: usize) -> Option<[f32; 4]> {
    let mut bounds: Option<[f32; 4]> = None;
    for (i, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
        let (x, y) = ((i % width) as f32, (i / width) as f32);
        let b = bounds.get_or_insert([x, y, x + 1.0, y + 1.0]);
        *b = [
            b[0].min(x),
            b[1].min(y),
            b[2].max(x + 1.0),
            b[3].max(y + 1.0),
        ];
    }
    bounds
}

/// Whether `path`'s control points' box (which holds its outline) meets `bounds` widened by a
/// pixel, for anti-aliased edges.
fn reaches(path: &Path, [x0, y0, x1, y1]: [f32; 4]) -> bool {
    let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
    for p in &path.points {
        lo = [lo[0].min(p.x), lo[1].min(p.y)];
        hi = [hi[0].max(p.x), hi[1].max(p.y)];
    }
    hi[0] >= x0 - 1.0 && lo[0] <= x1 + 1.0 && hi[1] >= y0 - 1.0 && lo[1] <= y1 + 1.0
}

/// The topmost albedo path whose outline contains `point` (non-zero rule).
pub fn albedo_path_at(scene: &Scene, point: Point) -> Option<PathId> {
    scene
        .albedo
        .paths
        .iter()
        .rposition(|path| winding_number(path, point) != 0)
        .map(|index| PathId {
            layer: LayerKind::Albedo,
            index,
        })
}

fn set_fill(id: PathId, path: &mut Path, color: [f32; 3], opacity: f32) -> Changed {
    let changed = Changed {
        path: id,
        old_color: path.color,
        new_color: color,
        old_opacity: path.opacity,
        new_opacity: opacity,
    };
    path.color = color;
    path.opacity = opacity;
    changed
}

/// Per pixel, the topmost albedo path whose silhouette (coverage ≥ ½, the path rendered alone
/// as the paper does) holds it.
pub(crate) fn albedo_owner(
    rasterizer: &mut Rasterizer,
    scene: &Scene,
    width: usize,
    height: usize,
) -> Vec<Option<usize>> {
    let mut owner = vec![None; width * height];
    let mut scratch = Image::default();
    for (index, path) in scene.albedo.paths.iter().enumerate() {
        let silhouette = Path {
            points: path.points.clone(),
            color: [1.0; 3],
            opacity: 1.0,
        };
        rasterizer.render(
            std::slice::from_ref(&silhouette),
            [0.0; 3],
            width,
            height,
            &mut scratch,
        );
        for (o, p) in owner.iter_mut().zip(scratch.data.chunks_exact(3)) {
            if p[0] >= 0.5 {
                *o = Some(index);
            }
        }
    }
    owner
}

fn masked_mean(image: &Image, mask: &[bool], area: usize) -> [f32; 3] {
    let mut sum = [0.0f64; 3];
    for (pixel, _) in image.data.chunks_exact(3).zip(mask).filter(|(_, m)| **m) {
        for c in 0..3 {
            sum[c] += f64::from(pixel[c]);
        }
    }
    sum.map(|s| (s / area as f64) as f32)
}

/// Winding number of the closed path around `point`, on a fine fixed flattening of each cubic.
fn winding_number(path: &Path, point: Point) -> i32 {
    const STEPS: usize = 32;
    let mut winding = 0;
    for k in 0..path.segment_count() {
        let [p0, p1, p2, p3] = path.segment(k);
        let at = |t: f32| {
            let u = 1.0 - t;
            let (a, b, c, d) = (u * u * u, 3.0 * u * u * t, 3.0 * u * t * t, t * t * t);
            Point::new(
                a * p0.x + b * p1.x + c * p2.x + d * p3.x,
                a * p0.y + b * p1.y + c * p2.y + d * p3.y,
            )
        };
        let mut a = p0;
        for i in 1..=STEPS {
            let b = if i == STEPS {
                p3
            } else {
                at(i as f32 / STEPS as f32)
            };
            if (a.y <= point.y) != (b.y <= point.y) {
                let x = a.x + (point.y - a.y) / (b.y - a.y) * (b.x - a.x);
                if x > point.x {
                    winding += if b.y > a.y { 1 } else { -1 };
                }
            }
            a = b;
        }
    }
    winding
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::composite::composite;

    fn scene_with_two_squares() -> Scene {
        let mut scene = Scene::new(20, 20, 20, 20);
        scene
            .albedo
            .paths
            .push(Path::rect(0.0, 0.0, 20.0, 20.0, [0.5; 3], 1.0));
        scene
            .albedo
            .paths
            .push(Path::rect(2.0, 2.0, 10.0, 10.0, [1.0, 0.0, 0.0], 1.0));
        scene
    }

    /// `image` with the pixels `xs` × `ys` painted blue: a reference edit.
    fn painted_blue(
        image: &Image,
        xs: std::ops::Range<usize>,
        ys: std::ops::Range<usize>,
    ) -> Image {
        let mut painted = image.clone();
        for y in ys {
            for x in xs.clone() {
                let i = 3 * (y * image.width + x);
                painted.data[i..i + 3].copy_from_slice(&[0.0, 0.0, 1.0]);
            }
        }
        painted
    }

    #[test]
    fn picks_the_topmost_albedo_path_under_a_point() {
        let scene = scene_with_two_squares();
        assert_eq!(
            albedo_path_at(&scene, Point::new(5.0, 5.0))
                .unwrap()
                .to_string(),
            "albedo-1"
        );
        assert_eq!(
            albedo_path_at(&scene, Point::new(15.0, 15.0))
                .unwrap()
                .to_string(),
            "albedo-0"
        );
        assert_eq!(albedo_path_at(&scene, Point::new(25.0, 5.0)), None);
    }

    #[test]
    fn direct_recolour_keeps_the_original_and_reports_the_change() {
        let scene = scene_with_two_squares();
        let change = ColorChange {
            target: Target::AlbedoAt(Point::new(5.0, 5.0)),
            color: [0.0, 0.0, 1.0],
            opacity: None,
        };
        let edit = recolor_paths(&scene, &[change]).unwrap();
        assert_eq!(edit.scene.albedo.paths[1].color, [0.0, 0.0, 1.0]);
        assert_eq!(scene.albedo.paths[1].color, [1.0, 0.0, 0.0]);
        assert_eq!(edit.changed.len(), 1);
        assert_eq!(edit.changed[0].old_color, [1.0, 0.0, 0.0]);
    }

    #[test]
    fn direct_recolour_refuses_bad_input() {
        let scene = scene_with_two_squares();
        let unknown = ColorChange {
            target: Target::Path("albedo-9".parse().unwrap()),
            color: [0.0; 3],
            opacity: None,
        };
        assert_eq!(
            recolor_paths(&scene, &[unknown]).unwrap_err(),
            EditError::UnknownPath("albedo-9".into())
        );
        let bad = ColorChange {
            target: Target::Path("albedo-0".parse().unwrap()),
            color: [2.0, 0.0, 0.0],
            opacity: None,
        };
        assert!(matches!(
            recolor_paths(&scene, &[bad]),
            Err(EditError::BadColor(_))
        ));
        let outside = ColorChange {
            target: Target::AlbedoAt(Point::new(-3.0, 5.0)),
            color: [0.0; 3],
            opacity: None,
        };
        assert!(matches!(
            recolor_paths(&scene, &[outside]),
            Err(EditError::NothingAt { .. })
        ));
    }

    #[test]
    fn a_reference_edit_recolours_the_objects_own_shade_and_keeps_the_rest() {
        // The red square's shade path is orange: blue albedo under it cannot show the
        // reference's blue (its blue channel would need 1.7), so that shade path is refit; the
        // shade over the whole canvas reaches far outside the object and is kept.
        let mut scene = scene_with_two_squares();
        scene.albedo.paths[1].color = [0.9, 0.2, 0.1];
        scene.shade.paths = vec![
            Path::rect(0.0, 0.0, 20.0, 20.0, [0.8; 3], 1.0),
            Path::rect(2.0, 2.0, 10.0, 10.0, [1.0, 0.7, 0.4], 1.0),
        ];
        let original = crate::render::composite::composite(&scene);
        let mut reference = original.clone();
        let inside = |i: usize| (2..10).contains(&(i % 20)) && (2..10).contains(&(i / 20));
        for i in (0..400).filter(|&i| inside(i)) {
            reference.data[3 * i..3 * i + 3].copy_from_slice(&[0.1, 0.2, 0.7]);
        }
        let edit = recolor_by_reference(&scene, &original, &reference, &ReferenceParams::default())
            .unwrap();
        let changed: Vec<String> = edit.changed.iter().map(|c| c.path.to_string()).collect();
        assert_eq!(changed, ["albedo-1", "shade-1"]);
        let shown = crate::render::composite::composite(&edit.scene);
        for i in 0..400 {
            let expected = if inside(i) { &reference } else { &original };
            for c in 0..3 {
                let (got, want) = (shown.data[3 * i + c], expected.data[3 * i + c]);
                assert!(
                    (got - want).abs() < 1e-3,
                    "pixel {i} channel {c}: {got} against {want}"
                );
            }
        }
    }

    #[test]
    fn a_reference_edit_of_an_object_leaves_the_base_under_it() {
        // The red square covers 16% of the canvas: the base's silhouette meets the edit
        // (IoU 0.16) and its mean changes by 0.16 × the edit, so the paper's rule would
        // recolour the background too; what the base paints does not change.
        let scene = scene_with_two_squares();
        let mut original = Image::default();
        Rasterizer::new().render(&scene.albedo.paths, [0.0; 3], 20, 20, &mut original);
        let reference = painted_blue(&original, 2..10, 2..10);
        let edit = recolor_by_reference(&scene, &original, &reference, &ReferenceParams::default())
            .unwrap();
        let changed: Vec<String> = edit.changed.iter().map(|c| c.path.to_string()).collect();
        assert_eq!(changed, ["albedo-1"]);
        assert_eq!(edit.scene.albedo.paths[1].color, [0.0, 0.0, 1.0]);
    }

    #[test]
    fn under_a_shade_layer_an_edit_of_part_of_a_path_splits_it() {
        let mut scene = scene_with_two_squares();
        let green = Path::rect(12.0, 12.0, 16.0, 16.0, [0.0, 1.0, 0.0], 1.0);
        scene.albedo.paths.push(green.clone());
        scene.shade.paths = vec![Path::rect(0.0, 0.0, 20.0, 20.0, [1.0; 3], 1.0)];
        let original = composite(&scene);
        let reference = painted_blue(&original, 2..6, 2..10);
        let edit = recolor_by_reference(&scene, &original, &reference, &ReferenceParams::default())
            .unwrap();
        // The left half of the red square gets a path of its own right above it; the square
        // keeps its colour, and the green square above moves up one id.
        let changed: Vec<String> = edit.changed.iter().map(|c| c.path.to_string()).collect();
        assert_eq!(changed, ["albedo-2"]);
        assert_eq!(edit.changed[0].old_opacity, 0.0);
        assert_eq!(edit.changed[0].old_color, [1.0, 0.0, 0.0]);
        let paths = &edit.scene.albedo.paths;
        assert_eq!(paths.len(), 4);
        assert_eq!(paths[1], scene.albedo.paths[1]);
        assert_eq!(paths[3], green);
        let after = composite(&edit.scene);
        let diff = |i: usize, image: &Image| {
            (0..3)
                .map(|c| (after.data[3 * i + c] - image.data[3 * i + c]).abs())
                .fold(0.0f32, f32::max)
        };
        // The added path's outline runs through the edge pixels' midpoints: a pixel's margin.
        for i in 0..400 {
            let (x, y) = (i % 20, i / 20);
            if (3..5).contains(&x) && (3..9).contains(&y) {
                assert!(diff(i, &reference) < 0.05, "pixel {x},{y}");
            } else if !(1..7).contains(&x) || !(1..11).contains(&y) {
                assert!(diff(i, &original) < 1e-6, "pixel {x},{y}");
            }
        }
    }
}
