//! Decoding inputs under limits, checking that they fit together, resizing to the working size,
//! and encoding previews.
//!
//! Every decoder here reads the header first and refuses an image over [`Limits::max_pixels`]
//! before any pixel is decoded, so a small file claiming a huge canvas costs nothing.

use std::io::Cursor;

use image::imageops::FilterType;
use image::{DynamicImage, GrayImage, ImageBuffer, ImageDecoder, ImageReader};

use crate::render::Image;

/// Input limits; every one is configurable (CLI flags, service settings).
#[derive(Clone, Debug, PartialEq)]
pub struct Limits {
    /// Largest decoded image, in pixels (width × height). Default 40 000 000.
    pub max_pixels: u64,
    /// Most masks accepted (binary masks, or distinct values of a label map). Default 256.
    pub max_masks: usize,
    /// Decode a JPEG that ends before its end-of-image marker (the decoder fills the missing
    /// part with grey). Default false: such a file is refused as [`InputError::Truncated`].
    pub accept_truncated: bool,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_pixels: 40_000_000,
            max_masks: 256,
            accept_truncated: false,
        }
    }
}

/// Why an input was refused; each names the problem for the user.
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum InputError {
    /// Not a PNG, JPEG or WebP file, or a broken one.
    #[error("the image could not be decoded: {0}")]
    Undecodable(String),
    /// No pixels.
    #[error("the image is empty ({width}×{height} pixels)")]
    #[allow(missing_docs)]
    Empty { width: u32, height: u32 },
    #[error(
        "the image has {width}×{height} = {pixels} pixels, more than the limit of {max} (raise --max-pixels)"
    )]
    /// More pixels than [`Limits::max_pixels`], read from the header.
    #[allow(missing_docs)]
    TooManyPixels {
        width: u32,
        height: u32,
        pixels: u64,
        max: u64,
    },
    #[error(
        "mask {name} is not binary: it holds {levels} distinct values; a binary mask holds 0 and one other value"
    )]
    /// A mask with more than two values, or two without 0.
    #[allow(missing_docs)]
    NonBinaryMask { name: String, levels: usize },
    #[error("{count} masks given, more than the limit of {max} (raise --max-masks)")]
    /// More masks than [`Limits::max_masks`].
    #[allow(missing_docs)]
    TooManyMasks { count: usize, max: usize },
    #[error(
        "the label map holds more than {max} distinct values, each of which would be a mask; the limit is {max} (raise --max-masks)"
    )]
    /// A label map with more distinct values than [`Limits::max_masks`] (counting stops at
    /// the first one over).
    #[allow(missing_docs)]
    TooManyLabels { max: usize },
    #[error(
        "the JPEG data ends before its end-of-image marker: the file is truncated (its missing part would be decoded as grey)"
    )]
    /// A JPEG cut short, refused unless [`Limits::accept_truncated`].
    Truncated,
    #[error(
        "{what} is {width}×{height}, which does not have the image's aspect ratio ({image_width}×{image_height})"
    )]
    /// An input without the image's aspect ratio ([`check_aspect`]).
    #[allow(missing_docs)]
    AspectRatio {
        what: String,
        width: u32,
        height: u32,
        image_width: u32,
        image_height: u32,
    },
    #[error(
        "the pixel array has {0} channels; an image has 1 (grey), 2 (grey and alpha), 3 (RGB) or 4 (RGBA)"
    )]
    /// [`Pixels`] with a channel count no image has.
    Channels(u32),
    #[error("the pixel array holds {actual} values, not {width}×{height}×{channels}")]
    /// [`Pixels`] whose samples do not fill its width × height × channels.
    #[allow(missing_docs)]
    SampleCount {
        actual: usize,
        width: u32,
        height: u32,
        channels: u32,
    },
    #[error(
        "the pixel array holds {0}, outside [0, 1]: float pixels are in [0, 1] (give 0-255 values as 8-bit integers)"
    )]
    /// [`Samples::F32`] with a value outside [0, 1] or not a number.
    FloatRange(f32),
}

