//! Synthetic scenes with known intrinsic layers, `I = clamp01(A · S + L)`: flat-coloured shapes
//! (albedo), a smooth directional shading with a soft cast shadow (shade), and Gaussian
//! highlights (light). Tests and the editing feature use them as ground truth.

pub mod scenes;

use crate::optim::rng::Rng;
use crate::render::Image;

/// A generated scene: the image and its three true layers, all `width × height`.
#[derive(Clone, Debug)]
pub struct SyntheticScene {
    /// `clamp01(albedo · shading + highlight)`.
    pub image: Image,
    /// The true surface colours.
    pub albedo: Image,
    /// The true (grey) shading.
    pub shading: Image,
    /// The true additive highlights.
    pub highlight: Image,
}

impl SyntheticScene {
    /// Pixels (`y * width + x`) where the highlight adds more than `threshold` in every channel.
    pub fn highlight_pixels(&self, threshold: f32) -> Vec<usize> {
        self.highlight
            .data
            .chunks_exact(3)
            .enumerate()
            .filter(|(_, px)| px.iter().all(|&v| v > threshold))
            .map(|(i, _)| i)
            .collect()
    }
}

/// Generates a scene of `width × height` pixels from `seed`: a background and three shapes
/// (two discs, one rectangle) of distinct colours, light from the upper left, a soft shadow band
/// and one highlight on the first disc.
pub fn generate(width: usize, height: usize, seed: u64) -> SyntheticScene {
    let mut rng = Rng::new(seed, 0x5359_4E54);
    let (w, h) = (width as f32, height as f32);
    let s = w.min(h);
    let palette = |rng: &mut Rng| {
        [
            rng.range(0.35, 0.95),
            rng.range(0.35, 0.95),
            rng.range(0.35, 0.95),
        ]
    };
    let background = palette(&mut rng);
    let disc_a = (
        rng.range(0.3, 0.4) * w,
        rng.range(0.3, 0.45) * h,
        rng.range(0.18, 0.24) * s,
        palette(&mut rng),
    );
    let disc_b = (
        rng.range(0.65, 0.75) * w,
        rng.range(0.6, 0.72) * h,
        rng.range(0.12, 0.18) * s,
        palette(&mut rng),
    );
    let rect = (
        rng.range(0.05, 0.15) * w,
        rng.range(0.62, 0.7) * h,
        rng.range(0.45, 0.55) * w,
        rng.range(0.85, 0.95) * h,
        palette(&mut rng),
    );
    let light_dir = (-0.6f32, -0.8f32);
    let shadow_offset = rng.range(-0.1, 0.1) * s;
    let highlight_center = (disc_a.0 - 0.35 * disc_a.2, disc_a.1 - 0.35 * disc_a.2);
    let highlight_sigma = 0.25 * disc_a.2;

    let mut albedo = Image::filled(width, height, background);
    let mut shading = Image::filled(width, height, [1.0; 3]);
    let mut highlight = Image::filled(width, height, [0.0; 3]);
    let mut image = Image::filled(width, height, [0.0; 3]);
    for y in 0..height {
        for x in 0..width {
            let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
            let mut a = background;
            let in_rect = px >= rect.0 && px < rect.2 && py >= rect.1 && py < rect.3;
            if in_rect {
                a = rect.4;
            }
            for disc in [&disc_b, &disc_a] {
                if (px - disc.0).hypot(py - disc.1) < disc.2 {
                    a = disc.3;
                }
            }
            // Directional ramp: brighter towards the light.
            let along = ((px / w - 0.5) * light_dir.0 + (py / h - 0.5) * light_dir.1) * 2f32.sqrt();
            let mut shade = 0.75 + 0.2 * along;
            // Soft diagonal shadow band.
            let band = ((px - py) * std::f32::consts::FRAC_1_SQRT_2 - shadow_offset - 0.25 * s)
                .abs()
                / (0.08 * s);
            shade *= 1.0 - 0.45 * (1.0 - smoothstep(band)).clamp(0.0, 1.0);
            let r2 = (px - highlight_center.0).powi(2) + (py - highlight_center.1).powi(2);
            let light = 0.7 * (-r2 / (2.0 * highlight_sigma * highlight_sigma)).exp();
            let i = 3 * (y * width + x);
            for c in 0..3 {
                albedo.data[i + c] = a[c];
                shading.data[i + c] = shade;
                highlight.data[i + c] = light;
                image.data[i + c] = (a[c] * shade + light).clamp(0.0, 1.0);
            }
        }
    }
    SyntheticScene {
        image,
        albedo,
        shading,
        highlight,
    }
}

/// 0 at t ≤ 0.5, 1 at t ≥ 1.5, smooth in between.
fn smoothstep(t: f32) -> f32 {
    let u = (t - 0.5).clamp(0.0, 1.0);
    u * u * (3.0 - 2.0 * u)
}

/// Scale-invariant MSE: `mean over channels c of min_s mean((s·estimate_c − truth_c)²)`. An
/// albedo is only known up to a scale, and per channel because the illuminant's colour cannot
/// be told from the surface's (a white wall under warm light looks like a cream wall).
pub fn scale_invariant_mse(estimate: &Image, truth: &Image) -> f32 {
    let scales = channel_scales(estimate, truth);
    let sum: f64 = estimate
        .data
        .iter()
        .zip(&truth.data)
        .enumerate()
        .map(|(k, (&e, &t))| (scales[k % 3] * f64::from(e) - f64::from(t)).powi(2))
        .sum();
    (sum / estimate.data.len().max(1) as f64) as f32
}

