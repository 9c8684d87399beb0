//! What `auto` mode looks at: whether an image is flat artwork (emoji, logos, icons,
//! screenshots: flat fills, crisp anti-aliased edges, drawn gradients) or has the shading or
//! photographic texture the photo mode's shade and light layers are for.
//!
//! The evidence comes from the part of the image that is *not* flat, however much flat
//! background surrounds it, so that a lit object on a plain backdrop or a product photo on a
//! clipped white background reads as what the object is:
//! 1. **Flat part.** A pixel is flat when its 3×3 neighbourhood holds one exact 8-bit colour;
//!    the flat part is those pixels grown by [`EDGE_RADIUS`], so the anti-aliased edges of flat
//!    shapes belong to it. The rest is the non-flat part.
//! 2. **Little non-flat part** (under [`MIN_NON_FLAT`]): flat artwork.
//! 3. **Texture.** Sensor noise, render noise, compression and the soft, uneven shading of
//!    rendered objects leave a residual that a flat fill or a drawn (linear or radial) gradient
//!    does not: Immerkaer's noise-estimation mask (which cancels any local plane) on a
//!    half-size copy (2 × 2 means, which also halves an 8-bit ramp's quantisation steps), per
//!    channel on the 0-255 scale, away from edges (within [`EDGE_RADIUS`] of a luma gradient
//!    of [`EDGE_GRADIENT`]: anti-aliasing and a resampler's ringing). When over
//!    [`NOISY_RESIDUAL`] on at least [`TEXTURE_SHARE`] of the smooth non-flat pixels: photo;
//!    so too when the image is mostly non-flat (at least [`PHOTO_NON_FLAT`]) with a little
//!    texture ([`MIN_PHOTO_TEXTURE`]): a photograph with smooth skies or walls.
//! 4. **Smooth shading.** Noise-free renders have no texture: the non-flat part is cut into
//!    regions of continuous chromaticity (neighbours within [`CHROMA_STEP`]), a lit object's
//!    body rather than its neighbour of another colour. A region mostly away from edges whose
//!    luminance spans [`SHADING_RANGE`] or more (2nd to 98th percentile), from lit to
//!    shadowed, is shading; shading over at least [`SHADING_SHARE`] of the non-flat part:
//!    photo. Drawn gradients span less; anti-aliased text spans more but is all edges.
//! 5. Otherwise flat artwork.
//!
//! The thresholds were chosen on the tuning half of the field set (`benches/field/`) and are
//! reported on its held-out half in docs/benchmarks.md ("How `auto` chooses").

use crate::render::Image;

/// Long side (pixels) of the image `auto` looks at: the input's own pixels up to this size.
pub const ANALYSIS_SIZE: u32 = 1024;
/// How far (pixels) the flat part reaches past its exactly flat pixels, and an edge past its
/// steepest pixels: anti-aliasing, thin outlines of flat shapes, a resampler's ringing.
pub const EDGE_RADIUS: usize = 2;
/// Under this share of non-flat pixels an image is flat artwork: too little to measure. A small
/// shaded object on a wide flat backdrop is more.
pub const MIN_NON_FLAT: f32 = 0.02;
/// From this share of non-flat pixels, a little texture ([`MIN_PHOTO_TEXTURE`]) makes a
/// photograph: drawn artwork keeps flat fills, or fills the frame with a textureless gradient.
pub const PHOTO_NON_FLAT: f32 = 0.7;
/// Texture share enough for a mostly non-flat image: midway between drawn gradients' most
/// (a twentieth) and photographs' least (a fifth, a brick wall).
pub const MIN_PHOTO_TEXTURE: f32 = 0.12;
/// Immerkaer residual (0-255 scale, largest channel, on the half-size copy) above which a
/// pixel counts as textured; a drawn gradient leaves about 1, its quantisation included.
pub const NOISY_RESIDUAL: f32 = 3.0;
/// Luma gradient (0-255 scale per pixel of the input, central differences) under which a
/// non-flat pixel is smooth: where texture and shading are looked for, away from edges.
pub const SMOOTH_GRADIENT: f32 = 4.0;
/// Luma gradient (as [`SMOOTH_GRADIENT`]) from which a pixel is on an edge: a step of a
/// fifth of the range within a pixel or two. Shading changes more slowly, even on a small sphere.
pub const EDGE_GRADIENT: f32 = 24.0;
/// Share of textured pixels among the smooth non-flat ones that makes an image photographic:
/// midway between drawn artwork's most (a fifth, a gradient-shaded emoji) and shaded 3D
/// artwork's least (two fifths).
pub const TEXTURE_SHARE: f32 = 0.3;
/// Fewer smooth non-flat pixels than this share of the image show no texture either way: what
/// is not flat is edges and fine detail.
const MIN_SMOOTH: f32 = 0.01;
/// Largest chromaticity step (radians) between neighbours of one shading region.
pub const CHROMA_STEP: f32 = 3.0 * std::f32::consts::PI / 180.0;
/// Luminance span (98th over 2nd percentile, offset by [`LUMA_OFFSET`]) from which a region
/// is shading, a lit surface against its own shadowed side: midway (geometrically) between
/// drawn gradients' widest (2.2) and noise-free renders' narrowest (4.4).
pub const SHADING_RANGE: f32 = 3.0;
/// Offset on the 0-255 luma scale against the ratio's blowing up in the dark.
pub const LUMA_OFFSET: f32 = 8.0;
/// Share of the non-flat part that shading regions must cover for the image to count as shaded.
pub const SHADING_SHARE: f32 = 0.5;
/// Regions under this share of the image are not weighed as shading.
const MIN_REGION: f32 = 0.005;

