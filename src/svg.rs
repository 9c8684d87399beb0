//! The SVG writer: one layered SVG whose blend modes show `clamp01(albedo · shade + light)`,
//! and standalone per-layer SVGs.
//!
//! Rules, so that browsers show what covec's renderer optimised: blend modes in `style`
//! (browsers and resvg ignore the attribute form), `isolation:isolate` on the root, colours and
//! opacities clamped to [0, 1], explicit `fill-rule="nonzero"`, paths closed with `Z`. Each
//! layer's group is an Inkscape layer with a `<title>`; its paths' coordinates are whole units
//! of a grid ([`SvgOptions::units_per_pixel`]) that the group scales back to the `viewBox`, the
//! working canvas in pixels. Output depends only on the scene, so
//! equal scenes give byte-identical files.

use std::fmt::Write;

use crate::opaque::{self, Region};
use crate::scene::{LayerKind, Path, PathId, Point, Scene};

/// Formatting choices.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SvgOptions {
    /// Decimals of coordinates in working-canvas pixels (0-6). Default `None`: a quarter-pixel
    /// grid ([`DEFAULT_UNITS_PER_PIXEL`]), a tenth in the flattened SVG.
    pub precision: Option<u32>,
}

/// Most decimals [`SvgOptions::precision`] takes: an f32 coordinate holds about 7 significant
/// digits, so more would only print noise.
pub const MAX_PRECISION: u32 = 6;

/// The default grid, in units per pixel: a quarter pixel makes the files smaller than a finer
/// grid at almost the same error, where half a pixel costs more (docs/history.md, "SVG
/// output").
pub const DEFAULT_UNITS_PER_PIXEL: u32 = 4;

/// The flattened SVG's default grid, a tenth of a pixel: its polygons follow curves with many
/// short edges, which a quarter-pixel grid shifts visibly (on a 96 px photo, the mean difference
/// from the layered drawing in resvg grows from 1.43/255 to 1.68/255).
const FLAT_UNITS_PER_PIXEL: u32 = 10;

impl SvgOptions {
    /// Path-data units per pixel of the working canvas in the layered and per-layer SVGs:
    /// coordinates are written as whole units (shorter than decimals, and as many as a chosen
    /// grid needs) inside groups scaled back to pixels ([`grid_scale`]).
    pub fn units_per_pixel(&self) -> u32 {
        self.units_or(DEFAULT_UNITS_PER_PIXEL)
    }

    /// 10^precision, or `default` when none is set.
    fn units_or(&self, default: u32) -> u32 {
        self.precision
            .map_or(default, |p| 10u32.pow(p.min(MAX_PRECISION)))
    }
}

/// ` transform="scale(1/units)"`: the attribute that brings whole units back to pixels (none
/// for one unit per pixel).
fn grid_scale(units_per_pixel: u32) -> String {
    if units_per_pixel == 1 {
        return String::new();
    }
    let scale = number(1.0 / units_per_pixel as f32, MAX_PRECISION);
    format!(" transform=\"scale({scale})\"")
}

