//! Masks drawn by hand on bench images (ellipses and polygons in a text file), shared by the
//! skin masks of [`super::faces`] and the object masks of [`super::edits`].
//!
//! A file is one statement a line (`#` starts a comment); each file names its own two keywords,
//! HEAD and SHAPE (`face` and `skin`, `edit` and `object`):
//!
//! ```text
//! HEAD NAME WIDTH HEIGHT ...     the image whose file stem is NAME, drawn at WIDTH × HEIGHT px
//!                                (what else the line holds is the file's own)
//! SHAPE ellipse CX CY RX RY      inside this ellipse (pixel units of the drawing)
//! SHAPE polygon X Y X Y X Y ...  inside this polygon
//! not ellipse|polygon ...        outside, though inside a SHAPE (an eye, the mouth)
//! as OTHER X Y SIZE              OTHER's shapes, scaled so its width is SIZE px, moved to (X, Y)
//! ```
//!
//! Shapes are scaled to whatever size the image is measured at.

/// One shape of a mask, in the drawing's pixel units (y down).
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

/// One image's mask as drawn: its shapes less the `not` shapes.
#[derive(Clone, Debug, PartialEq)]
pub struct Drawing {
    /// The file stem of the image it belongs to.
    pub image: String,
    width: f32,
    height: f32,
    /// Each shape, and whether it adds to the mask (else it is cut out).
    shapes: Vec<(bool, Outline)>,
}

impl Drawing {
    /// The size it was drawn at (its `face` or `edit` line's), in whole pixels.
    pub fn drawn_size(&self) -> (usize, usize) {
        (self.width.round() as usize, self.height.round() as usize)
    }

    /// The mask at `width × height` (the image scaled), sampled at pixel centres, row-major.
    pub fn rasterize(&self, width: usize, height: usize) -> Vec<bool> {
        let (sx, sy) = (self.width / width as f32, self.height / height as f32);
        (0..width * height)
            .map(|i| {
                let x = ((i % width) as f32 + 0.5) * sx;
                let y = ((i / width) as f32 + 0.5) * sy;
                let mut inside = false;
                for (adds, shape) in &self.shapes {
                    if shape.contains(x, y) {
                        if !adds {
                            return false;
                        }
                        inside = true;
                    }
                }
                inside
            })
            .collect()
    }
}

/// A line of a masks file that could not be read.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("line {line}: {reason}")]
pub struct ParseError {
    /// Its number, from 1.
    pub line: usize,
    /// What is wrong with it.
    pub reason: String,
}

/// The two keywords of a masks file (see the module's documentation).
#[derive(Clone, Copy, Debug)]
pub struct Keywords {
    /// Starts a drawing: `face`, `edit`.
    pub head: &'static str,
    /// Adds a shape to the mask: `skin`, `object`.
    pub shape: &'static str,
}

/// Reads a masks file. `rest` reads what a HEAD line holds after its size (its words, possibly
/// none) into the drawing's `T`, or says what is wrong with them.
pub fn parse<T>(
    text: &str,
    keywords: Keywords,
    rest: impl Fn(&[&str]) -> Result<T, String>,
) -> Result<Vec<(Drawing, T)>, ParseError> {
    let Keywords { head, shape } = keywords;
    let mut drawings: Vec<(Drawing, T)> = Vec::new();
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
        let Some((&keyword, args)) = words.split_first() else {
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
        if keyword == head {
            let [name, width, height, more @ ..] = args else {
                return Err(fail(format!("`{head}` needs a name, a width and a height")));
            };
            let size = numbers(&[width, height])?;
            let (width, height) = (size[0], size[1]);
            if width <= 0.0 || height <= 0.0 {
                return Err(fail("the size must be positive".into()));
            }
            if drawings.iter().any(|(d, _)| d.image == *name) {
                return Err(fail(format!("`{name}` is drawn twice")));
            }
            let extra = rest(more).map_err(fail)?;
            let drawing = Drawing {
                image: name.to_string(),
                width,
                height,
                shapes: Vec::new(),
            };
            drawings.push((drawing, extra));
            continue;
        }
        let (earlier, current) = match drawings.split_last_mut() {
            Some(((current, _), earlier)) => (earlier, current),
            None => return Err(fail(format!("`{keyword}` before any `{head}`"))),
        };
        if keyword == shape || keyword == "not" {
            let outline = match args {
                ["ellipse", values @ ..] => match numbers(values)?[..] {
                    [cx, cy, rx, ry] if rx > 0.0 && ry > 0.0 => Outline::Ellipse { cx, cy, rx, ry },
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
            current.shapes.push((keyword == shape, outline));
        } else if keyword == "as" {
            let [other, place @ ..] = args else {
                return Err(fail(format!("`as` needs a {head}, X, Y and a size")));
            };
            let [x, y, size] = numbers(place)?[..] else {
                return Err(fail(format!("`as` needs a {head}, X, Y and a size")));
            };
            let Some((other, _)) = earlier.iter().find(|(d, _)| d.image == *other) else {
                return Err(fail(format!("no {head} `{other}` drawn above")));
            };
            let scale = size / other.width;
            current.shapes.extend(
                other
                    .shapes
                    .iter()
                    .map(|(adds, s)| (*adds, s.placed(scale, [x, y]))),
            );
        } else {
            return Err(fail(format!("unknown statement `{keyword}`")));
        }
    }
    Ok(drawings)
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

    /// The masks of `text`, with the faces' keywords and no more on a `face` line.
    fn parse(text: &str) -> Result<Vec<Drawing>, ParseError> {
        let keywords = Keywords {
            head: "face",
            shape: "skin",
        };
        let drawings = super::parse(text, keywords, |rest| {
            rest.is_empty().then_some(()).ok_or("more".to_string())
        })?;
        Ok(drawings.into_iter().map(|(d, ())| d).collect())
    }

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
    fn bad_lines_are_refused_with_their_number() {
        let line = |text: &str| parse(text).unwrap_err().line;
        assert_eq!(line("skin ellipse 1 1 1 1"), 1);
        assert_eq!(line("face a 8 8\n\nskin ellipse 1 1 0 1"), 3);
        assert_eq!(line("face a 8 8\nskin polygon 1 1 2 2"), 2);
        assert_eq!(line("face a 8 8\nas b 0 0 4"), 2);
        assert_eq!(line("face a 8 8\nface a 8 8"), 2);
        assert_eq!(line("face a 8 x"), 1);
        assert_eq!(line("face a 8 8\nskin square 1 1 1"), 2);
        assert_eq!(line("face a 8 8\nobject ellipse 1 1 1 1"), 2);
        assert_eq!(line("face a 8 8 more"), 1);
        assert_eq!(line("face a 8"), 1);
    }
}