/// What the image shows, for `auto` mode.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Look {
    /// Flat fills and gentle gradients: the albedo-only variant.
    Artwork(Evidence),
    /// Smooth shading or photographic texture: the three-layer method.
    Photographic(Evidence),
}

/// The measurements behind a [`Look`], all shares in [0, 1].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Evidence {
    /// Share of the image outside the flat part.
    pub non_flat: f32,
    /// Share of the smooth non-flat pixels that is textured (`None`: not measured, or too few
    /// smooth non-flat pixels to tell).
    pub texture: Option<f32>,
    /// Share of the non-flat part covered by shading regions (`None`: not measured).
    pub shading: Option<f32>,
}

impl Look {
    /// The evidence either way.
    pub fn evidence(&self) -> Evidence {
        match *self {
            Look::Artwork(e) | Look::Photographic(e) => e,
        }
    }

    /// One sentence saying why, for logs and job records.
    pub fn reason(&self) -> String {
        let e = self.evidence();
        let pct = |v: f32| format!("{:.0}%", 100.0 * v);
        let smooth = |texture: Option<f32>| match texture {
            Some(t) => format!("{} of its smooth pixels are textured", pct(t)),
            None => "it is edges and fine detail, with hardly a smooth pixel".into(),
        };
        match (self, e.shading) {
            (Look::Artwork(_), _) if e.non_flat < MIN_NON_FLAT => format!(
                "flat artwork: flat colours cover all but {} of the image",
                pct(e.non_flat)
            ),
            (Look::Artwork(_), s) => format!(
                "flat artwork: in the {} of the image that is not flat, {}, and shading covers {} of it",
                pct(e.non_flat),
                smooth(e.texture),
                pct(s.unwrap_or(0.0))
            ),
            (Look::Photographic(_), None) => format!(
                "texture: in the {} of the image that is not flat, {}",
                pct(e.non_flat),
                smooth(e.texture)
            ),
            (Look::Photographic(_), Some(s)) => format!(
                "smooth shading: lit-to-shadowed regions cover {} of the {} of the image that is not flat",
                pct(s),
                pct(e.non_flat)
            ),
        }
    }
}

/// Looks at `image` (RGB in [0, 1]); see the module documentation.
pub fn look(image: &Image) -> Look {
    let (w, h) = (image.width, image.height);
    let n = w * h;
    if n == 0 {
        return Look::Artwork(Evidence {
            non_flat: 0.0,
            texture: None,
            shading: None,
        });
    }
    let rgb: Vec<[u8; 3]> = image
        .data
        .chunks_exact(3)
        .map(|px| [0, 1, 2].map(|c| (px[c].clamp(0.0, 1.0) * 255.0).round() as u8))
        .collect();
    let non_flat = non_flat_part(&rgb, w, h);
    let count = non_flat.iter().filter(|&&v| v).count();
    let share = count as f32 / n as f32;
    let mut evidence = Evidence {
        non_flat: share,
        texture: None,
        shading: None,
    };
    if share < MIN_NON_FLAT {
        return Look::Artwork(evidence);
    }
    let near_edge = near_edges(&rgb, w, h);
    let interior: Vec<bool> = (0..n).map(|i| non_flat[i] && !near_edge[i]).collect();
    let texture = texture_share(&rgb, &interior, w, h);
    evidence.texture = texture;
    let busy = share >= PHOTO_NON_FLAT && texture.is_none_or(|t| t >= MIN_PHOTO_TEXTURE);
    if busy || texture.is_some_and(|t| t >= TEXTURE_SHARE) {
        return Look::Photographic(evidence);
    }
    let shading = shading_cover(&rgb, &non_flat, &interior, w, h) / share;
    evidence.shading = Some(shading);
    if shading >= SHADING_SHARE {
        Look::Photographic(evidence)
    } else {
        Look::Artwork(evidence)
    }
}

