//! `covec edit`: recolour albedo paths of a scene while shade and light keep the lighting.

use std::path::{Path, PathBuf};

use clap::Args as ClapArgs;

use covec::decompose::resize_rgb;
use covec::edit::{self, ColorChange, EditError, ReferenceParams, Target};
use covec::imageio::{self, InputError, Limits};
use covec::pipeline;
use covec::scene::{PathId, Point, Scene};
use covec::svg::{self, SvgOptions};

/// Recolour a vectorised scene: from an edited reference image (paper Appendix D) or by path.
///
/// Examples:
///   covec edit photo.json --reference edited.png --original photo.png --k 4 -o edited.svg
///   covec edit photo.json --set albedo-3=#cc2200 --at 120.5,88=#3366ff -o edited.svg
#[derive(ClapArgs, Debug)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// The JSON scene written by `covec vectorize` (or the service's scene.json).
    pub scene: PathBuf,
    /// An edited copy of the original image: the albedo paths under the edited region take
    /// its colours, divided by the shade under them.
    #[arg(long, value_name = "EDITED.png", required_unless_present_any = ["set", "at"])]
    pub reference: Option<PathBuf>,
    /// The original image the reference was edited from (same size as the reference).
    /// Default: the scene's own rendering, which counts vectorisation error as edits too.
    #[arg(long, value_name = "IMAGE", requires = "reference")]
    pub original: Option<PathBuf>,
    /// Recolour at most this many paths (largest first).
    #[arg(long, default_value_t = ReferenceParams::default().k, requires = "reference")]
    pub k: usize,
    /// Edit-region threshold: mean absolute channel difference in [0, 1].
    #[arg(long, default_value_t = ReferenceParams::default().tau, requires = "reference")]
    pub tau: f32,
    /// Least IoU of a path's silhouette with the edit region.
    #[arg(long, default_value_t = ReferenceParams::default().gamma, requires = "reference")]
    pub gamma: f32,
    /// Least change of a path's mean colour (L2 over RGB in [0, 1]).
    #[arg(long, default_value_t = ReferenceParams::default().delta, requires = "reference")]
    pub delta: f32,
    /// Added to the mean shade before dividing by it.
    #[arg(long, default_value_t = ReferenceParams::default().epsilon, requires = "reference")]
    pub epsilon: f32,
    /// Set a path's colour: PATH_ID=#RRGGBB (e.g. albedo-3=#cc2200); repeatable.
    #[arg(long, value_name = "PATH_ID=#RRGGBB", conflicts_with = "reference")]
    pub set: Vec<String>,
    /// Set the colour of the albedo path under a point (viewBox coordinates): X,Y=#RRGGBB.
    #[arg(long, value_name = "X,Y=#RRGGBB", conflicts_with = "reference")]
    pub at: Vec<String>,
    /// Where to write the edited layered SVG.
    #[arg(short, long, value_name = "OUT.svg")]
    pub output: PathBuf,
    /// Where to write the edited JSON scene. Default: the SVG path with the extension `.json`.
    #[arg(long, value_name = "SCENE.json")]
    pub json: Option<PathBuf>,
    /// Also write a preview PNG of the edited scene, as covec's renderer draws it.
    #[arg(long, value_name = "OUT.png")]
    pub preview: Option<PathBuf>,
}

/// Why `covec edit` failed; printed as one line.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("cannot read {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot write {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path} is not a covec scene: {source}")]
    Scene {
        path: PathBuf,
        source: serde_json::Error,
    },
    #[error("{path}: {source}")]
    Image { path: PathBuf, source: InputError },
    #[error("`{0}` is not PATH_ID=#RRGGBB (e.g. albedo-3=#cc2200)")]
    BadSet(String),
    #[error("`{0}` is not X,Y=#RRGGBB (e.g. 120.5,88=#3366ff)")]
    BadAt(String),
    #[error("the reference is {0}×{1} but the original is {2}×{3}; they must be the same size")]
    SizeMismatch(u32, u32, u32, u32),
    #[error("the reference's aspect ratio differs from the scene's ({0}×{1})")]
    AspectMismatch(u32, u32),
    #[error(transparent)]
    Edit(#[from] EditError),
}

