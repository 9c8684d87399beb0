//! GMSD and MS-SSIM against their authors' MATLAB code run in GNU Octave 7.3.0 (Debian 12
//! `octave` 7.3.0-2, `octave-image` 2.14.0): `GMSD.m` (Xue et al., from the authors' page) and
//! `msssim.m` + `ssim_index_new.m` (Z. Wang, default arguments), each called on
//! `rgb2gray(double(imread(f)))`. The expected values below are what Octave printed.

use covec::imageio::to_rgb_image;
use covec::perceptual::{gmsd, ms_ssim};
use covec::render::Image;

fn fixture(name: &str) -> Image {
    let path = format!("{}/tests/fixtures/{name}", env!("CARGO_MANIFEST_DIR"));
    to_rgb_image(&image::open(&path).unwrap_or_else(|e| panic!("{path}: {e}")))
}

/// (distorted fixture, Octave's GMSD, Octave's MS-SSIM) against `hopper_ref.png` (176 × 176).
const REFERENCE: [(&str, f64, f64); 4] = [
    ("hopper_vector.png", 0.2404116720, 0.8887699712),
    ("hopper_blur.png", 0.1034118824, 0.9464888845),
    ("hopper_posterized.png", 0.0516201992, 0.9890694135),
    ("hopper_ref.png", 0.0, 1.0),
];

#[test]
fn gmsd_and_ms_ssim_match_the_authors_code() {
    let reference = fixture("hopper_ref.png");
    for (name, expected_gmsd, expected_ms_ssim) in REFERENCE {
        let distorted = fixture(name);
        let g = f64::from(gmsd(&reference, &distorted));
        let m = f64::from(ms_ssim(&reference, &distorted).expect("176 px has 5 scales"));
        assert!(
            (g - expected_gmsd).abs() < 1e-6,
            "{name}: GMSD {g} vs {expected_gmsd}"
        );
        assert!(
            (m - expected_ms_ssim).abs() < 1e-6,
            "{name}: MS-SSIM {m} vs {expected_ms_ssim}"
        );
    }
}
