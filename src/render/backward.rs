//! The backward pass: dLoss/dPixel → dLoss/d(control points, colour, opacity).
//!
//! Work is split into bands of [`STRIP_ROWS`] rows, one rayon task each, and every band writes
//! its own partial gradients; [`Totals::reduce`] adds them in band order, so the result does not
//! depend on the thread count. Inside a band, passes of `rows_per_pass` rows:
//! 1. rasterise every path meeting the pass, keeping its signed area per pixel of its row spans;
//! 2. per row, composite forwards keeping the colour below each path (never reconstructed by
//!    division, which breaks down at alpha 1), then walk the paths backwards: colour and
//!    opacity gradients, and dL/d(signed area) written over the signed area;
//! 3. push dL/d(signed area) through each path's edges in the pass (see `raster`).
//!
//! Memory per pass grows with the paths' overlap, so deep scenes use fewer rows per pass
//! ([`rows_per_pass`]) to keep the working set in cache.

use super::flatten::FlatScene;
use super::raster::{self, RowSpan};
use super::{
    Backdrop, Image, PathGrad, STRIP_ROWS, StripAreas, StripCoverage, meets_strip, strip_rows,
};
use crate::scene::Path;

/// Target size of one pass's signed-area buffer: small enough to stay in a core's L2 cache.
const PASS_AREA_BYTES: f64 = 1024.0 * 1024.0;

/// `|acc|` up to which coverage counts as unsaturated in the backward. Above 1 the forward's
/// `min(1, |acc|)` is flat; at exactly 1 (a pixel just fully covered, common with pixel-aligned
/// shapes) the backward takes the one-sided derivative towards less coverage, and the small
/// slack keeps prefix-sum rounding (`|acc| = 1 + ulp`) from zeroing it.
const SATURATION: f32 = 1.0 + 1e-5;

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
    /// The pass's active paths (band slots), their row spans and signed-area offsets.
    active: Vec<u32>,
    spans: Vec<RowSpan>,
    offsets: Vec<u32>,
    /// Signed area per active path and span pixel; overwritten by dL/d(signed area).
    area: Vec<f32>,
    /// One row: the colour below each active path over its span, stacked in paint order.
    below: Vec<f32>,
    row_color: Vec<f32>,
    row_grad: Vec<f32>,
}

/// Sums of the band partials, kept between calls.
#[derive(Default)]
pub(super) struct Totals {
    verts: Vec<[f64; 2]>,
    paint: Vec<([f64; 3], f64)>,
}

impl Totals {
    pub fn reduce(&mut self, flat: &FlatScene<f32>, bands: &[BandGrads], path_count: usize) {
        self.verts.clear();
        self.verts.resize(flat.verts.len(), [0.0; 2]);
        self.paint.clear();
        self.paint.resize(path_count, ([0.0; 3], 0.0));
        for band in bands {
            for partial in &band.paths {
                let i = partial.path as usize;
                for c in 0..3 {
                    self.paint[i].0[c] += partial.color[c];
                }
                self.paint[i].1 += partial.opacity;
                let range = flat.paths[i].verts.clone();
                let start = partial.verts as usize;
                let src = &band.verts[start..start + range.len()];
                for (acc, g) in self.verts[range].iter_mut().zip(src) {
                    acc[0] += g[0] as f64;
                    acc[1] += g[1] as f64;
                }
            }
        }
    }

    pub fn add_into(&self, flat: &FlatScene<f32>, grads: &mut [PathGrad]) {
        for (i, grad) in grads.iter_mut().enumerate().take(self.paint.len()) {
            for c in 0..3 {
                grad.color[c] += self.paint[i].0[c] as f32;
            }
            grad.opacity += self.paint[i].1 as f32;
            let range = flat.paths[i].verts.clone();
            if !range.is_empty() {
                flat.chain_to_control_points(i, &self.verts[range], &mut grad.points);
            }
        }
    }
}

/// One band's backward job.
pub(super) struct Band<'a> {
    pub flat: &'a FlatScene<f32>,
    pub paths: &'a [Path],
    pub backdrop: Backdrop<'a>,
    pub d_out: &'a Image,
    pub band: usize,
    pub rows_per_pass: usize,
    /// The signed areas the forward kept for this band's strip, if it kept them.
    pub stored: Option<&'a StripAreas<f32>>,
}