pub fn run(args: &Args) -> Result<(), Error> {
    let bytes = read(&args.scene)?;
    let scene: Scene = serde_json::from_slice(&bytes).map_err(|source| Error::Scene {
        path: args.scene.clone(),
        source,
    })?;
    let edit = match &args.reference {
        Some(reference) => {
            let params = ReferenceParams {
                k: args.k,
                tau: args.tau,
                gamma: args.gamma,
                delta: args.delta,
                epsilon: args.epsilon,
            };
            let reference_image = decode(reference)?;
            let (rw, rh) = (reference_image.width(), reference_image.height());
            // Same aspect ratio as the scene's original, within one pixel of rounding.
            if (u64::from(rw) * u64::from(scene.original_height))
                .abs_diff(u64::from(rh) * u64::from(scene.original_width))
                > u64::from(rw.max(rh))
            {
                return Err(Error::AspectMismatch(
                    scene.original_width,
                    scene.original_height,
                ));
            }
            let (w, h) = (scene.width, scene.height);
            let original = match &args.original {
                Some(path) => {
                    let original = decode(path)?;
                    if (original.width(), original.height()) != (rw, rh) {
                        return Err(Error::SizeMismatch(
                            rw,
                            rh,
                            original.width(),
                            original.height(),
                        ));
                    }
                    resize_rgb(&original, w, h)
                }
                None => pipeline::composite(&scene),
            };
            edit::recolor_by_reference(
                &scene,
                &original,
                &resize_rgb(&reference_image, w, h),
                &params,
            )?
        }
        None => {
            let mut changes = Vec::new();
            for set in &args.set {
                changes.push(parse_set(set).ok_or_else(|| Error::BadSet(set.clone()))?);
            }
            for at in &args.at {
                changes.push(parse_at(at).ok_or_else(|| Error::BadAt(at.clone()))?);
            }
            edit::recolor_paths(&scene, &changes)?
        }
    };

    let options = SvgOptions::default();
    write(&args.output, svg::to_svg(&edit.scene, &options).as_bytes())?;
    let json = args
        .json
        .clone()
        .unwrap_or_else(|| args.output.with_extension("json"));
    write(
        &json,
        &serde_json::to_vec_pretty(&edit.scene).expect("a scene serialises"),
    )?;
    if let Some(preview) = &args.preview {
        write(
            preview,
            &imageio::encode_png(&pipeline::composite(&edit.scene)),
        )?;
    }
    if edit.changed.is_empty() {
        println!("no path changed");
    }
    for c in &edit.changed {
        println!(
            "{}: {} -> {}",
            c.path,
            svg::hex_colour(c.old_color),
            svg::hex_colour(c.new_color)
        );
    }
    Ok(())
}

fn parse_set(text: &str) -> Option<ColorChange> {
    let (id, colour) = text.split_once('=')?;
    let id: PathId = id.trim().parse().ok()?;
    Some(ColorChange {
        target: Target::Path(id),
        color: svg::parse_hex_colour(colour.trim())?,
        opacity: None,
    })
}

fn parse_at(text: &str) -> Option<ColorChange> {
    let (point, colour) = text.split_once('=')?;
    let (x, y) = point.split_once(',')?;
    let point = Point::new(x.trim().parse().ok()?, y.trim().parse().ok()?);
    Some(ColorChange {
        target: Target::AlbedoAt(point),
        color: svg::parse_hex_colour(colour.trim())?,
        opacity: None,
    })
}

fn read(path: &Path) -> Result<Vec<u8>, Error> {
    std::fs::read(path).map_err(|source| Error::Read {
        path: path.to_owned(),
        source,
    })
}

fn write(path: &Path, bytes: &[u8]) -> Result<(), Error> {
    std::fs::write(path, bytes).map_err(|source| Error::Write {
        path: path.to_owned(),
        source,
    })
}

fn decode(path: &Path) -> Result<image::DynamicImage, Error> {
    imageio::decode_image(&read(path)?, &Limits::default()).map_err(|source| Error::Image {
        path: path.to_owned(),
        source,
    })
}
