//! The SVG writer: one layered SVG whose blend modes show `clamp01(albedo · shade + light)`,
//! and standalone per-layer SVGs.
//!
//! Rules, so that browsers show what covec's renderer optimised: blend modes in `style`
//! (browsers and resvg ignore the attribute form), `isolation:isolate` on the root, colours and
//! opacities clamped to [0, 1], explicit `fill-rule="nonzero"`, paths closed with `Z`. Each
//! layer's group is an Inkscape layer with a `<title>`. Output depends only on the scene, so
//! equal scenes give byte-identical files.

use std::fmt::Write;

use crate::opaque::{self, Region};
use crate::scene::{LayerKind, Path, PathId, Point, Scene};

/// Formatting choices.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SvgOptions {
    /// Decimals of coordinates (0-6). Default `None`: 1 up to a working long side of 1024 px,
    /// 2 above.
    pub precision: Option<u32>,
}

/// Most decimals [`SvgOptions::precision`] takes: an f32 coordinate holds about 7 significant
/// digits, so more would only print noise.
pub const MAX_PRECISION: u32 = 6;

impl SvgOptions {
    /// The decimals of `scene`'s coordinates: the set precision (at most [`MAX_PRECISION`]) or
    /// the default for its size.
    pub fn decimals(&self, scene: &Scene) -> u32 {
        self.precision
            .unwrap_or_else(|| default_decimals(scene.width.max(scene.height)))
            .min(MAX_PRECISION)
    }
}

/// [`SvgOptions::precision`]'s default. One decimal moves a point by at most 0.05 px (1/20 000
/// of a 1024 px canvas), half the renderer's flattening tolerance; the second decimal keeps that
/// relative bound on larger canvases.
fn default_decimals(long_side: u32) -> u32 {
    if long_side <= 1024 { 1 } else { 2 }
}

/// The layered SVG: `width`/`height` the original size, `viewBox` the working canvas.
pub fn to_svg(scene: &Scene, options: &SvgOptions) -> String {
    let mut out = header(scene);
    for kind in LayerKind::ALL {
        let blend = match kind {
            LayerKind::Albedo => "",
            LayerKind::Shade => " style=\"mix-blend-mode:multiply\"",
            LayerKind::Light => " style=\"mix-blend-mode:plus-lighter\"",
        };
        open_group(&mut out, kind, blend);
        write_paths(&mut out, scene, kind, options);
        out.push_str("</g>\n");
    }
    out.push_str("</svg>\n");
    out
}

/// One layer alone, as the model renders it: its paths over the layer's base colour (white
/// for albedo and shade, black for light), with normal blending.
pub fn layer_to_svg(scene: &Scene, kind: LayerKind, options: &SvgOptions) -> String {
    let mut out = header(scene);
    let _ = writeln!(
        out,
        "<rect id=\"{}-base\" width=\"{}\" height=\"{}\" fill=\"{}\"/>",
        kind.name(),
        scene.width,
        scene.height,
        hex_colour(kind.base())
    );
    open_group(&mut out, kind, "");
    write_paths(&mut out, scene, kind, options);
    out.push_str("</g>\n</svg>\n");
    out
}

/// The flattened SVG: the same picture as [`to_svg`] as plain opaque paths in painter's order
/// ([`opaque::regions`]), with no blend mode, opacity, filter or image, for programs that lack
/// `multiply` or `plus-lighter`.
pub fn to_flat_svg(scene: &Scene, options: &SvgOptions) -> String {
    let decimals = options.decimals(scene);
    let mut out = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{}\" height=\"{}\" viewBox=\"0 0 {} {}\">\n<title>covec, flattened: albedo × shade + light as opaque regions</title>\n",
        scene.original_width, scene.original_height, scene.width, scene.height
    );
    for region in opaque::regions(scene) {
        let data = polygon_data(&region, decimals);
        if !data.is_empty() {
            let _ = writeln!(
                out,
                "<path fill=\"{}\" d=\"{data}\"/>",
                hex_colour(region.color)
            );
        }
    }
    out.push_str("</svg>\n");
    out
}