impl Band<'_> {
    pub fn run(&self, out: &mut BandGrads, ws: &mut Workspace, coverage: &mut StripCoverage<f32>) {
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

    fn pass(
        &self,
        row0: usize,
        rows: usize,
        out: &mut BandGrads,
        ws: &mut Workspace,
        cov: &mut StripCoverage<f32>,
    ) {
        let width = self.d_out.width;

        // 1. Signed areas of every path meeting the pass.
        ws.active.clear();
        ws.spans.clear();
        ws.offsets.clear();
        match self.stored {
            Some(stored) => self.stored_areas(stored, row0, rows, ws),
            None => self.scan_areas(row0, rows, ws, cov),
        }

        // 2. Per row: composite forwards keeping the colour below each path, then backwards.
        // Row buffers are channel planes (R…, G…, B…) so the span loops vectorise.
        ws.row_color.resize(width * 3, 0.0);
        ws.row_grad.resize(width * 3, 0.0);
        for r in 0..rows {
            self.fill_backdrop(row0 + r, &mut ws.row_color);
            let mut below_len = 0;
            for (k, &slot) in ws.active.iter().enumerate() {
                let span = ws.spans[k * rows + r];
                let n = span.len();
                if n == 0 {
                    continue;
                }
                let path = &self.paths[out.paths[slot as usize].path as usize];
                let off = ws.offsets[k * rows + r] as usize;
                if ws.below.len() < below_len + 3 * n {
                    ws.below.resize(below_len + 3 * n, 0.0);
                }
                let below = &mut ws.below[below_len..below_len + 3 * n];
                below_len += 3 * n;
                let (lo, end) = (span.lo as usize, span.end as usize);
                let (cr, rest) = ws.row_color.split_at_mut(width);
                let (cg, cb) = rest.split_at_mut(width);
                composite_span(
                    &ws.area[off..off + n],
                    path.opacity,
                    path.color,
                    [&mut cr[lo..end], &mut cg[lo..end], &mut cb[lo..end]],
                    below,
                );
            }
            let y = row0 + r;
            let d_row = &self.d_out.data[y * width * 3..(y + 1) * width * 3];
            let (gr, rest) = ws.row_grad.split_at_mut(width);
            let (gg, gb) = rest.split_at_mut(width);
            for (x, px) in d_row.chunks_exact(3).enumerate() {
                gr[x] = px[0];
                gg[x] = px[1];
                gb[x] = px[2];
            }
            for (k, &slot) in ws.active.iter().enumerate().rev() {
                let span = ws.spans[k * rows + r];
                let n = span.len();
                if n == 0 {
                    continue;
                }
                let partial = &mut out.paths[slot as usize];
                let path = &self.paths[partial.path as usize];
                let off = ws.offsets[k * rows + r] as usize;
                below_len -= 3 * n;
                let (lo, end) = (span.lo as usize, span.end as usize);
                let (dc, dop) = backward_span(
                    &mut ws.area[off..off + n],
                    path.opacity,
                    path.color,
                    [&mut gr[lo..end], &mut gg[lo..end], &mut gb[lo..end]],
                    &ws.below[below_len..below_len + 3 * n],
                );
                for (sum, d) in partial.color.iter_mut().zip(dc) {
                    *sum += d as f64;
                }
                partial.opacity += dop as f64;
            }
        }

        // 3. dL/d(signed area) through the edges to the flattened vertices.
        for (k, &slot) in ws.active.iter().enumerate() {
            let partial = &out.paths[slot as usize];
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
                    area[offsets[r] as usize + (x - span.lo) as usize]
                } else {
                    0.0
                }
            };
            raster::backward_lines(
                self.flat.outline(partial.path as usize),
                row0 as i32,
                rows,
                width,
                &mut out.verts[start..start + fp.verts.len()],
                lookup,
            );
        }
    }
}

