//! The backward pass: dLoss/dPixel → dLoss/d(control points, colour, opacity).
//!
//! Work is split into bands of [`STRIP_ROWS`] rows, one rayon task each, and every band writes
//! its own partial gradients; [`add_bands_into`] adds them in band order, so the result does not
//! depend on the thread count. Inside a band, passes of `rows_per_pass` rows:
//! 1. the signed areas of every path meeting the pass, kept for whole [`GROUP`]s of pixels: the
//!    forward's (when it kept them) or scan-converted again;
//! 2. per row, per group of [`GROUP`] pixels, the paths covering the group in paint order, with
//!    the group's colour, transmittance and dL/dPixel in registers:
//!    - forwards: `u_k = g · (c_k − C_{k−1})`, with `g` the final dL/dPixel and `C_{k−1}` the
//!      colour below path `k` (composited, never reconstructed by division, which breaks down
//!      at alpha 1), kept on a small stack;
//!    - backwards: with `T_k = Π_{j>k} (1 − α_j)` the transmittance above path `k`, dL/dPixel
//!      at path `k` is `T_k · g`, so dL/dα_k = `T_k · u_k`, dL/dcolour += `α_k · T_k · g`, and
//!      dL/d(signed area) is written next to the signed area. A group whose `g` is zero costs
//!      no compositing; once `T` is below [`TRANSMITTANCE_FLOOR`] in every lane, nothing
//!      further down the stack can change the pixel and the walk stops;
//! 3. push dL/d(signed area) through each path's edges in the pass (see `raster`).
//!
//! With a second dL/dPixel for the colours (`Band::d_colour`), step 2 sums `α_k · T_k · g'`
//! with that `g'` into dL/dcolour; everything else takes `g`.
//!
//! Memory per pass grows with the paths' overlap, so deep scenes that are scan-converted again
//! use fewer rows per pass ([`rows_per_pass`]) to keep the working set in cache.

use super::flatten::FlatScene;
use super::raster::{self, GROUP, RowSpan};
use super::{
    Backdrop, Image, PathGrad, STRIP_ROWS, StripAreas, StripCoverage, meets_strip, strip_rows,
};
use crate::scene::Path;
use crate::simd::widest;

/// Target size of one pass's signed-area buffer: about a core's L2 cache. Each pass scan-converts
/// and walks the edges of every path meeting it, so thinner passes repeat that work; on the
/// worst case, 2 MiB beat both 1 MiB and 4 MiB (docs/benchmarks.md, "The renderer").
const PASS_AREA_BYTES: f64 = 2.0 * 1024.0 * 1024.0;

/// `|acc|` up to which coverage counts as unsaturated in the backward. Above 1 the forward's
/// `min(1, |acc|)` is flat; at exactly 1 (a pixel just fully covered, common with pixel-aligned
/// shapes) the backward takes the one-sided derivative towards less coverage, and the small
/// slack keeps prefix-sum rounding (`|acc| = 1 + ulp`) from zeroing it.
const SATURATION: f32 = 1.0 + 1e-5;

/// Transmittance below which a pixel's paths further down the stack get no gradient there
/// (2⁻⁶⁴): what they could change is below f32's resolution of the pixel, and their tiny
/// products would be subnormal numbers, which cost a hundred times a normal one.
const TRANSMITTANCE_FLOOR: f32 = 1.0 / 18_446_744_073_709_551_616.0;

/// Rows per pass: the largest power of two ≤ `STRIP_ROWS` whose signed-area buffer fits
/// [`PASS_AREA_BYTES`] at the scene's mean overlap depth (sum of clipped bounding-box areas
/// over the canvas area). A function of the scene only, so results stay thread-count free.
pub(super) fn rows_per_pass(flat: &FlatScene<f32>, width: usize, height: usize) -> usize {
    let covered = covered_area(flat, width, height);
    let depth = (covered / (width * height) as f64).max(1.0);
    let fit = PASS_AREA_BYTES / (4.0 * depth * width as f64);
    let mut rows = STRIP_ROWS;
    while rows > 1 && rows as f64 > fit {
        rows /= 2;
    }
    rows
}

