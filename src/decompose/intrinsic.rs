//! Classical intrinsic decomposition: the albedo map of a bare photo, standing in for the
//! paper's network (Careaga & Aksoy 2024) when the client sends none.
//!
//! The classical insight (Color Retinex; Grosse et al. 2009; the reflectance grouping of Bell
//! et al. 2014, Shen & Yeo 2011, Zhao et al. 2012): under one illuminant, a change of intensity
//! at constant chromaticity is shading, a change of chromaticity is albedo. So:
//! 1. **Illuminant.** Grey-edge (van de Weijer et al. 2007, Minkowski p = 6): the mean edge is
//!    achromatic, so the illuminant's colour is the per-channel norm of the gradients. The image
//!    is divided by it (von Kries) so surface chromaticity can be compared across the image.
//! 2. **Superpixels.** Felzenszwalb-Huttenlocher on the corrected image cuts at every edge,
//!    shading and shadow boundaries included.
//! 3. **Reflectance grouping.** Adjacent superpixels of nearly the same chromaticity are one
//!    surface: a sphere's lit and dark sides and a floor inside and outside a cast shadow join,
//!    across the shadow's boundary. The tolerance widens in the dark, where chromaticity is noisy,
//!    and more between light and shadow, which bounce light from coloured surfaces tints.
//!    Where the sky is bluer than the sun, shadows are bluer than the lit side: that shift is
//!    estimated once for the image and undone before comparing a darker piece with a lighter.
//!    Two groups of one chromaticity on both sides of a third (a ball's stripes) are one
//!    surface too, so each stripe takes its colour from the best-lit stripe of its kind.
//!    Superpixels that meet in a gradient, the colour hardly stepping across their boundary,
//!    are one surface though their groups' chromaticities differ by more than the tolerance:
//!    light changes colour gradually (a warm lamp giving way to a blue sky over a floor),
//!    albedo in steps.
//! 4. **Highlights** (dichromatic model, Shafer 1985): a small bright group whose colour is its
//!    neighbour's body colour plus a share of the (corrected, so white) illuminant is that
//!    neighbour's specular highlight, and joins it; the excess goes to the light layer later.
//! 5. **Albedo.** Each surface gets one flat colour: that of its lit part (the 75th-95th
//!    luminance percentiles: fully lit, highlights excluded), in the image's own colours, so
//!    that image / albedo, the shade, is near 1 where lit and near-grey in shadow.
//!
//! Departures: albedo is flat per surface, so texture of constant chromaticity goes to the
//! shade layer; surfaces of the same chromaticity that touch (a white wall on a grey floor)
//! join; a darker object whose colour differs from its lighter neighbour's exactly by the
//! shadow shift joins it; albedo that changes gradually (a blurred edge, a graded backdrop)
//! is one surface.

use rayon::prelude::*;

use super::albedo::intensity;
use super::segment::{DisjointSets, blur, superpixels};
use crate::render::Image;

