//! The one model everything shares: a [`Scene`] of three layers of closed cubic Bézier paths.
//!
//! The renderer, the SVG writer, the JSON form and the editor all read and write this type;
//! there is no parallel representation. Coordinates are in working-canvas pixels
//! (x right, y down; pixel (i, j) covers [i, i+1) × [j, j+1)). Colours are sRGB-encoded values,
//! nominally in [0, 1], composited without gamma conversion, as browsers do.

use serde::{Deserialize, Serialize};

/// A point in canvas pixels.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "service", derive(utoipa::ToSchema))]
pub struct Point {
    /// Rightwards from the canvas's left edge.
    pub x: f32,
    /// Downwards from the canvas's top edge.
    pub y: f32,
}

impl Point {
    /// The point `(x, y)`.
    pub const fn new(x: f32, y: f32) -> Self {
        Self { x, y }
    }
}

/// A closed path of cubic Bézier segments with a flat fill, filled with the non-zero rule.
///
/// `points` holds 3 points per segment: `[P0, C0a, C0b, P1, C1a, C1b, …]`; segment `k` runs
/// `P_k → C_k,a → C_k,b → P_(k+1 mod n)`, so the last segment ends at `P0`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Path {
    /// Control points, 3 per segment (see above).
    pub points: Vec<Point>,
    /// Fill colour, sRGB-encoded. The optimiser may let illumination colours exceed 1; files
    /// always hold them clamped to [0, 1].
    pub color: [f32; 3],
    /// Fill opacity in [0, 1].
    pub opacity: f32,
}

impl Path {
    /// A path from a closed polygon: each edge becomes a straight cubic with its control points
    /// at 1/3 and 2/3 of the edge. `None` for fewer than 2 vertices.
    pub fn from_polygon(vertices: &[Point], color: [f32; 3], opacity: f32) -> Option<Self> {
        if vertices.len() < 2 {
            return None;
        }
        let mut points = Vec::with_capacity(vertices.len() * 3);
        for (i, &a) in vertices.iter().enumerate() {
            let b = vertices[(i + 1) % vertices.len()];
            points.push(a);
            points.push(Point::new(a.x + (b.x - a.x) / 3.0, a.y + (b.y - a.y) / 3.0));
            points.push(Point::new(
                a.x + 2.0 * (b.x - a.x) / 3.0,
                a.y + 2.0 * (b.y - a.y) / 3.0,
            ));
        }
        Some(Self {
            points,
            color,
            opacity,
        })
    }

    /// A rectangle covering `[x0, x1] × [y0, y1]`.
    pub fn rect(x0: f32, y0: f32, x1: f32, y1: f32, color: [f32; 3], opacity: f32) -> Self {
        let corners = [
            Point::new(x0, y0),
            Point::new(x1, y0),
            Point::new(x1, y1),
            Point::new(x0, y1),
        ];
        Self::from_polygon(&corners, color, opacity).expect("four corners")
    }

    /// Number of cubic segments.
    pub fn segment_count(&self) -> usize {
        self.points.len() / 3
    }

    /// The four control points of segment `k`.
    pub fn segment(&self, k: usize) -> [Point; 4] {
        let n = self.points.len();
        [
            self.points[3 * k],
            self.points[3 * k + 1],
            self.points[3 * k + 2],
            self.points[(3 * k + 3) % n],
        ]
    }
}

/// Which of the three layers, which fixes its base colour and its blend mode in SVG.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LayerKind {
    /// Surface colour, composited normally; opaque full-canvas base path first.
    Albedo,
    /// Attenuation, multiplied onto the albedo (`mix-blend-mode: multiply`).
    Shade,
    /// Additive light (`mix-blend-mode: plus-lighter`).
    Light,
}

impl LayerKind {
    /// The layers in compositing order.
    pub const ALL: [LayerKind; 3] = [LayerKind::Albedo, LayerKind::Shade, LayerKind::Light];

    /// The colour the layer's paths are composited onto: white for albedo and shade (the
    /// neutral element of multiply), black for light (the neutral element of addition).
    pub fn base(self) -> [f32; 3] {
        match self {
            LayerKind::Albedo | LayerKind::Shade => [1.0; 3],
            LayerKind::Light => [0.0; 3],
        }
    }

    /// `albedo`, `shade` or `light`: the SVG group id and file name.
    pub fn name(self) -> &'static str {
        match self {
            LayerKind::Albedo => "albedo",
            LayerKind::Shade => "shade",
            LayerKind::Light => "light",
        }
    }

    /// The layer named `name`, if any.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == name)
    }
}

/// An ordered list of paths, painted back to front over the layer's base colour.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Layer {
    /// Back to front.
    pub paths: Vec<Path>,
}