/// Sum of the drawable paths' bounding-box areas clipped to the canvas: a bound on the number of
/// signed-area values a render computes.
pub(super) fn covered_area(flat: &FlatScene<f32>, width: usize, height: usize) -> f64 {
    let (w, h) = (width as f32, height as f32);
    flat.paths
        .iter()
        .filter(|p| !p.verts.is_empty())
        .map(|p| {
            let dx = (p.bbox[2].min(w) - p.bbox[0].max(0.0)).max(0.0);
            let dy = (p.bbox[3].min(h) - p.bbox[1].max(0.0)).max(0.0);
            dx as f64 * dy as f64
        })
        .sum()
}

/// Partial gradients of one band: one entry per path meeting it, in paint order.
#[derive(Default)]
pub(super) struct BandGrads {
    paths: Vec<PathPartial>,
    /// dL/d flattened vertex of those paths' vertices, concatenated.
    verts: Vec<[f32; 2]>,
}

struct PathPartial {
    path: u32,
    /// Start of the path's vertices in [`BandGrads::verts`].
    verts: u32,
    color: [f64; 3],
    opacity: f64,
}

/// Per-thread buffers of the backward.
#[derive(Default)]
pub(super) struct Workspace {
    /// Band slot of each path (`u32::MAX`: not in the band).
    slot: Vec<u32>,
    /// The pass's active paths (band slots), in paint order, and per active path and row of
    /// the pass its span and the offset of its values in `area`.
    active: Vec<u32>,
    spans: Vec<RowSpan>,
    offsets: Vec<u32>,
    /// Signed areas of the pass, for whole groups ([`RowSpan::groups`]); overwritten by
    /// dL/d(signed area).
    area: Vec<f32>,
    rows: RowWork,
    /// One path's dL/d flattened vertex, summed over the bands.
    vert_sums: Vec<[f64; 2]>,
}

/// A group's worth of one value per pixel.
type Lanes = [f32; GROUP];

/// Buffers of the per-row work.
#[derive(Default)]
struct RowWork {
    /// The row's paths with a non-empty span, in paint order.
    paths: Vec<RowPath>,
    /// Per group (and one past the last): whether a path of the row starts or ends there.
    breaks: Vec<bool>,
    /// The row's paths (indices into `paths`) by first group, in paint order within a group.
    starts: Vec<u32>,
    /// Where each group's entries in `starts` begin (one more entry than groups).
    start_at: Vec<u32>,
    /// Indices into `paths` of the paths covering the current group, in paint order, and the
    /// buffer the next group's list is merged into.
    cover: Vec<u32>,
    next: Vec<u32>,
    /// `u_k` of each covering path of the current group.
    stack: Vec<Lanes>,
    /// Per band slot: lane sums of dL/dcolour and dL/dopacity over the current row.
    sums: Vec<PaintSums>,
    /// The row's backdrop and dL/dPixel as channel planes (R…, G…, B…), whole groups wide.
    color: Vec<f32>,
    grad: Vec<f32>,
    /// The row's dL/dPixel for the colours, as `grad`, when it is apart (else empty).
    grad_colour: Vec<f32>,
}

/// One path of a row.
#[derive(Clone, Copy)]
struct RowPath {
    slot: u32,
    /// Its groups `g_lo..g_hi` ([`RowSpan::groups`]).
    g_lo: u32,
    g_hi: u32,
    /// Where its signed areas start (at group `g_lo`).
    offset: u32,
    color: [f32; 3],
    opacity: f32,
}

/// Per-lane running sums of one path's paint gradients.
#[derive(Clone, Copy, Default)]
struct PaintSums {
    color: [Lanes; 3],
    opacity: Lanes,
}

/// Paths per rayon task of [`add_bands_into`]: one path's sums and chain are little work, so
/// tasks of one path each would cost more to hand out than they spread.
pub(super) const PATHS_PER_TASK: usize = 4;