/// Minkowski norm of the grey-edge illuminant estimate.
const GREY_EDGE_P: i32 = 6;
/// No channel of the estimated illuminant falls below this share of the largest: keeps a
/// saturated scene (all foliage) from being read as a green light.
const MIN_ILLUMINANT_CHANNEL: f32 = 0.25;
/// Felzenszwalb granularity on the corrected image (colour distances in [0, √3]); finer than
/// the segmentation's, since grouping joins the pieces again. At 0.25 a dark superpixel could
/// straddle an object's shaded rim and the contact shadow under it and keep its own dark
/// albedo there.
const SUPERPIXEL_K: f32 = 0.15;
/// Chromaticity angle (radians) under which two adjacent superpixels are one surface, plus
/// [`DARK_TOLERANCE`] / luminance for noise in the dark.
const CHROMA_TOLERANCE: f32 = 0.07;
const DARK_TOLERANCE: f32 = 0.01;
/// The dark widening stops here: below a luminance of 0.1 chromaticity says little, and a
/// black object is not the shadow of the white one beside it.
const MAX_DARK_EXTRA: f32 = 0.1;
/// The same two for a pair [`MIN_SHADOW_CONTRAST`] or more apart in luminance, light and its
/// shadow: coloured bounce light (a Cornell box's red and green walls) tints a shadow more than
/// noise does; applied to every pair, it joined two pastel objects of like lightness, and a
/// recolour of one changed both (docs/history.md, "Intrinsic decomposition").
const SHADOW_DARK_TOLERANCE: f32 = 0.02;
const SHADOW_MAX_DARK_EXTRA: f32 = 0.15;
/// Two groups whose luminances differ by more than this factor are not one surface in light
/// and shadow: sky and bounce light keep shadows within about a fifth of full light.
const MAX_SHADING_RATIO: f32 = 5.0;
/// Adjacent superpixels this many times apart in luminance may be light and shadow.
const MIN_SHADOW_CONTRAST: f32 = 2.5;
/// Shifts within this log-chromaticity distance count as one.
const SHIFT_BANDWIDTH: f32 = 0.06;
/// The shadow shift's mode must hold this share of the contrasted boundary length...
const MIN_SHIFT_SUPPORT: f64 = 0.25;
/// ... and be at least this long to be used.
const MIN_SHIFT: f32 = 0.08;
/// Largest angle between the shadow shift and the daylight locus's direction towards blue.
const SKY_ANGLE: f32 = std::f32::consts::FRAC_PI_6;
/// A boundary is soft (see [`soft`]) when its chromaticity step is at most this share of the
/// difference of its superpixels' means and its luminance step at most
/// [`SOFT_LUMINANCE_STEP`] (log ratio): it lowers the Cornell scenes' map error and keeps the
/// generated scenes' (docs/history.md, "Intrinsic decomposition").
const SOFT_SHARE: f32 = 0.2;
/// Largest luminance step (log ratio) across a soft boundary: 0.2 joined the generated
/// warm-light scene's objects to their floor.
const SOFT_LUMINANCE_STEP: f32 = 0.1;
/// Groups a soft boundary joins differ in mean chromaticity by at most this angle (radians):
/// each gradient join lets a group chain on, and on the bench's portraits chained joins
/// flattened the map (a face's shaded half joined its lit half), leaving the vectoriser fewer
/// albedo masks. 0.12 keeps the photos' error and most of the Cornell scenes' gain
/// (docs/history.md, "Intrinsic decomposition").
const SOFT_GROUP_ANGLE: f32 = 0.12;
/// The colour step across a boundary is taken between pixels this far out on either side, so
/// that a superpixel boundary a pixel off an edge (or inside its anti-aliased ramp) still sees
/// the edge: taken between the boundary's own pixels, the generated scenes' objects joined
/// their backgrounds.
const SOFT_REACH: usize = 2;
/// A boundary shorter than this (pixel pairs) is too noisy to call soft.
const MIN_SOFT_BOUNDARY: u32 = 4;
/// A highlight adds at least this much illuminant (in corrected units) to its body colour.
const MIN_SPECULAR: f32 = 0.04;
/// A highlight group covers at most this share of the canvas.
const MAX_HIGHLIGHT_SHARE: f32 = 0.02;
/// A corrected colour with a channel at least this bright may be a clipped highlight.
const CLIPPED: f32 = 0.97;
/// Rounds of highlight joining: each peels one ring of a highlight's superpixels.
const HIGHLIGHT_PASSES: usize = 6;
/// The dichromatic fit may miss a highlight's colour by this share of its norm.
const DICHROMATIC_RESIDUAL: f32 = 0.08;
/// The luminance percentiles whose pixels give a surface's albedo.
const LIT_PERCENTILES: (f32, f32) = (0.75, 0.95);

/// The albedo map of `image`: one flat colour per surface; see the module documentation.
pub fn albedo_map(image: &Image) -> Image {
    let (w, h) = (image.width, image.height);
    if w * h == 0 {
        return image.clone();
    }
    let illuminant = grey_edge_illuminant(image);
    let corrected = Image {
        data: image
            .data
            .iter()
            .enumerate()
            .map(|(k, &v)| v / illuminant[k % 3])
            .collect(),
        ..image.clone()
    };
    let labels = superpixels(&corrected, SUPERPIXEL_K, 4000);
    let groups = group_surfaces(&corrected, &labels, illuminant);
    let surfaces = surfaces(&groups);
    let colours: Vec<[f32; 3]> = surfaces
        .par_iter()
        .map(|members| lit_colour(image, members))
        .collect();
    let mut map = image.clone();
    for (members, colour) in surfaces.iter().zip(colours) {
        for &i in members {
            map.data[3 * i..3 * i + 3].copy_from_slice(&colour);
        }
    }
    map
}

