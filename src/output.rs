//! The files covec writes for a scene, in one place: their names, media types and contents. The
//! command line writes them to paths, the service to its store, the editor to either; none of
//! them builds an SVG, JSON or preview of its own.

use crate::imageio::encode_png;
use crate::pdf;
use crate::render::Image;
use crate::render::composite::composite;
use crate::scene::{LayerKind, Scene};
use crate::svg::{self, SvgOptions};

/// One kind of file made from a scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FileKind {
    /// The layered SVG (`result.svg`).
    LayeredSvg,
    /// The JSON scene, full precision, loaded back losslessly (`scene.json`).
    SceneJson,
    /// One layer alone over its base colour (`layers/<layer>.svg`).
    Layer(LayerKind),
    /// The scene as shown, rendered by covec's own renderer (`preview.png`).
    Preview,
    /// The flattened SVG: the picture as plain opaque paths (`result-flat.svg`).
    FlatSvg,
    /// The flattened picture as a vector PDF (`result.pdf`).
    Pdf,
}

impl FileKind {
    /// The file's name relative to its job or output directory.
    pub fn name(self) -> String {
        match self {
            FileKind::LayeredSvg => "result.svg".into(),
            FileKind::SceneJson => "scene.json".into(),
            FileKind::Layer(kind) => format!("layers/{}.svg", kind.name()),
            FileKind::Preview => "preview.png".into(),
            FileKind::FlatSvg => "result-flat.svg".into(),
            FileKind::Pdf => "result.pdf".into(),
        }
    }

    /// What the file is called after an input's stem when offered for download: `photo.svg`,
    /// `photo-flat.svg`, `photo-albedo.svg`, `photo.json`, `photo.pdf`, `photo-preview.png`.
    pub fn download_suffix(self) -> String {
        match self {
            FileKind::LayeredSvg => ".svg".into(),
            FileKind::SceneJson => ".json".into(),
            FileKind::Layer(kind) => format!("-{}.svg", kind.name()),
            FileKind::Preview => "-preview.png".into(),
            FileKind::FlatSvg => "-flat.svg".into(),
            FileKind::Pdf => ".pdf".into(),
        }
    }

    /// The media type it is served as.
    pub fn media_type(self) -> &'static str {
        match self {
            FileKind::LayeredSvg | FileKind::Layer(_) | FileKind::FlatSvg => "image/svg+xml",
            FileKind::Pdf => "application/pdf",
            FileKind::SceneJson => "application/json",
            FileKind::Preview => "image/png",
        }
    }
}

/// A finished run's files. The layered SVG comes last: a store that finds it knows the set is
/// complete.
pub const RESULT_FILES: &[FileKind] = &[
    FileKind::Layer(LayerKind::Albedo),
    FileKind::Layer(LayerKind::Shade),
    FileKind::Layer(LayerKind::Light),
    FileKind::SceneJson,
    FileKind::LayeredSvg,
];

/// An edit's files.
pub const EDIT_FILES: &[FileKind] = &[FileKind::SceneJson, FileKind::LayeredSvg, FileKind::Preview];

/// Why a scene cannot be rasterised at the size asked for.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum RasterError {
    /// A width of 0.
    #[error("the width must be at least 1 pixel")]
    ZeroWidth,
    /// A scene without a canvas (only a hand-made JSON can have one).
    #[error("the scene's canvas has no pixels")]
    EmptyCanvas,
    /// More pixels than the caller allows.
    #[error("a {width} px wide raster has {actual} pixels, more than the limit of {limit}")]
    TooManyPixels {
        /// The width asked for.
        width: u32,
        /// Its pixels at the scene's aspect ratio.
        actual: u64,
        /// The most allowed.
        limit: u64,
    },
}

/// The width and height [`png`] draws at (the height rounded, at least 1), or why it cannot.
fn raster_size(
    scene: &Scene,
    width: Option<u32>,
    max_pixels: u64,
) -> Result<(u32, u32), RasterError> {
    if scene.width == 0 || scene.height == 0 {
        return Err(RasterError::EmptyCanvas);
    }
    let width = width.unwrap_or(scene.original_width);
    if width == 0 {
        return Err(RasterError::ZeroWidth);
    }
    let height = (f64::from(scene.height) * f64::from(width) / f64::from(scene.width))
        .round()
        .clamp(1.0, f64::from(u32::MAX)) as u32;
    let actual = u64::from(width) * u64::from(height);
    if actual > max_pixels {
        return Err(RasterError::TooManyPixels {
            width,
            actual,
            limit: max_pixels,
        });
    }
    Ok((width, height))
}

/// Refuses a scene whose working canvas is empty or over `max_pixels`: drawing a scene at its
/// own size (an edit's composite and preview) needs neither. Scenes from files are checked
/// through here (`covec edit`); the service reads only scenes it wrote.
pub fn check_canvas(scene: &Scene, max_pixels: u64) -> Result<(), RasterError> {
    raster_size(scene, Some(scene.width), max_pixels).map(|_| ())
}

/// PNG of `scene` as shown, `width` pixels wide (default: the original image's width; the height
/// keeps the working canvas's aspect ratio; at most `max_pixels` in all), drawn by covec's own
/// renderer with the geometry scaled by width / working width: the picture that was optimised,
/// at any size, without relying on a viewer's blend modes.
pub fn png(scene: &Scene, width: Option<u32>, max_pixels: u64) -> Result<Vec<u8>, RasterError> {
    Ok(encode_png(&raster(scene, width, max_pixels)?))
}

/// The picture [`png`] encodes, as values in [0, 1].
pub fn raster(scene: &Scene, width: Option<u32>, max_pixels: u64) -> Result<Image, RasterError> {
    let (w, h) = raster_size(scene, width, max_pixels)?;
    let scaled = scene.rescaled(w as f32 / scene.width as f32, w, h);
    Ok(composite(&scaled))
}

/// One file's contents.
#[derive(Clone, Debug, PartialEq)]
pub struct Artefact {
    /// What it is (and so its name and media type).
    pub kind: FileKind,
    /// Its bytes, ready to write.
    pub bytes: Vec<u8>,
}

/// The files of `kinds` for `scene`, in that order, with default SVG options. Equal scenes give
/// byte-identical files.
pub fn artefacts(scene: &Scene, kinds: &[FileKind]) -> Vec<Artefact> {
    artefacts_with(scene, kinds, &SvgOptions::default())
}

/// [`artefacts`] with the SVGs formatted as `options` say.
pub fn artefacts_with(scene: &Scene, kinds: &[FileKind], options: &SvgOptions) -> Vec<Artefact> {
    kinds
        .iter()
        .map(|&kind| Artefact {
            kind,
            bytes: match kind {
                FileKind::LayeredSvg => svg::to_svg(scene, options).into_bytes(),
                FileKind::SceneJson => {
                    serde_json::to_vec_pretty(scene).expect("a scene always serialises")
                }
                FileKind::Layer(layer) => svg::layer_to_svg(scene, layer, options).into_bytes(),
                FileKind::Preview => encode_png(&composite(scene)),
                FileKind::FlatSvg => svg::to_flat_svg(scene, options).into_bytes(),
                FileKind::Pdf => pdf::to_pdf(scene),
            },
        })
        .collect()
}