/// Adds the bands' partial gradients of paths `first..first + grads.len()` into `grads` and
/// chains them to the control points. Each path's sums run over the bands in band order, as
/// they would on one thread, so the result does not depend on how paths are shared out.
pub(super) fn add_bands_into(
    flat: &FlatScene<f32>,
    bands: &[BandGrads],
    first: usize,
    grads: &mut [PathGrad],
    ws: &mut Workspace,
) {
    for (i, grad) in (first..).zip(grads) {
        let vert_count = flat.paths[i].verts.len();
        let sums = &mut ws.vert_sums;
        sums.clear();
        sums.resize(vert_count, [0.0; 2]);
        let (mut color, mut opacity) = ([0.0f64; 3], 0.0f64);
        for band in bands {
            // A band lists its paths in paint order.
            let Ok(k) = band.paths.binary_search_by_key(&(i as u32), |p| p.path) else {
                continue;
            };
            let partial = &band.paths[k];
            for c in 0..3 {
                color[c] += partial.color[c];
            }
            opacity += partial.opacity;
            let start = partial.verts as usize;
            for (acc, g) in sums.iter_mut().zip(&band.verts[start..start + vert_count]) {
                acc[0] += g[0] as f64;
                acc[1] += g[1] as f64;
            }
        }
        for c in 0..3 {
            grad.color[c] += color[c] as f32;
        }
        grad.opacity += opacity as f32;
        if vert_count > 0 {
            flat.chain_to_control_points(i, sums, &mut grad.points);
        }
    }
}

/// One band's backward job.
pub(super) struct Band<'a> {
    pub flat: &'a FlatScene<f32>,
    pub paths: &'a [Path],
    pub backdrop: Backdrop<'a>,
    pub d_out: &'a Image,
    /// dL/dPixel for the fill colours, when it is not `d_out`.
    pub d_colour: Option<&'a Image>,
    /// A factor both are multiplied by, value by value, when given.
    pub factor: Option<&'a Image>,
    pub band: usize,
    pub rows_per_pass: usize,
    /// The signed areas the forward kept for this band's strip, if it kept them.
    pub stored: Option<&'a StripAreas<f32>>,
}