/// An input as the caller holds it.
pub enum Source<'a> {
    /// A PNG, JPEG or WebP file's bytes.
    Encoded(&'a [u8]),
    /// Pixels already decoded, e.g. an array from another library.
    Pixels(Pixels<'a>),
}

/// Decoded pixels: rows top to bottom, each pixel's channels together (as a row-major
/// height × width × channels array holds them).
#[derive(Clone, Copy)]
pub struct Pixels<'a> {
    /// Pixels per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// 1 (grey), 2 (grey and alpha), 3 (RGB) or 4 (RGBA).
    pub channels: u32,
    /// The values.
    pub samples: Samples<'a>,
}

/// The values of [`Pixels`], of one of the sample types an image holds.
#[derive(Clone, Copy)]
pub enum Samples<'a> {
    /// 0-255.
    U8(&'a [u8]),
    /// 0-65535.
    U16(&'a [u16]),
    /// 0-1.
    F32(&'a [f32]),
}

/// Refuses `size` unless it has the aspect ratio of `image` within one pixel of rounding: an
/// albedo map, mask or reference may be a scaled copy of the image, not a crop of it. The one
/// aspect rule of every input (pipeline, service, editor); `what` names the input in the error.
pub fn check_aspect(what: &str, size: (u32, u32), image: (u32, u32)) -> Result<(), InputError> {
    let ((w, h), (iw, ih)) = (size, image);
    let cross = (u64::from(w) * u64::from(ih)).abs_diff(u64::from(h) * u64::from(iw));
    if w == 0 || h == 0 || cross > u64::from(iw.max(ih)) {
        return Err(InputError::AspectRatio {
            what: what.to_owned(),
            width: w,
            height: h,
            image_width: iw,
            image_height: ih,
        });
    }
    Ok(())
}

/// Decodes PNG/JPEG/WebP bytes with EXIF orientation applied, refusing more than `limits.max_pixels`
/// before decoding. Alpha is composited over white, so the result has no alpha channel:
/// `Rgb8` for 8-bit sources, `Rgb16` for 16-bit ones, `Rgb32F` for float ones.
pub fn decode_image(bytes: &[u8], limits: &Limits) -> Result<DynamicImage, InputError> {
    load_image(Source::Encoded(bytes), limits)
}

/// [`decode_image`] for either [`Source`]: pixels in memory pass the same limits and lose
/// their alpha the same way.
pub fn load_image(source: Source<'_>, limits: &Limits) -> Result<DynamicImage, InputError> {
    Ok(flatten_over_white(oriented(source, limits)?))
}

/// Decodes one binary mask (any PNG/JPEG/WebP; colour is reduced to luma). `name` appears in
/// errors. Non-zero pixels are "inside"; the mask must hold at most two distinct values, one of
/// them 0 (an all-zero or all-one mask is allowed).
pub fn decode_mask(name: &str, bytes: &[u8], limits: &Limits) -> Result<GrayImage, InputError> {
    load_mask(name, Source::Encoded(bytes), limits)
}

/// [`decode_mask`] for either [`Source`].
pub fn load_mask(name: &str, source: Source<'_>, limits: &Limits) -> Result<GrayImage, InputError> {
    let image = flatten_over_white(oriented(source, limits)?).into_luma16();
    let mut levels: Vec<u16> = Vec::new();
    for &v in image.as_raw() {
        if !levels.contains(&v) {
            levels.push(v);
            if levels.len() > 2 {
                break;
            }
        }
    }
    let binary = levels.len() == 1 || (levels.len() == 2 && levels.contains(&0));
    if !binary {
        let levels = count_levels(image.as_raw());
        return Err(InputError::NonBinaryMask {
            name: name.to_string(),
            levels,
        });
    }
    let (width, height) = image.dimensions();
    let data = image
        .as_raw()
        .iter()
        .map(|&v| if v > 0 { 255 } else { 0 })
        .collect();
    Ok(GrayImage::from_raw(width, height, data).expect("same size"))
}

/// Decodes binary masks given as `(name, bytes)`, refusing more than `limits.max_masks`.
pub fn decode_masks<'a>(
    files: impl ExactSizeIterator<Item = (&'a str, &'a [u8])>,
    limits: &Limits,
) -> Result<Vec<GrayImage>, InputError> {
    check_mask_count(files.len(), limits)?;
    files
        .map(|(name, bytes)| decode_mask(name, bytes, limits))
        .collect()
}

/// Refuses more than `limits.max_masks` masks.
pub fn check_mask_count(count: usize, limits: &Limits) -> Result<(), InputError> {
    if count > limits.max_masks {
        return Err(InputError::TooManyMasks {
            count,
            max: limits.max_masks,
        });
    }
    Ok(())
}

/// Decodes a label map (each distinct colour or grey value is a segment), refusing more than
/// `limits.max_masks` distinct values. Returned as decoded (orientation applied), for the
/// pipeline's label-map input.
pub fn decode_labels(bytes: &[u8], limits: &Limits) -> Result<DynamicImage, InputError> {
    load_labels(Source::Encoded(bytes), limits)
}

/// [`decode_labels`] for either [`Source`].
pub fn load_labels(source: Source<'_>, limits: &Limits) -> Result<DynamicImage, InputError> {
    let image = oriented(source, limits)?;
    let rgba = image.to_rgba16();
    let mut seen = std::collections::HashSet::new();
    for pixel in rgba.pixels() {
        seen.insert(pixel.0);
        if seen.len() > limits.max_masks {
            return Err(InputError::TooManyLabels {
                max: limits.max_masks,
            });
        }
    }
    Ok(image)
}

/// PNG bytes of an image (values clamped to [0, 1], 8-bit sRGB).
pub fn encode_png(image: &Image) -> Vec<u8> {
    let rgb = image::RgbImage::from_raw(image.width as u32, image.height as u32, to_rgb8(image))
        .expect("Image data holds width × height × 3 values");
    let mut bytes = Vec::new();
    rgb.write_to(&mut Cursor::new(&mut bytes), image::ImageFormat::Png)
        .expect("PNG encoding into memory cannot fail");
    bytes
}

/// An image's values as 8-bit sRGB (clamped to [0, 1], rounded), as [`encode_png`] writes them.
pub fn to_rgb8(image: &Image) -> Vec<u8> {
    image
        .data
        .iter()
        .map(|&v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect()
}

/// An image as an f32 RGB [`Image`] in [0, 1], alpha composited over white.
pub fn to_rgb_image(image: &DynamicImage) -> Image {
    let rgb = flatten_over_white(image.clone()).into_rgb32f();
    Image {
        width: rgb.width() as usize,
        height: rgb.height() as usize,
        data: rgb.into_raw(),
    }
}

/// Width and height at which an image is processed: the long side brought down to `max_size`,
/// never up, aspect ratio kept.
pub fn working_size(width: u32, height: u32, max_size: u32) -> (u32, u32) {
    let long = width.max(height);
    if long <= max_size {
        return (width, height);
    }
    let scale = f64::from(max_size) / f64::from(long);
    let fit = |v: u32| ((f64::from(v) * scale).round() as u32).clamp(1, max_size);
    (fit(width), fit(height))
}

/// The image as f32 RGB at `w × h` (triangle filter, values in [0, 1]; unchanged when it
/// already has that size): how every stage and measurement sees an input at working size.
pub fn resize_rgb(image: &DynamicImage, w: u32, h: u32) -> Image {
    let rgb = to_rgb_image(image);
    if (rgb.width, rgb.height) == (w as usize, h as usize) {
        return rgb;
    }
    let buffer = image::Rgb32FImage::from_raw(rgb.width as u32, rgb.height as u32, rgb.data)
        .expect("same size");
    let small = image::imageops::resize(&buffer, w, h, FilterType::Triangle);
    let data = small
        .into_raw()
        .into_iter()
        .map(|v| v.clamp(0.0, 1.0))
        .collect();
    Image {
        width: w as usize,
        height: h as usize,
        data,
    }
}

/// The image at half size: each pixel the mean of a 2×2 block (edge pixels repeated where the
/// block overhangs an odd size).
pub fn halve_image(image: &Image) -> Image {
    let (w, h) = (image.width, image.height);
    let (hw, hh) = (w.div_ceil(2), h.div_ceil(2));
    let mut out = Image::filled(hw, hh, [0.0; 3]);
    for y in 0..hh {
        for x in 0..hw {
            let mut sum = [0.0f32; 3];
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let p = image.pixel((2 * x + dx).min(w - 1), (2 * y + dy).min(h - 1));
                for c in 0..3 {
                    sum[c] += p[c] / 4.0;
                }
            }
            out.data[3 * (y * hw + x)..3 * (y * hw + x) + 3].copy_from_slice(&sum);
        }
    }
    out
}

/// The media types of the image formats covec decodes (the `image` crate's features in
/// Cargo.toml): what an input may be.
pub const ACCEPTED_MEDIA_TYPES: [&str; 3] = ["image/png", "image/jpeg", "image/webp"];

/// An image's pixel count, unless it has none or more than `limits` allow: the check a file
/// gets from its header and pixels in memory from their shape.
fn check_size(width: u32, height: u32, limits: &Limits) -> Result<u64, InputError> {
    if width == 0 || height == 0 {
        return Err(InputError::Empty { width, height });
    }
    let pixels = u64::from(width) * u64::from(height);
    if pixels > limits.max_pixels {
        return Err(InputError::TooManyPixels {
            width,
            height,
            pixels,
            max: limits.max_pixels,
        });
    }
    Ok(pixels)
}

/// The image of `source` as decoded (orientation applied, alpha kept), within `limits`.
fn oriented(source: Source<'_>, limits: &Limits) -> Result<DynamicImage, InputError> {
    match source {
        Source::Encoded(bytes) => decode_oriented(bytes, limits),
        Source::Pixels(pixels) => from_pixels(pixels, limits),
    }
}

/// Pixels in memory as an image, refused as a file of their size would be (empty, over
/// `max_pixels`), and when their shape or values are no image's.
fn from_pixels(pixels: Pixels<'_>, limits: &Limits) -> Result<DynamicImage, InputError> {
    let Pixels {
        width,
        height,
        channels,
        samples,
    } = pixels;
    let count = check_size(width, height, limits)?;
    if !(1..=4).contains(&channels) {
        return Err(InputError::Channels(channels));
    }
    let actual = match samples {
        Samples::U8(values) => values.len(),
        Samples::U16(values) => values.len(),
        Samples::F32(values) => values.len(),
    };
    if actual as u64 != count * u64::from(channels) {
        return Err(InputError::SampleCount {
            actual,
            width,
            height,
            channels,
        });
    }
    let (w, h) = (width, height);
    let image = match samples {
        Samples::U8(values) => {
            let values = values.to_vec();
            match channels {
                1 => DynamicImage::ImageLuma8(ImageBuffer::from_raw(w, h, values).expect("sized")),
                2 => DynamicImage::ImageLumaA8(ImageBuffer::from_raw(w, h, values).expect("sized")),
                3 => DynamicImage::ImageRgb8(ImageBuffer::from_raw(w, h, values).expect("sized")),
                _ => DynamicImage::ImageRgba8(ImageBuffer::from_raw(w, h, values).expect("sized")),
            }
        }
        Samples::U16(values) => {
            let values = values.to_vec();
            match channels {
                1 => DynamicImage::ImageLuma16(ImageBuffer::from_raw(w, h, values).expect("sized")),
                2 => {
                    DynamicImage::ImageLumaA16(ImageBuffer::from_raw(w, h, values).expect("sized"))
                }
                3 => DynamicImage::ImageRgb16(ImageBuffer::from_raw(w, h, values).expect("sized")),
                _ => DynamicImage::ImageRgba16(ImageBuffer::from_raw(w, h, values).expect("sized")),
            }
        }
        Samples::F32(values) => {
            if let Some(&bad) = values.iter().find(|v| !(0.0..=1.0).contains(*v)) {
                return Err(InputError::FloatRange(bad));
            }
            // The image crate has no float grey: grey repeats into RGB, before any alpha.
            let values: Vec<f32> = match channels {
                1 => values.iter().flat_map(|&v| [v; 3]).collect(),
                2 => (values.chunks_exact(2))
                    .flat_map(|p| [p[0], p[0], p[0], p[1]])
                    .collect(),
                _ => values.to_vec(),
            };
            if channels % 2 == 0 {
                DynamicImage::ImageRgba32F(ImageBuffer::from_raw(w, h, values).expect("sized"))
            } else {
                DynamicImage::ImageRgb32F(ImageBuffer::from_raw(w, h, values).expect("sized"))
            }
        }
    };
    Ok(image)
}

fn decode_oriented(bytes: &[u8], limits: &Limits) -> Result<DynamicImage, InputError> {
    let undecodable = |e: image::ImageError| InputError::Undecodable(e.to_string());
    let mut reader = ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| InputError::Undecodable(e.to_string()))?;
    if reader.format().is_none() {
        return Err(InputError::Undecodable(
            "not a PNG, JPEG or WebP file".into(),
        ));
    }
    if reader.format() == Some(image::ImageFormat::Jpeg)
        && !limits.accept_truncated
        && !jpeg_is_complete(bytes)
    {
        return Err(InputError::Truncated);
    }
    if reader.format() == Some(image::ImageFormat::Png) {
        check_png_palette(bytes)?;
    }
    // Our own pixel limit is checked first, from the header; the decoder's allocation limit
    // is set after it (room for the largest allowed image at 16-bit RGBA, twice).
    reader.no_limits();
    let mut decoder = reader.into_decoder().map_err(undecodable)?;
    let (width, height) = decoder.dimensions();
    check_size(width, height, limits)?;
    let mut decoder_limits = image::Limits::default();
    decoder_limits.max_alloc = Some(limits.max_pixels.saturating_mul(16).max(512 << 20));
    decoder.set_limits(decoder_limits).map_err(undecodable)?;
    let orientation = decoder.orientation().map_err(undecodable)?;
    let mut image = DynamicImage::from_decoder(decoder).map_err(undecodable)?;
    image.apply_orientation(orientation);
    Ok(image)
}

