//! Edit leakage: recolour one object of a photo by reference (paper Appendix D, as
//! `covec edit --reference` does) and measure, in CIEDE2000, how much the render changes outside
//! the object and how close it comes to the reference inside it (`covec eval --edits FILE`).
//! When one albedo path holds the object and something else (a red hat and a pink curtain),
//! the edit recolours both; the whole-image MSE of the unedited render does not show it.
//!
//! The masks file is a file of drawings ([`super::drawn`] gives the format) whose keywords are
//! `edit` and `object`, and whose `edit` line ends with the recolour:
//!
//! ```text
//! edit NAME WIDTH HEIGHT to R G B    recolour NAME's object to this sRGB colour's hue (0-255)
//! object ellipse|polygon ...         the object (`not` cuts out what is not)
//! ```

use crate::edit::{EditError, ReferenceParams, recolor_by_reference};
use crate::eval::drawn::{self, Drawing, Keywords, ParseError};
use crate::perceptual::{ciede2000, lab, srgb_of_lab};
use crate::render::Image;
use crate::render::composite::composite;
use crate::scene::Scene;

/// Pixels this close (px, at the measured size) to the object's outline count as neither
/// inside nor outside: a hand-drawn outline is not exact to the pixel, nor is a path's edge.
pub const BAND: usize = 2;

/// Chroma (CIELAB) under which a target colour has no hue to give.
const LEAST_CHROMA: f64 = 5.0;

/// One object to recolour.
#[derive(Clone, Debug, PartialEq)]
pub struct EditCase {
    /// Its mask, as drawn.
    pub object: Drawing,
    /// The colour whose CIELAB hue the object takes.
    pub colour: [f32; 3],
}

/// Reads a masks file (the format is in this module's documentation).
pub fn parse(text: &str) -> Result<Vec<EditCase>, ParseError> {
    let keywords = Keywords {
        head: "edit",
        shape: "object",
    };
    let cases = drawn::parse(text, keywords, |rest| {
        let ["to", rgb @ ..] = rest else {
            return Err("`edit` needs a name, a width, a height, `to` and a colour R G B".into());
        };
        let channels: Option<Vec<u8>> = rgb.iter().map(|c| c.parse().ok()).collect();
        let Some([r, g, b]) = channels.as_deref() else {
            return Err("the colour is R G B, each a whole number 0-255".into());
        };
        let colour = [r, g, b].map(|&c| f32::from(c) / 255.0);
        let [_, a, b] = lab(colour);
        if a.hypot(b) < LEAST_CHROMA {
            return Err(format!("{r} {g} {b} is grey: it has no hue to give"));
        }
        Ok(colour)
    })?;
    Ok(cases
        .into_iter()
        .map(|(object, colour)| EditCase { object, colour })
        .collect())
}

/// The reference edit: `photo` with each pixel inside `mask` turned to `colour`'s CIELAB hue,
/// its lightness and chroma kept (out-of-gamut channels clipped), as a hue shift in an image
/// editor would; shading and texture stay, grey pixels stay grey.
pub fn reference(photo: &Image, mask: &[bool], colour: [f32; 3]) -> Image {
    let [_, a, b] = lab(colour);
    let hue = b.atan2(a);
    let mut out = photo.clone();
    for (px, _) in out.data.chunks_exact_mut(3).zip(mask).filter(|(_, m)| **m) {
        let [l, a, b] = lab([px[0], px[1], px[2]]);
        let chroma = a.hypot(b);
        px.copy_from_slice(&srgb_of_lab([l, chroma * hue.cos(), chroma * hue.sin()]));
    }
    out
}

/// How an edit of one object kept to it, in CIEDE2000 (pixels within [`BAND`] of its outline
/// left out).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Leakage {
    /// Mean outside the object, between the edited and the unedited render: 0 when the edit
    /// kept to the object.
    pub outside: f32,
    /// Mean inside the object, between the edited render and the reference.
    pub inside: f32,
    /// How many albedo paths the edit recoloured.
    pub changed: usize,
}

