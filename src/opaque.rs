//! The scene as plain opaque regions: the picture `clamp01(albedo · shade + light)` without blend
//! modes or opacities, for programs that lack `multiply` or `plus-lighter` (librsvg, CairoSVG,
//! PDF viewers).
//!
//! Exact, not an approximation: every part of the canvas covered by the same set of paths has
//! one colour, computed from those paths as the renderer composites them. The regions come
//! from boolean operations (`i_overlay`) on the paths flattened to polygons within
//! [`FLATTEN_TOLERANCE`].
//!
//! Painter's order, so that anti-aliasing shows no seams where regions meet: the paths are taken
//! in drawing order (albedo, shade, light, each bottom to top), and each one adds its own pieces
//! (its outline cut by the earlier paths' outlines) on top of everything drawn before, instead
//! of cutting holes into what lies below. Along each path's own outline the pieces then blend
//! with the complete picture beneath, as the path itself does in the layered file.

use i_overlay::core::fill_rule::FillRule;
use i_overlay::core::overlay_rule::OverlayRule;
use i_overlay::float::single::SingleFloatOverlay;

use crate::geom::bezier::{flatten_into, lines_for_tolerance};
use crate::scene::{LayerKind, Path, Point, Scene};

/// Largest distance, in working pixels, between a path's curve and the polygon standing for it.
pub const FLATTEN_TOLERANCE: f32 = 0.1;

/// One opaque region: closed contours filled together (even-odd and non-zero agree: the
/// contours never cross, holes run opposite to their outer contour).
#[derive(Clone, Debug, PartialEq)]
pub struct Region {
    /// The contours, each a closed polygon (the last vertex joins the first).
    pub contours: Vec<Vec<Point>>,
    /// Its colour, sRGB in [0, 1].
    pub color: [f32; 3],
}

impl Region {
    /// The region as one renderer path: the contours chained by bridges that are walked there
    /// and back, which cancel under the non-zero rule. For covec's renderer, which draws single
    /// closed paths; files keep the contours apart.
    pub fn to_path(&self) -> Option<Path> {
        let first = self.contours.first()?.first().copied()?;
        let mut vertices = Vec::new();
        for contour in &self.contours {
            vertices.extend_from_slice(contour);
            vertices.push(contour[0]);
            vertices.push(first);
        }
        vertices.pop();
        Path::from_polygon(&vertices, self.color, 1.0)
    }
}

/// Per-layer colours of a part of the canvas: what the layers show there before compositing.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Layers([[f32; 3]; 3]);

impl Layers {
    /// The empty canvas: each layer's base colour.
    fn base() -> Self {
        Self(LayerKind::ALL.map(LayerKind::base))
    }

    /// After painting `path` of layer `kind` over this part, as files show it (colour and
    /// opacity clamped to [0, 1]).
    fn painted(mut self, kind: LayerKind, path: &Path) -> Self {
        // Files hold 8-bit colours and opacities to 3 decimals.
        let a = (path.opacity.clamp(0.0, 1.0) * 1000.0).round() / 1000.0;
        let color = path
            .color
            .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() / 255.0);
        let slot = &mut self.0[layer_index(kind)];
        for c in 0..3 {
            slot[c] = slot[c] * (1.0 - a) + color[c] * a;
        }
        self
    }

    /// The colour shown: `clamp01(albedo · shade + light)`.
    fn shown(self) -> [f32; 3] {
        let [a, s, l] = self.0;
        std::array::from_fn(|c| (a[c] * s[c] + l[c]).clamp(0.0, 1.0))
    }
}

fn layer_index(kind: LayerKind) -> usize {
    LayerKind::ALL
        .iter()
        .position(|&k| k == kind)
        .expect("a listed layer")
}

type Shapes = Vec<Vec<Vec<[f64; 2]>>>;

/// A part of the canvas covered by one set of paths so far.
struct Face {
    shapes: Shapes,
    bounds: Bounds,
    layers: Layers,
}

#[derive(Clone, Copy)]
struct Bounds {
    min: [f64; 2],
    max: [f64; 2],
}

impl Bounds {
    fn of<'a>(points: impl IntoIterator<Item = &'a [f64; 2]>) -> Self {
        let mut b = Bounds {
            min: [f64::INFINITY; 2],
            max: [f64::NEG_INFINITY; 2],
        };
        for p in points {
            for i in 0..2 {
                b.min[i] = b.min[i].min(p[i]);
                b.max[i] = b.max[i].max(p[i]);
            }
        }
        b
    }

    fn of_shapes(shapes: &Shapes) -> Self {
        Self::of(shapes.iter().flatten().flatten())
    }

    fn overlaps(&self, other: &Bounds) -> bool {
        (0..2).all(|i| self.min[i] < other.max[i] && other.min[i] < self.max[i])
    }
}

