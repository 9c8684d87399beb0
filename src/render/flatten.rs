//! Flattening a list of paths into closed polylines at fixed Bézier parameters, and chaining
//! vertex gradients back to the control points through those parameters.

use std::ops::Range;

use crate::geom::bezier;
use crate::render::Flattening;
use crate::render::real::Real;
use crate::scene::{Path, Point};

/// Flattened coordinates are clamped to ±this many pixels so that no later difference can
/// overflow; anything that far away is off the canvas anyway.
const COORD_LIMIT: f32 = 1.0e6;

/// Edges per chunk of an outline (see [`Outline`]).
pub(crate) const EDGE_CHUNK: usize = 16;

/// A path's closed polyline, with the vertical extent of each run of [`EDGE_CHUNK`] edges: a
/// strip of rows visits only the runs that reach it, not every edge of a tall path.
#[derive(Clone, Copy)]
pub(crate) struct Outline<'a, T> {
    pub verts: &'a [[T; 2]],
    /// `[y_min, y_max]` of edges `k · EDGE_CHUNK .. (k + 1) · EDGE_CHUNK` (both ends), per `k`.
    pub chunks: &'a [[T; 2]],
}

impl<T: Real> Outline<'_, T> {
    /// The edges `(j, j + 1 mod n)` of the chunks for which `skip(y_min, y_max)` is false,
    /// in order.
    #[inline(always)]
    pub fn edges<'s>(
        &'s self,
        skip: impl Fn(T, T) -> bool + 's,
    ) -> impl Iterator<Item = usize> + 's {
        let n = self.verts.len();
        self.chunks
            .iter()
            .enumerate()
            .filter(move |(_, c)| !skip(c[0], c[1]))
            .flat_map(move |(k, _)| k * EDGE_CHUNK..((k + 1) * EDGE_CHUNK).min(n))
    }
}

/// One path after flattening.
#[derive(Clone, Debug, Default)]
pub(crate) struct FlatPath {
    /// Range into [`FlatScene::verts`]; empty for paths that are not drawn.
    pub verts: Range<usize>,
    /// Range into [`FlatScene::chunks`].
    pub chunks: Range<usize>,
    /// Range into [`FlatScene::lines_per_segment`].
    pub segments: Range<usize>,
    /// Bounding box of the polyline: `[x_min, y_min, x_max, y_max]`.
    pub bbox: [f32; 4],
}

/// All paths of one render, flattened; kept in the rasteriser and refilled each call.
#[derive(Debug, Default)]
pub(crate) struct FlatScene<T> {
    pub verts: Vec<[T; 2]>,
    /// Vertical extents of the outlines' edge chunks (see [`Outline`]).
    pub chunks: Vec<[T; 2]>,
    pub lines_per_segment: Vec<u32>,
    pub paths: Vec<FlatPath>,
}

impl<T: Real> FlatScene<T> {
    pub fn build(&mut self, paths: &[Path], flattening: Flattening) {
        self.verts.clear();
        self.chunks.clear();
        self.lines_per_segment.clear();
        self.paths.clear();
        for path in paths {
            let seg_start = self.lines_per_segment.len();
            let vert_start = self.verts.len();
            if super::check_path(path).is_ok() {
                for k in 0..path.segment_count() {
                    let c = path.segment(k);
                    let n = match flattening {
                        Flattening::Tolerance(tol) => {
                            bezier::lines_for_tolerance(&c, tol).max(super::MIN_LINES_PER_CUBIC)
                        }
                        Flattening::Fixed(n) => n.clamp(1, bezier::MAX_LINES_PER_CUBIC),
                    };
                    self.lines_per_segment.push(n);
                    let limit = T::from_f32(COORD_LIMIT);
                    self.verts.extend(
                        (0..n).map(|k| T::bezier_point(&c, k, n).map(|v| v.max(-limit).min(limit))),
                    );
                }
            }
            let verts = vert_start..self.verts.len();
            let chunk_start = self.chunks.len();
            let outline = &self.verts[verts.clone()];
            for k in (0..outline.len()).step_by(EDGE_CHUNK) {
                let end = (k + EDGE_CHUNK).min(outline.len());
                let last = outline[end % outline.len()][1];
                let (lo, hi) = outline[k..end]
                    .iter()
                    .fold((last, last), |(lo, hi), v| (lo.min(v[1]), hi.max(v[1])));
                self.chunks.push([lo, hi]);
            }
            let mut bbox = [
                f32::INFINITY,
                f32::INFINITY,
                f32::NEG_INFINITY,
                f32::NEG_INFINITY,
            ];
            for v in &self.verts[verts.clone()] {
                // Whole pixels, rounded outwards, so the f32 box contains the polyline.
                let (x, y) = (v[0].floor_i32() as f32, v[1].floor_i32() as f32);
                bbox = [
                    bbox[0].min(x),
                    bbox[1].min(y),
                    bbox[2].max(x + 1.0),
                    bbox[3].max(y + 1.0),
                ];
            }
            self.paths.push(FlatPath {
                verts,
                chunks: chunk_start..self.chunks.len(),
                segments: seg_start..self.lines_per_segment.len(),
                bbox,
            });
        }
    }
}

impl<T> FlatScene<T> {
    /// The outline of path `path`.
    pub fn outline(&self, path: usize) -> Outline<'_, T> {
        let p = &self.paths[path];
        Outline {
            verts: &self.verts[p.verts.clone()],
            chunks: &self.chunks[p.chunks.clone()],
        }
    }
}

impl FlatScene<f32> {
    /// Adds `vertex_grads` (dL/d flattened vertex of `path`, in vertex order) into
    /// `point_grads` (dL/d control point) using the Bernstein weights of each vertex's parameter.
    pub fn chain_to_control_points(
        &self,
        path: usize,
        vertex_grads: &[[f64; 2]],
        point_grads: &mut [Point],
    ) {
        let flat = &self.paths[path];
        let count = point_grads.len();
        let mut v = 0;
        for (s, &n) in self.lines_per_segment[flat.segments.clone()]
            .iter()
            .enumerate()
        {
            let idx = [3 * s, 3 * s + 1, 3 * s + 2, (3 * s + 3) % count];
            for k in 0..n {
                let g = vertex_grads[v];
                v += 1;
                if k == 0 {
                    // B(0) is the start point itself (see `bezier::flatten_into`).
                    point_grads[idx[0]].x += g[0] as f32;
                    point_grads[idx[0]].y += g[1] as f32;
                    continue;
                }
                let w = bezier::bernstein(bezier::parameter(k, n));
                for (j, &i) in idx.iter().enumerate() {
                    point_grads[i].x += (w[j] as f64 * g[0]) as f32;
                    point_grads[i].y += (w[j] as f64 * g[1]) as f32;
                }
            }
        }
    }
}
