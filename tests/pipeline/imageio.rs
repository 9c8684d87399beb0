//! Decoding with limits: formats, bit depths, alpha over white, EXIF orientation; pixels in
//! memory under the same rules.

use std::io::Cursor;

use covec::imageio::{
    InputError, Limits, Pixels, Samples, Source, decode_image, decode_labels, decode_mask,
    encode_png, load_image, load_labels, load_mask,
};
use covec::render::Image;
use image::{DynamicImage, ImageEncoder, ImageFormat};

fn encode(image: &DynamicImage, format: ImageFormat) -> Vec<u8> {
    let mut bytes = Vec::new();
    image
        .write_to(&mut Cursor::new(&mut bytes), format)
        .unwrap();
    bytes
}

#[test]
fn alpha_is_composited_over_white_in_8_and_16_bit() {
    let rgba8 = image::RgbaImage::from_fn(4, 2, |x, _| {
        image::Rgba([0, 0, 0, if x == 0 { 0 } else { 255 }])
    });
    let decoded = decode_image(
        &encode(&DynamicImage::ImageRgba8(rgba8), ImageFormat::Png),
        &Limits::default(),
    )
    .unwrap();
    let rgb = decoded.to_rgb8();
    assert_eq!(
        rgb.get_pixel(0, 0).0,
        [255, 255, 255],
        "transparent → white"
    );
    assert_eq!(rgb.get_pixel(1, 0).0, [0, 0, 0]);

    let la16 =
        image::ImageBuffer::<image::LumaA<u16>, _>::from_fn(2, 2, |_, _| image::LumaA([0, 32768]));
    let decoded = decode_image(
        &encode(&DynamicImage::ImageLumaA16(la16), ImageFormat::Png),
        &Limits::default(),
    )
    .unwrap();
    assert!(
        matches!(decoded, DynamicImage::ImageRgb16(_)),
        "16-bit depth kept"
    );
    let v = decoded.to_rgb16().get_pixel(0, 0).0[0];
    assert!(
        (32766..=32768).contains(&v),
        "half-transparent black over white: {v}"
    );
}

#[test]
fn grey_and_webp_and_jpeg_decode_to_rgb() {
    let grey = DynamicImage::ImageLuma8(image::GrayImage::from_fn(8, 4, |x, _| {
        image::Luma([x as u8 * 30])
    }));
    for format in [ImageFormat::Png, ImageFormat::Jpeg, ImageFormat::WebP] {
        let decoded = decode_image(&encode(&grey, format), &Limits::default()).unwrap();
        assert_eq!((decoded.width(), decoded.height()), (8, 4), "{format:?}");
        assert!(
            !decoded.color().has_alpha() && decoded.color().channel_count() == 3,
            "{format:?}"
        );
    }
}

#[test]
fn exif_orientation_is_applied() {
    // 3×2 image, red at top-left; EXIF orientation 6 = rotate 90° clockwise to display.
    let image = image::RgbImage::from_fn(3, 2, |x, y| {
        image::Rgb(if (x, y) == (0, 0) {
            [255, 0, 0]
        } else {
            [0, 0, 255]
        })
    });
    let exif = {
        let mut e = b"MM\0\x2a\0\0\0\x08".to_vec(); // big-endian TIFF header, IFD at 8
        e.extend_from_slice(&[0, 1]); // one entry
        e.extend_from_slice(&[0x01, 0x12, 0, 3, 0, 0, 0, 1, 0, 6, 0, 0]); // Orientation SHORT 6
        e.extend_from_slice(&[0, 0, 0, 0]); // no next IFD
        e
    };
    let mut bytes = Vec::new();
    let mut encoder = image::codecs::png::PngEncoder::new(Cursor::new(&mut bytes));
    encoder.set_exif_metadata(exif).unwrap();
    encoder
        .write_image(image.as_raw(), 3, 2, image::ExtendedColorType::Rgb8)
        .unwrap();
    let decoded = decode_image(&bytes, &Limits::default()).unwrap().to_rgb8();
    assert_eq!(decoded.dimensions(), (2, 3), "rotated");
    assert_eq!(
        decoded.get_pixel(1, 0).0,
        [255, 0, 0],
        "top-left moves to top-right"
    );
}

#[test]
fn the_pixel_limit_is_checked_from_the_header() {
    // A PNG whose header claims 100 000 × 100 000 pixels but holds no image data.
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = b"IHDR".to_vec();
    ihdr.extend_from_slice(&100_000u32.to_be_bytes());
    ihdr.extend_from_slice(&100_000u32.to_be_bytes());
    ihdr.extend_from_slice(&[8, 2, 0, 0, 0]);
    png.extend_from_slice(&13u32.to_be_bytes());
    png.extend_from_slice(&ihdr);
    png.extend_from_slice(&crc32(&ihdr).to_be_bytes());
    for chunk in [&b"IDAT"[..], &b"IEND"[..]] {
        png.extend_from_slice(&0u32.to_be_bytes());
        png.extend_from_slice(chunk);
        png.extend_from_slice(&crc32(chunk).to_be_bytes());
    }
    let err = decode_image(&png, &Limits::default()).unwrap_err();
    assert!(
        matches!(
            err,
            InputError::TooManyPixels {
                width: 100_000,
                height: 100_000,
                ..
            }
        ),
        "{err}"
    );
    assert!(
        err.to_string().contains("more than the limit of 40000000"),
        "{err}"
    );
}