impl Band<'_> {
    /// Step 1 by scan conversion: the signed areas of every path meeting rows
    /// `row0..row0 + rows` into `ws`.
    fn scan_areas(
        &self,
        row0: usize,
        rows: usize,
        ws: &mut Workspace,
        cov: &mut StripCoverage<f32>,
    ) {
        let width = self.d_out.width;
        let stride = width + 2;
        let mut total = 0usize;
        for (i, fp) in self.flat.paths.iter().enumerate() {
            if fp.verts.is_empty() || !meets_strip(fp.bbox, row0, rows, width) {
                continue;
            }
            ws.active.push(ws.slot[i]);
            raster::accumulate(
                self.flat.outline(i),
                row0 as i32,
                rows,
                width,
                &mut cov.delta,
                &mut cov.spans,
            );
            let first = total;
            for &span in &cov.spans[..rows] {
                ws.spans.push(span);
                ws.offsets.push(total as u32);
                total += span.len();
            }
            if ws.area.len() < total {
                ws.area.resize(total, 0.0);
            }
            let mut off = first;
            for (r, &span) in cov.spans[..rows].iter().enumerate() {
                if span.len() == 0 {
                    continue;
                }
                let dst = &mut ws.area[off..off + span.len()];
                let lo = span.lo as usize;
                raster::prefix_row(
                    &mut cov.delta[r * stride..(r + 1) * stride],
                    span,
                    width,
                    |x, acc| dst[x - lo] = acc,
                );
                off += span.len();
            }
        }
    }

    /// Step 1 from the areas the forward kept (the same values: a row's signed areas do not
    /// depend on which rows are scan-converted with it).
    fn stored_areas(&self, stored: &StripAreas<f32>, row0: usize, rows: usize, ws: &mut Workspace) {
        let width = self.d_out.width;
        let (band0, band_rows) = strip_rows(self.band, self.d_out.height);
        let mut total = 0usize;
        for (k, &i) in stored.paths.iter().enumerate() {
            let fp = &self.flat.paths[i as usize];
            if !meets_strip(fp.bbox, row0, rows, width) {
                continue;
            }
            ws.active.push(ws.slot[i as usize]);
            let first = k * band_rows + (row0 - band0);
            for (&span, &offset) in stored.spans[first..first + rows]
                .iter()
                .zip(&stored.offsets[first..first + rows])
            {
                ws.spans.push(span);
                ws.offsets.push(total as u32);
                let n = span.len();
                if ws.area.len() < total + n {
                    ws.area.resize(total + n, 0.0);
                }
                let offset = offset as usize;
                ws.area[total..total + n].copy_from_slice(&stored.area[offset..offset + n]);
                total += n;
            }
        }
    }

    /// Whether dL/dPixel is zero on rows `row0..row0 + rows`: they add exactly nothing to any
    /// gradient, so they are skipped (a penalty that acts on few pixels, like the structure
    /// stage's overlap term, then costs only where it acts).
    fn rows_without_gradient(&self, row0: usize, rows: usize) -> bool {
        let width = self.d_out.width;
        self.d_out.data[3 * row0 * width..3 * (row0 + rows) * width]
            .iter()
            .all(|&v| v == 0.0)
    }

    /// Row `y` of the backdrop as channel planes (R…, G…, B…) in `planes`.
    fn fill_backdrop(&self, y: usize, planes: &mut [f32]) {
        let width = self.d_out.width;
        match self.backdrop {
            Backdrop::Color(color) => {
                for (plane, &v) in planes.chunks_exact_mut(width).zip(&color) {
                    plane.fill(v);
                }
            }
            Backdrop::Image(image) => {
                let row = &image.data[3 * y * width..3 * (y + 1) * width];
                let (r, rest) = planes.split_at_mut(width);
                let (g, b) = rest.split_at_mut(width);
                for (x, px) in row.chunks_exact(3).enumerate() {
                    r[x] = px[0];
                    g[x] = px[1];
                    b[x] = px[2];
                }
            }
        }
    }
}

/// "Over" for one path across one span: saves the colour below (`below` = R, G, B planes of the
/// span) and composites `color` with alpha `min(1, |area|) · opacity` into the row planes.
#[inline(always)]
fn composite_span(
    area: &[f32],
    opacity: f32,
    color: [f32; 3],
    row: [&mut [f32]; 3],
    below: &mut [f32],
) {
    let n = area.len();
    let [r, g, b] = row;
    let (r, g, b) = (&mut r[..n], &mut g[..n], &mut b[..n]);
    let (br, rest) = below.split_at_mut(n);
    let (bg, bb) = rest.split_at_mut(n);
    let (bb, [cr, cg, cb]) = (&mut bb[..n], color);
    br.copy_from_slice(r);
    bg.copy_from_slice(g);
    bb.copy_from_slice(b);
    for i in 0..n {
        let a = area[i].abs().min(1.0) * opacity;
        r[i] += a * (cr - r[i]);
        g[i] += a * (cg - g[i]);
        b[i] += a * (cb - b[i]);
    }
}

/// Lanes of the span reductions: a fixed width, so the summation order (and so every bit of the
/// result) is the same on every machine, while the compiler can vectorise the lanes.
const LANES: usize = 8;