/// Per channel, the scale `s` minimising `Σ (s·estimate − truth)²`.
pub fn channel_scales(estimate: &Image, truth: &Image) -> [f64; 3] {
    let (mut num, mut den) = ([0.0f64; 3], [0.0f64; 3]);
    for (k, (&e, &t)) in estimate.data.iter().zip(&truth.data).enumerate() {
        num[k % 3] += f64::from(e) * f64::from(t);
        den[k % 3] += f64::from(e) * f64::from(e);
    }
    [0, 1, 2].map(|c| if den[c] > 0.0 { num[c] / den[c] } else { 0.0 })
}

/// An 8-bit RGB copy of `img` (values clamped to [0, 1]), e.g. to feed `pipeline::Inputs`.
pub fn to_rgb8(img: &Image) -> image::RgbImage {
    let bytes = img
        .data
        .iter()
        .map(|&v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect();
    image::RgbImage::from_raw(img.width as u32, img.height as u32, bytes)
        .expect("buffer matches size")
}

/// A deterministic small "photo" for tests: smooth shading over several flat-albedo blobs,
/// with mild noise.
pub fn blobs_photo(w: u32, h: u32) -> image::RgbImage {
    let mut state = 12345u32;
    let mut noise = move || {
        state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        (state >> 24) as f32 / 255.0 - 0.5
    };
    image::RgbImage::from_fn(w, h, |x, y| {
        let (fx, fy) = (x as f32 / w as f32, y as f32 / h as f32);
        let albedo = if (fx - 0.35).powi(2) + (fy - 0.4).powi(2) < 0.05 {
            [0.9, 0.3, 0.2]
        } else if fx > 0.6 && fy > 0.55 {
            [0.2, 0.4, 0.85]
        } else if fy < 0.2 {
            [0.3, 0.8, 0.3]
        } else {
            [0.85, 0.85, 0.8]
        };
        let shading = 0.45 + 0.55 * (1.0 - fx * 0.8) * (1.0 - fy * 0.3);
        image::Rgb(
            albedo.map(|a| ((a * shading + 0.03 * noise()).clamp(0.0, 1.0) * 255.0).round() as u8),
        )
    })
}

/// A lit sphere on a flat backdrop, as a renderer draws it with no noise: Lambertian shading
/// of `albedo` (ambient 0.12) with a Blinn-Phong highlight, light from the upper left, each
/// pixel the mean of 4 × 4 samples, 8-bit. The sphere's radius is 0.3 of the side; `size²`.
pub fn lit_sphere(size: u32, albedo: [f32; 3], backdrop: [f32; 3]) -> image::RgbImage {
    let unit = |d: [f32; 3]| {
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        d.map(|c| c / n)
    };
    let dot = |a: [f32; 3], b: [f32; 3]| (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]).max(0.0);
    let light = unit([-1.0, -1.0, 1.2]);
    let half = unit([light[0], light[1], light[2] + 1.0]);
    let colour = |u: f32, v: f32| {
        let (x, y) = (u / 0.6, v / 0.6);
        let d2 = x * x + y * y;
        if d2 >= 1.0 {
            return backdrop;
        }
        let normal = [x, y, (1.0 - d2).sqrt()];
        let (lit, shine) = (dot(normal, light), dot(normal, half).powi(40));
        albedo.map(|a| (a * (0.12 + 0.88 * lit) + 0.4 * shine).min(1.0))
    };
    antialiased(size, colour)
}

/// A `size²` 8-bit image of `colour` (a function of points in [−1, 1]², values in [0, 1]),
/// each pixel the mean of 4 × 4 samples: anti-aliased, as a renderer or a rasteriser draws it.
pub fn antialiased(size: u32, colour: impl Fn(f32, f32) -> [f32; 3]) -> image::RgbImage {
    image::RgbImage::from_fn(size, size, |x, y| {
        let mut sum = [0.0f32; 3];
        for k in 0..16 {
            let (sx, sy) = ((k % 4) as f32 + 0.5, (k / 4) as f32 + 0.5);
            let u = (x as f32 + sx / 4.0) / size as f32 * 2.0 - 1.0;
            let v = (y as f32 + sy / 4.0) / size as f32 * 2.0 - 1.0;
            let c = colour(u, v);
            (0..3).for_each(|i| sum[i] += c[i] / 16.0);
        }
        image::Rgb(sum.map(|c| (c.clamp(0.0, 1.0) * 255.0).round() as u8))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layers_compose_to_the_image_and_are_deterministic() {
        let a = generate(48, 40, 3);
        let b = generate(48, 40, 3);
        assert_eq!(a.image, b.image);
        assert_ne!(a.image, generate(48, 40, 4).image);
        for i in 0..a.image.data.len() {
            let v = (a.albedo.data[i] * a.shading.data[i] + a.highlight.data[i]).clamp(0.0, 1.0);
            assert!((v - a.image.data[i]).abs() < 1e-6);
        }
        assert!(!a.highlight_pixels(0.3).is_empty());
        // The shading varies: not a flat image.
        let (lo, hi) = a
            .shading
            .data
            .iter()
            .fold((1.0f32, 0.0f32), |(lo, hi), &v| (lo.min(v), hi.max(v)));
        assert!(hi - lo > 0.3, "{lo}..{hi}");
    }

    #[test]
    fn scale_invariant_mse_ignores_global_scale() {
        let scene = generate(16, 16, 1);
        let mut scaled = scene.albedo.clone();
        scaled.data.iter_mut().for_each(|v| *v *= 0.5);
        assert!(scale_invariant_mse(&scaled, &scene.albedo) < 1e-10);
        assert!(scale_invariant_mse(&scene.image, &scene.albedo) > 1e-4);
    }
}