/// The illuminant's colour by grey-edge, largest channel 1.
pub fn grey_edge_illuminant(image: &Image) -> [f32; 3] {
    let (w, h) = (image.width, image.height);
    let smooth = blur(image);
    let mut norm = [0f64; 3];
    for y in 0..h {
        for x in 0..w {
            let i = 3 * (y * w + x);
            let right = 3 * (y * w + (x + 1).min(w - 1));
            let down = 3 * ((y + 1).min(h - 1) * w + x);
            for c in 0..3 {
                let gx = smooth.data[right + c] - smooth.data[i + c];
                let gy = smooth.data[down + c] - smooth.data[i + c];
                norm[c] += f64::from(gx.hypot(gy)).powi(GREY_EDGE_P);
            }
        }
    }
    let e = norm.map(|n| n.powf(1.0 / f64::from(GREY_EDGE_P)) as f32);
    let max = e.iter().copied().fold(0.0, f32::max);
    if max <= 0.0 {
        return [1.0; 3];
    }
    e.map(|v| (v / max).max(MIN_ILLUMINANT_CHANNEL))
}

/// Per-superpixel statistics during grouping.
#[derive(Clone, Default)]
struct Piece {
    sum: [f64; 3],
    count: f64,
}

impl Piece {
    fn mean(&self) -> [f32; 3] {
        self.sum.map(|s| (s / self.count.max(1.0)) as f32)
    }
}

/// Chromaticity: the colour's direction.
fn chroma(c: [f32; 3]) -> [f32; 3] {
    let n = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt().max(1e-6);
    c.map(|v| v / n)
}

fn angle(a: [f32; 3], b: [f32; 3]) -> f32 {
    let (a, b) = (chroma(a), chroma(b));
    (a[0] * b[0] + a[1] * b[1] + a[2] * b[2])
        .clamp(-1.0, 1.0)
        .acos()
}

/// Log-chromaticity: log colour less its mean, so intensity drops out and a change of
/// illuminant colour is a translation.
fn log_chroma(c: [f32; 3]) -> [f32; 3] {
    let l = c.map(|v| v.max(1e-3).ln());
    let mean = (l[0] + l[1] + l[2]) / 3.0;
    l.map(|v| v - mean)
}

/// Shadows lit by a sky of another colour than the sun's shift every surface's chromaticity by
/// one translation in log-chromaticity (the lit-to-shadow illuminant ratio; Finlayson et al.
/// 2006), and the sky being bluer than the sun, towards blue. Estimated as the mode of the shifts across the boundaries of adjacent superpixels at
/// least [`MIN_SHADOW_CONTRAST`] apart in luminance, weighted by boundary length: albedo edges
/// scatter, shadow edges agree. `None` when no mode holds [`MIN_SHIFT_SUPPORT`] of that weight
/// or it is under [`MIN_SHIFT`] (a white sun and a grey sky: the plain tolerance covers it).
fn shadow_shift(
    pieces: &[Piece],
    boundaries: &std::collections::BTreeMap<(usize, usize), Boundary>,
) -> Option<Shadow> {
    // Shifts as points of the log-chromaticity plane (an orthonormal basis of sum-zero vectors).
    let plane = |d: [f32; 3]| {
        (
            (d[0] - d[1]) / std::f32::consts::SQRT_2,
            (d[0] + d[1] - 2.0 * d[2]) / 6f32.sqrt(),
        )
    };
    let mut shifts = Vec::new();
    for (&(a, b), boundary) in boundaries {
        let (ma, mb) = (pieces[a].mean(), pieces[b].mean());
        let (la, lb) = (intensity(ma), intensity(mb));
        let (lit, dark) = if la >= lb { (ma, mb) } else { (mb, ma) };
        let ratio = la.max(lb) / la.min(lb).max(1e-3);
        if (MIN_SHADOW_CONTRAST..=MAX_SHADING_RATIO).contains(&ratio) {
            let (dl, dd) = (log_chroma(lit), log_chroma(dark));
            let shift = [0, 1, 2].map(|c| dd[c] - dl[c]);
            shifts.push((plane(shift), shift, f64::from(boundary.length), ratio.ln()));
        }
    }
    let total: f64 = shifts.iter().map(|s| s.2).sum();
    // Support of each shift: the weight of the shifts within SHIFT_BANDWIDTH of it.
    let near = |p: (f32, f32), q: (f32, f32)| (p.0 - q.0).hypot(p.1 - q.1) <= SHIFT_BANDWIDTH;
    let (support, centre) = shifts
        .iter()
        .map(|s| {
            let support: f64 = shifts.iter().filter(|t| near(s.0, t.0)).map(|t| t.2).sum();
            (support, s.0)
        })
        .max_by(|a, b| a.0.total_cmp(&b.0))?;
    if support < MIN_SHIFT_SUPPORT * total {
        return None;
    }
    let (mut mean, mut log_ratio) = ([0f64; 3], 0f64);
    for t in shifts.iter().filter(|t| near(centre, t.0)) {
        for c in 0..3 {
            mean[c] += f64::from(t.1[c]) * t.2 / support;
        }
        log_ratio += f64::from(t.3) * t.2 / support;
    }
    let shift = mean.map(|v| v as f32);
    let (u, v) = plane(shift);
    let length = u.hypot(v);
    // Sun and sky both lie near the daylight locus, the sky on its blue side: the shift runs
    // from red to blue (the plane's direction of log(blue / red)), within SKY_ANGLE.
    let bluer = (-0.5 * u - 0.75f32.sqrt() * v) / length.max(1e-6);
    (length >= MIN_SHIFT && bluer >= SKY_ANGLE.cos()).then_some(Shadow {
        shift,
        log_ratio: log_ratio as f32,
    })
}