/// Whether JPEG data reaches its end-of-image marker: the segments are walked from the start
/// (each scan's entropy-coded data up to the next marker), so data appended after the image
/// does not count and a file cut anywhere before the marker is caught. The decoders accept a
/// cut file and fill the rest with grey.
fn jpeg_is_complete(bytes: &[u8]) -> bool {
    const EOI: u8 = 0xD9;
    const SOS: u8 = 0xDA;
    let mut at = 2; // after SOI
    loop {
        // A marker: 0xFF (fill bytes allowed), then its code.
        while bytes.get(at) == Some(&0xFF) && bytes.get(at + 1) == Some(&0xFF) {
            at += 1;
        }
        let (Some(0xFF), Some(&code)) = (bytes.get(at), bytes.get(at + 1)) else {
            return false;
        };
        at += 2;
        match code {
            EOI => return true,
            // Markers without a length.
            0x01 | 0xD0..=0xD7 => continue,
            _ => {}
        }
        let Some(length) = bytes
            .get(at..at + 2)
            .map(|b| usize::from(u16::from_be_bytes([b[0], b[1]])))
        else {
            return false;
        };
        at += length;
        if code == SOS {
            // Entropy-coded data: up to a 0xFF that is neither stuffing (0x00) nor a restart.
            loop {
                match (bytes.get(at), bytes.get(at + 1)) {
                    (Some(0xFF), Some(0x00 | 0xD0..=0xD7)) => at += 2,
                    (Some(0xFF), Some(_)) => break,
                    (Some(_), _) => at += 1,
                    (None, _) => return false,
                }
            }
        }
    }
}

