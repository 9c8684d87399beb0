//! Refinement (paper Sec. 4.4, LIVE / LayerVec path addition): with everything else frozen, new
//! paths are added to one layer where the reconstruction error is high, trained alone, then
//! pruned and merged, for a few rounds, until the path budget is used exactly.
//!
//! The photo mode refines the illumination layer (`scene.shade`, multiplied onto the fixed
//! albedo); the simple mode refines the albedo layer itself (the illumination is empty, i.e. 1).

use rayon::prelude::*;

use super::coarse::PlateauSettings;
use super::descent::{Descent, Objective};
use super::keep::{Keep, KeepRun, containment_term};
use super::params::Error;
use super::regions::{Ellipse, REGION_PATH_SEGMENTS, Region, high_error_regions, outline};
use super::stage::{Canvas, IterationSpan, StageRun, strip_ranges};
use super::structure::Scratch;
use crate::optim::loss::PartialMse;
use crate::optim::rng::Rng;
use crate::optim::{Adam, AdamSettings, Bounds};
use crate::render::composite::{product, product_range};
use crate::render::{Image, PathGrad};
use crate::scene::{LayerKind, Path, Scene};

/// Settings of the refinement.
#[derive(Clone, Debug, PartialEq)]
pub struct RefineSettings {
    /// Adam for the new paths. Default: points 1.0, colours and opacities 0.01 (paper).
    pub adam: AdamSettings,
    /// Share of the remaining budget added in each round but the last (which adds the rest).
    /// Default 0.6 (LayerVec).
    pub round_share: f32,
    /// A new path is pruned when removing it changes the composite by at most this much, summed
    /// over pixels × channels, per 512² pixels (scaled to the working size). Default 7.0 (LayerVec).
    pub prune_threshold: f32,
    /// Two new paths merge when they overlap on at least `merge_overlap` pixels and their
    /// colours + opacities differ by at most `merge_color_l1` (L1). Defaults 3 and 0.1 (LayerVec).
    pub merge_overlap: usize,
    pub merge_color_l1: f32,
    /// Smallest semi-axis of a new path, in pixels. Default 1.5.
    pub min_radius: f32,
    /// Most vertices of a new path that starts as its region's outline ([`Growth::outline`]).
    /// Default 10. The region's ellipse reaches past a curved or forked region, where an
    /// outline keeps to it; the segment budget still reserves [`REGION_PATH_SEGMENTS`] per new
    /// path (`super::segments::refinement_reserve`), so the files grow a little
    /// (docs/history.md, "Refinement").
    pub outline_vertices: usize,
    /// When a round's training stops early.
    pub plateau: PlateauSettings,
}

impl Default for RefineSettings {
    fn default() -> Self {
        Self {
            adam: AdamSettings::default(),
            round_share: 0.6,
            prune_threshold: 7.0,
            merge_overlap: 3,
            merge_color_l1: 0.1,
            min_radius: 1.5,
            outline_vertices: 10,
            plateau: PlateauSettings::default(),
        }
    }
}

/// Which layer grows, and the colour range of its paths.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Growth {
    /// `Shade` (the illumination layer before separation) or `Albedo` (simple mode).
    pub layer: LayerKind,
    pub color_max: f32,
    /// Whether a new path starts as its region's outline ([`RefineSettings::outline_vertices`])
    /// rather than its ellipse. Photo mode's illumination paths do; simple mode's albedo paths
    /// do not: the emoji's regions are compact and outlines cost MSE (docs/history.md,
    /// "Refinement").
    pub outline: bool,
}

/// One call of [`refine`]: which rounds, how, into which layer.
pub(crate) struct RefinePlan<'a> {
    pub growth: Growth,
    /// Paths the scene may hold in the end.
    pub budget: usize,
    /// The rounds to run, of all rounds of the stage.
    pub rounds: IterationSpan,
    /// Iterations per round.
    pub iterations: u32,
    pub settings: &'a RefineSettings,
    pub seed: u64,
    /// The albedo regions new paths are held to (photo mode).
    pub keep: Option<&'a KeepRun<'a>>,
}

