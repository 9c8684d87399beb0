//! Files for the subcommands: reading, writing and decoding with the path in every error, and
//! writing a scene's [`Artefact`]s where the command line puts them.

use std::path::{Path, PathBuf};

use covec::imageio::{self, InputError, Limits};
use covec::output::{self, Artefact, FileKind, RasterError};
use covec::scene::Scene;

/// A file that could not be read, written or decoded; printed as one line.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
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
    #[error("{path}: {source}")]
    Input { path: PathBuf, source: InputError },
    #[error("{path} is not a covec scene: {source}")]
    Scene {
        path: PathBuf,
        source: serde_json::Error,
    },
    #[error("cannot write {path}: {source}")]
    Raster { path: PathBuf, source: RasterError },
    #[error("{path}: {source}")]
    Canvas { path: PathBuf, source: RasterError },
}

/// Whether `path` is `-`, which stands for standard input (read) or output (write).
pub fn is_stdio(path: &Path) -> bool {
    path.as_os_str() == "-"
}

pub fn read(path: &Path) -> Result<Vec<u8>, IoError> {
    let bytes = if is_stdio(path) {
        let mut bytes = Vec::new();
        std::io::Read::read_to_end(&mut std::io::stdin().lock(), &mut bytes).map(|_| bytes)
    } else {
        std::fs::read(path)
    };
    bytes.map_err(|source| IoError::Read {
        path: path.into(),
        source,
    })
}

pub fn write(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    let written = if is_stdio(path) {
        let mut stdout = std::io::stdout().lock();
        std::io::Write::write_all(&mut stdout, bytes)
            .and_then(|()| std::io::Write::flush(&mut stdout))
    } else {
        std::fs::write(path, bytes)
    };
    written.map_err(|source| IoError::Write {
        path: path.into(),
        source,
    })
}

pub fn create_dir(dir: &Path) -> Result<(), IoError> {
    std::fs::create_dir_all(dir).map_err(|source| IoError::Write {
        path: dir.into(),
        source,
    })
}

/// The entries of a directory, in file-name order.
pub fn list_dir(dir: &Path) -> Result<Vec<PathBuf>, IoError> {
    let unreadable = |source| IoError::Read {
        path: dir.into(),
        source,
    };
    let mut paths = std::fs::read_dir(dir)
        .map_err(unreadable)?
        .map(|entry| entry.map(|e| e.path()).map_err(unreadable))
        .collect::<Result<Vec<_>, _>>()?;
    paths.sort();
    Ok(paths)
}

/// A file's extension in lower case ("" when it has none).
fn extension(path: &Path) -> String {
    path.extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default()
}

/// Whether a file's extension is one covec decodes (PNG, JPEG, WebP).
pub fn is_image_file(path: &Path) -> bool {
    matches!(extension(path).as_str(), "png" | "jpg" | "jpeg" | "webp")
}

/// The kind of file a command writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// The SVG (layered, or flattened with --flatten).
    Svg,
    /// A PNG drawn by covec's own renderer.
    Png,
    /// A vector PDF of the flattened picture.
    Pdf,
    /// The JSON scene.
    Json,
}

impl Format {
    /// The format an output path's extension (any case) names, if any.
    pub fn of_path(path: &Path) -> Option<Self> {
        match extension(path).as_str() {
            "svg" => Some(Format::Svg),
            "png" => Some(Format::Png),
            "pdf" => Some(Format::Pdf),
            "json" => Some(Format::Json),
            _ => None,
        }
    }
}

/// Reads a JSON scene (`covec vectorize`'s or the service's `scene.json`).
pub fn read_scene(path: &Path) -> Result<Scene, IoError> {
    serde_json::from_slice(&read(path)?).map_err(|source| IoError::Scene {
        path: path.into(),
        source,
    })
}

/// Renders `scene` with covec's renderer and writes it as a PNG (see [`output::png`]).
pub fn write_png(
    path: &Path,
    scene: &Scene,
    width: Option<u32>,
    max_pixels: u64,
) -> Result<(), IoError> {
    let bytes = output::png(scene, width, max_pixels).map_err(|source| IoError::Raster {
        path: path.into(),
        source,
    })?;
    write(path, &bytes)
}

/// Reads and decodes an image under `limits`.
pub fn decode_image(path: &Path, limits: &Limits) -> Result<image::DynamicImage, IoError> {
    imageio::decode_image(&read(path)?, limits).map_err(|source| IoError::Input {
        path: path.into(),
        source,
    })
}

/// Writes each artefact to the path `destination` gives its kind; kinds without one are skipped.
pub fn write_artefacts(
    artefacts: &[Artefact],
    destination: impl Fn(FileKind) -> Option<PathBuf>,
) -> Result<(), IoError> {
    for artefact in artefacts {
        if let Some(path) = destination(artefact.kind) {
            write(&path, &artefact.bytes)?;
        }
    }
    Ok(())
}
