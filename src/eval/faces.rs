//! Skin colour on faces: how far a render's skin is from the photo's, in CIEDE2000, inside
//! skin masks drawn by hand (`covec eval --faces FILE`). A face whose albedo path was not kept
//! takes the colour of what lies around it (a grey wall), which MSE over the whole image
//! hardly sees and a person sees at once.
//!
//! The masks file, one statement a line (`#` starts a comment):
//!
//! ```text
//! face NAME WIDTH HEIGHT        the image whose file stem is NAME, drawn at WIDTH × HEIGHT px
//! skin ellipse CX CY RX RY      skin inside this ellipse (pixel units of the drawing)
//! skin polygon X Y X Y X Y ...  skin inside this polygon
//! not ellipse|polygon ...       not skin, though inside a skin shape (an eye, the mouth)
//! as OTHER X Y SIZE             OTHER's shapes, scaled so its width is SIZE px, moved to (X, Y)
//! ```
//!
//! Shapes are scaled to whatever size the image is measured at.

use crate::perceptual::{ciede2000, lab};
use crate::render::Image;

/// One shape of a face's skin mask, in the drawing's pixel units (y down).
#[derive(Clone, Debug, PartialEq)]
enum Outline {
    Ellipse { cx: f32, cy: f32, rx: f32, ry: f32 },
    Polygon(Vec<[f32; 2]>),
}

impl Outline {
    fn contains(&self, x: f32, y: f32) -> bool {
        match self {
            Outline::Ellipse { cx, cy, rx, ry } => {
                ((x - cx) / rx).powi(2) + ((y - cy) / ry).powi(2) <= 1.0
            }
            Outline::Polygon(points) => {
                // Even-odd rule, a ray to +x.
                let mut inside = false;
                let mut j = points.len() - 1;
                for (i, p) in points.iter().enumerate() {
                    let q = points[j];
                    if (p[1] > y) != (q[1] > y)
                        && x < p[0] + (y - p[1]) * (q[0] - p[0]) / (q[1] - p[1])
                    {
                        inside = !inside;
                    }
                    j = i;
                }
                inside
            }
        }
    }

    /// The shape scaled by `scale` about the origin, then moved by `offset`.
    fn placed(&self, scale: f32, offset: [f32; 2]) -> Self {
        let at = |p: [f32; 2]| [offset[0] + scale * p[0], offset[1] + scale * p[1]];
        match self {
            Outline::Ellipse { cx, cy, rx, ry } => {
                let [cx, cy] = at([*cx, *cy]);
                Outline::Ellipse {
                    cx,
                    cy,
                    rx: scale * rx,
                    ry: scale * ry,
                }
            }
            Outline::Polygon(points) => Outline::Polygon(points.iter().map(|&p| at(p)).collect()),
        }
    }
}

/// One face's skin mask as drawn: skin shapes less the `not` shapes.
#[derive(Clone, Debug, PartialEq)]
pub struct FaceMask {
    /// The file stem of the image it belongs to.
    pub image: String,
    width: f32,
    height: f32,
    /// Each shape, and whether it is skin (else it is cut out).
    shapes: Vec<(bool, Outline)>,
}

impl FaceMask {
    /// The mask at `width × height` (the image scaled), sampled at pixel centres, row-major.
    pub fn rasterize(&self, width: usize, height: usize) -> Vec<bool> {
        let (sx, sy) = (self.width / width as f32, self.height / height as f32);
        (0..width * height)
            .map(|i| {
                let x = ((i % width) as f32 + 0.5) * sx;
                let y = ((i / width) as f32 + 0.5) * sy;
                let mut skin = false;
                for (is_skin, shape) in &self.shapes {
                    if shape.contains(x, y) {
                        if !is_skin {
                            return false;
                        }
                        skin = true;
                    }
                }
                skin
            })
            .collect()
    }
}

/// A line of the masks file that could not be read.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("line {line}: {reason}")]
pub struct ParseError {
    /// Its number, from 1.
    pub line: usize,
    /// What is wrong with it.
    pub reason: String,
}