fn header(scene: &Scene) -> String {
    format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" xmlns:inkscape=\"{INKSCAPE_NS}\" width=\"{}\" height=\"{}\" viewBox=\"0 0 {} {}\" style=\"isolation:isolate\">\n",
        scene.original_width, scene.original_height, scene.width, scene.height
    )
}

/// Inkscape's namespace, for its layer attributes.
const INKSCAPE_NS: &str = "http://www.inkscape.org/namespaces/inkscape";

/// `<g>` of a layer's paths, with `attributes` (e.g. its blend mode). Marked as an Inkscape layer
/// and titled, so design tools list the three layers by name instead of as anonymous groups.
fn open_group(out: &mut String, kind: LayerKind, attributes: &str) {
    let title = match kind {
        LayerKind::Albedo => "albedo (surface colour)",
        LayerKind::Shade => "shade (multiplies the albedo)",
        LayerKind::Light => "light (added to albedo × shade)",
    };
    let name = kind.name();
    let _ = writeln!(
        out,
        "<g id=\"{name}\" inkscape:groupmode=\"layer\" inkscape:label=\"{name}\"{attributes}>\n<title>{title}</title>"
    );
}

fn write_paths(out: &mut String, scene: &Scene, kind: LayerKind, options: &SvgOptions) {
    let decimals = options.decimals(scene);
    for (index, path) in scene.layer(kind).paths.iter().enumerate() {
        let id = PathId { layer: kind, index };
        let _ = writeln!(
            out,
            "<path id=\"{id}\" fill=\"{}\" fill-opacity=\"{}\" fill-rule=\"nonzero\" d=\"{}\"/>",
            hex_colour(path.color),
            number(path.opacity.clamp(0.0, 1.0), 3),
            path_data(path, decimals)
        );
    }
}

/// Compact path data: `M` to the first point, one cubic per segment (the last ending at the
/// first point) and `Z`. Each cubic is written absolute (`C`) or relative (`c`), whichever is
/// shorter, without repeating an unchanged command letter or writing separators a parser does
/// not need (`M1.5 2c.3-.4…`). Relative offsets are taken between the rounded points, so
/// rounding errors never accumulate along a path.
pub fn path_data(path: &Path, decimals: u32) -> String {
    let n = path.segment_count();
    if n == 0 {
        return String::new();
    }
    let scale = 10f64.powi(decimals as i32);
    let fixed = |p: Point| [p.x, p.y].map(|v| quantize(v, scale));
    let mut data = PathData::default();
    let mut current = fixed(path.points[0]);
    data.command('M');
    data.numbers(&current, decimals);
    for k in 0..n {
        let [_, a, b, end] = path.segment(k).map(fixed);
        let absolute = [a, b, end].concat();
        let relative: Vec<i64> = absolute
            .iter()
            .enumerate()
            .map(|(i, &v)| v - current[i % 2])
            .collect();
        data.append_shorter(('C', &absolute), ('c', &relative), decimals);
        current = end;
    }
    data.command('Z');
    data.text
}

/// Compact path data of a region's polygons: per contour `M`, lines absolute (`L`) or relative
/// (`l`), whichever is shorter, and `Z`; vertices that round onto the previous one are dropped,
/// and so are contours left with fewer than 3.
fn polygon_data(region: &Region, decimals: u32) -> String {
    let scale = 10f64.powi(decimals as i32);
    let mut data = PathData::default();
    for contour in &region.contours {
        let mut vertices: Vec<[i64; 2]> = Vec::with_capacity(contour.len());
        for p in contour {
            let v = [p.x, p.y].map(|c| quantize(c, scale));
            if vertices.last() != Some(&v) {
                vertices.push(v);
            }
        }
        while vertices.len() > 1 && vertices.first() == vertices.last() {
            vertices.pop();
        }
        if vertices.len() < 3 {
            continue;
        }
        data.command('M');
        data.numbers(&vertices[0], decimals);
        let mut current = vertices[0];
        for &v in &vertices[1..] {
            let relative = [v[0] - current[0], v[1] - current[1]];
            data.append_shorter(('L', &v), ('l', &relative), decimals);
            current = v;
        }
        data.command('Z');
    }
    data.text
}

