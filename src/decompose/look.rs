//! What `auto` mode looks at: whether an image is flat artwork (emoji, logos, icons,
//! screenshots: flat fills, crisp anti-aliased edges, gentle gradients) or has the smooth
//! shading or photographic texture the photo mode's shade and light layers are for.
//!
//! The evidence comes from the part of the image that is *not* flat, however much flat
//! background surrounds it, so that a lit object on a plain backdrop or a product photo on a
//! clipped white background reads as what the object is:
//! 1. **Flat part.** A pixel is flat when its 3×3 neighbourhood holds one exact 8-bit colour;
//!    the flat part is those pixels grown by [`EDGE_RADIUS`], so the anti-aliased edges of flat
//!    shapes belong to it. The rest is the non-flat part.
//! 2. **Little non-flat part** (under [`MIN_NON_FLAT`]): flat artwork. **Mostly non-flat**
//!    (at least [`PHOTO_NON_FLAT`]): a photograph, a render or a smooth picture.
//! 3. **Photographic texture.** Sensor and render noise and fine texture leave a residual that
//!    a flat fill or a linear gradient does not: the image convolved with Immerkaer's
//!    noise-estimation mask (which cancels any local plane), per channel on the 0-255 scale.
//!    When over [`NOISY_RESIDUAL`] on at least [`TEXTURE_SHARE`] of the non-flat part: photo.
//! 4. **Smooth shading.** The non-flat part is cut into regions of continuous chromaticity
//!    (neighbours within [`CHROMA_STEP`]): a lit object's body, not its neighbour of another
//!    colour. A region whose luminance spans [`SHADING_RANGE`] or more (2nd to 98th
//!    percentile), from lit to shadowed, is shading; such regions covering
//!    [`SHADING_COVER`] of the image: photo. Drawn gradients are gentler or smaller.
//! 5. Otherwise flat artwork.
//!
//! The thresholds sit between the covec-bench emoji, 100 Noto emoji and logos (Iconify's
//! `noto` and `logos` sets, rendered with resvg) and scikit-image's logo on one side, and the
//! bench photos, rendered lit spheres on flat backdrops and product shots on clipped white on
//! the other (`benches/quality/auto_mode.py` makes and scores such a set).

use crate::render::Image;

/// Long side (pixels) of the image `auto` looks at: the input's own pixels up to this size.
/// The thresholds below were set on 256 px images and hold at 1024 px.
pub const ANALYSIS_SIZE: u32 = 1024;
/// How far (pixels) the flat part reaches past its exactly flat pixels: anti-aliasing and
/// thin outlines of flat shapes.
pub const EDGE_RADIUS: usize = 2;
/// Under this share of non-flat pixels an image is flat artwork.
pub const MIN_NON_FLAT: f32 = 0.05;
/// From this share of non-flat pixels an image is a photograph (or a render or smooth picture):
/// drawn artwork keeps flat fills.
pub const PHOTO_NON_FLAT: f32 = 0.7;
/// Immerkaer residual (0-255 scale, largest channel) above which a pixel counts as noisy. A
/// linear gradient or an 8-bit step leaves at most about 3.
pub const NOISY_RESIDUAL: f32 = 4.0;
/// Luma gradient (0-255 scale per pixel, central differences) under which a non-flat pixel is
/// smooth, where texture is looked for.
pub const SMOOTH_GRADIENT: f32 = 4.0;
/// Share of noisy pixels among the smooth non-flat ones that makes photographic texture:
/// drawn gradients stay under a fifth, a logo with hatching about a third; photographs and
/// renders reach 0.4-0.6 and noisy renders more.
pub const TEXTURE_SHARE: f32 = 0.4;
/// Fewer smooth non-flat pixels than this share of the image show no texture either way.
const MIN_SMOOTH: f32 = 0.01;
/// Largest chromaticity step (radians) between neighbours of one shading region.
pub const CHROMA_STEP: f32 = 3.0 * std::f32::consts::PI / 180.0;
/// Luminance span (98th over 2nd percentile, offset by [`LUMA_OFFSET`]) from which a region
/// is shading.
pub const SHADING_RANGE: f32 = 5.0;
/// Offset on the 0-255 luma scale against the ratio's blowing up in the dark.
pub const LUMA_OFFSET: f32 = 8.0;
/// Share of the image that shading regions must cover for the image to count as shaded.
pub const SHADING_COVER: f32 = 0.1;
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
    /// Share of the smooth non-flat pixels that is noisy (`None`: not measured).
    pub texture: Option<f32>,
    /// Share of the image covered by shading regions (`None`: not measured).
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
        match (self, e.texture, e.shading) {
            (Look::Artwork(_), None, _) => format!(
                "flat artwork: flat colours cover all but {} of the image",
                pct(e.non_flat)
            ),
            (Look::Artwork(_), Some(t), Some(s)) => format!(
                "flat artwork: the {} of the image that is not flat has no photographic texture ({} noisy) and little shading ({} of the image)",
                pct(e.non_flat),
                pct(t),
                pct(s)
            ),
            (Look::Photographic(_), Some(t), None) => format!(
                "photographic texture: {} of the smooth pixels of the non-flat part ({} of the image) are noisy",
                pct(t),
                pct(e.non_flat)
            ),
            (Look::Photographic(_), Some(_), Some(s)) => format!(
                "smooth shading: lit-to-shadowed regions cover {} of the image",
                pct(s)
            ),
            _ => format!("photographic: {} of the image is not flat", pct(e.non_flat)),
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
    if share >= PHOTO_NON_FLAT {
        return Look::Photographic(evidence);
    }
    let smooth: Vec<usize> = (0..n)
        .filter(|&i| non_flat[i] && luma_gradient(&rgb, w, h, i) < SMOOTH_GRADIENT)
        .collect();
    let noisy = smooth
        .iter()
        .filter(|&&i| residual(&rgb, w, h, i) > NOISY_RESIDUAL)
        .count();
    let texture = if (smooth.len() as f32) < MIN_SMOOTH * n as f32 {
        0.0
    } else {
        noisy as f32 / smooth.len() as f32
    };
    evidence.texture = Some(texture);
    if texture >= TEXTURE_SHARE {
        return Look::Photographic(evidence);
    }
    let shading = shading_cover(&rgb, &non_flat, w, h);
    evidence.shading = Some(shading);
    if shading >= SHADING_COVER {
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
    // Grow by the radius: rows, then columns (a square neighbourhood).
    let r = EDGE_RADIUS;
    let rows: Vec<bool> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            (x.saturating_sub(r)..=(x + r).min(w - 1)).any(|xx| flat[y * w + xx])
        })
        .collect();
    (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            !(y.saturating_sub(r)..=(y + r).min(h - 1)).any(|yy| rows[yy * w + x])
        })
        .collect()
}

