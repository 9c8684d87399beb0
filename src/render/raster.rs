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

impl RowSpan {
    pub const EMPTY: RowSpan = RowSpan { lo: 0, end: 0 };

    #[inline]
    pub fn len(self) -> usize {
        (self.end - self.lo) as usize
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
/// touched rows; [`prefix_row`] restores that.
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

/// Calls `f(x, acc)` for every cell of `span` with the running signed area, and clears the row's
/// deltas (including the one past the canvas edge) for the next path.
#[inline(always)]
pub(crate) fn prefix_row<T: Real>(
    delta_row: &mut [T],
    span: RowSpan,
    width: usize,
    mut f: impl FnMut(usize, T),
) {
    let mut acc = T::ZERO;
    let (lo, end) = (span.lo as usize, span.end as usize);
    for (i, d) in delta_row[lo..end].iter_mut().enumerate() {
        acc += *d;
        *d = T::ZERO;
        f(lo + i, acc);
    }
    if end == width {
        delta_row[width] = T::ZERO;
    }
}

/// The adjoint of [`accumulate`] followed by the prefix sum: given `g(cx, cy)` = dL/d(signed
/// area of cell), adds dL/d(vertex) of the closed polyline into `grad` (one entry per vertex).
/// `g` must return 0 outside the canvas.
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
