//! The decompose stage: the working-size target, its albedo map and candidate albedo masks,
//! from the client's network outputs when given, else from the classical substitutes of
//! [`crate::decompose`]; and `auto` resolved.

use rayon::prelude::*;

use super::params::{Inputs, Masks, Mode, Params, ResolvedMode};
use crate::decompose::look::{ANALYSIS_SIZE, Look, look};
use crate::decompose::mask::Mask;
use crate::decompose::segment::{self, Candidate, Sides};
use crate::decompose::{intrinsic, label_masks, min_mask_area, sample_mask, score_masks};
use crate::imageio::{resize_rgb, working_size};
use crate::render::Image;

/// How many segmentation masks the decompose stage offers the init stage to choose from.
const SEGMENT_CANDIDATES: usize = 128;

/// Segmentation masks of our own albedo map that remove less squared error than this are
/// splits of one flat surface (the map is flat per surface): their shading, if any, belongs
/// to the illumination layer, so they seed no albedo path.
const MIN_ALBEDO_GAIN: f32 = 1e-5;

/// What the init stage starts from.
pub(crate) struct Decomposition {
    /// The image at working size.
    pub target: Image,
    /// The albedo map at working size (the target itself in simple mode).
    pub albedo: Image,
    /// Albedo mask candidates, most useful first: holes filled, connected, none tiny.
    pub candidates: Vec<Candidate>,
    /// The mode to run.
    pub mode: ResolvedMode,
    /// Why (see [`resolve_mode`]).
    pub mode_reason: String,
    /// Whether the candidates are the client's masks (or label map) rather than covec's own.
    pub masks_given: bool,
}

/// Resolves `auto` (see [`look`]): `simple` for flat artwork, `photo` for smooth shading or
/// photographic texture. Returns the mode and why. `auto` looks at the input at up to
/// [`ANALYSIS_SIZE`] (or the working size, when larger), not at `target` alone: a small
/// working size blurs the details of flat artwork into what reads as texture.
pub(crate) fn resolve_mode(
    mode: Mode,
    image: &image::DynamicImage,
    target: &Image,
) -> (ResolvedMode, String) {
    match mode {
        Mode::Photo => (ResolvedMode::Photo, "photo mode was asked for".into()),
        Mode::Simple => (ResolvedMode::Simple, "simple mode was asked for".into()),
        Mode::Auto => {
            let size = ANALYSIS_SIZE.max(target.width.max(target.height) as u32);
            let (w, h) = working_size(image.width(), image.height(), size);
            let look = if (w as usize, h as usize) == (target.width, target.height) {
                look(target)
            } else {
                look(&resize_rgb(image, w, h))
            };
            let mode = match look {
                Look::Artwork(_) => ResolvedMode::Simple,
                Look::Photographic(_) => ResolvedMode::Photo,
            };
            (mode, format!("auto: {}", look.reason()))
        }
    }
}

/// The decompose stage, on inputs that passed [`Inputs::check`].
pub(crate) fn run(inputs: &Inputs, params: &Params) -> Decomposition {
    let (ow, oh) = (inputs.image.width(), inputs.image.height());
    let (w, h) = working_size(ow, oh, params.max_size);
    let target = resize_rgb(&inputs.image, w, h);
    let own_albedo = || intrinsic::albedo_map(&target);
    let resolve = || resolve_mode(params.mode, &inputs.image, &target);
    // `auto` looks at the image while our own albedo map is made beside it, in case it goes
    // photo (both are mostly serial); the map is dropped if it goes simple.
    let ((mode, mode_reason), made) = if params.mode == Mode::Auto && inputs.albedo.is_none() {
        let (resolved, albedo) = rayon::join(resolve, own_albedo);
        (resolved, Some(albedo))
    } else {
        (resolve(), None)
    };
    let albedo = match (&inputs.albedo, mode) {
        (Some(map), _) => resize_rgb(map, w, h),
        (None, ResolvedMode::Simple) => target.clone(),
        (None, ResolvedMode::Photo) => made.unwrap_or_else(own_albedo),
    };
    let (w, h) = (w as usize, h as usize);
    let min_area = min_mask_area(w, h);
    let given: Option<Vec<Mask>> = match &inputs.masks {
        Masks::None => None,
        Masks::Binary(masks) => Some(masks.iter().map(|m| sample_mask(m, w, h)).collect()),
        Masks::Labels(labels) => Some(label_masks(labels, w, h)),
    };
    let masks_given = given.is_some();
    // Filling holes and splitting components, candidate by candidate on rayon's pool: on one
    // thread the other cores waited (docs/history.md, "Decomposition").
    let candidates = match given {
        Some(given) => {
            let prepared = given
                .par_iter()
                .flat_map_iter(|m| m.fill_holes().components(min_area))
                .collect();
            score_masks(prepared, &albedo)
        }
        // Photo mode ranks candidates by what each adds over the others (`rank`), so it can
        // take both sides of a merge; simple mode keeps the segmentation's nested order.
        None => segment::segment(
            &albedo,
            SEGMENT_CANDIDATES,
            match mode {
                ResolvedMode::Photo => Sides::Both,
                ResolvedMode::Simple => Sides::Smaller,
            },
        )
        .into_par_iter()
        .filter(|c| {
            mode == ResolvedMode::Simple || inputs.albedo.is_some() || c.gain >= MIN_ALBEDO_GAIN
        })
        .flat_map_iter(|c| {
            c.mask
                .fill_holes()
                .components(min_area)
                .into_iter()
                .map(move |mask| Candidate { mask, gain: c.gain })
        })
        .collect(),
    };
    Decomposition {
        target,
        albedo,
        candidates,
        mode,
        mode_reason,
        masks_given,
    }
}
