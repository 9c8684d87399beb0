//! Scan conversion of flattened outlines into signed-area deltas, and its exact adjoint.
//!
//! Forward (font-rs style): every part of an edge inside one pixel cell `(cx, cy)`, with
//! vertical extent `dy` (signed by the edge's direction) and mid x `xm`, adds
//! `dy·(cx + 1 − xm)` to cell `cx` and `dy·(xm − cx)` to cell `cx + 1`; the prefix sum along the
//! row is then the signed area of the outline inside each pixel (its winding-weighted area).
//!
//! Adjoint: `Σ_p g(p)·acc(p)` is the integral of the piecewise-constant field `G = g(pixel)`
//! over the winding-weighted region, so moving the boundary by `δr` changes it by
//! `∮ G(r)·(δy·x′ − δx·y′) dt`. For a line `P0 → P1` with `δr(t) = (1−t)δP0 + tδP1` that is,
//! summed over the line's pieces, `dL/dP0 = (−y′, x′)·Σ g(cell)∫(1−t)dt` and
//! `dL/dP1 = (−y′, x′)·Σ g(cell)∫t dt` with `(x′, y′) = P1 − P0`: only the cells the edge passes
//! through matter, so the backward costs O(perimeter).

use super::flatten::Outline;
use super::real::Real;

/// One row of the path's coverage inside a strip: cells `lo..end` hold its signed area; outside
/// that range the path's coverage is zero.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct RowSpan {
    pub lo: u32,
    pub end: u32,
}

/// Pixels per group: the backward works on runs of this many pixels of a row at once (SIMD
/// lanes), and signed areas are kept for whole groups (see [`RowSpan::groups`]).
pub(crate) const GROUP: usize = 8;

impl RowSpan {
    pub const EMPTY: RowSpan = RowSpan { lo: 0, end: 0 };

    #[inline]
    pub fn len(self) -> usize {
        (self.end - self.lo) as usize
    }

    /// The groups `g_lo..g_hi` holding the span (pixels `GROUP · g_lo .. GROUP · g_hi`); empty
    /// for an empty span. Kept signed areas cover these whole groups, zero outside the span.
    #[inline]
    pub fn groups(self) -> (usize, usize) {
        if self.lo >= self.end {
            (0, 0)
        } else {
            (
                self.lo as usize / GROUP,
                (self.end as usize).div_ceil(GROUP),
            )
        }
    }

    /// Values kept for the span: whole groups.
    #[inline]
    pub fn padded_len(self) -> usize {
        let (lo, hi) = self.groups();
        (hi - lo) * GROUP
    }
}

/// Calls `piece(cx, cy, xa, ya, xb, yb)` for every part of the line `(x0, y0) → (x1, y1)` that
/// lies in one pixel row of `row_lo..row_hi` and one column. Columns are split only at
/// `x = 0..=width`, so everything left of the canvas comes as one piece per row with `cx < 0`
/// and everything right of it with `cx ≥ width`. Pieces come top to bottom (`ya ≤ yb`).
/// Horizontal lines yield nothing unless `HORIZONTAL` (the forward ignores them: they enclose no
/// area, but moving them vertically does change the area, which the backward needs).
#[inline(always)]
pub(crate) fn walk_line<T: Real, const HORIZONTAL: bool>(
    p0: [T; 2],
    p1: [T; 2],
    row_lo: i32,
    row_hi: i32,
    width: i32,
    mut piece: impl FnMut(i32, i32, T, T, T, T),
) {
    let ([xt, yt], [xb, yb]) = if p0[1] <= p1[1] { (p0, p1) } else { (p1, p0) };
    if yt == yb {
        if HORIZONTAL {
            let row = yt.floor_i32();
            if row >= row_lo && row < row_hi {
                split_row(p0[0], yt, p1[0], yb, row, width, &mut piece);
            }
        }
        return;
    }
    let ys = yt.max(T::from_i32(row_lo));
    let ye = yb.min(T::from_i32(row_hi));
    if ys >= ye {
        return;
    }
    let slope = (xb - xt) / (yb - yt);
    let mut row = ys.floor_i32();
    let mut y = ys;
    let mut x = if ys == yt { xt } else { xt + (ys - yt) * slope };
    loop {
        let row_end = T::from_i32(row + 1);
        let (nx, ny) = if ye <= row_end {
            (if ye == yb { xb } else { xt + (ye - yt) * slope }, ye)
        } else {
            (xt + (row_end - yt) * slope, row_end)
        };
        split_row(x, y, nx, ny, row, width, &mut piece);
        if ny >= ye {
            break;
        }
        row += 1;
        x = nx;
        y = ny;
    }
}

