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
        // The layout first, on one thread: each segment's line count sets where every path's
        // vertices and chunks go. Then the vertices, most of the cost, path by path on
        // rayon's pool, each into its own place.
        self.lines_per_segment.clear();
        self.paths.clear();
        let (mut vert_count, mut chunk_count) = (0, 0);
        for path in paths {
            let seg_start = self.lines_per_segment.len();
            if super::check_path(path).is_ok() {
                self.lines_per_segment
                    .extend((0..path.segment_count()).map(|k| {
                        match flattening {
                            Flattening::Tolerance(tol) => {
                                bezier::lines_for_tolerance(&path.segment(k), tol)
                                    .max(super::MIN_LINES_PER_CUBIC)
                            }
                            Flattening::Fixed(n) => n.clamp(1, bezier::MAX_LINES_PER_CUBIC),
                        }
                    }));
            }
            let lines = &self.lines_per_segment[seg_start..];
            let verts = lines.iter().map(|&n| n as usize).sum::<usize>();
            let chunks = verts.div_ceil(EDGE_CHUNK);
            self.paths.push(FlatPath {
                verts: vert_count..vert_count + verts,
                chunks: chunk_count..chunk_count + chunks,
                segments: seg_start..self.lines_per_segment.len(),
                bbox: [0.0; 4],
            });
            vert_count += verts;
            chunk_count += chunks;
        }
        self.verts.clear();
        self.verts.resize(vert_count, [T::ZERO; 2]);
        self.chunks.clear();
        self.chunks.resize(chunk_count, [T::ZERO; 2]);
        let layout = Layout {
            paths,
            lines_per_segment: &self.lines_per_segment,
        };
        layout.fill(&mut self.paths, &mut self.verts, &mut self.chunks);
    }
}

/// Vertices per rayon task when flattening: enough work that handing the task out costs
/// little beside it.
const VERTS_PER_TASK: usize = 2048;

/// What [`FlatScene::build`] fills paths from.
struct Layout<'a> {
    paths: &'a [Path],
    lines_per_segment: &'a [u32],
}

impl Layout<'_> {
    /// Fills each of `flats` (laid out by [`FlatScene::build`], its path at the same index of
    /// `self.paths`): its vertices into `verts` and its chunk extents into `chunks`, the parts
    /// of the scene's that begin at the first path's, and its box. The two halves of the paths
    /// go at once while they hold more than [`VERTS_PER_TASK`] vertices.
    fn fill<T: Real>(&self, flats: &mut [FlatPath], verts: &mut [[T; 2]], chunks: &mut [[T; 2]]) {
        if flats.len() > 1 && verts.len() > VERTS_PER_TASK {
            let mid = flats.len() / 2;
            let (vert_base, chunk_base) = (flats[0].verts.start, flats[0].chunks.start);
            let (verts_lo, verts_hi) = verts.split_at_mut(flats[mid].verts.start - vert_base);
            let (chunks_lo, chunks_hi) = chunks.split_at_mut(flats[mid].chunks.start - chunk_base);
            let (lo, hi) = flats.split_at_mut(mid);
            let (lo_paths, hi_paths) = self.paths.split_at(mid);
            let (lo_layout, hi_layout) = (
                Layout {
                    paths: lo_paths,
                    ..*self
                },
                Layout {
                    paths: hi_paths,
                    ..*self
                },
            );
            rayon::join(
                || lo_layout.fill(lo, verts_lo, chunks_lo),
                || hi_layout.fill(hi, verts_hi, chunks_hi),
            );
            return;
        }
        let (vert_base, chunk_base) = match flats.first() {
            Some(first) => (first.verts.start, first.chunks.start),
            None => return,
        };
        for (flat, path) in flats.iter_mut().zip(self.paths) {
            let (v, c) = (flat.verts.start - vert_base, flat.chunks.start - chunk_base);
            flat.bbox = fill_path(
                path,
                &self.lines_per_segment[flat.segments.clone()],
                &mut verts[v..v + flat.verts.len()],
                &mut chunks[c..c + flat.chunks.len()],
            );
        }
    }
}

/// Fills one path's vertices (`lines[k]` per segment `k`) and chunk extents; returns its box.
fn fill_path<T: Real>(
    path: &Path,
    lines: &[u32],
    verts: &mut [[T; 2]],
    chunks: &mut [[T; 2]],
) -> [f32; 4] {
    let limit = T::from_f32(COORD_LIMIT);
    let mut start = 0;
    for (k, &n) in lines.iter().enumerate() {
        let c = path.segment(k);
        let end = start + n as usize;
        let segment = &mut verts[start..end];
        T::flatten_segment(&c, segment);
        for vert in segment {
            *vert = vert.map(|v| v.max(-limit).min(limit));
        }
        start = end;
    }
    for (k, chunk) in chunks.iter_mut().enumerate() {
        let (first, end) = (k * EDGE_CHUNK, ((k + 1) * EDGE_CHUNK).min(verts.len()));
        let last = verts[end % verts.len()][1];
        *chunk = verts[first..end]
            .iter()
            .fold([last, last], |[lo, hi], v| [lo.min(v[1]), hi.max(v[1])]);
    }
    let mut bbox = [
        f32::INFINITY,
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::NEG_INFINITY,
    ];
    for v in verts.iter() {
        // Whole pixels, rounded outwards, so the f32 box contains the polyline.
        let (x, y) = (v[0].floor_i32() as f32, v[1].floor_i32() as f32);
        bbox = [
            bbox[0].min(x),
            bbox[1].min(y),
            bbox[2].max(x + 1.0),
            bbox[3].max(y + 1.0),
        ];
    }
    bbox
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
            let table = bezier::weight_table(n);
            for k in 0..n {
                let g = vertex_grads[v];
                v += 1;
                if k == 0 {
                    // B(0) is the start point itself (see `bezier::flatten_into`).
                    point_grads[idx[0]].x += g[0] as f32;
                    point_grads[idx[0]].y += g[1] as f32;
                    continue;
                }
                let w = bezier::weight(table, k, n);
                for (j, &i) in idx.iter().enumerate() {
                    point_grads[i].x += (w[j] as f64 * g[0]) as f32;
                    point_grads[i].y += (w[j] as f64 * g[1]) as f32;
                }
            }
        }
    }
}
