//! `covec render`: a JSON scene to a PNG of any width, drawn by covec's own renderer.

use std::path::PathBuf;

use clap::Args as ClapArgs;

use super::io::{self, IoError};
use covec::imageio::Limits;
use covec::output::{self, FileKind};

/// Render a JSON scene: a PNG of any width drawn by covec's own renderer (the picture that was
/// optimised), or the layered or flattened SVG, the PDF or the JSON scene again.
///
/// Examples:
///   covec render photo.json -o photo-2048.png --width 2048
///   covec render photo.json -o photo.pdf
#[derive(ClapArgs, Debug)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// The JSON scene written by `covec vectorize` (or the service's scene.json); `-`: standard
    /// input.
    pub scene: PathBuf,
    /// Where to write: a `.png`, `.svg` (layered, flattened with --flatten), `.pdf` or `.json`
    /// path (see --format); `-`: standard output. Default: the scene path with the extension
    /// `.png`.
    #[arg(short, long, value_name = "OUT.png|OUT.svg|OUT.pdf|-")]
    pub output: Option<PathBuf>,
    /// What to write, whatever the output's extension. Default: from the extension (PNG for `-`).
    #[arg(long, value_enum, value_name = "FORMAT")]
    pub format: Option<io::Format>,
    /// Width of a PNG in pixels; the height keeps the aspect ratio. Default: the original
    /// image's width.
    #[arg(long, value_name = "PX")]
    pub width: Option<u32>,
    /// Write the SVG flattened: plain opaque paths, without blend modes or opacities.
    #[arg(long)]
    pub flatten: bool,
    /// Refuse to render more pixels than this.
    #[arg(long, default_value_t = Limits::default().max_pixels, value_name = "N")]
    pub max_pixels: u64,
}

/// Why `covec render` failed; printed as one line.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Io(#[from] IoError),
    #[error(
        "{0}: no format in its extension; give -o a .png, .svg, .pdf or .json path, or --format"
    )]
    NoFormat(PathBuf),
    #[error("--width sets the size of a PNG output")]
    WidthWithoutPng,
    #[error("--flatten applies to an SVG output")]
    FlattenWithoutSvg,
}

pub fn run(args: &Args) -> Result<(), Error> {
    let output = args
        .output
        .clone()
        .unwrap_or_else(|| args.scene.with_extension("png"));
    let format = match args.format.or_else(|| io::Format::of_path(&output)) {
        Some(format) => format,
        None if io::is_stdio(&output) => io::Format::Png,
        None => return Err(Error::NoFormat(output)),
    };
    if args.width.is_some() && format != io::Format::Png {
        return Err(Error::WidthWithoutPng);
    }
    if args.flatten && format != io::Format::Svg {
        return Err(Error::FlattenWithoutSvg);
    }
    let scene = io::read_scene(&args.scene)?;
    let kind = match format {
        io::Format::Png => {
            io::write_png(&output, &scene, args.width, args.max_pixels)?;
            return Ok(());
        }
        io::Format::Svg if args.flatten => FileKind::FlatSvg,
        io::Format::Svg => FileKind::LayeredSvg,
        io::Format::Pdf => FileKind::Pdf,
        io::Format::Json => FileKind::SceneJson,
    };
    io::write_artefacts(&output::artefacts(&scene, &[kind]), |_| {
        Some(output.clone())
    })?;
    Ok(())
}