/// Recolours `case`'s object in `scene` by reference (default [`ReferenceParams`]), `photo`
/// (at the scene's working size) being the original, and scores it; `None` when the object or
/// what lies outside it is empty at this size.
pub fn leakage(
    scene: &Scene,
    photo: &Image,
    case: &EditCase,
) -> Result<Option<Leakage>, EditError> {
    let mask = case.object.rasterize(photo.width, photo.height);
    let reference = reference(photo, &mask, case.colour);
    let edit = recolor_by_reference(scene, photo, &reference, &ReferenceParams::default())?;
    let renders = Renders {
        before: &composite(scene),
        after: &composite(&edit.scene),
        reference: &reference,
    };
    Ok(renders.score(&mask).map(|(outside, inside)| Leakage {
        outside,
        inside,
        changed: edit.changed.len(),
    }))
}

/// The three images [`leakage`] compares, all of one size.
struct Renders<'a> {
    before: &'a Image,
    after: &'a Image,
    reference: &'a Image,
}

impl Renders<'_> {
    /// Mean CIEDE2000 outside `mask` (after against before) and inside it (after against the
    /// reference), [`BAND`] left out; `None` when either side is empty.
    fn score(&self, mask: &[bool]) -> Option<(f32, f32)> {
        let (width, height) = (self.after.width, self.after.height);
        let colour = |image: &Image, i: usize| {
            let px = &image.data[3 * i..3 * i + 3];
            lab([px[0], px[1], px[2]])
        };
        let band = band(mask, width, height);
        let (mut outside, mut inside) = ((0f64, 0usize), (0f64, 0usize));
        for i in (0..width * height).filter(|&i| !band[i]) {
            let after = colour(self.after, i);
            let (sum, other) = if mask[i] {
                (&mut inside, self.reference)
            } else {
                (&mut outside, self.before)
            };
            sum.0 += ciede2000(after, colour(other, i));
            sum.1 += 1;
        }
        let mean = |(sum, n): (f64, usize)| (n > 0).then(|| (sum / n as f64) as f32);
        Some((mean(outside)?, mean(inside)?))
    }
}

