//! Measuring a decomposition against known layers: how close each vector layer is
//! to the true albedo, shade and light of a scene, and how faithful a recolour by reference is.
//! The scenes come from [`crate::synth::scenes`] or from any directory holding the
//! [`TRUTH_FILES`].
//!
//! Conventions: layers are rendered alone (albedo and shade over white, light over black) and
//! compared with [`scale_invariant_mse`]; the ratio to the image's own error against the true
//! albedo says how much of the lighting the albedo layer has shed (1 = none, 0 = all).

use std::path::Path;

use crate::decompose::{albedo, intrinsic};
use crate::edit::{ReferenceParams, recolor_by_reference};
use crate::imageio::{encode_png, to_rgb_image};
use crate::render::composite::{composite, render_layers};
use crate::render::{Image, Rasterizer};
use crate::scene::Scene;
use crate::synth::scenes::LitScene;
use crate::synth::{channel_scales, scale_invariant_mse};

/// A scene's image and its true layers, all the same size.
#[derive(Clone, Debug)]
pub struct Truth {
    /// What the vectoriser sees.
    pub image: Image,
    /// The true surface colours.
    pub albedo: Image,
    /// The true illumination (multiplied).
    pub shade: Image,
    /// The true highlights (added).
    pub light: Image,
    /// Pixels in the main light's cast shadow, if known.
    pub cast_shadow: Option<Vec<bool>>,
    /// The true result of recolouring one object, if known.
    pub edited: Option<Image>,
    /// The object seen at each pixel (semantic labels), if known.
    pub objects: Option<Vec<u8>>,
}

/// The files of a truth directory: the first four are required.
pub const TRUTH_FILES: [&str; 7] = [
    "image.png",
    "albedo.png",
    "shade.png",
    "light.png",
    "cast-shadow.png",
    "edited.png",
    "labels.png",
];

/// Grey step between object labels in `labels.png` (8-bit values).
const LABEL_GREY_STEP: u8 = 40;
const LABEL_STEP: f32 = LABEL_GREY_STEP as f32 / 255.0;

/// A pixel counts as a highlight where the true light exceeds this in some channel.
pub const HIGHLIGHT_LEVEL: f32 = 0.2;
/// A cast-shadow pixel counts as "shadow left in the albedo" where the albedo layer's luminance
/// is below the true albedo's by more than this.
pub const DARK_MARGIN: f32 = 0.15;
/// Paths a reference recolour may change (the K of the recolour).
pub const EDIT_PATHS: usize = 4;

impl From<LitScene> for Truth {
    fn from(s: LitScene) -> Self {
        Self {
            image: s.image,
            albedo: s.albedo,
            shade: s.shade,
            light: s.light,
            cast_shadow: Some(s.cast_shadow),
            edited: Some(s.edited),
            objects: Some(s.objects),
        }
    }
}

impl Truth {
    /// The files to write for this truth, as (name, PNG bytes).
    pub fn to_pngs(&self) -> Vec<(&'static str, Vec<u8>)> {
        let mut out = vec![
            (TRUTH_FILES[0], encode_png(&self.image)),
            (TRUTH_FILES[1], encode_png(&self.albedo)),
            (TRUTH_FILES[2], encode_png(&self.shade)),
            (TRUTH_FILES[3], encode_png(&self.light)),
        ];
        if let Some(mask) = &self.cast_shadow {
            let grey = mask.iter().flat_map(|&b| [f32::from(u8::from(b)); 3]);
            let image = Image {
                width: self.image.width,
                height: self.image.height,
                data: grey.collect(),
            };
            out.push((TRUTH_FILES[4], encode_png(&image)));
        }
        if let Some(edited) = &self.edited {
            out.push((TRUTH_FILES[5], encode_png(edited)));
        }
        if let Some(objects) = &self.objects {
            let grey = objects.iter().flat_map(|&k| [f32::from(k) * LABEL_STEP; 3]);
            let image = Image {
                width: self.image.width,
                height: self.image.height,
                data: grey.collect(),
            };
            out.push((TRUTH_FILES[6], encode_png(&image)));
        }
        out
    }

    /// One binary mask per object present, in label order.
    pub fn object_masks(&self) -> Vec<Vec<bool>> {
        let Some(objects) = &self.objects else {
            return Vec::new();
        };
        let mut labels: Vec<u8> = objects.clone();
        labels.sort_unstable();
        labels.dedup();
        labels
            .iter()
            .map(|&k| objects.iter().map(|&o| o == k).collect())
            .collect()
    }

