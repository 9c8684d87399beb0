//! `covec render`: a JSON scene to a PNG of any width, drawn by covec's own renderer.

use std::path::PathBuf;

use clap::Args as ClapArgs;

use super::io::{self, IoError};
use covec::imageio::Limits;

/// Render a JSON scene to PNG with covec's own renderer (the picture that was optimised).
///
/// Example:
///   covec render photo.json -o photo-2048.png --width 2048
#[derive(ClapArgs, Debug)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// The JSON scene written by `covec vectorize` (or the service's scene.json).
    pub scene: PathBuf,
    /// Where to write the PNG. Default: the scene path with the extension `.png`.
    #[arg(short, long, value_name = "OUT.png")]
    pub output: Option<PathBuf>,
    /// Width in pixels; the height keeps the aspect ratio. Default: the original image's width.
    #[arg(long, value_name = "PX")]
    pub width: Option<u32>,
    /// Refuse to render more pixels than this.
    #[arg(long, default_value_t = Limits::default().max_pixels, value_name = "N")]
    pub max_pixels: u64,
}

/// Why `covec render` failed; printed as one line.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Io(#[from] IoError),
    #[error("{0}: covec render writes PNG; give -o a .png path")]
    NotPng(PathBuf),
}

pub fn run(args: &Args) -> Result<(), Error> {
    let output = args
        .output
        .clone()
        .unwrap_or_else(|| args.scene.with_extension("png"));
    if !io::is_png_output(&output) {
        return Err(Error::NotPng(output));
    }
    let scene = io::read_scene(&args.scene)?;
    io::write_png(&output, &scene, args.width, args.max_pixels)?;
    Ok(())
}