/// The pixels within [`BAND`] px (Euclidean, between pixel centres) of one on the other side of
/// `mask`'s outline.
fn band(mask: &[bool], width: usize, height: usize) -> Vec<bool> {
    let reach = BAND as isize;
    (0..width * height)
        .map(|i| {
            let (x, y) = ((i % width) as isize, (i / width) as isize);
            (-reach..=reach).any(|dy| {
                (-reach..=reach).any(|dx| {
                    let (nx, ny) = (x + dx, y + dy);
                    dx * dx + dy * dy <= reach * reach
                        && (0..width as isize).contains(&nx)
                        && (0..height as isize).contains(&ny)
                        && mask[ny as usize * width + nx as usize] != mask[i]
                })
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Path;

    #[test]
    fn the_file_is_read_with_its_colours() {
        let text =
            "edit cap 64 32 to 32 80 208 # blue\nobject ellipse 32 16 8 8\nnot ellipse 32 16 2 2";
        let cases = parse(text).unwrap();
        assert_eq!(cases.len(), 1);
        assert_eq!(cases[0].object.image, "cap");
        assert_eq!(cases[0].colour, [32.0 / 255.0, 80.0 / 255.0, 208.0 / 255.0]);
        let mask = cases[0].object.rasterize(64, 32);
        assert!(mask[16 * 64 + 28] && !mask[16 * 64 + 32] && !mask[0]);
        let line = |text: &str| parse(text).unwrap_err().line;
        assert_eq!(line("edit cap 8 8"), 1, "no colour");
        assert_eq!(line("edit cap 8 8 to blue"), 1);
        assert_eq!(line("edit cap 8 8 to 32 80 256"), 1);
        assert_eq!(line("edit cap 8 8 to 32 80"), 1);
        assert_eq!(line("edit cap 8 8 to 32 80 208 9"), 1);
        assert_eq!(line("edit cap 8 8 to 128 128 128"), 1, "grey has no hue");
        assert_eq!(line("edit cap 8 8 to 32 80 208\nskin ellipse 1 1 1 1"), 2);
        let bench = parse(include_str!("../../benches/quality/edits.txt")).unwrap();
        assert!(bench.len() >= 3, "{} edits", bench.len());
        for case in &bench {
            let object = case.object.rasterize(64, 64).iter().filter(|&&v| v).count();
            assert!(object > 0, "{} has no object at 64²", case.object.image);
        }
    }

    #[test]
    fn the_reference_turns_the_hue_inside_only() {
        let (red, grey) = ([0.8, 0.1, 0.1], [0.5; 3]);
        let mut photo = Image::filled(2, 1, red);
        photo.data.extend_from_slice(&grey);
        photo.width = 3;
        let blue = [0.1, 0.2, 0.9];
        let out = reference(&photo, &[true, false, true], blue);
        let (turned, kept, still_grey) = (out.pixel(0, 0), out.pixel(1, 0), out.pixel(2, 0));
        assert_eq!(kept, red);
        assert!(ciede2000(lab(still_grey), lab(grey)) < 1e-3);
        let ([l0, a0, b0], [l1, a1, b1]) = (lab(red), lab(turned));
        assert!((l0 - l1).abs() < 3.0, "lightness {l0} -> {l1}");
        let [_, ab, bb] = lab(blue);
        let hue = |a: f64, b: f64| b.atan2(a).to_degrees();
        assert!((hue(a1, b1) - hue(ab, bb)).abs() < 5.0, "{turned:?}");
        assert!(a0.hypot(b0) > 50.0 && a1.hypot(b1) > 40.0, "chroma kept");
    }

    #[test]
    fn the_score_is_the_mean_outside_and_inside_without_the_band() {
        // 16 × 16; the object is the square [4, 12)², its band the pixels within 2 px of the
        // outline on either side. Outside, one pixel in the corner changed colour.
        let (w, h) = (16, 16);
        let mask: Vec<bool> = (0..w * h)
            .map(|i| (4..12).contains(&(i % w)) && (4..12).contains(&(i / w)))
            .collect();
        let before = Image::filled(w, h, [0.5; 3]);
        let mut after = before.clone();
        after.data[..3].copy_from_slice(&[0.9, 0.1, 0.1]);
        let reference = Image::filled(w, h, [0.5, 0.5, 0.6]);
        let renders = Renders {
            before: &before,
            after: &after,
            reference: &reference,
        };
        let (outside, inside) = renders.score(&mask).unwrap();
        // Outside without the band: 16² less the square grown by 2 px, whose corners are round
        // (3 of each corner's 2 × 2 pixels lie further than 2 px); inside, the 4 × 4 middle.
        let band = band(&mask, w, h);
        let counted_outside = (0..w * h).filter(|&i| !mask[i] && !band[i]).count();
        let counted_inside = (0..w * h).filter(|&i| mask[i] && !band[i]).count();
        assert_eq!(counted_inside, 16);
        assert_eq!(counted_outside, 16 * 16 - 12 * 12 + 4 * 3);
        let one = ciede2000(lab([0.9, 0.1, 0.1]), lab([0.5; 3]));
        assert!((f64::from(outside) - one / counted_outside as f64).abs() < 1e-4);
        let grey_to_blueish = ciede2000(lab([0.5; 3]), lab([0.5, 0.5, 0.6]));
        assert!((f64::from(inside) - grey_to_blueish).abs() < 1e-4);
        assert!(renders.score(&[false; 256]).is_none());
    }

    /// A grey canvas with a red bar [4, 28) × [12, 20) as one albedo path; the object drawn is
    /// its left half or the whole bar.
    fn bar_scene() -> Scene {
        let mut scene = Scene::new(32, 32, 32, 32);
        scene.albedo.paths = vec![
            Path::rect(0.0, 0.0, 32.0, 32.0, [0.5; 3], 1.0),
            Path::rect(4.0, 12.0, 28.0, 20.0, [0.8, 0.1, 0.1], 1.0),
        ];
        scene
    }

    #[test]
    fn an_edit_of_half_a_path_leaks_into_the_other_half() {
        let scene = bar_scene();
        let photo = composite(&scene);
        let case = |x1: u32| {
            let text =
                format!("edit bar 32 32 to 32 80 208\nobject polygon 4 12 {x1} 12 {x1} 20 4 20");
            parse(&text).unwrap().remove(0)
        };
        let whole = leakage(&scene, &photo, &case(28)).unwrap().unwrap();
        assert_eq!(whole.changed, 1);
        assert!(whole.outside < 1e-6, "{whole:?}");
        assert!(whole.inside < 0.5, "{whole:?}");
        // The object is the left half, but the path is the whole bar: its right half turns
        // too, far outside the band.
        let half = leakage(&scene, &photo, &case(16)).unwrap().unwrap();
        assert_eq!(half.changed, 1);
        assert!(half.outside > 1.0, "{half:?}");
    }
}