#[test]
fn undecodable_bytes_and_non_binary_masks_are_named() {
    let err = decode_image(b"GIF89a....", &Limits::default()).unwrap_err();
    assert!(matches!(err, InputError::Undecodable(_)), "{err}");
    let ramp = DynamicImage::ImageLuma8(image::GrayImage::from_fn(4, 4, |x, _| {
        image::Luma([x as u8 * 80])
    }));
    let err = decode_mask(
        "m.png",
        &encode(&ramp, ImageFormat::Png),
        &Limits::default(),
    )
    .unwrap_err();
    assert_eq!(
        err.to_string(),
        "mask m.png is not binary: it holds 4 distinct values; a binary mask holds 0 and one other value"
    );
    let ones = DynamicImage::ImageLuma8(image::GrayImage::from_fn(4, 4, |x, _| {
        image::Luma([u8::from(x < 2)])
    }));
    let mask = decode_mask(
        "ones.png",
        &encode(&ones, ImageFormat::Png),
        &Limits::default(),
    )
    .unwrap();
    assert_eq!(mask.get_pixel(0, 0).0, [255], "0/1 masks are binary too");
    let labels = DynamicImage::ImageLuma8(image::GrayImage::from_fn(4, 4, |x, y| {
        image::Luma([(x + 4 * y) as u8])
    }));
    let err = decode_labels(
        &encode(&labels, ImageFormat::Png),
        &Limits {
            max_masks: 10,
            ..Limits::default()
        },
    )
    .unwrap_err();
    assert!(
        matches!(err, InputError::TooManyLabels { max: 10 }),
        "{err}"
    );
}

/// `samples` as [`Pixels`] of `width × height × channels`.
fn pixels(width: u32, height: u32, channels: u32, samples: Samples<'_>) -> Source<'_> {
    Source::Pixels(Pixels {
        width,
        height,
        channels,
        samples,
    })
}

#[test]
fn pixels_in_memory_are_the_image_a_file_of_them_is() {
    let rgba: Vec<u8> = (0..4 * 3 * 4).map(|v| (v * 5) as u8).collect();
    let file = encode(
        &DynamicImage::ImageRgba8(image::RgbaImage::from_raw(4, 3, rgba.clone()).unwrap()),
        ImageFormat::Png,
    );
    let limits = Limits::default();
    let from_file = decode_image(&file, &limits).unwrap();
    let from_memory = load_image(pixels(4, 3, 4, Samples::U8(&rgba)), &limits).unwrap();
    assert_eq!(from_memory, from_file, "alpha over white, as decoded");

    // Grey floats become RGB; 16 bits stay 16 bits.
    let grey = load_image(pixels(2, 1, 1, Samples::F32(&[0.0, 0.5])), &limits).unwrap();
    assert_eq!(grey.to_rgb32f().into_raw(), [0.0, 0.0, 0.0, 0.5, 0.5, 0.5]);
    let deep = load_image(pixels(1, 1, 3, Samples::U16(&[1, 2, 3])), &limits).unwrap();
    assert!(matches!(deep, DynamicImage::ImageRgb16(_)));

    // A mask and a label map from memory pass the files' checks.
    let mask = load_mask("1", pixels(2, 1, 1, Samples::U8(&[0, 1])), &limits).unwrap();
    assert_eq!(mask.into_raw(), [0, 255]);
    let error = load_mask("2", pixels(3, 1, 1, Samples::U8(&[0, 1, 2])), &limits).unwrap_err();
    assert!(
        matches!(error, InputError::NonBinaryMask { levels: 3, .. }),
        "{error}"
    );
    let few = Limits {
        max_masks: 1,
        ..Limits::default()
    };
    let error = load_labels(pixels(2, 1, 1, Samples::U16(&[7, 9])), &few).unwrap_err();
    assert_eq!(error, InputError::TooManyLabels { max: 1 });
}

#[test]
fn pixels_no_image_holds_are_refused() {
    let limits = Limits::default();
    let refused = |source| load_image(source, &limits).unwrap_err();
    assert_eq!(
        refused(pixels(0, 3, 3, Samples::U8(&[]))),
        InputError::Empty {
            width: 0,
            height: 3
        }
    );
    assert_eq!(
        refused(pixels(1, 1, 5, Samples::U8(&[0; 5]))),
        InputError::Channels(5)
    );
    assert_eq!(
        refused(pixels(2, 2, 3, Samples::U8(&[0; 11]))),
        InputError::SampleCount {
            actual: 11,
            width: 2,
            height: 2,
            channels: 3
        }
    );
    assert_eq!(
        refused(pixels(1, 1, 1, Samples::F32(&[255.0]))),
        InputError::FloatRange(255.0)
    );
    assert!(matches!(
        refused(pixels(1, 1, 1, Samples::F32(&[f32::NAN]))),
        InputError::FloatRange(v) if v.is_nan()
    ));
    let small = Limits {
        max_pixels: 3,
        ..Limits::default()
    };
    let error = load_image(pixels(2, 2, 1, Samples::U8(&[0; 4])), &small).unwrap_err();
    assert!(matches!(error, InputError::TooManyPixels { pixels: 4, .. }));
}

#[test]
fn previews_encode_clamped() {
    let image = Image {
        width: 2,
        height: 1,
        data: vec![-0.5, 0.5, 1.5, 1.0, 0.0, 0.25],
    };
    let png = image::load_from_memory(&encode_png(&image))
        .unwrap()
        .to_rgb8();
    assert_eq!(png.get_pixel(0, 0).0, [0, 128, 255]);
    assert_eq!(png.get_pixel(1, 0).0, [255, 0, 64]);
}

fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}