/// Pixels farther than [`EDGE_RADIUS`] from every pixel whose 3×3 neighbourhood (clamped at
/// the borders) is one colour.
fn non_flat_part(rgb: &[[u8; 3]], w: usize, h: usize) -> Vec<bool> {
    let at = |x: usize, y: usize| rgb[y * w + x];
    let flat: Vec<bool> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let c = rgb[i];
            (y.saturating_sub(1)..=(y + 1).min(h - 1))
                .all(|yy| (x.saturating_sub(1)..=(x + 1).min(w - 1)).all(|xx| at(xx, yy) == c))
        })
        .collect();
    grow(&flat, w, h, EDGE_RADIUS).iter().map(|&v| !v).collect()
}

/// Pixels within [`EDGE_RADIUS`] of an edge (a luma gradient of [`EDGE_GRADIENT`] or more):
/// where anti-aliasing and a resampler's ringing lie, which neither texture nor shading is.
fn near_edges(rgb: &[[u8; 3]], w: usize, h: usize) -> Vec<bool> {
    let edges: Vec<bool> = (0..w * h)
        .map(|i| luma_gradient(rgb, w, h, i) >= EDGE_GRADIENT)
        .collect();
    grow(&edges, w, h, EDGE_RADIUS)
}

/// `mask` grown by `r` pixels in a square neighbourhood: rows, then columns.
fn grow(mask: &[bool], w: usize, h: usize, r: usize) -> Vec<bool> {
    let rows: Vec<bool> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            (x.saturating_sub(r)..=(x + r).min(w - 1)).any(|xx| mask[y * w + xx])
        })
        .collect();
    (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            (y.saturating_sub(r)..=(y + r).min(h - 1)).any(|yy| rows[yy * w + x])
        })
        .collect()
}

/// BT.601 luma on the 0-255 scale.
fn luma(px: [u8; 3]) -> f32 {
    0.299 * f32::from(px[0]) + 0.587 * f32::from(px[1]) + 0.114 * f32::from(px[2])
}

/// Share of the smooth pixels of the half-size copy (2 × 2 means; blocks wholly in `interior`,
/// the non-flat part away from edges) whose Immerkaer residual is over [`NOISY_RESIDUAL`];
/// `None` when fewer than [`MIN_SMOOTH`] of the image is such.
fn texture_share(rgb: &[[u8; 3]], interior: &[bool], w: usize, h: usize) -> Option<f32> {
    let (hw, hh) = (w / 2, h / 2);
    if hw < 3 || hh < 3 {
        return None;
    }
    let mut half = vec![[0f32; 3]; hw * hh];
    let mut inside = vec![false; hw * hh];
    for y in 0..hh {
        for x in 0..hw {
            let block =
                [(0, 0), (1, 0), (0, 1), (1, 1)].map(|(dx, dy)| (2 * y + dy) * w + 2 * x + dx);
            inside[y * hw + x] = block.iter().all(|&i| interior[i]);
            for c in 0..3 {
                half[y * hw + x][c] =
                    block.iter().map(|&i| f32::from(rgb[i][c])).sum::<f32>() / 4.0;
            }
        }
    }
    let luma = |px: [f32; 3]| 0.299 * px[0] + 0.587 * px[1] + 0.114 * px[2];
    let at = |x: usize, y: usize| half[y.min(hh - 1) * hw + x.min(hw - 1)];
    let (mut smooth, mut textured) = (0usize, 0usize);
    for y in 0..hh {
        for x in 0..hw {
            if !inside[y * hw + x] {
                continue;
            }
            // Central differences on the half-size grid, per pixel of the input.
            let gx = luma(at(x + 1, y)) - luma(at(x.saturating_sub(1), y));
            let gy = luma(at(x, y + 1)) - luma(at(x, y.saturating_sub(1)));
            if 0.25 * gx.hypot(gy) >= SMOOTH_GRADIENT {
                continue;
            }
            smooth += 1;
            // Immerkaer's mask [1 −2 1; −2 4 −2; 1 −2 1], borders clamped: zero on any plane.
            let mut sums = [0f32; 3];
            for (dy, wy) in [(0, 1.0), (1, -2.0), (2, 1.0)] {
                for (dx, wx) in [(0, 1.0), (1, -2.0), (2, 1.0)] {
                    let px = at((x + dx).saturating_sub(1), (y + dy).saturating_sub(1));
                    for c in 0..3 {
                        sums[c] += wy * wx * px[c];
                    }
                }
            }
            if sums.iter().any(|s| s.abs() > NOISY_RESIDUAL) {
                textured += 1;
            }
        }
    }
    ((smooth as f32) >= MIN_SMOOTH * (hw * hh) as f32).then(|| textured as f32 / smooth as f32)
}

