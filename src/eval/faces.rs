//! Skin colour on faces: how far a render's skin is from the photo's, in CIEDE2000, inside
//! skin masks drawn by hand (`covec eval --faces FILE`). A face whose albedo path was not kept
//! takes the colour of what lies around it (a grey wall), which MSE over the whole image
//! hardly sees and a person sees at once.
//!
//! The masks file is a file of drawings ([`super::drawn`] gives the format) whose keywords are
//! `face` and `skin`: `skin` shapes are skin, `not` shapes cut out what is not (an eye, the
//! mouth).

use crate::eval::drawn::{self, Drawing, Keywords, ParseError};
use crate::perceptual::{ciede2000, lab};
use crate::render::Image;

/// Reads a masks file (the format is in this module's documentation).
pub fn parse(text: &str) -> Result<Vec<Drawing>, ParseError> {
    let keywords = Keywords {
        head: "face",
        shape: "skin",
    };
    let faces = drawn::parse(text, keywords, |rest| match rest {
        [] => Ok(()),
        _ => Err("`face` needs a name, a width and a height, and no more".into()),
    })?;
    Ok(faces.into_iter().map(|(face, ())| face).collect())
}

/// How far a render's skin is from the photo's, in CIEDE2000.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SkinScores {
    /// Between the mean skin colours (means taken in CIELAB).
    pub mean_colour: f32,
    /// Mean over the skin pixels of the per-pixel difference.
    pub per_pixel: f32,
}

/// [`SkinScores`] of `render` against `photo` (same size) inside `mask` (row-major, one entry
/// a pixel); `None` when the mask is empty.
pub fn skin_scores(render: &Image, photo: &Image, mask: &[bool]) -> Option<SkinScores> {
    assert_eq!(
        (render.width, render.height),
        (photo.width, photo.height),
        "the render and the photo differ in size"
    );
    assert_eq!(mask.len(), photo.width * photo.height, "the mask's size");
    let colour = |image: &Image, i: usize| {
        let px = &image.data[3 * i..3 * i + 3];
        lab([px[0], px[1], px[2]])
    };
    let (mut sum_render, mut sum_photo, mut sum_de, mut n) = ([0f64; 3], [0f64; 3], 0f64, 0usize);
    for i in (0..mask.len()).filter(|&i| mask[i]) {
        let (r, p) = (colour(render, i), colour(photo, i));
        for c in 0..3 {
            sum_render[c] += r[c];
            sum_photo[c] += p[c];
        }
        sum_de += ciede2000(r, p);
        n += 1;
    }
    (n > 0).then(|| {
        let mean = |sum: [f64; 3]| sum.map(|s| s / n as f64);
        SkinScores {
            mean_colour: ciede2000(mean(sum_render), mean(sum_photo)) as f32,
            per_pixel: (sum_de / n as f64) as f32,
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_bench_masks_file_reads() {
        let faces = parse(include_str!("../../benches/quality/faces.txt")).unwrap();
        assert!(faces.len() >= 10, "{} faces", faces.len());
        for face in &faces {
            let skin = face.rasterize(64, 64).iter().filter(|&&v| v).count();
            assert!(skin > 0, "{} has no skin at 64²", face.image);
        }
    }

    #[test]
    fn grey_skin_is_far_from_skin_and_skin_is_near() {
        let skin = [0.87, 0.67, 0.55];
        let photo = Image::filled(8, 8, skin);
        let mask = vec![true; 64];
        let same = skin_scores(&photo, &photo, &mask).unwrap();
        assert_eq!((same.mean_colour, same.per_pixel), (0.0, 0.0));
        let grey = Image::filled(8, 8, [0.7; 3]);
        let far = skin_scores(&grey, &photo, &mask).unwrap();
        assert!(far.mean_colour > 10.0, "{far:?}");
        // Noise that averages out: the mean colour is close, the pixels are not.
        let mut noisy = photo.clone();
        for (i, v) in noisy.data.iter_mut().enumerate() {
            *v += if (i / 3) % 2 == 0 { 0.08 } else { -0.08 };
        }
        let noisy = skin_scores(&noisy, &photo, &mask).unwrap();
        assert!(noisy.mean_colour < 1.0, "{noisy:?}");
        assert!(noisy.per_pixel > 3.0, "{noisy:?}");
        assert!(skin_scores(&photo, &photo, &[false; 64]).is_none());
    }
}
