//! The SVG writer: one layered SVG whose blend modes show `clamp01(albedo · shade + light)`,
//! and standalone per-layer SVGs.
//!
//! Rules, so that browsers show what covec's renderer optimised: blend modes in `style`
//! (browsers and resvg ignore the attribute form), `isolation:isolate` on the root, colours and opacities clamped to [0, 1],
//! explicit `fill-rule="nonzero"`, paths closed with `Z`. Output depends only on the scene, so
//! equal scenes give byte-identical files.

use std::fmt::Write;

use crate::scene::{LayerKind, Path, PathId, Scene};

/// Formatting choices.
#[derive(Clone, Debug, PartialEq)]
pub struct SvgOptions {
    /// Decimals of coordinates. Default 2.
    pub decimals: usize,
}

impl Default for SvgOptions {
    fn default() -> Self {
        Self { decimals: 2 }
    }
}

/// The layered SVG: `width`/`height` the original size, `viewBox` the working canvas.
pub fn to_svg(scene: &Scene, options: &SvgOptions) -> String {
    let mut out = header(scene);
    for kind in LayerKind::ALL {
        let blend = match kind {
            LayerKind::Albedo => String::new(),
            LayerKind::Shade => " style=\"mix-blend-mode:multiply\"".into(),
            LayerKind::Light => " style=\"mix-blend-mode:plus-lighter\"".into(),
        };
        let _ = writeln!(out, "<g id=\"{}\"{blend}>", kind.name());
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
    let _ = writeln!(out, "<g id=\"{}\">", kind.name());
    write_paths(&mut out, scene, kind, options);
    out.push_str("</g>\n</svg>\n");
    out
}

fn header(scene: &Scene) -> String {
    format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{}\" height=\"{}\" viewBox=\"0 0 {} {}\" style=\"isolation:isolate\">\n",
        scene.original_width, scene.original_height, scene.width, scene.height
    )
}

fn write_paths(out: &mut String, scene: &Scene, kind: LayerKind, options: &SvgOptions) {
    for (index, path) in scene.layer(kind).paths.iter().enumerate() {
        let id = PathId { layer: kind, index };
        let _ = writeln!(
            out,
            "<path id=\"{id}\" fill=\"{}\" fill-opacity=\"{}\" fill-rule=\"nonzero\" d=\"{}\"/>",
            hex_colour(path.color),
            number(path.opacity.clamp(0.0, 1.0), 3),
            path_data(path, options.decimals)
        );
    }
}

/// `M x y C … Z`: one `C` per cubic segment, the last one ending at the start point.
pub fn path_data(path: &Path, decimals: usize) -> String {
    let mut d = String::new();
    let n = path.segment_count();
    if n == 0 {
        return d;
    }
    let p = |d: &mut String, point: crate::scene::Point| {
        let _ = write!(
            d,
            "{} {}",
            number(point.x, decimals),
            number(point.y, decimals)
        );
    };
    d.push('M');
    p(&mut d, path.points[0]);
    for k in 0..n {
        let [_, a, b, end] = path.segment(k);
        d.push('C');
        p(&mut d, a);
        d.push(' ');
        p(&mut d, b);
        d.push(' ');
        p(&mut d, end);
    }
    d.push('Z');
    d
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

/// A number with at most `decimals` decimals, trailing zeros dropped, no `-0`.
fn number(v: f32, decimals: usize) -> String {
    let v = if v.is_finite() { v } else { 0.0 };
    let mut s = format!("{v:.decimals$}");
    if s.contains('.') {
        s.truncate(s.trim_end_matches('0').trim_end_matches('.').len());
    }
    if s == "-0" {
        s = "0".into();
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_are_short_and_never_negative_zero() {
        assert_eq!(number(1.0, 2), "1");
        assert_eq!(number(1.256, 2), "1.26");
        assert_eq!(number(-0.001, 2), "0");
        assert_eq!(number(2.50, 2), "2.5");
        assert_eq!(hex_colour([1.2, -0.1, 0.5]), "#ff0080");
    }
}