/// The backward of [`composite_span`]: given dL/d(colour above) in `grad` (planes), returns
/// dL/d(colour) and dL/d(opacity) of the path over the span, overwrites `area` with
/// dL/d(signed area) and turns `grad` into dL/d(colour below).
#[inline(always)]
fn backward_span(
    area: &mut [f32],
    opacity: f32,
    color: [f32; 3],
    grad: [&mut [f32]; 3],
    below: &[f32],
) -> ([f32; 3], f32) {
    let n = area.len();
    let [gr, gg, gb] = grad;
    let (br, bg, bb) = (&below[..n], &below[n..2 * n], &below[2 * n..3 * n]);
    let mut sums = Lanes::default();
    let full = n - n % LANES;
    for i in (0..full).step_by(LANES) {
        let s = i..i + LANES;
        sums.step(
            lanes_mut(&mut area[s.clone()]),
            [
                lanes_mut(&mut gr[s.clone()]),
                lanes_mut(&mut gg[s.clone()]),
                lanes_mut(&mut gb[s.clone()]),
            ],
            [lanes(&br[s.clone()]), lanes(&bg[s.clone()]), lanes(&bb[s])],
            opacity,
            color,
        );
    }
    if full < n {
        // The tail, zero-padded: padding lanes have zero coverage and gradient, so they add
        // exactly nothing.
        let s = full..n;
        let pad = |v: &[f32]| {
            let mut a = [0.0f32; LANES];
            a[..v.len()].copy_from_slice(v);
            a
        };
        let mut t_area = pad(&area[s.clone()]);
        let mut t_grad = [
            pad(&gr[s.clone()]),
            pad(&gg[s.clone()]),
            pad(&gb[s.clone()]),
        ];
        let t_below = [
            pad(&br[s.clone()]),
            pad(&bg[s.clone()]),
            pad(&bb[s.clone()]),
        ];
        let [tr, tg, tb] = &mut t_grad;
        sums.step(
            &mut t_area,
            [tr, tg, tb],
            [&t_below[0], &t_below[1], &t_below[2]],
            opacity,
            color,
        );
        let m = n - full;
        area[s.clone()].copy_from_slice(&t_area[..m]);
        gr[s.clone()].copy_from_slice(&t_grad[0][..m]);
        gg[s.clone()].copy_from_slice(&t_grad[1][..m]);
        gb[s].copy_from_slice(&t_grad[2][..m]);
    }
    let sum = |v: [f32; LANES]| v.iter().sum::<f32>();
    (
        [sum(sums.color[0]), sum(sums.color[1]), sum(sums.color[2])],
        sum(sums.opacity),
    )
}

fn lanes_mut(v: &mut [f32]) -> &mut [f32; LANES] {
    v.try_into().expect("a LANES-long chunk")
}

fn lanes(v: &[f32]) -> &[f32; LANES] {
    v.try_into().expect("a LANES-long chunk")
}

/// Per-lane partial sums of dL/d(colour) and dL/d(opacity).
#[derive(Default)]
struct Lanes {
    color: [[f32; LANES]; 3],
    opacity: [f32; LANES],
}

impl Lanes {
    #[inline(always)]
    fn step(
        &mut self,
        area: &mut [f32; LANES],
        grad: [&mut [f32; LANES]; 3],
        below: [&[f32; LANES]; 3],
        opacity: f32,
        color: [f32; 3],
    ) {
        let [gr, gg, gb] = grad;
        let [br, bg, bb] = below;
        let [cr, cg, cb] = color;
        // Whole-array steps in local copies: the shape the SLP vectoriser recognises.
        let acc = *area;
        let cov: [f32; LANES] = std::array::from_fn(|l| {
            let v = acc[l].abs();
            if v < 1.0 { v } else { 1.0 }
        });
        let a: [f32; LANES] = std::array::from_fn(|l| cov[l] * opacity);
        let (r, g, b) = (*gr, *gg, *gb);
        let da: [f32; LANES] = std::array::from_fn(|l| {
            r[l] * (cr - br[l]) + g[l] * (cg - bg[l]) + b[l] * (cb - bb[l])
        });
        for l in 0..LANES {
            self.color[0][l] += r[l] * a[l];
            self.color[1][l] += g[l] * a[l];
            self.color[2][l] += b[l] * a[l];
            self.opacity[l] += da[l] * cov[l];
            let unsaturated = acc[l].abs() <= SATURATION;
            area[l] = if unsaturated {
                da[l] * opacity * 1.0f32.copysign(acc[l])
            } else {
                0.0
            };
            let keep = 1.0 - a[l];
            gr[l] = r[l] * keep;
            gg[l] = g[l] * keep;
            gb[l] = b[l] * keep;
        }
    }
}