/// A coordinate as an integer number of `1/scale` units. Clamped to ±10¹⁸ units (far beyond
/// any canvas) so that differences of two of them cannot overflow; non-finite values are 0.
fn quantize(v: f32, scale: f64) -> i64 {
    if !v.is_finite() {
        return 0;
    }
    (f64::from(v) * scale).round().clamp(-1e18, 1e18) as i64
}

/// Path data being written, and what decides the separators the next token needs.
#[derive(Default)]
struct PathData {
    text: String,
    /// The last command letter written (implicitly repeated by further numbers).
    command: Option<char>,
    /// What the text ends with: `None` after a command letter, else whether the last number
    /// holds a decimal point (then a following `.5` needs no separator).
    last_number_has_dot: Option<bool>,
}

impl PathData {
    /// An empty continuation of `self`: same state, no text (to measure alternatives).
    fn continuation(&self) -> Self {
        Self {
            text: String::new(),
            command: self.command,
            last_number_has_dot: self.last_number_has_dot,
        }
    }

    /// Appends the shorter of one command in its absolute and relative forms (relative on a
    /// tie).
    fn append_shorter(
        &mut self,
        absolute: (char, &[i64]),
        relative: (char, &[i64]),
        decimals: u32,
    ) {
        let [abs, rel] = [absolute, relative].map(|(command, values)| {
            let mut candidate = self.continuation();
            candidate.command(command);
            candidate.numbers(values, decimals);
            candidate
        });
        self.append(if rel.text.len() <= abs.text.len() {
            rel
        } else {
            abs
        });
    }

    /// Appends a continuation made by [`PathData::continuation`].
    fn append(&mut self, next: PathData) {
        self.text.push_str(&next.text);
        self.command = next.command;
        self.last_number_has_dot = next.last_number_has_dot;
    }

    /// Writes `command` unless it is the current one (numbers repeat it implicitly).
    fn command(&mut self, command: char) {
        if self.command != Some(command) {
            self.text.push(command);
            self.command = Some(command);
            self.last_number_has_dot = None;
        }
    }

    fn numbers(&mut self, values: &[i64], decimals: u32) {
        for &v in values {
            let number = fixed_point(v, decimals);
            let joins = match self.last_number_has_dot {
                None => true,
                Some(dot) => number.starts_with('-') || (dot && number.starts_with('.')),
            };
            if !joins {
                self.text.push(' ');
            }
            self.last_number_has_dot = Some(number.contains('.'));
            self.text.push_str(&number);
        }
    }
}

/// `units / 10^decimals` written shortest: no trailing zeros, no leading zero before the point
/// (`-.5`), no `-0`.
fn fixed_point(units: i64, decimals: u32) -> String {
    let scale = 10u64.pow(decimals);
    let (whole, fraction) = (units.unsigned_abs() / scale, units.unsigned_abs() % scale);
    let mut s = String::new();
    if units < 0 {
        s.push('-');
    }
    if whole != 0 || fraction == 0 {
        let _ = write!(s, "{whole}");
    }
    if fraction != 0 {
        let digits = format!("{fraction:0width$}", width = decimals as usize);
        s.push('.');
        s.push_str(digits.trim_end_matches('0'));
    }
    s
}

/// `#rrggbb` of a colour clamped to [0, 1].
pub fn hex_colour(colour: [f32; 3]) -> String {
    let [r, g, b] = colour.map(|c| (c.clamp(0.0, 1.0) * 255.0).round() as u8);
    format!("#{r:02x}{g:02x}{b:02x}")
}