/// A cast shadow's colour change: log-chromaticity shift and log luminance ratio, lit to
/// shadow, of a full shadow.
#[derive(Clone, Copy, Debug)]
struct Shadow {
    shift: [f32; 3],
    log_ratio: f32,
}

/// The chromaticity angle between two colours once the darker is relit by the share of the
/// shadow shift its darkness implies (a penumbra: part of the sun's light, part of the shift);
/// infinite without a shadow shift.
fn relit_angle(a: [f32; 3], b: [f32; 3], shadow: Option<Shadow>) -> f32 {
    let Some(Shadow { shift, log_ratio }) = shadow else {
        return f32::INFINITY;
    };
    let (la, lb) = (intensity(a).max(1e-3), intensity(b).max(1e-3));
    let (lit, dark) = if la >= lb { (a, b) } else { (b, a) };
    let share = ((la.max(lb) / la.min(lb)).ln() / log_ratio).min(1.0);
    angle(lit, [0, 1, 2].map(|c| dark[c] * (-share * shift[c]).exp()))
}

/// Superpixels joined into groups, with each root's statistics.
struct Grouping {
    sets: DisjointSets,
    stats: Vec<Piece>,
}

impl Grouping {
    /// Joins two roots, adding their statistics.
    fn join(&mut self, a: usize, b: usize) {
        let root = self.sets.union(a, b);
        let other = if root == a { b } else { a };
        let moved = self.stats[other].clone();
        for c in 0..3 {
            self.stats[root].sum[c] += moved.sum[c];
        }
        self.stats[root].count += moved.count;
    }
}

/// Whether two groups' mean colours may be one surface in light and shadow: luminances within
/// [`MAX_SHADING_RATIO`], and chromaticities within [`CHROMA_TOLERANCE`] plus `widening`, or
/// within [`CHROMA_TOLERANCE`] once the darker is relit by the shadow shift.
fn one_surface(a: [f32; 3], b: [f32; 3], shift: Option<Shadow>, widening: f32) -> bool {
    let (la, lb) = (intensity(a).max(0.02), intensity(b).max(0.02));
    la.max(lb) / la.min(lb) <= MAX_SHADING_RATIO
        && (angle(a, b) <= CHROMA_TOLERANCE + widening
            || relit_angle(a, b, shift) <= CHROMA_TOLERANCE)
}

/// A group holding at least this share of a middle group's boundary is one of its sides.
const INTERRUPTION_SIDE: u32 = 10;

/// Joins groups of one surface that a third group interrupts (a ball's stripes, a wall behind
/// a post): two groups that each hold at least 1/[`INTERRUPTION_SIDE`] of a middle group's
/// boundary and pass [`one_surface`] at the strict tolerance.
fn join_interrupted(
    groups: &mut Grouping,
    boundaries: &std::collections::BTreeMap<(usize, usize), Boundary>,
    shift: Option<Shadow>,
) {
    let mut sides: std::collections::BTreeMap<usize, std::collections::BTreeMap<usize, u32>> =
        Default::default();
    for (&(a, b), boundary) in boundaries {
        let (ra, rb) = (groups.sets.find(a), groups.sets.find(b));
        if ra != rb {
            *sides.entry(ra).or_default().entry(rb).or_default() += boundary.length;
            *sides.entry(rb).or_default().entry(ra).or_default() += boundary.length;
        }
    }
    for around in sides.values() {
        let total: u32 = around.values().sum();
        let major: Vec<usize> = around
            .iter()
            .filter(|&(_, &length)| length * INTERRUPTION_SIDE >= total)
            .map(|(&g, _)| g)
            .collect();
        for (k, &a) in major.iter().enumerate() {
            for &c in &major[k + 1..] {
                let (ra, rc) = (groups.sets.find(a), groups.sets.find(c));
                if ra != rc
                    && one_surface(groups.stats[ra].mean(), groups.stats[rc].mean(), shift, 0.0)
                {
                    groups.join(ra, rc);
                }
            }
        }
    }
}