/// BT.601 luma on the 0-255 scale.
fn luma(px: [u8; 3]) -> f32 {
    0.299 * f32::from(px[0]) + 0.587 * f32::from(px[1]) + 0.114 * f32::from(px[2])
}

/// Magnitude of the luma gradient at pixel `i` by central differences (borders clamped).
fn luma_gradient(rgb: &[[u8; 3]], w: usize, h: usize, i: usize) -> f32 {
    let (x, y) = (i % w, i / w);
    let at = |x: usize, y: usize| luma(rgb[y * w + x]);
    let gx = at((x + 1).min(w - 1), y) - at(x.saturating_sub(1), y);
    let gy = at(x, (y + 1).min(h - 1)) - at(x, y.saturating_sub(1));
    0.5 * gx.hypot(gy)
}

/// Immerkaer's noise-estimation mask [1 −2 1; −2 4 −2; 1 −2 1] at pixel `i`, borders clamped;
/// the largest absolute value over the channels (0-255 scale). It is zero on any plane.
fn residual(rgb: &[[u8; 3]], w: usize, h: usize, i: usize) -> f32 {
    const MASK: [[i32; 3]; 3] = [[1, -2, 1], [-2, 4, -2], [1, -2, 1]];
    let (x, y) = (i % w, i / w);
    let mut sums = [0i32; 3];
    for (dy, row) in MASK.iter().enumerate() {
        let yy = (y + dy).saturating_sub(1).min(h - 1);
        for (dx, &m) in row.iter().enumerate() {
            let xx = (x + dx).saturating_sub(1).min(w - 1);
            let px = rgb[yy * w + xx];
            for (s, &v) in sums.iter_mut().zip(&px) {
                *s += m * i32::from(v);
            }
        }
    }
    sums.iter().map(|s| s.unsigned_abs()).max().unwrap_or(0) as f32
}

/// Share of the image in non-flat regions of continuous chromaticity whose luminance spans
/// [`SHADING_RANGE`] or more.
fn shading_cover(rgb: &[[u8; 3]], non_flat: &[bool], w: usize, h: usize) -> f32 {
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
        while let Some(p) = stack.pop() {
            lumas.push(luma(rgb[p]));
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
        if (lumas.len() as f32) < MIN_REGION * n as f32 {
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
        let sphere = lit_sphere(64, [0.8, 0.3, 0.2], [0.6, 0.6, 0.62]);
        let look = look(&to_image(&image::DynamicImage::ImageRgb8(sphere)));
        assert!(matches!(look, Look::Photographic(_)), "{look:?}");
        let e = look.evidence();
        assert!(e.non_flat < PHOTO_NON_FLAT, "{e:?}");
        assert!(e.shading.unwrap() >= SHADING_COVER, "{e:?}");
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
        assert!(
            look.reason().starts_with("photographic texture"),
            "{}",
            look.reason()
        );
    }
}