/// Runs the plan's rounds (each of up to `iterations`, stopping early once the loss has
/// plateaued) and returns the reconstruction loss ‖I − R(A)·R(I)‖² before and after. After the
/// last of all rounds `scene.path_count() == budget` unless the scene already held more; only
/// then are previews made.
pub(crate) fn refine(
    scene: &mut Scene,
    target: &Image,
    plan: &RefinePlan,
    stage: &StageRun,
) -> Result<[f32; 2], Error> {
    let RefinePlan {
        growth,
        budget,
        rounds,
        iterations,
        settings,
        seed,
        ref keep,
    } = *plan;

    let (w, h) = (target.width, target.height);
    let mut canvas = Canvas::new(w, h);
    let mut rng = Rng::new(seed, 0x5245_4649);
    let other = match growth.layer {
        LayerKind::Albedo => LayerKind::Shade,
        _ => LayerKind::Albedo,
    };
    // The frozen factor the growing layer is multiplied with.
    let mut factor = Image::default();
    canvas.render_layer(scene, other, &mut factor);
    let bounds = Bounds::canvas(w, h, growth.color_max);
    let total_iterations = rounds.total * iterations;
    // The growing layer's render shares its buffer with the rounds' frozen render, and the
    // composite lives only outside the training: full-size images are a job's largest buffers.
    let mut frozen = Image::default();
    let layer_loss = |canvas: &mut Canvas, scene: &Scene, layer: &mut Image| {
        canvas.render_layer(scene, growth.layer, layer);
        let mut composite = Image::default();
        product(layer, &factor, &mut composite);
        (crate::optim::loss::mse_value(&composite, target), composite)
    };
    let (initial, _) = layer_loss(&mut canvas, scene, &mut frozen);

    for round in rounds.start..rounds.start + rounds.count {
        let remaining = budget.saturating_sub(scene.path_count());
        if remaining == 0 {
            break;
        }
        let last = round + 1 == rounds.total;
        let count = if last {
            remaining
        } else {
            ((settings.round_share * remaining as f32) as usize).max(1)
        };

        let (_, composite) = layer_loss(&mut canvas, scene, &mut frozen);
        // Per pixel and per region on rayon's pool: at 1024² the full-size round's setup ran
        // on one thread.
        let error: Vec<f32> = composite
            .data
            .par_chunks_exact(3)
            .zip(target.data.par_chunks_exact(3))
            .map(|(p, t)| (0..3).map(|c| (p[c] - t[c]) * (p[c] - t[c])).sum())
            .collect();
        drop(composite);
        let regions = high_error_regions(&error, w, h, count);
        let mut new_paths: Vec<Path> = regions
            .par_iter()
            .filter_map(|r| region_path(r, target, &factor, w, settings, growth))
            .collect();
        while new_paths.len() < count {
            new_paths.push(random_path(
                &mut rng,
                target,
                &factor,
                w,
                h,
                growth.color_max,
            ));
        }

        let base_iteration = round * iterations;
        let schedule = Schedule {
            iterations,
            settings,
            bounds,
        };
        let parents = keep
            .as_ref()
            .map(|k| k.keep.parents(&mut canvas, &new_paths))
            .unwrap_or_default();
        let frame = Frame {
            backdrop: &frozen,
            factor: &factor,
            target,
            containment: keep.as_ref().map(|k| Containment {
                parents: &parents,
                keep: k.keep,
            }),
        };
        train(
            &mut canvas,
            &mut new_paths,
            &frame,
            &schedule,
            |it, loss| stage.iteration(base_iteration + it, total_iterations, Some(loss)),
        )?;

        if !last {
            prune(&mut canvas, &mut new_paths, &frame, settings);
            let merged = merge(&mut canvas, &mut new_paths, settings);
            if merged > 0 {
                // Train only the merged paths (on top), over everything else.
                let kept = new_paths.len() - merged;
                let mut below = Image::default();
                canvas.render_over(&new_paths[..kept], &frozen, &mut below);
                let mut merged_paths = new_paths.split_off(kept);
                let report = base_iteration + iterations;
                let merged_parents = keep
                    .as_ref()
                    .map(|k| k.keep.parents(&mut canvas, &merged_paths))
                    .unwrap_or_default();
                let frame = Frame {
                    backdrop: &below,
                    containment: frame.containment.map(|c| Containment {
                        parents: &merged_parents,
                        ..c
                    }),
                    ..frame
                };
                let schedule = Schedule {
                    iterations: iterations / 2,
                    ..schedule
                };
                train(
                    &mut canvas,
                    &mut merged_paths,
                    &frame,
                    &schedule,
                    |_, loss| stage.iteration(report, total_iterations, Some(loss)),
                )?;
                new_paths.extend(merged_paths);
            }
        }
        scene.layer_mut(growth.layer).paths.extend(new_paths);
    }

    let (loss, composite) = layer_loss(&mut canvas, scene, &mut frozen);
    if rounds.ends_early() {
        return Ok([initial, loss]);
    }
    stage.preview("composite", &composite);
    stage.preview(
        if growth.layer == LayerKind::Albedo {
            "albedo"
        } else {
            "illumination"
        },
        &frozen,
    );
    Ok([initial, loss])
}