/// A layered vector image: shown as `clamp01(R(albedo) · R(shade) + R(light))`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Scene {
    /// Working canvas size in pixels: the coordinate system of every path (the SVG `viewBox`).
    pub width: u32,
    /// Working canvas height in pixels.
    pub height: u32,
    /// Size of the original image, written as the SVG's `width` and `height`.
    pub original_width: u32,
    /// Height of the original image.
    pub original_height: u32,
    /// Surface colour; its first path is an opaque full-canvas base.
    pub albedo: Layer,
    /// Shading, multiplied onto the albedo (`mix-blend-mode: multiply`).
    pub shade: Layer,
    /// Highlights, added on top (`mix-blend-mode: plus-lighter`).
    pub light: Layer,
}

impl Scene {
    /// An empty scene of the given working and original sizes.
    pub fn new(width: u32, height: u32, original_width: u32, original_height: u32) -> Self {
        Self {
            width,
            height,
            original_width,
            original_height,
            albedo: Layer::default(),
            shade: Layer::default(),
            light: Layer::default(),
        }
    }

    /// The layer of `kind`.
    pub fn layer(&self, kind: LayerKind) -> &Layer {
        match kind {
            LayerKind::Albedo => &self.albedo,
            LayerKind::Shade => &self.shade,
            LayerKind::Light => &self.light,
        }
    }

    /// The layer of `kind`, to change.
    pub fn layer_mut(&mut self, kind: LayerKind) -> &mut Layer {
        match kind {
            LayerKind::Albedo => &mut self.albedo,
            LayerKind::Shade => &mut self.shade,
            LayerKind::Light => &mut self.light,
        }
    }

    /// Total number of paths over all layers.
    pub fn path_count(&self) -> usize {
        LayerKind::ALL
            .iter()
            .map(|&k| self.layer(k).paths.len())
            .sum()
    }

    /// Total number of cubic segments over all layers.
    pub fn segment_count(&self) -> usize {
        LayerKind::ALL
            .iter()
            .flat_map(|&k| &self.layer(k).paths)
            .map(Path::segment_count)
            .sum()
    }

    /// A copy on a `width × height` canvas with every point multiplied by `factor`; colours,
    /// opacities and the original size are kept.
    pub fn rescaled(&self, factor: f32, width: u32, height: u32) -> Scene {
        let mut out = self.clone();
        out.width = width;
        out.height = height;
        for kind in LayerKind::ALL {
            for path in &mut out.layer_mut(kind).paths {
                for p in &mut path.points {
                    p.x *= factor;
                    p.y *= factor;
                }
            }
        }
        out
    }

    /// Looks a path up by its id (see [`PathId`]).
    pub fn path(&self, id: PathId) -> Option<&Path> {
        self.layer(id.layer).paths.get(id.index)
    }

    /// Looks a path up by its id, to change it.
    pub fn path_mut(&mut self, id: PathId) -> Option<&mut Path> {
        self.layer_mut(id.layer).paths.get_mut(id.index)
    }
}

/// A path's stable name within a scene: `albedo-3`, `shade-0`, `light-12` (layer and paint
/// order). It is the `id` attribute in the SVG and the key the editor takes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct PathId {
    /// The path's layer.
    pub layer: LayerKind,
    /// Its position in the layer's paint order.
    pub index: usize,
}

impl std::fmt::Display for PathId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}-{}", self.layer.name(), self.index)
    }
}

impl std::str::FromStr for PathId {
    type Err = ();

    fn from_str(s: &str) -> Result<Self, ()> {
        let (layer, index) = s.rsplit_once('-').ok_or(())?;
        let layer = LayerKind::from_name(layer).ok_or(())?;
        let index = index.parse().map_err(|_| ())?;
        Ok(Self { layer, index })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn path_ids_round_trip() {
        let id: PathId = "shade-12".parse().unwrap();
        assert_eq!(
            id,
            PathId {
                layer: LayerKind::Shade,
                index: 12
            }
        );
        assert_eq!(id.to_string(), "shade-12");
        assert!("halo-1".parse::<PathId>().is_err());
        assert!("albedo-x".parse::<PathId>().is_err());
    }

    #[test]
    fn polygon_edges_become_straight_cubics() {
        let p = Path::rect(0.0, 0.0, 3.0, 6.0, [1.0; 3], 1.0);
        assert_eq!(p.segment_count(), 4);
        assert_eq!(
            p.segment(0),
            [
                Point::new(0.0, 0.0),
                Point::new(1.0, 0.0),
                Point::new(2.0, 0.0),
                Point::new(3.0, 0.0)
            ]
        );
        assert_eq!(p.segment(3)[3], Point::new(0.0, 0.0));
    }
}