impl Band<'_> {
    /// Adds the band's partial gradients into `out`. Compiled for the widest vector unit the
    /// processor has ([`widest!`]).
    pub fn run(&self, out: &mut BandGrads, ws: &mut Workspace, coverage: &mut StripCoverage<f32>) {
        widest!(self.run_in(out, ws, coverage))
    }

    #[inline(always)]
    fn run_in(&self, out: &mut BandGrads, ws: &mut Workspace, coverage: &mut StripCoverage<f32>) {
        let (width, height) = (self.d_out.width, self.d_out.height);
        let (band0, band_rows) = strip_rows(self.band, height);
        out.paths.clear();
        out.verts.clear();
        if self.rows_without_gradient(band0, band_rows) {
            return;
        }
        ws.slot.clear();
        ws.slot.resize(self.paths.len(), u32::MAX);
        for (i, fp) in self.flat.paths.iter().enumerate() {
            if !fp.verts.is_empty() && meets_strip(fp.bbox, band0, band_rows, width) {
                ws.slot[i] = out.paths.len() as u32;
                out.paths.push(PathPartial {
                    path: i as u32,
                    verts: out.verts.len() as u32,
                    color: [0.0; 3],
                    opacity: 0.0,
                });
                out.verts.resize(out.verts.len() + fp.verts.len(), [0.0; 2]);
            }
        }
        ws.rows.sums.clear();
        ws.rows.sums.resize(out.paths.len(), PaintSums::default());
        coverage.prepare(width);
        let mut row0 = band0;
        while row0 < band0 + band_rows {
            let rows = self.rows_per_pass.min(band0 + band_rows - row0);
            if !self.rows_without_gradient(row0, rows) {
                self.pass(row0, rows, out, ws, coverage);
            }
            row0 += rows;
        }
    }

    #[inline(always)]
    fn pass(
        &self,
        row0: usize,
        rows: usize,
        out: &mut BandGrads,
        ws: &mut Workspace,
        cov: &mut StripCoverage<f32>,
    ) {
        // 1. Signed areas of every path meeting the pass.
        ws.active.clear();
        ws.spans.clear();
        ws.offsets.clear();
        ws.area.clear();
        match self.stored {
            Some(stored) => self.stored_areas(stored, row0, rows, ws),
            None => self.scan_areas(row0, rows, ws, cov),
        }

        // 2. Per row, per group: paint gradients and dL/d(signed area).
        for r in 0..rows {
            self.row(row0 + r, r, rows, ws, out);
        }

        // 3. dL/d(signed area) through the edges to the flattened vertices.
        let BandGrads { paths, verts } = out;
        for (k, &slot) in ws.active.iter().enumerate() {
            let partial = &paths[slot as usize];
            let fp = &self.flat.paths[partial.path as usize];
            let start = partial.verts as usize;
            let spans = &ws.spans[k * rows..(k + 1) * rows];
            let offsets = &ws.offsets[k * rows..(k + 1) * rows];
            let area = &ws.area;
            let lookup = |cx: i32, cy: i32| -> f32 {
                let r = (cy - row0 as i32) as usize;
                let span = spans[r];
                let x = cx as u32;
                if cx >= 0 && x >= span.lo && x < span.end {
                    let lead = span.groups().0 * GROUP;
                    area[offsets[r] as usize + x as usize - lead]
                } else {
                    0.0
                }
            };
            raster::backward_lines(
                self.flat.outline(partial.path as usize),
                row0 as i32,
                rows,
                self.d_out.width,
                &mut verts[start..start + fp.verts.len()],
                lookup,
            );
        }
    }

    /// Step 2 for row `y`, row `r` of a pass of `rows`.
    #[inline(always)]
    fn row(&self, y: usize, r: usize, rows: usize, ws: &mut Workspace, out: &mut BandGrads) {
        let work = &mut ws.rows;
        work.paths.clear();
        for (k, &slot) in ws.active.iter().enumerate() {
            let span = ws.spans[k * rows + r];
            if span.len() == 0 {
                continue;
            }
            let (g_lo, g_hi) = span.groups();
            let path = &self.paths[out.paths[slot as usize].path as usize];
            work.paths.push(RowPath {
                slot,
                g_lo: g_lo as u32,
                g_hi: g_hi as u32,
                offset: ws.offsets[k * rows + r],
                color: path.color,
                opacity: path.opacity,
            });
        }
        if work.paths.is_empty() {
            return;
        }
        let width = self.d_out.width;
        let groups = width.div_ceil(GROUP);
        let planes = groups * GROUP;
        work.color.resize(3 * planes, 0.0);
        work.grad.resize(3 * planes, 0.0);
        self.fill_backdrop(y, planes, &mut work.color);
        let row = 3 * y * width..3 * (y + 1) * width;
        let (d_row, factor) = (
            &self.d_out.data[row.clone()],
            self.factor.map(|f| &f.data[row.clone()]),
        );
        to_planes(d_row, factor, planes, &mut work.grad);
        match self.d_colour {
            Some(d_colour) => {
                work.grad_colour.resize(3 * planes, 0.0);
                to_planes(&d_colour.data[row], factor, planes, &mut work.grad_colour);
            }
            None => work.grad_colour.clear(),
        }
        work.index_starts(groups);
        if work.stack.len() < work.paths.len() {
            work.stack.resize(work.paths.len(), [0.0; GROUP]);
        }
        if self.d_colour.is_some() {
            walk_groups::<true>(work, &mut ws.area, groups);
        } else {
            walk_groups::<false>(work, &mut ws.area, groups);
        }
        // The row's lane sums into the band's partials.
        for p in &work.paths {
            let sums = &mut work.sums[p.slot as usize];
            let partial = &mut out.paths[p.slot as usize];
            for c in 0..3 {
                partial.color[c] += sums.color[c].iter().sum::<f32>() as f64;
            }
            partial.opacity += sums.opacity.iter().sum::<f32>() as f64;
            *sums = PaintSums::default();
        }
    }
}