/// Splits a line part lying within one row at the integer columns `0..=width` it crosses.
#[inline(always)]
fn split_row<T: Real>(
    xa: T,
    ya: T,
    xb: T,
    yb: T,
    row: i32,
    width: i32,
    piece: &mut impl FnMut(i32, i32, T, T, T, T),
) {
    let (lo, hi) = if xa <= xb { (xa, xb) } else { (xb, xa) };
    let first = lo.floor_i32().saturating_add(1).max(0);
    let last = hi.ceil_i32().saturating_sub(1).min(width);
    if first > last {
        piece(cell(T::HALF * (xa + xb)), row, xa, ya, xb, yb);
        return;
    }
    let dydx = (yb - ya) / (xb - xa);
    let (mut px, mut py) = (xa, ya);
    let mut emit = |bx: i32| {
        let x = T::from_i32(bx);
        let y = ya + (x - xa) * dydx;
        piece(cell(T::HALF * (px + x)), row, px, py, x, y);
        px = x;
        py = y;
    };
    if xa < xb {
        for bx in first..=last {
            emit(bx);
        }
    } else {
        for bx in (first..=last).rev() {
            emit(bx);
        }
    }
    piece(cell(T::HALF * (px + xb)), row, px, py, xb, yb);
}

#[inline(always)]
fn cell<T: Real>(x: T) -> i32 {
    x.floor_i32()
}

/// Accumulates the signed-area deltas of one closed polyline into `delta` (rows
/// `row0..row0 + rows` of a canvas `width` wide, row stride `width + 2`) and records, per row,
/// the span of cells whose coverage may be non-zero. `delta` must be zero on entry over the
/// touched rows; [`clear_rows`] restores that.
#[inline(always)]
pub(crate) fn accumulate<T: Real>(
    outline: Outline<T>,
    row0: i32,
    rows: usize,
    width: usize,
    delta: &mut [T],
    spans: &mut [RowSpan],
) {
    let stride = width + 2;
    let w = width as i32;
    // Per-row min / max cell touched, in i32 with empty = (i32::MAX, i32::MIN).
    let mut lo = [i32::MAX; crate::render::STRIP_ROWS];
    let mut hi = [i32::MIN; crate::render::STRIP_ROWS];
    let row_hi = row0 + rows as i32;
    let (y_lo, y_hi) = (T::from_i32(row0), T::from_i32(row_hi));
    let verts = outline.verts;
    let n = verts.len();
    for j in outline.edges(|lo, hi| hi <= y_lo || lo >= y_hi) {
        let a = verts[j];
        let b = verts[if j + 1 == n { 0 } else { j + 1 }];
        if (a[1] <= y_lo && b[1] <= y_lo) || (a[1] >= y_hi && b[1] >= y_hi) {
            continue;
        }
        let sign = if a[1] <= b[1] { T::ONE } else { -T::ONE };
        walk_line::<T, false>(a, b, row0, row_hi, w, |cx, cy, xa, ya, xb, yb| {
            let r = (cy - row0) as usize;
            let dy = (yb - ya) * sign;
            let row = &mut delta[r * stride..(r + 1) * stride];
            let c = if cx < 0 {
                row[0] += dy;
                0
            } else if cx >= w {
                w - 1
            } else {
                let m = T::HALF * (xa + xb) - T::from_i32(cx);
                let c = cx as usize;
                row[c] += dy * (T::ONE - m);
                row[c + 1] += dy * m;
                cx
            };
            lo[r] = lo[r].min(c);
            hi[r] = hi[r].max(c);
        });
    }
    for r in 0..rows {
        spans[r] = if lo[r] > hi[r] {
            RowSpan::EMPTY
        } else {
            RowSpan {
                lo: lo[r] as u32,
                end: (hi[r] + 2).min(w) as u32,
            }
        };
    }
}

/// Rows whose prefix sums [`prefix_rows`] runs side by side: independent running sums, so that
/// each addition need not wait for the one before it.
const PREFIX_ROWS: usize = 4;

/// Turns each row's deltas (row stride `width + 2`) into running signed areas, in place: after
/// it, cell `x` of row `r`'s span holds the signed area of that pixel. Each row is summed left
/// to right from 0, as a sum over its own span alone would be; cells past a row's span may hold
/// leftovers, which [`clear_rows`] (to call once the areas are used) clears with the rest.
#[inline(always)]
pub(crate) fn prefix_rows<T: Real>(delta: &mut [T], spans: &[RowSpan], width: usize) {
    let stride = width + 2;
    for (block, spans) in spans.chunks(PREFIX_ROWS).enumerate() {
        let Some((lo, end)) = block_range(spans) else {
            continue;
        };
        let first = block * PREFIX_ROWS;
        let delta = &mut delta[first * stride..(first + spans.len()) * stride];
        if let Some([d0, d1, d2, d3]) = four_rows(delta, stride, lo, end) {
            // Cells left of a row's span hold no delta, so its sum starts there at exactly 0.
            let n = d0.len();
            let (d1, d2, d3) = (&mut d1[..n], &mut d2[..n], &mut d3[..n]);
            let mut acc = [T::ZERO; PREFIX_ROWS];
            for x in 0..n {
                acc[0] += d0[x];
                acc[1] += d1[x];
                acc[2] += d2[x];
                acc[3] += d3[x];
                (d0[x], d1[x], d2[x], d3[x]) = (acc[0], acc[1], acc[2], acc[3]);
            }
        } else {
            for (r, span) in spans.iter().enumerate() {
                let row = &mut delta[r * stride + span.lo as usize..r * stride + span.end as usize];
                let mut acc = T::ZERO;
                for d in row {
                    acc += *d;
                    *d = acc;
                }
            }
        }
    }
}

