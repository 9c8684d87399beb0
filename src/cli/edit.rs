//! `covec edit`: recolour albedo paths of a scene while shade and light keep the lighting.

use std::path::PathBuf;

use clap::Args as ClapArgs;

use super::io::{self, IoError};
use covec::edit::{self, ColorChange, EditError, ReferenceParams, Target};
use covec::imageio::Limits;
use covec::output::{self, EDIT_FILES, FileKind};
use covec::scene::{PathId, Point};
use covec::svg;

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
    /// its colours, divided by the shade under them (in photo mode a path that also paints
    /// outside the region is split: new paths over its parts inside take them); the shade and
    /// light paths lying (half or more) inside the recoloured region are refit to it.
    #[arg(long, value_name = "EDITED.png", required_unless_present_any = ["set", "at"])]
    pub reference: Option<PathBuf>,
    /// The original image the reference was edited from (same aspect ratio as the reference).
    /// Default: the scene's own rendering, which counts vectorisation error as edits too.
    #[arg(long, value_name = "IMAGE", requires = "reference")]
    pub original: Option<PathBuf>,
    /// Recolour or add at most this many albedo paths (largest first).
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
    #[error(transparent)]
    Io(#[from] IoError),
    #[error("`{0}` is not PATH_ID=#RRGGBB (e.g. albedo-3=#cc2200)")]
    BadSet(String),
    #[error("`{0}` is not X,Y=#RRGGBB (e.g. 120.5,88=#3366ff)")]
    BadAt(String),
    #[error(transparent)]
    Edit(#[from] EditError),
}

pub fn run(args: &Args) -> Result<(), Error> {
    let scene = io::read_scene(&args.scene)?;
    // An edit draws the scene at its canvas size (the default original, the preview).
    output::check_canvas(&scene, Limits::default().max_pixels).map_err(|source| {
        IoError::Canvas {
            path: args.scene.clone(),
            source,
        }
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
            let reference = io::decode_image(reference, &Limits::default())?;
            let original = (args.original.as_deref())
                .map(|path| io::decode_image(path, &Limits::default()))
                .transpose()?;
            edit::recolor_by_reference_images(&scene, &reference, original.as_ref(), &params)?
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

    let json = args
        .json
        .clone()
        .unwrap_or_else(|| args.output.with_extension("json"));
    let kinds: &[FileKind] = if args.preview.is_some() {
        EDIT_FILES
    } else {
        &[FileKind::SceneJson, FileKind::LayeredSvg]
    };
    io::write_artefacts(&output::artefacts(&edit.scene, kinds), |kind| match kind {
        FileKind::LayeredSvg => Some(args.output.clone()),
        FileKind::SceneJson => Some(json.clone()),
        FileKind::Preview => args.preview.clone(),
        FileKind::Layer(_) | FileKind::FlatSvg | FileKind::Pdf => None,
    })?;
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