/// An interleaved RGB row as three channel planes of `planes` values each (zero past the row)
/// in `out`, times `factor` (a row like it) value by value when given.
#[inline(always)]
fn to_planes(row: &[f32], factor: Option<&[f32]>, planes: usize, out: &mut [f32]) {
    let width = row.len() / 3;
    let (r, rest) = out.split_at_mut(planes);
    let (g, b) = rest.split_at_mut(planes);
    for (x, px) in row.chunks_exact(3).enumerate() {
        r[x] = px[0];
        g[x] = px[1];
        b[x] = px[2];
    }
    if let Some(factor) = factor {
        for (x, f) in factor.chunks_exact(3).enumerate() {
            r[x] *= f[0];
            g[x] *= f[1];
            b[x] *= f[2];
        }
    }
    for plane in [r, g, b] {
        plane[width..].fill(0.0);
    }
}

/// The groups `0..groups` of one row (step 2's inner loop); `APART`: whether the colours
/// have their own dL/dPixel (`RowWork::grad_colour`), a constant so that the usual walk
/// compiles without it.
#[inline(always)]
fn walk_groups<const APART: bool>(work: &mut RowWork, area: &mut [f32], groups: usize) {
    let planes = groups * GROUP;
    work.cover.clear();
    for g in 0..groups {
        if work.breaks[g] {
            work.advance_cover(g);
        }
        if work.cover.is_empty() {
            continue;
        }
        let lanes = |plane: &[f32], c: usize| -> Lanes {
            let at = c * planes + g * GROUP;
            plane[at..at + GROUP].try_into().expect("a group")
        };
        let grad = [0, 1, 2].map(|c| lanes(&work.grad, c));
        let group = Group {
            index: g,
            grad,
            grad_colour: if APART {
                [0, 1, 2].map(|c| lanes(&work.grad_colour, c))
            } else {
                grad
            },
            color: [0, 1, 2].map(|c| lanes(&work.color, c)),
        };
        group.run::<APART>(
            &work.paths,
            &work.cover,
            area,
            &mut work.stack,
            &mut work.sums,
        );
    }
}

impl RowWork {
    /// Buckets the row's paths by first group (`starts`, `start_at`) and marks in `breaks`
    /// the groups where the covering paths change.
    fn index_starts(&mut self, groups: usize) {
        self.breaks.clear();
        self.breaks.resize(groups + 1, false);
        self.start_at.clear();
        self.start_at.resize(groups + 2, 0);
        for p in &self.paths {
            self.breaks[p.g_lo as usize] = true;
            self.breaks[p.g_hi as usize] = true;
            self.start_at[p.g_lo as usize + 2] += 1;
        }
        for g in 2..self.start_at.len() {
            self.start_at[g] += self.start_at[g - 1];
        }
        // Counting sort, stable: `start_at[g + 1]` is the next free place of group g.
        self.starts.clear();
        self.starts.resize(self.paths.len(), 0);
        for (i, p) in self.paths.iter().enumerate() {
            let at = &mut self.start_at[p.g_lo as usize + 1];
            self.starts[*at as usize] = i as u32;
            *at += 1;
        }
    }

    /// Makes `cover` the paths covering group `g`: those of the last list still covering it,
    /// merged in paint order with those starting at `g`.
    fn advance_cover(&mut self, g: usize) {
        let starting = &self.starts[self.start_at[g] as usize..self.start_at[g + 1] as usize];
        let paths = &self.paths;
        let mut staying = self
            .cover
            .iter()
            .copied()
            .filter(|&i| paths[i as usize].g_hi as usize > g)
            .peekable();
        let mut starting = starting.iter().copied().peekable();
        self.next.clear();
        loop {
            let take_staying = match (staying.peek(), starting.peek()) {
                (Some(&a), Some(&b)) => a < b,
                (Some(_), None) => true,
                (None, Some(_)) => false,
                (None, None) => break,
            };
            let i = if take_staying {
                staying.next()
            } else {
                starting.next()
            };
            self.next.extend(i);
        }
        std::mem::swap(&mut self.cover, &mut self.next);
    }
}

