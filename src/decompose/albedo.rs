//! The grey Retinex albedo estimate: an edge-preserving shading estimate, and albedo = image /
//! shading. Photo mode now uses [`super::intrinsic`]; this stays as
//! the baseline `covec eval --intrinsic` measures against, and for [`intensity`].
//!
//! Shading is taken as the log-luminance smoothed by a self-guided filter (He et al. 2010):
//! gradual variations (shading) are kept and fine texture goes to the albedo, while strong
//! edges stay sharp so shadows do not bleed as halos. It is grey (one value per pixel), so the
//! albedo keeps the image's chroma. This is far weaker than the network; supplying a real
//! albedo map is the path to the paper's quality.

use crate::render::Image;

/// Luminance weights (Rec. 601), applied to sRGB-encoded values.
pub fn intensity(rgb: [f32; 3]) -> f32 {
    0.299 * rgb[0] + 0.587 * rgb[1] + 0.114 * rgb[2]
}

/// Guided-filter ε in squared log-luminance units: edges whose log contrast is well above
/// √ε stay sharp in the shading.
const EDGE_EPS: f32 = 0.25;
/// Share of the smoothed log-luminance attributed to shading. Below 1 because a dark surface
/// and a shadow look alike to a filter; without the network, keep most of it in the albedo.
const SHADING_STRENGTH: f32 = 0.6;
/// Darkest shading: keeps albedo = image / shading from blowing up in deep shadow.
const MIN_SHADING: f32 = 0.3;

/// Grey shading in [0.3, 1] per pixel, scaled so that the brightest tenth of the image is fully lit.
pub fn estimate_shading(image: &Image) -> Vec<f32> {
    let (w, h) = (image.width, image.height);
    let log_lum: Vec<f32> = (0..w * h)
        .map(|i| {
            intensity([
                image.data[3 * i],
                image.data[3 * i + 1],
                image.data[3 * i + 2],
            ])
            .max(1.0 / 255.0)
            .ln()
        })
        .collect();
    // Radius ~ 1/12 of the long side: shading varies over object scale, not texture scale.
    let radius = (w.max(h) / 12).max(2);
    let smooth = guided_filter(&log_lum, w, h, radius, EDGE_EPS);
    let mut sorted = smooth.clone();
    sorted.sort_by(f32::total_cmp);
    let lit = sorted[(sorted.len() * 9 / 10).min(sorted.len() - 1)];
    smooth
        .iter()
        .map(|&s| {
            (SHADING_STRENGTH * (s - lit))
                .min(0.0)
                .exp()
                .max(MIN_SHADING)
        })
        .collect()
}

/// Albedo = image / shading, clamped to [0, 1].
pub fn albedo_from_shading(image: &Image, shading: &[f32]) -> Image {
    let data = image
        .data
        .iter()
        .enumerate()
        .map(|(k, &v)| (v / shading[k / 3]).clamp(0.0, 1.0))
        .collect();
    Image {
        width: image.width,
        height: image.height,
        data,
    }
}

/// Self-guided filter of a single-channel image: edge-preserving smoothing in O(pixels).
fn guided_filter(p: &[f32], w: usize, h: usize, radius: usize, eps: f32) -> Vec<f32> {
    let mean = box_mean(p, w, h, radius);
    let sq: Vec<f32> = p.iter().map(|v| v * v).collect();
    let mean_sq = box_mean(&sq, w, h, radius);
    let (mut a, mut b) = (Vec::with_capacity(p.len()), Vec::with_capacity(p.len()));
    for i in 0..p.len() {
        let var = (mean_sq[i] - mean[i] * mean[i]).max(0.0);
        let ai = var / (var + eps);
        a.push(ai);
        b.push(mean[i] - ai * mean[i]);
    }
    let (mean_a, mean_b) = (box_mean(&a, w, h, radius), box_mean(&b, w, h, radius));
    (0..p.len()).map(|i| mean_a[i] * p[i] + mean_b[i]).collect()
}

/// Mean over the (2r+1)² window clipped to the image, via a summed-area table.
fn box_mean(v: &[f32], w: usize, h: usize, r: usize) -> Vec<f32> {
    let mut table = vec![0f64; (w + 1) * (h + 1)];
    for y in 0..h {
        let mut row = 0f64;
        for x in 0..w {
            row += f64::from(v[y * w + x]);
            table[(y + 1) * (w + 1) + x + 1] = table[y * (w + 1) + x + 1] + row;
        }
    }
    let mut out = Vec::with_capacity(w * h);
    for y in 0..h {
        let (y0, y1) = (y.saturating_sub(r), (y + r + 1).min(h));
        for x in 0..w {
            let (x0, x1) = (x.saturating_sub(r), (x + r + 1).min(w));
            let sum =
                table[y1 * (w + 1) + x1] - table[y0 * (w + 1) + x1] - table[y1 * (w + 1) + x0]
                    + table[y0 * (w + 1) + x0];
            out.push((sum / ((x1 - x0) * (y1 - y0)) as f64) as f32);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_smooth_shading_ramp_goes_to_the_shading_and_leaves_a_flat_albedo() {
        let (w, h) = (64, 32);
        let mut image = Image::filled(w, h, [0.0; 3]);
        for y in 0..h {
            for x in 0..w {
                let s = 0.4 + 0.6 * x as f32 / (w - 1) as f32;
                for (c, a) in [0.8f32, 0.6, 0.4].into_iter().enumerate() {
                    image.data[3 * (y * w + x) + c] = a * s;
                }
            }
        }
        let shading = estimate_shading(&image);
        let albedo = albedo_from_shading(&image, &shading);
        assert!(
            shading[0] < 0.7 * shading[w - 1],
            "shading follows the ramp"
        );
        // The image's ramp spans a factor 0.96 / 0.46 ≈ 2.1 between these columns; the albedo's
        // must be much flatter (only SHADING_STRENGTH of the log contrast is removed).
        let (left, right) = (albedo.pixel(4, 16), albedo.pixel(60, 16));
        let (image_ratio, albedo_ratio) = (
            image.pixel(60, 16)[0] / image.pixel(4, 16)[0],
            right[0] / left[0],
        );
        assert!(
            albedo_ratio < 1.0 + 0.6 * (image_ratio - 1.0),
            "albedo {left:?} → {right:?}, image ratio {image_ratio}"
        );
        assert!(
            (right[1] / right[0] - 0.75).abs() < 0.01,
            "chroma kept: {right:?}"
        );
    }
}