/// What new paths are trained in: painted over `backdrop` (the frozen paths below them),
/// multiplied by `factor` (the other layer), compared with `target`.
#[derive(Clone, Copy)]
struct Frame<'a> {
    backdrop: &'a Image,
    factor: &'a Image,
    target: &'a Image,
    /// Holds each new path to its parent region (photo mode).
    containment: Option<Containment<'a>>,
}

/// The new paths' parent regions, the region of every pixel, and the term's weight.
#[derive(Clone, Copy)]
struct Containment<'a> {
    parents: &'a [u32],
    keep: &'a Keep,
}

/// How long and how new paths are trained.
#[derive(Clone, Copy)]
struct Schedule<'a> {
    iterations: u32,
    settings: &'a RefineSettings,
    bounds: Bounds,
}

/// Trains `paths` in `frame`.
fn train(
    canvas: &mut Canvas,
    paths: &mut [Path],
    frame: &Frame,
    schedule: &Schedule,
    report: impl FnMut(u32, f32) -> Result<(), Error>,
) -> Result<(), Error> {
    let mut adams = [Adam::new(schedule.settings.adam, schedule.bounds)];
    let mut objective = NewPaths {
        frame,
        scratch: Scratch::default(),
        painted: Vec::new(),
        mse: PartialMse::default(),
    };
    let descent = Descent {
        iterations: schedule.iterations,
        plateau: schedule.settings.plateau,
    };
    descent.run(canvas, paths, &mut adams, &mut objective, report)
}

/// The image loss of new paths painted in their frame (`a`: the layer, `c`: the composite),
/// with their containment term.
///
/// A few new paths cover a small part of the canvas, so after the first iteration only the
/// strips they have met are rendered and composited again: everywhere else every buffer
/// still holds what the first iteration wrote there, the frame alone, which is what a whole
/// pass would write again.
struct NewPaths<'a> {
    frame: &'a Frame<'a>,
    scratch: Scratch,
    /// The strips some new path has met in an iteration so far (empty before the first).
    painted: Vec<bool>,
    mse: PartialMse,
}

impl Objective<[Path]> for NewPaths<'_> {
    fn loss(&mut self, canvas: &mut Canvas, paths: &[Path], grads: &mut [Vec<PathGrad>]) -> f32 {
        let Frame {
            backdrop,
            factor,
            target,
            containment,
        } = *self.frame;
        let (grads, s) = (&mut grads[0], &mut self.scratch);
        let first = self.painted.is_empty();
        canvas.mark_strips(paths, &mut self.painted);
        let mut loss = if first {
            canvas.render_over(paths, backdrop, &mut s.a);
            product(&s.a, factor, &mut s.c);
            let loss = self.mse.update(&s.c, target, &mut s.d_c, None);
            // `d_a` alone: the frame takes no gradient.
            product(&s.d_c, factor, &mut s.d_a);
            loss
        } else {
            canvas.render_over_strips(paths, backdrop, &self.painted, &mut s.a);
            let changed: Vec<_> =
                strip_ranges(&self.painted, canvas.width, canvas.height).collect();
            for range in &changed {
                product_range(&s.a, factor, &mut s.c, range.clone());
            }
            let loss = self
                .mse
                .update(&s.c, target, &mut s.d_c, Some(changed.as_slice()));
            for range in changed {
                product_range(&s.d_c, factor, &mut s.d_a, range);
            }
            loss
        };
        canvas.backward_over(paths, backdrop, &s.d_a, grads);
        if let Some(c) = containment {
            loss += containment_term(canvas, paths, c.parents, c.keep, grads);
        }
        loss
    }
}