/// Magnitude of the luma gradient at pixel `i` by central differences (borders clamped).
fn luma_gradient(rgb: &[[u8; 3]], w: usize, h: usize, i: usize) -> f32 {
    let (x, y) = (i % w, i / w);
    let at = |x: usize, y: usize| luma(rgb[y * w + x]);
    let gx = at((x + 1).min(w - 1), y) - at(x.saturating_sub(1), y);
    let gy = at(x, (y + 1).min(h - 1)) - at(x, y.saturating_sub(1));
    0.5 * gx.hypot(gy)
}

/// Share of the image in regions of the non-flat part, of continuous chromaticity and mostly
/// in `interior` (away from edges), whose luminance spans [`SHADING_RANGE`] or more.
fn shading_cover(rgb: &[[u8; 3]], non_flat: &[bool], interior: &[bool], w: usize, h: usize) -> f32 {
    let n = w * h;
    // Chromaticity of the colour lifted by a few levels, so that near-black noise does not
    // cut regions apart.
    let chroma: Vec<[f32; 3]> = rgb
        .iter()
        .map(|px| {
            let v = px.map(|c| f32::from(c) + 4.0);
            let norm = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            v.map(|c| c / norm)
        })
        .collect();
    let cos_step = CHROMA_STEP.cos();
    let joins = |a: usize, b: usize| {
        let (p, q) = (chroma[a], chroma[b]);
        p[0] * q[0] + p[1] * q[1] + p[2] * q[2] >= cos_step
    };
    let mut seen = vec![false; n];
    let mut stack = Vec::new();
    let mut shaded = 0usize;
    for start in 0..n {
        if seen[start] || !non_flat[start] {
            continue;
        }
        seen[start] = true;
        stack.push(start);
        let mut lumas = Vec::new();
        let mut inner = 0usize;
        while let Some(p) = stack.pop() {
            lumas.push(luma(rgb[p]));
            inner += usize::from(interior[p]);
            let (x, y) = (p % w, p / w);
            let neighbours = [
                (x > 0).then(|| p - 1),
                (x + 1 < w).then(|| p + 1),
                (y > 0).then(|| p - w),
                (y + 1 < h).then(|| p + w),
            ];
            for q in neighbours.into_iter().flatten() {
                if !seen[q] && non_flat[q] && joins(p, q) {
                    seen[q] = true;
                    stack.push(q);
                }
            }
        }
        if (lumas.len() as f32) < MIN_REGION * n as f32 || 2 * inner < lumas.len() {
            continue;
        }
        lumas.sort_by(f32::total_cmp);
        let at = |q: f32| lumas[((lumas.len() - 1) as f32 * q).round() as usize];
        if (at(0.98) + LUMA_OFFSET) / (at(0.02) + LUMA_OFFSET) >= SHADING_RANGE {
            shaded += lumas.len();
        }
    }
    shaded as f32 / n as f32
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imageio::to_rgb_image as to_image;
    use crate::synth::{antialiased, lit_sphere};

    /// A `size²` anti-aliased 8-bit image of a colour function of points in [−1, 1]².
    fn image(size: usize, colour: impl Fn(f32, f32) -> [f32; 3]) -> Image {
        to_image(&image::DynamicImage::ImageRgb8(antialiased(
            size as u32,
            colour,
        )))
    }

    #[test]
    fn a_shaded_sphere_on_a_flat_backdrop_is_photographic() {
        let sphere = lit_sphere(128, [0.8, 0.3, 0.2], [0.6, 0.6, 0.62]);
        let look = look(&to_image(&image::DynamicImage::ImageRgb8(sphere)));
        assert!(matches!(look, Look::Photographic(_)), "{look:?}");
        let e = look.evidence();
        assert!(e.non_flat < PHOTO_NON_FLAT, "{e:?}");
        assert!(e.shading.unwrap() >= SHADING_SHARE, "{e:?}");
        assert!(
            look.reason().starts_with("smooth shading"),
            "{}",
            look.reason()
        );
    }

    #[test]
    fn flat_shapes_and_a_gentle_gradient_are_artwork() {
        // A yellow disc with a gentle vertical gradient and a dark flat eye, on white.
        let icon = image(64, |u, v| {
            if (u - 0.2).powi(2) + (v + 0.1).powi(2) < 0.02 {
                [0.2, 0.15, 0.1]
            } else if u * u + v * v < 0.8 {
                [1.0, 0.85 - 0.1 * v, 0.2]
            } else {
                [1.0; 3]
            }
        });
        let look = look(&icon);
        assert!(matches!(look, Look::Artwork(_)), "{look:?}");
        // All flat: artwork, without further measurement.
        let flat = look_of_flat();
        assert!(
            matches!(flat, Look::Artwork(e) if e.texture.is_none()),
            "{flat:?}"
        );
    }

    fn look_of_flat() -> Look {
        look(&image(
            48,
            |u, _| if u < 0.0 { [0.1, 0.5, 0.9] } else { [1.0; 3] },
        ))
    }

    #[test]
    fn a_noisy_object_on_clipped_white_is_photographic() {
        let mut state = 7u32;
        let mut noise = move || {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (state >> 24) as f32 / 255.0 - 0.5
        };
        let mut product = image(64, |u, v| {
            if u.abs() < 0.4 && v.abs() < 0.5 {
                [0.5, 0.35, 0.2]
            } else {
                [1.0; 3]
            }
        });
        for (i, v) in product.data.iter_mut().enumerate() {
            if *v < 1.0 {
                *v = (*v + 0.03 * noise() + 0.001 * (i % 7) as f32).clamp(0.0, 1.0);
            }
        }
        let look = look(&product);
        assert!(
            matches!(look, Look::Photographic(e) if e.shading.is_none()),
            "{look:?}"
        );
        assert!(look.reason().starts_with("texture"), "{}", look.reason());
    }

    #[test]
    fn a_small_shaded_sphere_on_a_wide_backdrop_is_photographic() {
        // The sphere is about 7 % of the image: the backdrop does not outvote it.
        let (size, r) = (160usize, 0.3f32);
        let shaded = image(size, |u, v| {
            let d2 = u * u + v * v;
            if d2 < r * r {
                let z = (r * r - d2).sqrt() / r;
                let lit = (-0.5 * u / r - 0.5 * v / r + 0.7 * z).max(0.0);
                [0.9, 0.4, 0.3].map(|c| c * (0.1 + 0.9 * lit))
            } else {
                [0.2, 0.5, 0.3]
            }
        });
        let look = look(&shaded);
        assert!(matches!(look, Look::Photographic(_)), "{look:?}");
    }

    #[test]
    fn a_drawn_radial_gradient_and_grey_text_are_artwork() {
        // A purple ball drawn with a radial gradient and crisp flat shapes over it.
        let ball = image(128, |u, v| {
            let d = (u + 0.2).hypot(v + 0.2);
            if (u - 0.3).abs() < 0.08 && (v + 0.3).abs() < 0.08 {
                [1.0; 3]
            } else if u * u + v * v < 0.7 {
                let t = (d / 1.2).min(1.0);
                [0.75 - 0.3 * t, 0.55 - 0.3 * t, 0.95 - 0.2 * t]
            } else {
                [1.0; 3]
            }
        });
        assert!(matches!(look(&ball), Look::Artwork(_)), "{:?}", look(&ball));
        // Black strokes on white, anti-aliased: grey from white to black, but all edges.
        let text = image(96, |u, v| {
            let stroke = ((u * 9.0).sin().abs() < 0.25 && v.abs() < 0.6)
                || ((v * 7.0).sin().abs() < 0.2 && u.abs() < 0.7);
            if stroke { [0.0; 3] } else { [1.0; 3] }
        });
        assert!(matches!(look(&text), Look::Artwork(_)), "{:?}", look(&text));
    }
}