/// The colour of `#rrggbb` (case-insensitive), or `None`.
pub fn parse_hex_colour(text: &str) -> Option<[f32; 3]> {
    let hex = text.strip_prefix('#')?;
    if hex.len() != 6 || !hex.bytes().all(|b| b.is_ascii_hexdigit()) {
        return None;
    }
    let channel = |i: usize| {
        u8::from_str_radix(&hex[i..i + 2], 16)
            .ok()
            .map(|v| f32::from(v) / 255.0)
    };
    Some([channel(0)?, channel(2)?, channel(4)?])
}

/// A number with at most `decimals` decimals, written as [`fixed_point`] does.
fn number(v: f32, decimals: u32) -> String {
    fixed_point(quantize(v, 10f64.powi(decimals as i32)), decimals)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_are_short_and_never_negative_zero() {
        assert_eq!(number(1.0, 2), "1");
        assert_eq!(number(1.256, 2), "1.26");
        assert_eq!(number(-0.001, 2), "0");
        assert_eq!(number(-0.04, 1), "0");
        assert_eq!(number(2.50, 2), "2.5");
        assert_eq!(number(0.5, 1), ".5");
        assert_eq!(number(-0.25, 2), "-.25");
        assert_eq!(number(-12.05, 1), "-12.1");
        assert_eq!(number(0.8, 3), ".8");
        assert_eq!(number(7.0, 0), "7");
        assert_eq!(number(f32::NAN, 1), "0");
        assert_eq!(hex_colour([1.2, -0.1, 0.5]), "#ff0080");
    }

    #[test]
    fn path_data_is_compact_and_exact() {
        // Absolute start, relative cubics where shorter, an unchanged command not repeated, a
        // separator only where the next number would otherwise run into the last.
        let path = Path {
            points: vec![
                Point::new(1.5, 2.0),
                Point::new(1.8, 1.6),
                Point::new(2.04, 1.0),
                Point::new(3.0, 1.0),
                Point::new(3.0, 2.3),
                Point::new(1.5, 2.3),
            ],
            color: [0.0; 3],
            opacity: 1.0,
        };
        assert_eq!(
            path_data(&path, 1),
            "M1.5 2c.3-.4.5-1 1.5-1 0 1.3-1.5 1.3-1.5 1Z"
        );
        // Far from the origin relative offsets are shorter; near it, absolute ones.
        let far = Path::rect(500.25, 600.0, 510.75, 610.0, [0.0; 3], 1.0);
        assert_eq!(
            path_data(&far, 2),
            "M500.25 600c3.5 0 7 0 10.5 0 0 3.33 0 6.67 0 10-3.5 0-7 0-10.5 0 0-3.33 0-6.67 0-10Z"
        );
        let near = Path {
            points: [
                (9.9, 9.9),
                (1.0, 1.0),
                (1.0, 2.0),
                (2.0, 2.0),
                (5.0, 5.0),
                (9.0, 9.0),
            ]
            .map(|(x, y)| Point::new(x, y))
            .to_vec(),
            ..path
        };
        assert_eq!(path_data(&near, 1), "M9.9 9.9C1 1 1 2 2 2c3 3 7 7 7.9 7.9Z");
        assert_eq!(
            path_data(
                &Path {
                    points: vec![],
                    ..near
                },
                1
            ),
            ""
        );
    }

    #[test]
    fn precision_follows_the_working_size_unless_set() {
        let options = SvgOptions::default();
        assert_eq!(options.decimals(&Scene::new(1024, 512, 4000, 2000)), 1);
        assert_eq!(options.decimals(&Scene::new(600, 1025, 600, 1025)), 2);
        let set = SvgOptions { precision: Some(9) };
        assert_eq!(set.decimals(&Scene::new(64, 64, 64, 64)), MAX_PRECISION);
    }
}
