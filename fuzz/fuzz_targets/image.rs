//! Image, mask and label-map decoding (`covec::imageio`), as the CLI and the service call it,
//! then the conversion every stage starts from. The first byte picks the decoder and whether a
//! JPEG cut short is accepted.
#![no_main]

use covec::imageio::{self, Limits};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&which, bytes)) = data.split_first() else {
        return;
    };
    // Small enough that a header claiming the most allowed pixels decodes quickly.
    let limits = Limits {
        max_pixels: 1 << 18,
        max_masks: 16,
        accept_truncated: which & 0x80 != 0,
    };
    match which % 3 {
        0 => {
            if let Ok(image) = imageio::decode_image(bytes, &limits) {
                let (w, h) = imageio::working_size(image.width(), image.height(), 64);
                let rgb = imageio::resize_rgb(&image, w, h);
                assert_eq!(rgb.data.len(), w as usize * h as usize * 3);
            }
        }
        1 => {
            if let Ok(mask) = imageio::decode_mask("mask", bytes, &limits) {
                assert!(mask.as_raw().iter().all(|&v| v == 0 || v == 255));
            }
        }
        _ => {
            let _ = imageio::decode_labels(bytes, &limits);
        }
    }
});