/// The shared boundary of two adjacent superpixels.
#[derive(Default)]
struct Boundary {
    /// Pixel pairs across it.
    length: u32,
    /// Summed corrected colour, [`SOFT_REACH`] pixels out from the boundary, on the
    /// lower-numbered superpixel's side, then on the other's.
    sides: [[f64; 3]; 2],
}

/// Whether superpixels `a` and `b` meet in a gradient, not an edge (Land's Retinex and
/// Color Retinex, Funt et al. 1992: illumination changes smoothly, albedo steps): the colour
/// hardly steps across their boundary, in chromaticity ([`SOFT_SHARE`] of the difference of
/// their means) and in luminance ([`SOFT_LUMINANCE_STEP`]), though the superpixels differ.
/// Light whose colour changes across a surface (a lamp's warm light giving way to a blue sky's
/// over a floor) shifts its chromaticity more than any tolerance, but gradually.
fn soft(pieces: &[Piece], (a, b): (usize, usize), boundary: &Boundary) -> bool {
    if boundary.length < MIN_SOFT_BOUNDARY {
        return false;
    }
    let [side_a, side_b] = boundary.sides.map(|side| side.map(|v| v as f32));
    let (ma, mb) = (pieces[a].mean(), pieces[b].mean());
    let (la, lb) = (intensity(ma).max(0.02), intensity(mb).max(0.02));
    let luminance_step = (intensity(side_a).max(1e-3) / intensity(side_b).max(1e-3))
        .ln()
        .abs();
    la.max(lb) / la.min(lb) <= MAX_SHADING_RATIO
        && luminance_step <= SOFT_LUMINANCE_STEP
        && angle(side_a, side_b) <= SOFT_SHARE * angle(ma, mb)
}

/// Surface groups: a root per pixel.
struct Groups {
    root: Vec<usize>,
}