/// Refuses a PNG palette (PLTE chunk) that is empty, longer than 256 entries or not a whole
/// number of 3-byte entries, all errors by the PNG specification (11.2.3), before the decoder
/// sees it: png 0.18.1 panics expanding such a palette when its CRC is right (found by the
/// `image` fuzz target, which skips CRC checks). Chunks are walked up to the first IDAT, which
/// a palette must precede; a malformed chunk list is left for the decoder to report.
fn check_png_palette(bytes: &[u8]) -> Result<(), InputError> {
    const SIGNATURE: usize = 8;
    let mut at = SIGNATURE;
    while let Some(header) = bytes.get(at..at + 8) {
        let length = u32::from_be_bytes([header[0], header[1], header[2], header[3]]) as usize;
        match &header[4..8] {
            b"IDAT" => break,
            b"PLTE" if length == 0 || !length.is_multiple_of(3) || length > 3 * 256 => {
                return Err(InputError::Undecodable(format!(
                    "the PNG palette is {length} bytes long; a palette holds 1 to 256 entries of 3 bytes"
                )));
            }
            _ => {}
        }
        at = at.saturating_add(length).saturating_add(12);
    }
    Ok(())
}

/// Composites any alpha over white and drops it, keeping the bit depth.
fn flatten_over_white(image: DynamicImage) -> DynamicImage {
    if !image.color().has_alpha() {
        return match image {
            DynamicImage::ImageLuma8(_) => DynamicImage::ImageRgb8(image.into_rgb8()),
            DynamicImage::ImageLuma16(_) => DynamicImage::ImageRgb16(image.into_rgb16()),
            other => other,
        };
    }
    match image {
        DynamicImage::ImageLumaA8(_) | DynamicImage::ImageRgba8(_) => {
            let rgba = image.into_rgba8();
            let (w, h) = rgba.dimensions();
            let data = rgba.pixels().flat_map(|p| over_white_u8(p.0)).collect();
            DynamicImage::ImageRgb8(image::RgbImage::from_raw(w, h, data).expect("same size"))
        }
        DynamicImage::ImageLumaA16(_) | DynamicImage::ImageRgba16(_) => {
            let rgba = image.into_rgba16();
            let (w, h) = rgba.dimensions();
            let data = rgba.pixels().flat_map(|p| over_white_u16(p.0)).collect();
            DynamicImage::ImageRgb16(image::ImageBuffer::from_raw(w, h, data).expect("same size"))
        }
        other => {
            let rgba = other.into_rgba32f();
            let (w, h) = rgba.dimensions();
            let data = rgba
                .pixels()
                .flat_map(|p| {
                    let a = p.0[3].clamp(0.0, 1.0);
                    [0, 1, 2].map(|c| p.0[c] * a + (1.0 - a))
                })
                .collect();
            DynamicImage::ImageRgb32F(image::ImageBuffer::from_raw(w, h, data).expect("same size"))
        }
    }
}

fn over_white_u8([r, g, b, a]: [u8; 4]) -> [u8; 3] {
    let a = u32::from(a);
    [r, g, b].map(|c| ((u32::from(c) * a + 255 * (255 - a) + 127) / 255) as u8)
}

fn over_white_u16([r, g, b, a]: [u16; 4]) -> [u16; 3] {
    let a = u64::from(a);
    [r, g, b].map(|c| ((u64::from(c) * a + 65535 * (65535 - a) + 32767) / 65535) as u16)
}

fn count_levels(values: &[u16]) -> usize {
    let mut seen = vec![false; 65536];
    values
        .iter()
        .filter(|&&v| !std::mem::replace(&mut seen[usize::from(v)], true))
        .count()
}