/// One group of a row: its dL/dPixel (for the colours, and for the rest) and backdrop colour,
/// per channel.
struct Group {
    index: usize,
    grad: [Lanes; 3],
    grad_colour: [Lanes; 3],
    color: [Lanes; 3],
}

impl Group {
    /// The forward and backward walks over the paths `cover` (indices into `paths`, in paint
    /// order) covering this group; their signed areas in `area` become dL/d(signed area).
    #[inline(always)]
    fn run<const APART: bool>(
        &self,
        paths: &[RowPath],
        cover: &[u32],
        area: &mut [f32],
        stack: &mut [Lanes],
        sums: &mut [PaintSums],
    ) {
        let at = |p: &RowPath| p.offset as usize + (self.index - p.g_lo as usize) * GROUP;
        let (g, g_colour) = (self.grad, self.grad_colour);
        let idle = |g: &[Lanes; 3]| g.iter().flatten().all(|&v| v == 0.0);
        if idle(&g) && (!APART || idle(&g_colour)) {
            for &i in cover {
                let o = at(&paths[i as usize]);
                area[o..o + GROUP].fill(0.0);
            }
            return;
        }
        let lanes =
            |area: &[f32], o: usize| -> Lanes { area[o..o + GROUP].try_into().expect("a group") };
        let [mut cr, mut cg, mut cb] = self.color;
        for (s, &i) in cover.iter().enumerate() {
            let p = &paths[i as usize];
            let acc = lanes(area, at(p));
            let a: Lanes = std::array::from_fn(|l| coverage(acc[l]) * p.opacity);
            let dr: Lanes = std::array::from_fn(|l| p.color[0] - cr[l]);
            let dg: Lanes = std::array::from_fn(|l| p.color[1] - cg[l]);
            let db: Lanes = std::array::from_fn(|l| p.color[2] - cb[l]);
            stack[s] = std::array::from_fn(|l| g[0][l] * dr[l] + g[1][l] * dg[l] + g[2][l] * db[l]);
            for l in 0..GROUP {
                cr[l] += a[l] * dr[l];
                cg[l] += a[l] * dg[l];
                cb[l] += a[l] * db[l];
            }
        }
        let mut t: Lanes = [1.0; GROUP];
        for (s, &i) in cover.iter().enumerate().rev() {
            let p = &paths[i as usize];
            let o = at(p);
            let acc = lanes(area, o);
            let cov: Lanes = std::array::from_fn(|l| coverage(acc[l]));
            let u = stack[s];
            let v: Lanes = std::array::from_fn(|l| t[l] * u[l]);
            let a_t: Lanes = std::array::from_fn(|l| cov[l] * p.opacity * t[l]);
            let sum = &mut sums[p.slot as usize];
            for c in 0..3 {
                sum.color[c] = std::array::from_fn(|l| sum.color[c][l] + a_t[l] * g_colour[c][l]);
            }
            sum.opacity = std::array::from_fn(|l| sum.opacity[l] + cov[l] * v[l]);
            // dL/d(signed area): dL/dα · opacity · sign(area) where the coverage is not
            // saturated (the sign applied by flipping the sign bit, as × ±1 would).
            let d: Lanes = std::array::from_fn(|l| {
                let signed =
                    f32::from_bits((v[l] * p.opacity).to_bits() ^ (acc[l].to_bits() & SIGN));
                if acc[l].abs() <= SATURATION {
                    signed
                } else {
                    0.0
                }
            });
            area[o..o + GROUP].copy_from_slice(&d);
            let rest: Lanes = std::array::from_fn(|l| t[l] - a_t[l]);
            t = std::array::from_fn(|l| {
                if rest[l] < TRANSMITTANCE_FLOOR {
                    0.0
                } else {
                    rest[l]
                }
            });
            if t.iter().all(|&v| v == 0.0) {
                for &j in &cover[..s] {
                    let o = at(&paths[j as usize]);
                    area[o..o + GROUP].fill(0.0);
                }
                return;
            }
        }
    }
}