    /// The labels as a label-map image, as a client would send it.
    pub fn label_map(&self) -> Option<image::DynamicImage> {
        let objects = self.objects.as_ref()?;
        let (w, h) = (self.image.width as u32, self.image.height as u32);
        let grey: Vec<u8> = objects
            .iter()
            .map(|&k| k.saturating_mul(LABEL_GREY_STEP))
            .collect();
        image::GrayImage::from_raw(w, h, grey).map(image::DynamicImage::ImageLuma8)
    }

    /// Reads a truth directory. Missing optional files give `None`; differing sizes are an error.
    pub fn read(dir: &Path) -> Result<Self, String> {
        let load = |name: &str| -> Result<Option<Image>, String> {
            let path = dir.join(name);
            if !path.exists() {
                return Ok(None);
            }
            let image = image::open(&path).map_err(|e| format!("{}: {e}", path.display()))?;
            Ok(Some(to_rgb_image(&image)))
        };
        let required = |name: &str| {
            load(name)?.ok_or_else(|| format!("{}: missing", dir.join(name).display()))
        };
        let truth = Self {
            image: required(TRUTH_FILES[0])?,
            albedo: required(TRUTH_FILES[1])?,
            shade: required(TRUTH_FILES[2])?,
            light: required(TRUTH_FILES[3])?,
            cast_shadow: load(TRUTH_FILES[4])?
                .map(|m| m.data.chunks_exact(3).map(|p| p[0] > 0.5).collect()),
            edited: load(TRUTH_FILES[5])?,
            objects: load(TRUTH_FILES[6])?.map(|m| {
                m.data
                    .chunks_exact(3)
                    .map(|p| (p[0] / LABEL_STEP).round() as u8)
                    .collect()
            }),
        };
        let size = (truth.image.width, truth.image.height);
        let pixels = size.0 * size.1;
        let layers_fit = [&truth.albedo, &truth.shade, &truth.light]
            .into_iter()
            .chain(&truth.edited)
            .all(|other| (other.width, other.height) == size);
        let masks_fit = [
            truth.cast_shadow.as_ref().map(Vec::len),
            truth.objects.as_ref().map(Vec::len),
        ]
        .into_iter()
        .flatten()
        .all(|len| len == pixels);
        if !(layers_fit && masks_fit) {
            return Err(format!("{}: layers differ in size", dir.display()));
        }
        Ok(truth)
    }
}

/// Which albedo map a measurement starts from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AlbedoEstimate {
    /// The image itself (no decomposition).
    Image,
    /// The grey Retinex estimate photo mode used before the intrinsic substitute.
    Retinex,
    /// covec's classical intrinsic decomposition (the photo-mode default).
    Intrinsic,
}

impl AlbedoEstimate {
    /// The albedo map this estimate gives for `image`.
    pub fn map(self, image: &Image) -> Image {
        match self {
            AlbedoEstimate::Image => image.clone(),
            AlbedoEstimate::Retinex => {
                albedo::albedo_from_shading(image, &albedo::estimate_shading(image))
            }
            AlbedoEstimate::Intrinsic => intrinsic::albedo_map(image),
        }
    }
}

/// How a vectorisation's layers compare with the truth.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LayerScores {
    /// Scale-invariant MSE of the albedo layer to the true albedo.
    pub albedo: f32,
    /// Scale-invariant MSE of the shade layer to the true shade.
    pub shade: f32,
    /// Scale-invariant MSE of the light layer to the true light.
    pub light: f32,
    /// Share of highlight pixels (true light > [`HIGHLIGHT_LEVEL`]) covered by a light path;
    /// `None` without highlights.
    pub highlight_coverage: Option<f32>,
    /// Share of cast-shadow pixels where the albedo layer is darker than the true albedo by more
    /// than [`DARK_MARGIN`]; `None` without a cast-shadow mask.
    pub shadow_in_albedo: Option<f32>,
    /// MSE to the true edit of a recolour by reference with [`EDIT_PATHS`] paths; `None`
    /// without an edited image.
    pub edit: Option<f32>,
}

/// Scale-invariant MSE of the image itself to the true albedo: the "no decomposition" error.
pub fn image_error(truth: &Truth) -> f32 {
    scale_invariant_mse(&truth.image, &truth.albedo)
}