/// Joins superpixels into surfaces (steps 3 and 4).
fn group_surfaces(corrected: &Image, labels: &[u32], illuminant: [f32; 3]) -> Groups {
    let (w, h) = (corrected.width, corrected.height);
    let n = labels.iter().max().map_or(0, |&m| m as usize + 1);
    let mut pieces = vec![Piece::default(); n];
    let mut boundaries: std::collections::BTreeMap<(usize, usize), Boundary> = Default::default();
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let p = &mut pieces[labels[i] as usize];
            p.count += 1.0;
            for c in 0..3 {
                p.sum[c] += f64::from(corrected.data[3 * i + c]);
            }
            // Each neighbour, with the pixels SOFT_REACH further out on either side.
            let right = (x + 1 < w).then(|| {
                let out = y * w + x.saturating_sub(SOFT_REACH);
                (i + 1, out, y * w + (x + 1 + SOFT_REACH).min(w - 1))
            });
            let down = (y + 1 < h).then(|| {
                let out = y.saturating_sub(SOFT_REACH) * w + x;
                (i + w, out, (y + 1 + SOFT_REACH).min(h - 1) * w + x)
            });
            for (j, outer_i, outer_j) in [right, down].into_iter().flatten() {
                let (a, b) = (labels[i], labels[j]);
                if a != b {
                    let (lo, hi) = if a < b {
                        (outer_i, outer_j)
                    } else {
                        (outer_j, outer_i)
                    };
                    let boundary = boundaries
                        .entry((a.min(b) as usize, a.max(b) as usize))
                        .or_default();
                    boundary.length += 1;
                    for c in 0..3 {
                        boundary.sides[0][c] += f64::from(corrected.data[3 * lo + c]);
                        boundary.sides[1][c] += f64::from(corrected.data[3 * hi + c]);
                    }
                }
            }
        }
    }
    let mut groups = Grouping {
        sets: DisjointSets::new(n),
        stats: pieces.clone(),
    };
    // Step 3, closest chromaticities first; statistics follow the growing groups.
    let shift = shadow_shift(&pieces, &boundaries);
    let mut edges: Vec<(f32, usize, usize)> = boundaries
        .keys()
        .map(|&(a, b)| {
            let (ma, mb) = (pieces[a].mean(), pieces[b].mean());
            (angle(ma, mb).min(relit_angle(ma, mb, shift)), a, b)
        })
        .collect();
    edges.sort_by(|x, y| x.0.total_cmp(&y.0));
    for &(_, a, b) in &edges {
        let (ra, rb) = (groups.sets.find(a), groups.sets.find(b));
        if ra == rb {
            continue;
        }
        let (ma, mb) = (groups.stats[ra].mean(), groups.stats[rb].mean());
        let darker = intensity(ma).min(intensity(mb)).max(0.02);
        let lighter = intensity(ma).max(intensity(mb)).max(0.02);
        let (tolerance, most) = if lighter / darker >= MIN_SHADOW_CONTRAST {
            (SHADOW_DARK_TOLERANCE, SHADOW_MAX_DARK_EXTRA)
        } else {
            (DARK_TOLERANCE, MAX_DARK_EXTRA)
        };
        let widening = (tolerance / darker).min(most);
        if one_surface(ma, mb, shift, widening)
            || (angle(ma, mb) <= SOFT_GROUP_ANGLE && soft(&pieces, (a, b), &boundaries[&(a, b)]))
        {
            groups.join(ra, rb);
        }
    }
    join_interrupted(&mut groups, &boundaries, shift);
    // Step 4, from the outside in: a highlight's rim joins its body first, then its core,
    // which only then touches the body.
    let canvas = (w * h) as f64;
    for _ in 0..HIGHLIGHT_PASSES {
        let mut neighbours: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
        for &(a, b) in boundaries.keys() {
            let (ra, rb) = (groups.sets.find(a), groups.sets.find(b));
            if ra != rb {
                neighbours.entry(ra).or_default().push(rb);
                neighbours.entry(rb).or_default().push(ra);
            }
        }
        let mut joins = Vec::new();
        for (&group, around) in &neighbours {
            let count = groups.stats[group].count;
            if count > f64::from(MAX_HIGHLIGHT_SHARE) * canvas {
                continue;
            }
            let colour = groups.stats[group].mean();
            let best = around
                .iter()
                .filter(|&&n| groups.stats[n].count > count)
                .filter_map(|&n| {
                    let body = groups.stats[n].mean();
                    // The estimated illuminant's colour, or the image's white should the
                    // estimate be off: a clipped highlight is white whatever the light.
                    [[1.0; 3], illuminant.map(|e| 1.0 / e)]
                        .into_iter()
                        .filter_map(|white| specular_excess(colour, body, white))
                        .min_by(f32::total_cmp)
                        .map(|f| (f, n))
                })
                .min_by(|a, b| a.0.total_cmp(&b.0));
            if let Some((_, body)) = best {
                joins.push((group, body));
            }
        }
        if joins.is_empty() {
            break;
        }
        for (group, body) in joins {
            let (rg, rb) = (groups.sets.find(group), groups.sets.find(body));
            if rg != rb {
                groups.join(rg, rb);
            }
        }
    }
    Groups {
        root: labels
            .iter()
            .map(|&l| groups.sets.find(l as usize))
            .collect(),
    }
}

/// If `colour` = a·`body` + s·`white` with s ≥ [`MIN_SPECULAR`], a > 0 (or `colour` clipped),
/// and it is brighter than the body, the relative residual of that fit; else `None`.
fn specular_excess(colour: [f32; 3], body: [f32; 3], white: [f32; 3]) -> Option<f32> {
    if intensity(colour) <= intensity(body) {
        return None;
    }
    // Least squares for [body, white] · (a, s) = colour.
    let dot = |u: [f32; 3], v: [f32; 3]| u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
    let (bb, bw, ww) = (dot(body, body), dot(body, white), dot(white, white));
    let (bc, wc) = (dot(body, colour), dot(white, colour));
    let det = bb * ww - bw * bw;
    if det.abs() < 1e-8 {
        return None; // a grey body: a highlight is just brighter grey, not told from albedo
    }
    let a = (bc * ww - wc * bw) / det;
    let s = (bb * wc - bw * bc) / det;
    // A clipped highlight's core is white (a ≈ 0): accepted only when nearly saturated, so a
    // small white object on a coloured surface keeps its own albedo.
    let clipped = colour.iter().fold(0.0f32, |m, &v| m.max(v)) >= CLIPPED;
    if (a <= 0.0 && !clipped) || s < MIN_SPECULAR {
        return None;
    }
    let a = a.max(0.0);
    let fit = [0, 1, 2].map(|c| a * body[c] + s * white[c] - colour[c]);
    let residual = dot(fit, fit).sqrt() / dot(colour, colour).sqrt().max(1e-6);
    (residual <= DICHROMATIC_RESIDUAL).then_some(residual)
}