/// The least-squares colour `c` with `factor · c ≈ target` over `pixels`, clamped to `[0, max]`.
fn fitted_color(
    pixels: impl Iterator<Item = usize> + Clone,
    target: &Image,
    factor: &Image,
    max: f32,
) -> [f32; 3] {
    let mut color = [0.0; 3];
    for (c, out) in color.iter_mut().enumerate() {
        let (mut num, mut den) = (0.0f64, 0.0f64);
        for p in pixels.clone() {
            let f = f64::from(factor.data[3 * p + c]);
            num += f * f64::from(target.data[3 * p + c]);
            den += f * f;
        }
        *out = if den > 1e-9 { (num / den) as f32 } else { 1.0 }.clamp(0.0, max);
    }
    color
}

fn region_path(
    region: &Region,
    target: &Image,
    factor: &Image,
    width: usize,
    settings: &RefineSettings,
    growth: Growth,
) -> Option<Path> {
    let color = fitted_color(
        region.pixels.iter().copied(),
        target,
        factor,
        growth.color_max,
    );
    let outline = growth
        .outline
        .then(|| outline(region, width, settings.outline_vertices))
        .flatten();
    match outline {
        Some(polygon) => Path::from_polygon(&polygon, color, 1.0),
        None => Ellipse::of_region(region, width, settings.min_radius)
            .map(|ellipse| ellipse.to_path(REGION_PATH_SEGMENTS, color, 1.0)),
    }
}

/// A small disc at a seeded random position, for when no error region is left (LIVE's fallback).
fn random_path(
    rng: &mut Rng,
    target: &Image,
    factor: &Image,
    w: usize,
    h: usize,
    color_max: f32,
) -> Path {
    let radius = (w.min(h) as f32 * 0.03).max(1.5);
    let center = crate::scene::Point::new(rng.range(0.0, w as f32), rng.range(0.0, h as f32));
    let ellipse = Ellipse {
        center,
        radii: [radius, radius],
        angle: 0.0,
    };
    let (x, y) = (
        (center.x as usize).min(w - 1),
        (center.y as usize).min(h - 1),
    );
    let color = fitted_color(std::iter::once(y * w + x), target, factor, color_max);
    ellipse.to_path(REGION_PATH_SEGMENTS, color, 1.0)
}

/// Removes (all at once) every new path whose removal changes the composite by at most the prune
/// threshold (Σ |Δ| over pixels × channels, scaled from 512² to `pixels`).
fn prune(canvas: &mut Canvas, paths: &mut Vec<Path>, frame: &Frame, settings: &RefineSettings) {
    if paths.is_empty() {
        return;
    }
    let (backdrop, factor) = (frame.backdrop, frame.factor);
    let pixels = factor.width * factor.height;
    let threshold = settings.prune_threshold * pixels as f32 / (512.0 * 512.0);
    let mut full = Image::default();
    canvas.render_over(paths, backdrop, &mut full);
    // Without path `i` the render differs from the full one only in the strips path `i`
    // meets: those are rendered again and compared, the rest adds exact zeros to the change.
    let mut without = full.clone();
    let mut keep = vec![true; paths.len()];
    let mut others = Vec::with_capacity(paths.len());
    let mut strips = Vec::new();
    for i in 0..paths.len() {
        others.clear();
        others.extend(
            paths
                .iter()
                .enumerate()
                .filter(|&(j, _)| j != i)
                .map(|(_, p)| p.clone()),
        );
        strips.clear();
        canvas.mark_strips(std::slice::from_ref(&paths[i]), &mut strips);
        canvas.render_over_strips(&others, backdrop, &strips, &mut without);
        let change: f32 = strip_ranges(&strips, canvas.width, canvas.height)
            .flatten()
            .map(|k| ((full.data[k] - without.data[k]) * factor.data[k]).abs())
            .sum();
        keep[i] = change > threshold;
    }
    let mut index = 0;
    paths.retain(|_| {
        index += 1;
        keep[index - 1]
    });
}