/// `path`'s outline as a polygon within [`FLATTEN_TOLERANCE`].
fn polygon(path: &Path) -> Vec<[f64; 2]> {
    let mut vertices = Vec::new();
    for k in 0..path.segment_count() {
        let c = path.segment(k);
        flatten_into(
            &c,
            lines_for_tolerance(&c, FLATTEN_TOLERANCE),
            &mut vertices,
        );
    }
    vertices
        .iter()
        .filter(|p| p.x.is_finite() && p.y.is_finite())
        .map(|p| [f64::from(p.x), f64::from(p.y)])
        .collect()
}

/// The scene as opaque regions, to be drawn in order (see the module doc). The first region
/// is the whole canvas.
pub fn regions(scene: &Scene) -> Vec<Region> {
    let (w, h) = (f64::from(scene.width), f64::from(scene.height));
    let canvas: Shapes = vec![vec![vec![[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]]]];
    let mut drawn = vec![region(&canvas, Layers::base().shown())];
    let mut faces = vec![Face {
        bounds: Bounds::of_shapes(&canvas),
        shapes: canvas,
        layers: Layers::base(),
    }];
    for kind in LayerKind::ALL {
        for path in &scene.layer(kind).paths {
            if path.opacity.is_nan() || path.opacity <= 0.0 {
                continue;
            }
            let outline = polygon(path);
            if outline.len() < 3 {
                continue;
            }
            let bounds = Bounds::of(&outline);
            // (the new face in `next`, its colour)
            let mut pieces: Vec<(usize, [f32; 3])> = Vec::new();
            let mut next = Vec::with_capacity(faces.len());
            for face in faces {
                if !face.bounds.overlaps(&bounds) {
                    next.push(face);
                    continue;
                }
                let inside =
                    face.shapes
                        .overlay(&outline, OverlayRule::Intersect, FillRule::NonZero);
                if inside.is_empty() {
                    next.push(face);
                    continue;
                }
                let outside =
                    face.shapes
                        .overlay(&outline, OverlayRule::Difference, FillRule::NonZero);
                let layers = face.layers.painted(kind, path);
                pieces.push((next.len(), layers.shown()));
                next.push(Face {
                    bounds: Bounds::of_shapes(&inside),
                    shapes: inside,
                    layers,
                });
                if !outside.is_empty() {
                    next.push(Face {
                        bounds: Bounds::of_shapes(&outside),
                        shapes: outside,
                        layers: face.layers,
                    });
                }
            }
            drawn.extend(merge_equal_colours(
                pieces
                    .iter()
                    .map(|&(face, color)| (&next[face].shapes, color)),
            ));
            faces = next;
        }
    }
    drawn
}

/// Pieces of one path with the same 8-bit colour joined into one region: fewer regions, and no
/// edge drawn between parts that look alike.
fn merge_equal_colours<'a>(pieces: impl Iterator<Item = (&'a Shapes, [f32; 3])>) -> Vec<Region> {
    let key = |c: [f32; 3]| c.map(|v| (v * 255.0).round() as u8);
    let mut groups: Vec<([u8; 3], [f32; 3], Vec<&'a Shapes>)> = Vec::new();
    for (shapes, color) in pieces {
        match groups.iter_mut().find(|g| g.0 == key(color)) {
            Some(group) => group.2.push(shapes),
            None => groups.push((key(color), color, vec![shapes])),
        }
    }
    groups
        .into_iter()
        .map(|(_, color, parts)| {
            let joined = if parts.len() > 1 {
                let contours: Vec<Vec<[f64; 2]>> =
                    parts.into_iter().flatten().flatten().cloned().collect();
                clean_contours(&contours)
            } else {
                parts[0].clone()
            };
            region(&joined, color)
        })
        .collect()
}

/// The union of `contours` under the non-zero rule.
fn clean_contours(contours: &Vec<Vec<[f64; 2]>>) -> Shapes {
    contours.overlay(
        &Vec::<Vec<[f64; 2]>>::new(),
        OverlayRule::Subject,
        FillRule::NonZero,
    )
}

fn region(shapes: &Shapes, color: [f32; 3]) -> Region {
    Region {
        contours: shapes
            .iter()
            .flatten()
            .map(|contour| {
                contour
                    .iter()
                    .map(|p| Point::new(p[0] as f32, p[1] as f32))
                    .collect()
            })
            .collect(),
        color,
    }
}
