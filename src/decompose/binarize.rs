//! Region-wise semantic binarisation (paper Sec. 4.2, "Illumination Masks").
//!
//! Inside each region, the threshold is the region's mean intensity of the target image;
//! pixels at or below it are shadow pixels, and their connected components (holes filled)
//! become illumination masks. Regions are the visible parts of the albedo masks, a partition
//! of the canvas, so every pixel is thresholded against exactly one region's mean.

use rayon::prelude::*;

use super::albedo::intensity;
use super::mask::Mask;
use super::segment::Candidate;
use crate::render::Image;

/// Shadow masks of `target` inside each of `regions`, components of at least `min_area`
/// pixels, scored by the squared error that a flat intensity inside them removes (×3 for the
/// three channels, to compare with colour segmentation gains). Unsorted.
///
/// With `levels` > 1 each region's shadow and lit parts are binarised again at their own
/// means (a documented departure, docs/design.md): a flat-per-surface albedo map leaves a whole
/// surface's shading to the illumination layer, and a sphere's core shadow and terminator are
/// two levels of it, not one.
pub fn binarize(target: &Image, regions: &[Mask], min_area: usize, levels: u32) -> Vec<Candidate> {
    let lum: Vec<f32> = target
        .data
        .par_chunks(3)
        .map(|p| intensity([p[0], p[1], p[2]]))
        .collect();
    // Region by region on rayon's pool, collected in the regions' order.
    regions
        .par_iter()
        .filter(|r| !r.is_empty())
        .flat_map_iter(|region| {
            let mut out = Vec::new();
            threshold_region(&lum, region, min_area, levels, &mut out);
            out
        })
        .collect()
}

/// One region's shadow components at its mean, then (for `levels` > 1) both halves again.
fn threshold_region(
    lum: &[f32],
    region: &Mask,
    min_area: usize,
    levels: u32,
    out: &mut Vec<Candidate>,
) {
    if levels == 0 || region.area() < 2 * min_area {
        return;
    }
    let total: f64 = region.indices().map(|i| f64::from(lum[i])).sum();
    let n = region.area() as f64;
    let threshold = (total / n) as f32;
    let shadow = region.filter(|i| lum[i] <= threshold);
    // A flat region has every pixel at the threshold: nothing to separate.
    if shadow.area() == region.area() {
        return;
    }
    if levels > 1 {
        let lit = region.filter(|i| !shadow.contains_index(i));
        threshold_region(lum, &shadow, min_area, levels - 1, out);
        threshold_region(lum, &lit, min_area, levels - 1, out);
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::decompose::mask::Mask;
    use crate::render::Image;

    #[test]
    fn region_wise_binarisation_thresholds_each_region_at_its_own_mean() {
        // Left region: 0.2 / 0.4 stripes; right region: 0.6 / 0.8 stripes. A global threshold
        // (0.5) would call the whole left half shadow and nothing on the right.
        let (w, h) = (40usize, 20usize);
        let value = |x: usize, y: usize| match (x < 20, y < 10) {
            (true, true) => 0.2,
            (true, false) => 0.4,
            (false, true) => 0.6,
            (false, false) => 0.8,
        };
        let mut image = Image::filled(w, h, [0.0; 3]);
        for y in 0..h {
            for x in 0..w {
                image.data[3 * (y * w + x)..3 * (y * w + x) + 3].copy_from_slice(&[value(x, y); 3]);
            }
        }
        let regions = [
            Mask::from_fn(w, h, |x, _| x < 20),
            Mask::from_fn(w, h, |x, _| x >= 20),
        ];
        let mut shadows: Vec<Mask> = binarize(&image, &regions, 4, 1)
            .into_iter()
            .map(|c| c.mask)
            .collect();
        shadows.sort_by_key(|m| m.bbox());
        let expected = [
            Mask::from_fn(w, h, |x, y| x < 20 && y < 10),
            Mask::from_fn(w, h, |x, y| x >= 20 && y < 10),
        ];
        assert_eq!(shadows, expected);
    }
}
