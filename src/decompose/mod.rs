//! The decompose stage: the working-size target, its albedo map and candidate albedo masks,
//! from the client's network outputs when given, else from classical substitutes.
//!
//! | paper (Sec. 4.2) | given by the client | classical substitute here |
//! |---|---|---|
//! | albedo map, Careaga & Aksoy 2024 | `Inputs::albedo` | [`albedo`]: edge-preserving Retinex shading, albedo = image / shading |
//! | SAM masks of the albedo map | `Inputs::masks` | [`segment`]: Felzenszwalb superpixels merged by Ward's criterion, all scales |
//! | region-wise binarisation | — | [`binarize`] (as in the paper) |
//! | LayerVec mask organisation | — | [`organize`] (as in LayerVec) |

pub mod albedo;
pub mod binarize;
pub mod mask;
pub mod organize;
pub mod segment;

use image::imageops::FilterType;
use image::{DynamicImage, GrayImage};

use crate::imageio::to_rgb_image;
use crate::pipeline::{Error, Inputs, Masks, Mode, Params};
use crate::render::Image;
use mask::Mask;
use segment::Candidate;

/// What the init stage starts from.
pub struct Decomposition {
    /// The image at working size.
    pub target: Image,
    /// The albedo map at working size (the target itself in simple mode).
    pub albedo: Image,
    /// Albedo mask candidates, most useful first: holes filled, connected, none tiny.
    pub candidates: Vec<Candidate>,
    /// The mode to run (`auto` resolved).
    pub mode: Mode,
    /// Whether the candidates came from the client (else from [`segment`]).
    pub masks_given: bool,
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

/// Masks smaller than this many pixels are dropped: 1/2000 of the canvas, at least 8 pixels
/// (LayerVec's SAM setting drops regions under 100 px at 512², about 1/2600).
pub fn min_mask_area(width: usize, height: usize) -> usize {
    (width * height / 2000).max(8)
}

/// Share of the pixels covered by the [`PALETTE_SIZE`] most frequent exact 8-bit colours.
/// Flat artwork (emoji, icons, logos) is painted in few exact colours and scores high (0.55-0.98
/// on the covec-bench emoji); photographs, even blurred or upscaled ones, spread over thousands
/// of colours and score low (at most 0.06 on the covec-bench photos).
pub fn palette_coverage(image: &Image) -> f32 {
    let pixels = image.width * image.height;
    if pixels == 0 {
        return 1.0;
    }
    let mut counts = std::collections::HashMap::new();
    for rgb in image.data.chunks_exact(3) {
        let key = [0, 1, 2].map(|c| (rgb[c].clamp(0.0, 1.0) * 255.0).round() as u8);
        *counts.entry(key).or_insert(0usize) += 1;
    }
    let mut counts: Vec<usize> = counts.into_values().collect();
    counts.sort_unstable_by(|a, b| b.cmp(a));
    counts.iter().take(PALETTE_SIZE).sum::<usize>() as f32 / pixels as f32
}

/// How many colours count as the palette in [`palette_coverage`].
pub const PALETTE_SIZE: usize = 16;

/// `auto` picks `simple` when the palette covers at least this share of the image.
pub const SIMPLE_PALETTE_COVERAGE: f32 = 0.3;

/// Resolves `auto` from the working-size target.
pub fn resolve_mode(mode: Mode, target: &Image) -> Mode {
    match mode {
        Mode::Auto if palette_coverage(target) >= SIMPLE_PALETTE_COVERAGE => Mode::Simple,
        Mode::Auto => Mode::Photo,
        other => other,
    }
}

/// The decompose stage.
pub fn run(
    inputs: &Inputs,
    params: &Params,
    candidate_count: usize,
) -> Result<Decomposition, Error> {
    let (ow, oh) = (inputs.image.width(), inputs.image.height());
    if ow == 0 || oh == 0 {
        return Err(Error::Input(format!(
            "the image is empty ({ow}×{oh} pixels)"
        )));
    }
    let (w, h) = working_size(ow, oh, params.max_size);
    let target = resize_rgb(&inputs.image, w, h);
    let mode = resolve_mode(params.mode, &target);
    let albedo = match (&inputs.albedo, mode) {
        (Some(map), _) => {
            check_aspect("the albedo map", map.width(), map.height(), ow, oh)?;
            resize_rgb(map, w, h)
        }
        (None, Mode::Simple) => target.clone(),
        (None, _) => albedo::albedo_from_shading(&target, &albedo::estimate_shading(&target)),
    };
    let (w, h) = (w as usize, h as usize);
    let min_area = min_mask_area(w, h);
    let given: Vec<Mask> = match &inputs.masks {
        Masks::None => Vec::new(),
        Masks::Binary(masks) => {
            let mut out = Vec::with_capacity(masks.len());
            for (k, m) in masks.iter().enumerate() {
                check_aspect(&format!("mask {}", k + 1), m.width(), m.height(), ow, oh)?;
                out.push(sample_mask(m, w, h));
            }
            out
        }
        Masks::Labels(labels) => {
            check_aspect("the label map", labels.width(), labels.height(), ow, oh)?;
            label_masks(labels, w, h)
        }
    };
    let masks_given = !matches!(inputs.masks, Masks::None);
    let candidates = if masks_given {
        let prepared = given
            .iter()
            .flat_map(|m| m.fill_holes().components(min_area))
            .collect();
        score_masks(prepared, &albedo)
    } else {
        segment::segment(&albedo, candidate_count)
            .into_iter()
            .flat_map(|c| {
                c.mask
                    .fill_holes()
                    .components(min_area)
                    .into_iter()
                    .map(move |mask| Candidate { mask, gain: c.gain })
            })
            .collect()
    };
    Ok(Decomposition {
        target,
        albedo,
        candidates,
        mode,
        masks_given,
    })
}

/// Scores client masks by the squared error a flat colour inside them removes (a Ward split
/// against the rest of the canvas), most useful first.
fn score_masks(masks: Vec<Mask>, albedo: &Image) -> Vec<Candidate> {
    let n = (albedo.width * albedo.height) as f64;
    let total = channel_sums(albedo, 0..albedo.width * albedo.height);
    let mut out: Vec<Candidate> = masks
        .into_iter()
        .map(|mask| {
            let inside = channel_sums(albedo, mask.indices());
            let (n_in, n_out) = (mask.area() as f64, (n - mask.area() as f64).max(1.0));
            let d2: f64 = (0..3)
                .map(|c| (inside[c] / n_in - (total[c] - inside[c]) / n_out).powi(2))
                .sum();
            Candidate {
                mask,
                gain: (n_in * n_out / n * d2) as f32,
            }
        })
        .collect();
    out.sort_by(|a, b| b.gain.total_cmp(&a.gain));
    out
}

/// Per-channel sums of `image` over the pixel indices `pixels`.
pub fn channel_sums(image: &Image, pixels: impl Iterator<Item = usize>) -> [f64; 3] {
    let mut sum = [0f64; 3];
    for i in pixels {
        for (s, &v) in sum.iter_mut().zip(&image.data[3 * i..3 * i + 3]) {
            *s += f64::from(v);
        }
    }
    sum
}

fn check_aspect(what: &str, w: u32, h: u32, image_w: u32, image_h: u32) -> Result<(), Error> {
    let (a, b) = (
        f64::from(w) / f64::from(h.max(1)),
        f64::from(image_w) / f64::from(image_h),
    );
    // 1% slack, and at least the rounding of one pixel either way.
    let slack = (0.01f64).max(1.0 / f64::from(w.min(h).max(1)));
    if w == 0 || h == 0 || (a / b - 1.0).abs() > slack {
        return Err(Error::Input(format!(
            "{what} is {w}×{h}, which does not have the image's aspect ratio ({image_w}×{image_h})"
        )));
    }
    Ok(())
}

/// The image as f32 RGB at `w × h` (unchanged when it already has that size).
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

/// Nearest-neighbour sample of a binary mask at working size (pixel centres).
fn sample_mask(mask: &GrayImage, w: usize, h: usize) -> Mask {
    let (mw, mh) = (mask.width() as usize, mask.height() as usize);
    Mask::from_fn(w, h, |x, y| {
        let (sx, sy) = (
            ((x * 2 + 1) * mw / (2 * w)).min(mw - 1),
            ((y * 2 + 1) * mh / (2 * h)).min(mh - 1),
        );
        mask.get_pixel(sx as u32, sy as u32).0[0] > 0
    })
}

/// One mask per distinct value of a label map, in order of first appearance.
fn label_masks(labels: &DynamicImage, w: usize, h: usize) -> Vec<Mask> {
    let rgba = labels.to_rgba16();
    let (mw, mh) = (rgba.width() as usize, rgba.height() as usize);
    let mut values: Vec<[u16; 4]> = Vec::new();
    let mut index = vec![0usize; w * h];
    for y in 0..h {
        for x in 0..w {
            let (sx, sy) = (
                ((x * 2 + 1) * mw / (2 * w)).min(mw - 1),
                ((y * 2 + 1) * mh / (2 * h)).min(mh - 1),
            );
            let v = rgba.get_pixel(sx as u32, sy as u32).0;
            index[y * w + x] = match values.iter().position(|&u| u == v) {
                Some(k) => k,
                None => {
                    values.push(v);
                    values.len() - 1
                }
            };
        }
    }
    (0..values.len())
        .map(|k| Mask::from_fn(w, h, |x, y| index[y * w + x] == k))
        .collect()
}