/// The pixel indices of each surface, surfaces in the order of their first pixel. Roots are
/// superpixel ids, so a table indexed by root finds a surface's slot, with no hashing per
/// pixel.
fn surfaces(groups: &Groups) -> Vec<Vec<usize>> {
    let roots = groups.root.iter().max().map_or(0, |&r| r + 1);
    let mut slot = vec![usize::MAX; roots];
    let mut out: Vec<Vec<usize>> = Vec::new();
    for (i, &root) in groups.root.iter().enumerate() {
        if slot[root] == usize::MAX {
            slot[root] = out.len();
            out.push(Vec::new());
        }
        out[slot[root]].push(i);
    }
    out
}

/// Mean colour of the pixels of `members` between the [`LIT_PERCENTILES`] of luminance, in
/// order of luminance, then pixel index (`members` ascends). Only the pixels between the
/// percentiles are sorted: two selections find them, in a fifth of a full sort's time.
fn lit_colour(image: &Image, members: &[usize]) -> [f32; 3] {
    let pixel = |i: usize| [0, 1, 2].map(|c| image.data[3 * i + c]);
    let mut by_luminance: Vec<(f32, usize)> =
        members.iter().map(|&i| (intensity(pixel(i)), i)).collect();
    let order = |a: &(f32, usize), b: &(f32, usize)| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1));
    let n = by_luminance.len();
    let lo = ((n as f32 * LIT_PERCENTILES.0) as usize).min(n - 1);
    let hi = ((n as f32 * LIT_PERCENTILES.1) as usize).clamp(lo + 1, n);
    by_luminance.select_nth_unstable_by(lo, order);
    if hi < n {
        by_luminance[lo..].select_nth_unstable_by(hi - lo, order);
    }
    let lit = &mut by_luminance[lo..hi];
    lit.sort_unstable_by(order);
    let mut sum = [0f64; 3];
    for &(_, i) in lit.iter() {
        for (s, v) in sum.iter_mut().zip(pixel(i)) {
            *s += f64::from(v);
        }
    }
    sum.map(|s| (s / (hi - lo) as f64) as f32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::scale_invariant_mse;
    use crate::synth::scenes::{scene, scene_names};

    #[test]
    fn the_lit_colour_is_that_of_a_full_stable_sort() {
        // Few grey levels, so many pixels tie in luminance across the percentile bounds.
        let mut state = 7u64;
        let data: Vec<f32> = (0..3 * 997)
            .map(|_| {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (state >> 61) as f32 / 8.0
            })
            .collect();
        let image = Image {
            width: 997,
            height: 1,
            data,
        };
        let pixel = |i: usize| [0, 1, 2].map(|c| image.data[3 * i + c]);
        for members in [
            (0..997).collect::<Vec<_>>(),
            (0..997).step_by(3).collect(),
            vec![5],
        ] {
            let mut sorted: Vec<(f32, usize)> =
                members.iter().map(|&i| (intensity(pixel(i)), i)).collect();
            sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
            let n = sorted.len();
            let lo = ((n as f32 * LIT_PERCENTILES.0) as usize).min(n - 1);
            let hi = ((n as f32 * LIT_PERCENTILES.1) as usize).clamp(lo + 1, n);
            let mut sum = [0f64; 3];
            for &(_, i) in &sorted[lo..hi] {
                for (s, v) in sum.iter_mut().zip(pixel(i)) {
                    *s += f64::from(v);
                }
            }
            let expected = sum.map(|s| (s / (hi - lo) as f64) as f32);
            assert_eq!(lit_colour(&image, &members), expected);
        }
    }

    #[test]
    fn a_warm_light_is_estimated_warm() {
        let s = scene(4, 64);
        let e = grey_edge_illuminant(&s.image);
        assert!(e[0] > e[2], "{e:?}");
    }

    #[test]
    fn the_map_is_closer_to_the_true_albedo_than_the_image_on_the_generated_scenes() {
        let mut ratios = Vec::new();
        for index in 0..scene_names().len() {
            let s = scene(index, 96);
            let map = albedo_map(&s.image);
            ratios.push(
                scale_invariant_mse(&map, &s.albedo) / scale_invariant_mse(&s.image, &s.albedo),
            );
        }
        let mean = ratios.iter().sum::<f32>() / ratios.len() as f32;
        assert!(mean < 0.6, "{ratios:?}");
    }

    #[test]
    fn a_shadow_under_a_blue_sky_joins_its_surface() {
        // Warm sun, blue sky; the floor is lit in the bottom-left corner. At the bench's size:
        // smaller, the penumbrae are too few pixels to show the shift.
        let size = 256;
        let s = scene(4, size);
        let map = albedo_map(&s.image);
        let floor = map.pixel(2, size - 3);
        let shadow: Vec<usize> = (0..s.cast_shadow.len())
            .filter(|&i| s.cast_shadow[i])
            .collect();
        let joined = shadow
            .iter()
            .filter(|&&i| map.pixel(i % size, i / size) == floor)
            .count();
        assert!(
            joined * 10 >= shadow.len() * 9,
            "{joined} of {}",
            shadow.len()
        );
    }

    #[test]
    fn a_highlight_on_a_coloured_surface_joins_the_surface() {
        // A red square with a white-ish highlight blob: body · 1 + 0.4 · white.
        let (w, h) = (48, 48);
        let body = [0.7f32, 0.2, 0.15];
        let mut image = Image::filled(w, h, [0.5, 0.5, 0.5]);
        for y in 8..40 {
            for x in 8..40 {
                let d2 = (x as f32 - 20.0).powi(2) + (y as f32 - 20.0).powi(2);
                let s = if d2 < 16.0 { 0.3 } else { 0.0 };
                let px = body.map(|b| (b + s).min(1.0));
                image.data[3 * (y * w + x)..3 * (y * w + x) + 3].copy_from_slice(&px);
            }
        }
        let map = albedo_map(&image);
        let at = map.pixel(20, 20);
        let body_px = map.pixel(34, 34);
        assert_eq!(at, body_px, "highlight {at:?} vs body {body_px:?}");
    }

    #[test]
    fn a_boundary_is_soft_only_where_the_colour_hardly_steps() {
        // Two superpixels of a floor whose light turns from warm to blue: their means differ
        // by more than the tolerance, their boundary by little; an edge steps by the full
        // difference; a shading edge steps in luminance.
        let piece = |c: [f32; 3]| Piece {
            sum: c.map(|v| f64::from(v) * 100.0),
            count: 100.0,
        };
        let (warm, blue) = ([0.60, 0.42, 0.38], [0.35, 0.33, 0.41]);
        let pieces = [piece(warm), piece(blue)];
        assert!(angle(warm, blue) > 2.0 * CHROMA_TOLERANCE);
        let boundary = |a: [f32; 3], b: [f32; 3]| Boundary {
            length: 20,
            sides: [a, b].map(|c| c.map(|v| f64::from(v) * 20.0)),
        };
        let mid = [0.47, 0.375, 0.395];
        let near = [0.465, 0.373, 0.397];
        assert!(soft(&pieces, (0, 1), &boundary(mid, near)));
        assert!(!soft(&pieces, (0, 1), &boundary(warm, blue)));
        assert!(!soft(
            &pieces,
            (0, 1),
            &boundary(mid, near.map(|v| 0.8 * v))
        ));
        let short = Boundary {
            length: MIN_SOFT_BOUNDARY - 1,
            ..boundary(mid, near)
        };
        assert!(!soft(&pieces, (0, 1), &short));
    }

    #[test]
    fn a_cast_shadow_joins_its_surface_and_a_new_colour_does_not() {
        // A green floor, a band of it in shadow (same colour × 0.35), and a blue square.
        let (w, h) = (48, 48);
        let floor = [0.3f32, 0.6, 0.25];
        let mut image = Image::filled(w, h, floor);
        for y in 0..h {
            for x in 0..w {
                let px = if (30..40).contains(&x) && (4..44).contains(&y) {
                    [0.2, 0.3, 0.8]
                } else if (12..24).contains(&x) {
                    floor.map(|v| 0.35 * v)
                } else {
                    continue;
                };
                image.data[3 * (y * w + x)..3 * (y * w + x) + 3].copy_from_slice(&px);
            }
        }
        let map = albedo_map(&image);
        let (lit, shadow, square) = (map.pixel(4, 20), map.pixel(18, 20), map.pixel(35, 20));
        assert_eq!(shadow, lit, "shadow {shadow:?} vs lit {lit:?}");
        assert!((0..3).all(|c| (lit[c] - floor[c]).abs() < 0.02), "{lit:?}");
        assert!(angle(square, lit) > 0.3, "{square:?} joined {lit:?}");
    }
}