/// Zeroes what [`prefix_rows`] left in `delta` (and the deltas past the canvas edge), ready for
/// the next path.
#[inline(always)]
pub(crate) fn clear_rows<T: Real>(delta: &mut [T], spans: &[RowSpan], width: usize) {
    let stride = width + 2;
    for (block, spans) in spans.chunks(PREFIX_ROWS).enumerate() {
        let Some((lo, end)) = block_range(spans) else {
            continue;
        };
        let first = block * PREFIX_ROWS;
        for r in first..first + spans.len() {
            delta[r * stride + lo..r * stride + end].fill(T::ZERO);
            delta[r * stride + width] = T::ZERO;
        }
    }
}

/// The cells `lo..end` the non-empty spans of a block of rows cover together.
#[inline(always)]
fn block_range(spans: &[RowSpan]) -> Option<(usize, usize)> {
    let filled = spans.iter().filter(|s| s.len() > 0);
    Some((
        filled.clone().map(|s| s.lo as usize).min()?,
        filled.map(|s| s.end as usize).max()?,
    ))
}

/// Cells `lo..end` of each row of `rows` (row stride `stride`), if it holds exactly
/// [`PREFIX_ROWS`] rows.
#[inline(always)]
fn four_rows<T>(
    rows: &mut [T],
    stride: usize,
    lo: usize,
    end: usize,
) -> Option<[&mut [T]; PREFIX_ROWS]> {
    if rows.len() != PREFIX_ROWS * stride {
        return None;
    }
    let (r0, rest) = rows.split_at_mut(stride);
    let (r1, rest) = rest.split_at_mut(stride);
    let (r2, r3) = rest.split_at_mut(stride);
    Some([
        &mut r0[lo..end],
        &mut r1[lo..end],
        &mut r2[lo..end],
        &mut r3[lo..end],
    ])
}

/// Appends the values of `span` in `row` (a row of cells), kept for the span's whole groups:
/// zeros where the groups overhang it ([`RowSpan::groups`]).
#[inline(always)]
pub(crate) fn push_groups<T: Real>(row: &[T], span: RowSpan, out: &mut Vec<T>) {
    let (g_lo, g_hi) = span.groups();
    let (lo, end) = (span.lo as usize, span.end as usize);
    out.extend(std::iter::repeat_n(T::ZERO, lo - g_lo * GROUP));
    out.extend_from_slice(&row[lo..end]);
    out.extend(std::iter::repeat_n(T::ZERO, g_hi * GROUP - end));
}

/// The adjoint of [`accumulate`] followed by the prefix sum: given `g(cx, cy)` = dL/d(signed
/// area of cell), adds dL/d(vertex) of the closed polyline into `grad` (one entry per vertex).
/// `g` must return 0 outside the canvas.
#[inline(always)]
pub(crate) fn backward_lines(
    outline: Outline<f32>,
    row0: i32,
    rows: usize,
    width: usize,
    grad: &mut [[f32; 2]],
    g: impl Fn(i32, i32) -> f32,
) {
    let w = width as i32;
    let row_hi = row0 + rows as i32;
    let (y_lo, y_hi) = (row0 as f32, row_hi as f32);
    let verts = outline.verts;
    let n = verts.len();
    for j in outline.edges(|lo, hi| hi < y_lo || lo >= y_hi) {
        let k = if j + 1 == n { 0 } else { j + 1 };
        let (a, b) = (verts[j], verts[k]);
        if (a[1] < y_lo && b[1] < y_lo) || (a[1] >= y_hi && b[1] >= y_hi) {
            continue;
        }
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        // Parameter along P0 → P1 from the dominant coordinate (well conditioned).
        let (origin, inv, axis) = if dy.abs() >= dx.abs() {
            (a[1], 1.0 / dy, 1)
        } else {
            (a[0], 1.0 / dx, 0)
        };
        if !inv.is_finite() {
            continue;
        }
        let (mut s0, mut s1) = (0.0f32, 0.0f32);
        walk_line::<f32, true>(a, b, row0, row_hi, w, |cx, cy, xa, ya, xb, yb| {
            let gv = g(cx, cy);
            if gv == 0.0 {
                return;
            }
            let (pa, pb) = if axis == 1 { (ya, yb) } else { (xa, xb) };
            let ta = ((pa - origin) * inv).clamp(0.0, 1.0);
            let tb = ((pb - origin) * inv).clamp(0.0, 1.0);
            let (ta, tb) = if ta <= tb { (ta, tb) } else { (tb, ta) };
            let int_t = 0.5 * (tb * tb - ta * ta);
            s0 += gv * ((tb - ta) - int_t);
            s1 += gv * int_t;
        });
        grad[j][0] -= dy * s0;
        grad[j][1] += dx * s0;
        grad[k][0] -= dy * s1;
        grad[k][1] += dx * s1;
    }
}
