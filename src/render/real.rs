//! The scalar the rasteriser core is written over: `f32` for real work, `f64` for the
//! double-precision reference forward ([`Rasterizer::render_f64`](super::Rasterizer::render_f64))
//! that finite-difference checks of the gradients need.

use std::ops::{Add, AddAssign, Div, Mul, Neg, Sub};

use crate::geom::bezier;
use crate::scene::Point;

pub(crate) trait Real:
    Copy
    + Default
    + PartialOrd
    + Send
    + Sync
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
{
    const ZERO: Self;
    const ONE: Self;
    const HALF: Self;
    fn from_f32(v: f32) -> Self;
    fn from_i32(v: i32) -> Self;
    /// `floor(self)` as i32 (saturating), without a libm call: baseline x86-64 has no
    /// rounding instruction, and `f32::floor` there is a function call in the hottest loops.
    fn floor_i32(self) -> i32;
    /// `ceil(self)` as i32 (saturating).
    fn ceil_i32(self) -> i32;
    fn abs(self) -> Self;
    fn min(self, other: Self) -> Self;
    fn max(self, other: Self) -> Self;
    /// `B(k/n)` of the cubic `c` for `k = 0..n` into `out`, `n = out.len()`, evaluated in
    /// this precision; `B(0)` is the start point itself.
    fn flatten_segment(c: &[Point; 4], out: &mut [[Self; 2]]);
}

impl Real for f32 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
    const HALF: Self = 0.5;
    #[inline(always)]
    fn from_f32(v: f32) -> Self {
        v
    }
    #[inline(always)]
    fn from_i32(v: i32) -> Self {
        v as f32
    }
    #[inline(always)]
    fn floor_i32(self) -> i32 {
        let t = self as i32;
        if (t as f32) > self {
            t.saturating_sub(1)
        } else {
            t
        }
    }
    #[inline(always)]
    fn ceil_i32(self) -> i32 {
        let t = self as i32;
        if (t as f32) < self {
            t.saturating_add(1)
        } else {
            t
        }
    }
    #[inline(always)]
    fn abs(self) -> Self {
        f32::abs(self)
    }
    #[inline(always)]
    fn min(self, other: Self) -> Self {
        f32::min(self, other)
    }
    #[inline(always)]
    fn max(self, other: Self) -> Self {
        f32::max(self, other)
    }
    #[inline(always)]
    fn flatten_segment(c: &[Point; 4], out: &mut [[Self; 2]]) {
        let n = out.len() as u32;
        let table = bezier::weight_table(n);
        for (k, vert) in (0..n).zip(out) {
            let p = if k == 0 {
                c[0]
            } else {
                bezier::eval_weighted(c, bezier::weight(table, k, n))
            };
            *vert = [p.x, p.y];
        }
    }
}

impl Real for f64 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
    const HALF: Self = 0.5;
    #[inline(always)]
    fn from_f32(v: f32) -> Self {
        v as f64
    }
    #[inline(always)]
    fn from_i32(v: i32) -> Self {
        v as f64
    }
    #[inline(always)]
    fn floor_i32(self) -> i32 {
        let t = self as i32;
        if (t as f64) > self {
            t.saturating_sub(1)
        } else {
            t
        }
    }
    #[inline(always)]
    fn ceil_i32(self) -> i32 {
        let t = self as i32;
        if (t as f64) < self {
            t.saturating_add(1)
        } else {
            t
        }
    }
    #[inline(always)]
    fn abs(self) -> Self {
        f64::abs(self)
    }
    #[inline(always)]
    fn min(self, other: Self) -> Self {
        f64::min(self, other)
    }
    #[inline(always)]
    fn max(self, other: Self) -> Self {
        f64::max(self, other)
    }
    fn flatten_segment(c: &[Point; 4], out: &mut [[Self; 2]]) {
        let n = out.len() as f64;
        for (k, vert) in out.iter_mut().enumerate() {
            let t = k as f64 / n;
            let s = 1.0 - t;
            let w = [s * s * s, 3.0 * s * s * t, 3.0 * s * t * t, t * t * t];
            let mut p = [0.0; 2];
            for j in 0..4 {
                p[0] += w[j] * c[j].x as f64;
                p[1] += w[j] * c[j].y as f64;
            }
            *vert = p;
        }
    }
}
