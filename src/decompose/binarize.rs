//! Region-wise semantic binarisation (paper Sec. 4.2, "Illumination Masks").
//!
//! Inside each region, the threshold is the region's mean intensity of the target image;
//! pixels at or below it are shadow pixels, and their connected components (holes filled)
//! become illumination masks. Regions are the visible parts of the albedo masks, a partition
//! of the canvas, so every pixel is thresholded against exactly one region's mean.

use super::albedo::intensity;
use super::mask::Mask;
use super::segment::Candidate;
use crate::render::Image;

/// Shadow masks of `target` inside each of `regions`, components of at least `min_area`
/// pixels, scored by the squared error that a flat intensity inside them removes (×3 for the
/// three channels, to compare with colour segmentation gains). Unsorted.
pub fn binarize(target: &Image, regions: &[Mask], min_area: usize) -> Vec<Candidate> {
    let lum: Vec<f32> = (0..target.width * target.height)
        .map(|i| intensity(target.pixel(i % target.width, i / target.width)))
        .collect();
    let mut out = Vec::new();
    for region in regions.iter().filter(|r| !r.is_empty()) {
        let total: f64 = region.indices().map(|i| f64::from(lum[i])).sum();
        let n = region.area() as f64;
        let threshold = (total / n) as f32;
        let shadow = Mask::from_fn(region.width(), region.height(), |x, y| {
            region.contains(x, y) && lum[y * region.width() + x] <= threshold
        });
        // A flat region has every pixel at the threshold: nothing to separate.
        if shadow.area() == region.area() {
            continue;
        }
        for component in shadow.components(min_area) {
            let component = component.fill_holes();
            let inside: f64 = component.indices().map(|i| f64::from(lum[i])).sum();
            let (n_in, n_out) = (
                component.area() as f64,
                (n - component.area() as f64).max(1.0),
            );
            let (mean_in, mean_out) = (inside / n_in, (total - inside) / n_out);
            let gain = 3.0 * n_in * n_out / (n_in + n_out) * (mean_in - mean_out).powi(2);
            out.push(Candidate {
                mask: component,
                gain: gain as f32,
            });
        }
    }
    out
}
