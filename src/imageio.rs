//! Decoding inputs under limits, and encoding previews.

use crate::render::Image;

/// Input limits; every one is configurable (CLI flags, service settings).
#[derive(Clone, Debug, PartialEq)]
pub struct Limits {
    /// Largest decoded image, in pixels (width × height). Default 40 000 000.
    pub max_pixels: u64,
    /// Most masks accepted. Default 256.
    pub max_masks: usize,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_pixels: 40_000_000,
            max_masks: 256,
        }
    }
}

/// Why an input was refused; each names the problem for the user.
#[derive(Debug, thiserror::Error)]
pub enum InputError {
    #[error("the image could not be decoded: {0}")]
    Undecodable(String),
}

/// Decodes PNG/JPEG/WebP bytes with EXIF orientation applied, refusing more than `limits.max_pixels`
/// before decoding.
pub fn decode_image(bytes: &[u8], limits: &Limits) -> Result<image::DynamicImage, InputError> {
    let _ = (bytes, limits);
    todo!("issue 3")
}

/// PNG bytes of an image (values clamped to [0, 1], 8-bit sRGB).
pub fn encode_png(image: &Image) -> Vec<u8> {
    let _ = image;
    todo!("issue 3")
}