/// Merges overlapping new paths of nearly the same colour, greedily and transitively; each group
/// becomes one path (ellipse of the union, coverage-weighted mean colour) appended at the end.
/// Returns the number of merged paths appended.
fn merge(canvas: &mut Canvas, paths: &mut Vec<Path>, settings: &RefineSettings) -> usize {
    let n = paths.len();
    if n < 2 {
        return 0;
    }
    let coverages: Vec<Vec<(u32, f32)>> = paths.iter().map(|p| canvas.coverage(p)).collect();
    let mut parent: Vec<usize> = (0..n).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    for i in 0..n {
        for j in i + 1..n {
            let l1: f32 = (0..3)
                .map(|c| (paths[i].color[c] - paths[j].color[c]).abs())
                .sum::<f32>()
                + (paths[i].opacity - paths[j].opacity).abs();
            if l1 > settings.merge_color_l1 {
                continue;
            }
            let overlap = solid_overlap(&coverages[i], &coverages[j]);
            if overlap >= settings.merge_overlap {
                let (ri, rj) = (root(&mut parent, i), root(&mut parent, j));
                parent[ri.max(rj)] = ri.min(rj);
            }
        }
    }
    let mut groups: Vec<Vec<usize>> = vec![Vec::new(); n];
    for i in 0..n {
        let r = root(&mut parent, i);
        groups[r].push(i);
    }
    let width = canvas.width;
    let mut merged = Vec::new();
    let mut removed = vec![false; n];
    for group in groups.iter().filter(|g| g.len() > 1) {
        let mut union = std::collections::BTreeMap::new();
        for &i in group {
            for &(p, c) in &coverages[i] {
                let v = union.entry(p).or_insert(0.0f32);
                *v = v.max(c);
            }
        }
        let weighted = union.iter().map(|(&p, &c)| {
            let p = p as usize;
            ((p % width) as f32 + 0.5, (p / width) as f32 + 0.5, c)
        });
        let Some(ellipse) = super::regions::ellipse_for_pixels(weighted, settings.min_radius)
        else {
            continue;
        };
        let areas: Vec<f32> = group
            .iter()
            .map(|&i| coverages[i].iter().map(|&(_, c)| c).sum::<f32>().max(1e-6))
            .collect();
        let total: f32 = areas.iter().sum();
        let mut color = [0.0; 3];
        let mut opacity = 0.0;
        for (&i, &a) in group.iter().zip(&areas) {
            for c in 0..3 {
                color[c] += paths[i].color[c] * a / total;
            }
            opacity += paths[i].opacity * a / total;
        }
        let segments = group
            .iter()
            .map(|&i| paths[i].segment_count())
            .max()
            .unwrap_or(REGION_PATH_SEGMENTS);
        merged.push(ellipse.to_path(segments, color, opacity));
        for &i in group {
            removed[i] = true;
        }
    }
    let mut index = 0;
    paths.retain(|_| {
        index += 1;
        !removed[index - 1]
    });
    let count = merged.len();
    paths.extend(merged);
    count
}

/// Pixels where two sparse coverages (sorted by pixel) are both nearly full (sum > 1.9).
fn solid_overlap(a: &[(u32, f32)], b: &[(u32, f32)]) -> usize {
    let (mut i, mut j, mut count) = (0, 0, 0);
    while i < a.len() && j < b.len() {
        match a[i].0.cmp(&b[j].0) {
            std::cmp::Ordering::Less => i += 1,
            std::cmp::Ordering::Greater => j += 1,
            std::cmp::Ordering::Equal => {
                count += usize::from(a[i].1 + b[j].1 > 1.9);
                i += 1;
                j += 1;
            }
        }
    }
    count
}