/// Scale-invariant MSE of an albedo map to the true albedo.
pub fn map_error(map: &Image, truth: &Truth) -> f32 {
    scale_invariant_mse(map, &truth.albedo)
}

/// Scores `scene` (at the truth's size) against `truth`.
///
/// # Panics
/// If the scene's canvas differs from the truth's size.
pub fn score(scene: &Scene, truth: &Truth) -> LayerScores {
    let (w, h) = (truth.image.width, truth.image.height);
    assert_eq!((scene.width as usize, scene.height as usize), (w, h));
    let [albedo, shade, light] = render_layers(scene);
    let highlights: Vec<usize> = (0..w * h)
        .filter(|&i| (0..3).any(|c| truth.light.data[3 * i + c] > HIGHLIGHT_LEVEL))
        .collect();
    let highlight_coverage = (!highlights.is_empty()).then(|| {
        let coverage = light_coverage(scene, w, h);
        let covered = highlights.iter().filter(|&&i| coverage[i] > 0.5).count();
        covered as f32 / highlights.len() as f32
    });
    let shadow_in_albedo = truth.cast_shadow.as_ref().and_then(|mask| {
        let scales = channel_scales(&albedo, &truth.albedo);
        let luminance = |image: &Image, i: usize, s: [f64; 3]| {
            let p = &image.data[3 * i..3 * i + 3];
            [0.299, 0.587, 0.114]
                .iter()
                .zip(p)
                .zip(s)
                .map(|((w, &v), s)| w * s * f64::from(v))
                .sum::<f64>()
        };
        let pixels: Vec<usize> = (0..w * h).filter(|&i| mask[i]).collect();
        let dark = pixels
            .iter()
            .filter(|&&i| {
                luminance(&albedo, i, scales)
                    < luminance(&truth.albedo, i, [1.0; 3]) - f64::from(DARK_MARGIN)
            })
            .count();
        (!pixels.is_empty()).then(|| dark as f32 / pixels.len() as f32)
    });
    LayerScores {
        albedo: scale_invariant_mse(&albedo, &truth.albedo),
        shade: scale_invariant_mse(&shade, &truth.shade),
        light: scale_invariant_mse(&light, &truth.light),
        highlight_coverage,
        shadow_in_albedo,
        edit: truth
            .edited
            .as_ref()
            .map(|edited| edit_error(scene, truth, edited)),
    }
}

/// Per pixel, the coverage of the light layer's paths (their union, opacity ignored).
fn light_coverage(scene: &Scene, w: usize, h: usize) -> Vec<f32> {
    let mut paths = scene.light.paths.clone();
    for p in &mut paths {
        (p.color, p.opacity) = ([1.0; 3], 1.0);
    }
    let mut image = Image::default();
    Rasterizer::new().render(&paths, [0.0; 3], w, h, &mut image);
    image.data.chunks_exact(3).map(|p| p[0]).collect()
}

/// MSE to the true edit of a recolour by reference of `scene`, both images 8-bit as a client
/// would send them.
fn edit_error(scene: &Scene, truth: &Truth, edited: &Image) -> f32 {
    let quantised = |image: &Image| Image {
        data: image
            .data
            .iter()
            .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() / 255.0)
            .collect(),
        ..image.clone()
    };
    let (original, target) = (quantised(&truth.image), quantised(edited));
    let params = ReferenceParams {
        k: EDIT_PATHS,
        ..ReferenceParams::default()
    };
    match recolor_by_reference(scene, &original, &target, &params) {
        Ok(edit) => crate::optim::loss::mse_value(&composite(&edit.scene), &target),
        Err(_) => crate::optim::loss::mse_value(&composite(scene), &target),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::scenes::scene;

    #[test]
    fn truth_survives_its_files_and_the_image_is_its_own_worst_albedo() {
        let truth = Truth::from(scene(0, 24));
        let dir = std::env::temp_dir().join(format!("covec-truth-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for (name, bytes) in truth.to_pngs() {
            std::fs::write(dir.join(name), bytes).unwrap();
        }
        let back = Truth::read(&dir).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!(back.cast_shadow, truth.cast_shadow);
        assert_eq!(back.objects, truth.objects);
        assert_eq!(back.object_masks().len(), 3); // floor, wall, sphere
        assert!(scale_invariant_mse(&back.albedo, &truth.albedo) < 1e-4);
        assert!(map_error(&truth.albedo, &truth) < 1e-9);
        assert!(image_error(&truth) > 1e-3);
    }
}