/// Reads a masks file (the format is in this module's documentation).
pub fn parse(text: &str) -> Result<Vec<FaceMask>, ParseError> {
    let mut faces: Vec<FaceMask> = Vec::new();
    for (index, raw) in text.lines().enumerate() {
        let fail = |reason: String| ParseError {
            line: index + 1,
            reason,
        };
        let words: Vec<&str> = raw
            .split('#')
            .next()
            .unwrap_or("")
            .split_whitespace()
            .collect();
        let Some((&keyword, rest)) = words.split_first() else {
            continue;
        };
        let numbers = |words: &[&str]| -> Result<Vec<f32>, ParseError> {
            words
                .iter()
                .map(|w| match w.parse::<f32>() {
                    Ok(v) if v.is_finite() => Ok(v),
                    _ => Err(fail(format!("`{w}` is not a number"))),
                })
                .collect()
        };
        if keyword == "face" {
            let [name, size @ ..] = rest else {
                return Err(fail("`face` needs a name, a width and a height".into()));
            };
            let size = numbers(size)?;
            let [width, height] = size[..] else {
                return Err(fail("`face` needs a name, a width and a height".into()));
            };
            if width <= 0.0 || height <= 0.0 {
                return Err(fail("the size must be positive".into()));
            }
            if faces.iter().any(|f| f.image == *name) {
                return Err(fail(format!("`{name}` is drawn twice")));
            }
            faces.push(FaceMask {
                image: name.to_string(),
                width,
                height,
                shapes: Vec::new(),
            });
            continue;
        }
        let (earlier, current) = match faces.split_last_mut() {
            Some((current, earlier)) => (earlier, current),
            None => return Err(fail(format!("`{keyword}` before any `face`"))),
        };
        match keyword {
            "skin" | "not" => {
                let shape = match rest {
                    ["ellipse", values @ ..] => match numbers(values)?[..] {
                        [cx, cy, rx, ry] if rx > 0.0 && ry > 0.0 => {
                            Outline::Ellipse { cx, cy, rx, ry }
                        }
                        _ => return Err(fail("an ellipse is CX CY RX RY, radii positive".into())),
                    },
                    ["polygon", values @ ..] => {
                        let values = numbers(values)?;
                        if values.len() < 6 || values.len() % 2 != 0 {
                            return Err(fail("a polygon is at least 3 points, X Y each".into()));
                        }
                        Outline::Polygon(values.chunks_exact(2).map(|p| [p[0], p[1]]).collect())
                    }
                    _ => return Err(fail("a shape is `ellipse` or `polygon`".into())),
                };
                current.shapes.push((keyword == "skin", shape));
            }
            "as" => {
                let [other, place @ ..] = rest else {
                    return Err(fail("`as` needs a face, X, Y and a size".into()));
                };
                let [x, y, size] = numbers(place)?[..] else {
                    return Err(fail("`as` needs a face, X, Y and a size".into()));
                };
                let Some(other) = earlier.iter().find(|f| f.image == *other) else {
                    return Err(fail(format!("no face `{other}` drawn above")));
                };
                let scale = size / other.width;
                current.shapes.extend(
                    other
                        .shapes
                        .iter()
                        .map(|(skin, s)| (*skin, s.placed(scale, [x, y]))),
                );
            }
            _ => return Err(fail(format!("unknown statement `{keyword}`"))),
        }
    }
    Ok(faces)
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

    const FILE: &str = "
# two faces
face small 32 32
skin ellipse 16 16 10 12
not polygon 10 10 14 10 14 14 10 14   # an eye
face pasted 64 64
as small 32 0 16   # half size, top right
";

    #[test]
    fn masks_are_read_scaled_and_cut() {
        let faces = parse(FILE).unwrap();
        assert_eq!(faces.len(), 2);
        let small = faces[0].rasterize(32, 32);
        let at = |mask: &[bool], w: usize, x: usize, y: usize| mask[y * w + x];
        assert!(at(&small, 32, 16, 16), "the face's middle");
        assert!(!at(&small, 32, 12, 12), "the eye is cut out");
        assert!(!at(&small, 32, 1, 1), "outside");
        // At twice the size the same shapes cover four times the pixels.
        let count = |m: &[bool]| m.iter().filter(|&&v| v).count();
        let large = faces[0].rasterize(64, 64);
        let ratio = count(&large) as f32 / count(&small) as f32;
        assert!((ratio - 4.0).abs() < 0.2, "{ratio}");
        // `as`: the small face at half size at (32, 0).
        let pasted = faces[1].rasterize(64, 64);
        assert!(at(&pasted, 64, 40, 8));
        assert!(!at(&pasted, 64, 38, 6), "the eye, moved");
        assert!(!at(&pasted, 64, 16, 16), "where the small face was");
        // At half the scale on the same pixel grid: a quarter of the pixels.
        let ratio = count(&pasted) as f32 / count(&small) as f32;
        assert!((ratio - 0.25).abs() < 0.03, "{ratio}");
    }

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
    fn bad_lines_are_refused_with_their_number() {
        let line = |text: &str| parse(text).unwrap_err().line;
        assert_eq!(line("skin ellipse 1 1 1 1"), 1);
        assert_eq!(line("face a 8 8\n\nskin ellipse 1 1 0 1"), 3);
        assert_eq!(line("face a 8 8\nskin polygon 1 1 2 2"), 2);
        assert_eq!(line("face a 8 8\nas b 0 0 4"), 2);
        assert_eq!(line("face a 8 8\nface a 8 8"), 2);
        assert_eq!(line("face a 8 x"), 1);
        assert_eq!(line("face a 8 8\nskin square 1 1 1"), 2);
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