/// The layered SVG: `width`/`height` the original size, `viewBox` the working canvas.
pub fn to_svg(scene: &Scene, options: &SvgOptions) -> String {
    let mut out = header(scene);
    let scale = grid_scale(options.units_per_pixel());
    for kind in LayerKind::ALL {
        let blend = match kind {
            LayerKind::Albedo => "",
            LayerKind::Shade => " style=\"mix-blend-mode:multiply\"",
            LayerKind::Light => " style=\"mix-blend-mode:plus-lighter\"",
        };
        open_group(&mut out, kind, &format!("{scale}{blend}"));
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
    open_group(&mut out, kind, &grid_scale(options.units_per_pixel()));
    write_paths(&mut out, scene, kind, options);
    out.push_str("</g>\n</svg>\n");
    out
}

/// The flattened SVG: the same picture as [`to_svg`] as plain opaque paths in painter's order
/// ([`opaque::regions`]), with no blend mode, opacity, filter, image or group, for programs that
/// lack `multiply` or `plus-lighter`. Without a group to scale them, its whole grid units are
/// the `viewBox`'s: the working canvas measured in them.
pub fn to_flat_svg(scene: &Scene, options: &SvgOptions) -> String {
    let units = options.units_or(FLAT_UNITS_PER_PIXEL);
    let mut out = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{}\" height=\"{}\" viewBox=\"0 0 {} {}\">\n<title>covec, flattened: albedo × shade + light as opaque regions</title>\n",
        scene.original_width,
        scene.original_height,
        u64::from(scene.width) * u64::from(units),
        u64::from(scene.height) * u64::from(units)
    );
    for region in opaque::regions(scene) {
        let data = polygon_data(&region, units);
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
    let units = options.units_per_pixel();
    for (index, path) in scene.layer(kind).paths.iter().enumerate() {
        let id = PathId { layer: kind, index };
        let _ = writeln!(
            out,
            "<path id=\"{id}\" fill=\"{}\" fill-opacity=\"{}\" fill-rule=\"nonzero\" d=\"{}\"/>",
            hex_colour(path.color),
            number(path.opacity.clamp(0.0, 1.0), 3),
            path_data(path, units)
        );
    }
}

/// Compact path data in whole units (`units_per_pixel` to a pixel): `M` to the first point,
/// one cubic per segment (the last ending at the first point) and `Z`. Each cubic is written
/// absolute (`C`) or relative (`c`), whichever is shorter, without repeating an unchanged command
/// letter or writing separators a parser does not need (`M6 8c1-2…`). Relative offsets are taken
/// between the rounded points, so rounding errors never accumulate along a path.
pub fn path_data(path: &Path, units_per_pixel: u32) -> String {
    let n = path.segment_count();
    if n == 0 {
        return String::new();
    }
    let scale = f64::from(units_per_pixel);
    let fixed = |p: Point| [p.x, p.y].map(|v| quantize(v, scale));
    let mut data = PathData::default();
    let mut current = fixed(path.points[0]);
    data.command('M');
    data.numbers(&current);
    for k in 0..n {
        let [_, a, b, end] = path.segment(k).map(fixed);
        let absolute = [a, b, end].concat();
        let relative: Vec<i64> = absolute
            .iter()
            .enumerate()
            .map(|(i, &v)| v - current[i % 2])
            .collect();
        data.append_shorter(('C', &absolute), ('c', &relative));
        current = end;
    }
    data.command('Z');
    data.text
}

/// Compact path data of a region's polygons, in whole units as [`path_data`]: per contour `M`,
/// lines absolute (`L`) or relative (`l`), whichever is shorter, and `Z`; vertices that round
/// onto the previous one are dropped, and so are contours left with fewer than 3.
fn polygon_data(region: &Region, units_per_pixel: u32) -> String {
    let scale = f64::from(units_per_pixel);
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
        data.numbers(&vertices[0]);
        let mut current = vertices[0];
        for &v in &vertices[1..] {
            let relative = [v[0] - current[0], v[1] - current[1]];
            data.append_shorter(('L', &v), ('l', &relative));
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
    /// Whether the text ends with a number (then a following one needs a space unless it
    /// starts with its sign).
    after_number: bool,
}

impl PathData {
    /// An empty continuation of `self`: same state, no text (to measure alternatives).
    fn continuation(&self) -> Self {
        Self {
            text: String::new(),
            command: self.command,
            after_number: self.after_number,
        }
    }

    /// Appends the shorter of one command in its absolute and relative forms (relative on a
    /// tie).
    fn append_shorter(&mut self, absolute: (char, &[i64]), relative: (char, &[i64])) {
        let [abs, rel] = [absolute, relative].map(|(command, values)| {
            let mut candidate = self.continuation();
            candidate.command(command);
            candidate.numbers(values);
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
        self.after_number = next.after_number;
    }

    /// Writes `command` unless it is the current one (numbers repeat it implicitly).
    fn command(&mut self, command: char) {
        if self.command != Some(command) {
            self.text.push(command);
            self.command = Some(command);
            self.after_number = false;
        }
    }

    fn numbers(&mut self, values: &[i64]) {
        for &v in values {
            if self.after_number && v >= 0 {
                self.text.push(' ');
            }
            let _ = write!(self.text, "{v}");
            self.after_number = true;
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
            path_data(&path, 10),
            "M15 20c3-4 5-10 15-10 0 13-15 13-15 10Z"
        );
        // Far from the origin relative offsets are shorter; near it, absolute ones.
        let far = Path::rect(500.25, 600.0, 510.75, 610.0, [0.0; 3], 1.0);
        assert_eq!(
            path_data(&far, 4),
            "M2001 2400c14 0 28 0 42 0 0 13 0 27 0 40-14 0-28 0-42 0 0-13 0-27 0-40Z"
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
        assert_eq!(
            path_data(&near, 10),
            "M99 99C10 10 10 20 20 20c30 30 70 70 79 79Z"
        );
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
    fn coordinates_are_whole_units_of_a_quarter_pixel_unless_set() {
        assert_eq!(SvgOptions::default().units_per_pixel(), 4);
        assert_eq!(grid_scale(4), " transform=\"scale(.25)\"");
        let set = |precision| SvgOptions {
            precision: Some(precision),
        };
        assert_eq!(set(0).units_per_pixel(), 1);
        assert_eq!(grid_scale(1), "");
        assert_eq!(set(1).units_per_pixel(), 10);
        assert_eq!(grid_scale(10), " transform=\"scale(.1)\"");
        assert_eq!(set(9).units_per_pixel(), 1_000_000);
        assert_eq!(grid_scale(1_000_000), " transform=\"scale(.000001)\"");
    }
}
