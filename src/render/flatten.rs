//! Flattening a list of paths into closed polylines at fixed Bézier parameters, and chaining
//! vertex gradients back to the control points through those parameters.

use std::ops::Range;

use crate::geom::bezier;
use crate::render::Flattening;
use crate::scene::{Path, Point};

/// Flattened coordinates are clamped to ±this many pixels so that no later difference can
/// overflow; anything that far away is off the canvas anyway.
const COORD_LIMIT: f32 = 1.0e6;

/// One path after flattening.
#[derive(Clone, Debug, Default)]
pub(crate) struct FlatPath {
    /// Range into [`FlatScene::verts`]; empty for paths that are not drawn.
    pub verts: Range<usize>,
    /// Range into [`FlatScene::lines_per_segment`].
    pub segments: Range<usize>,
    /// Bounding box of the polyline: `[x_min, y_min, x_max, y_max]`.
    pub bbox: [f32; 4],
}

/// All paths of one render, flattened; kept in the rasteriser and refilled each call.
#[derive(Debug, Default)]
pub(crate) struct FlatScene {
    pub verts: Vec<[f32; 2]>,
    pub lines_per_segment: Vec<u32>,
    pub paths: Vec<FlatPath>,
    scratch: Vec<Point>,
}

impl FlatScene {
    pub fn build(&mut self, paths: &[Path], flattening: Flattening) {
        self.verts.clear();
        self.lines_per_segment.clear();
        self.paths.clear();
        for path in paths {
            let seg_start = self.lines_per_segment.len();
            let vert_start = self.verts.len();
            if super::check_path(path).is_ok() {
                for k in 0..path.segment_count() {
                    let c = path.segment(k);
                    let n = match flattening {
                        Flattening::Tolerance(tol) => bezier::lines_for_tolerance(&c, tol),
                        Flattening::Fixed(n) => n.clamp(1, bezier::MAX_LINES_PER_CUBIC),
                    };
                    self.lines_per_segment.push(n);
                    self.scratch.clear();
                    bezier::flatten_into(&c, n, &mut self.scratch);
                    self.verts.extend(self.scratch.iter().map(|p| {
                        [
                            p.x.clamp(-COORD_LIMIT, COORD_LIMIT),
                            p.y.clamp(-COORD_LIMIT, COORD_LIMIT),
                        ]
                    }));
                }
            }
            let verts = vert_start..self.verts.len();
            let mut bbox = [
                f32::INFINITY,
                f32::INFINITY,
                f32::NEG_INFINITY,
                f32::NEG_INFINITY,
            ];
            for v in &self.verts[verts.clone()] {
                bbox = [
                    bbox[0].min(v[0]),
                    bbox[1].min(v[1]),
                    bbox[2].max(v[0]),
                    bbox[3].max(v[1]),
                ];
            }
            self.paths.push(FlatPath {
                verts,
                segments: seg_start..self.lines_per_segment.len(),
                bbox,
            });
        }
    }

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
            let inv = 1.0 / n as f32;
            for k in 0..n {
                let g = vertex_grads[v];
                v += 1;
                if k == 0 {
                    // B(0) is the start point itself (see `bezier::flatten_into`).
                    point_grads[idx[0]].x += g[0] as f32;
                    point_grads[idx[0]].y += g[1] as f32;
                    continue;
                }
                let w = bezier::bernstein(k as f32 * inv);
                for (j, &i) in idx.iter().enumerate() {
                    point_grads[i].x += (w[j] as f64 * g[0]) as f32;
                    point_grads[i].y += (w[j] as f64 * g[1]) as f32;
                }
            }
        }
    }
}