/// The sign bit of an f32.
const SIGN: u32 = 0x8000_0000;

/// `min(1, |acc|)`, in the form that vectorises.
#[inline(always)]
fn coverage(acc: f32) -> f32 {
    let v = acc.abs();
    if v < 1.0 { v } else { 1.0 }
}

impl Band<'_> {
    /// Step 1 by scan conversion: the signed areas of every path meeting rows
    /// `row0..row0 + rows` into `ws`.
    #[inline(always)]
    fn scan_areas(
        &self,
        row0: usize,
        rows: usize,
        ws: &mut Workspace,
        cov: &mut StripCoverage<f32>,
    ) {
        let width = self.d_out.width;
        for (i, fp) in self.flat.paths.iter().enumerate() {
            if fp.verts.is_empty() || !meets_strip(fp.bbox, row0, rows, width) {
                continue;
            }
            ws.active.push(ws.slot[i]);
            let spans = &mut cov.spans[..rows];
            raster::accumulate(
                self.flat.outline(i),
                row0 as i32,
                rows,
                width,
                &mut cov.delta,
                spans,
            );
            raster::prefix_rows(&mut cov.delta, spans, width);
            let stride = width + 2;
            for (r, &span) in spans.iter().enumerate() {
                ws.spans.push(span);
                ws.offsets.push(ws.area.len() as u32);
                if span.len() > 0 {
                    let row = &cov.delta[r * stride..r * stride + width];
                    raster::push_groups(row, span, &mut ws.area);
                }
            }
            raster::clear_rows(&mut cov.delta, spans, width);
        }
    }

    /// Step 1 from the areas the forward kept (the same values: a row's signed areas do not
    /// depend on which rows are scan-converted with it).
    fn stored_areas(&self, stored: &StripAreas<f32>, row0: usize, rows: usize, ws: &mut Workspace) {
        let width = self.d_out.width;
        let (band0, band_rows) = strip_rows(self.band, self.d_out.height);
        for (k, &i) in stored.paths.iter().enumerate() {
            let fp = &self.flat.paths[i as usize];
            if !meets_strip(fp.bbox, row0, rows, width) {
                continue;
            }
            ws.active.push(ws.slot[i as usize]);
            let first = k * band_rows + (row0 - band0);
            let (from, start) = (stored.offsets[first] as usize, ws.area.len());
            let mut len = 0;
            for &span in &stored.spans[first..first + rows] {
                ws.spans.push(span);
                ws.offsets.push((start + len) as u32);
                len += span.padded_len();
            }
            // A path's rows are kept one after the other: one copy.
            ws.area.extend_from_slice(&stored.area[from..from + len]);
        }
    }

    /// Whether dL/dPixel is zero on rows `row0..row0 + rows`: they add exactly nothing to any
    /// gradient, so they are skipped (a penalty that acts on few pixels, like the structure
    /// stage's overlap term, then costs only where it acts).
    fn rows_without_gradient(&self, row0: usize, rows: usize) -> bool {
        let width = self.d_out.width;
        let range = 3 * row0 * width..3 * (row0 + rows) * width;
        std::iter::once(self.d_out)
            .chain(self.d_colour)
            .all(|d| d.data[range.clone()].iter().all(|&v| v == 0.0))
    }

    /// Row `y` of the backdrop as channel planes (R…, G…, B…), `planes` values each, in `out`.
    fn fill_backdrop(&self, y: usize, planes: usize, out: &mut [f32]) {
        let width = self.d_out.width;
        match self.backdrop {
            Backdrop::Color(color) => {
                for (plane, &v) in out.chunks_exact_mut(planes).zip(&color) {
                    plane.fill(v);
                }
            }
            Backdrop::Image(image) => {
                let row = &image.data[3 * y * width..3 * (y + 1) * width];
                to_planes(row, None, planes, out);
            }
        }
    }
}
