//! A job's inputs: the limits they are held to, the files they are stored as (named by
//! [`InputKind`], as results are by [`crate::output::FileKind`]) and their decoding, which the
//! submission runs to refuse bad input up front and the runner again before the pipeline.

use axum::body::Bytes;

use super::model::InputManifest;
use crate::imageio;
use crate::pipeline::{Inputs, Masks, ParamLimits};

/// Limits on what one job may ask for.
#[derive(Clone, Debug)]
pub struct InputLimits {
    /// Largest request body in bytes. Default 32 MiB.
    pub max_body_bytes: u64,
    /// Largest image (and albedo, mask, label map) in pixels, checked before decoding. Default 16 000 000.
    pub max_pixels: u64,
    /// Most masks per job. Default 256.
    pub max_masks: usize,
    /// Largest `params.paths`. Default 1024.
    pub max_paths: u32,
    /// Largest `params.max_size`. Default 1024.
    pub max_size: u32,
    /// Largest total iteration budget ([`crate::Iterations::total`]). Default 5000 (the defaults
    /// add up to 760).
    pub max_iterations: u64,
    /// Largest total of a job's decoded inputs in bytes (image and albedo at 3 bytes a pixel,
    /// masks at 1, a label map as decoded), counted as they decode. Default 256 MiB: 256 masks
    /// of 4000² would otherwise hold 4 GB.
    pub max_decoded_bytes: u64,
    /// Requests that decode their inputs at once; others wait their turn, up to
    /// `decode_wait`, then get 503 `decode-busy`. Default 2: with the decoded budget this
    /// bounds the memory decoding can take.
    pub decode_slots: usize,
    /// Longest wait for a decode slot before a request is refused with 503 `decode-busy` (its
    /// body stays in memory while it waits, so the wait is bounded too). Default 5 s.
    pub decode_wait: std::time::Duration,
}

impl InputLimits {
    /// The parameter ranges these limits allow.
    pub fn params(&self) -> ParamLimits {
        ParamLimits {
            max_paths: self.max_paths,
            max_size: self.max_size,
            max_iterations: Some(self.max_iterations),
        }
    }

    /// The decoder limits these limits imply; `accept_truncated` is the client's choice.
    pub fn decoding(&self, accept_truncated: bool) -> imageio::Limits {
        imageio::Limits {
            max_pixels: self.max_pixels,
            max_masks: self.max_masks,
            accept_truncated,
        }
    }
}

impl Default for InputLimits {
    fn default() -> Self {
        Self {
            max_body_bytes: 32 << 20,
            max_pixels: 16_000_000,
            max_masks: 256,
            max_paths: 1024,
            max_size: 1024,
            max_iterations: 5000,
            max_decoded_bytes: 256 << 20,
            decode_slots: 2,
            decode_wait: std::time::Duration::from_secs(5),
        }
    }
}

/// One stored input of a job, among its files under `input/`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InputKind {
    Image,
    Albedo,
    Labels,
    /// The binary mask at this index, in the order sent.
    Mask(usize),
}

impl InputKind {
    /// The file's name relative to its job.
    pub fn name(self) -> String {
        match self {
            InputKind::Image => "input/image".into(),
            InputKind::Albedo => "input/albedo".into(),
            InputKind::Labels => "input/labels".into(),
            InputKind::Mask(index) => format!("input/mask-{index}"),
        }
    }

    /// The inputs a job stored, as its manifest lists them.
    fn stored(manifest: &InputManifest) -> impl Iterator<Item = InputKind> {
        let albedo = manifest.albedo.then_some(InputKind::Albedo);
        let labels = manifest.labels.then_some(InputKind::Labels);
        [Some(InputKind::Image), albedo, labels]
            .into_iter()
            .flatten()
            .chain((0..manifest.masks).map(InputKind::Mask))
    }
}

/// The encoded inputs of one job, as uploaded and as stored.
pub struct EncodedInputs {
    pub image: Bytes,
    pub albedo: Option<Bytes>,
    pub masks: Vec<Bytes>,
    pub labels: Option<Bytes>,
}

/// Why a job's inputs cannot be used; the handlers answer 413 for limits and 422 for the rest.
#[derive(Debug, thiserror::Error)]
pub enum InputError {
    /// The decoder refused `what` (`image`, `albedo`, `mask`, …).
    #[error("{what}: {source}")]
    Refused {
        what: &'static str,
        source: imageio::InputError,
    },
    #[error("the decoded inputs reach {actual} bytes, more than the limit of {limit}")]
    TooLarge { limit: u64, actual: u64 },
    #[error("send either `mask` fields or one `labels` map, not both")]
    MasksAndLabels,
}

impl InputError {
    /// A decoder's refusal of `what`.
    pub fn refused(what: &'static str) -> impl Fn(imageio::InputError) -> InputError {
        move |source| InputError::Refused { what, source }
    }
}

impl EncodedInputs {
    /// What the job's record says of these inputs.
    pub fn manifest(&self, accept_truncated: bool) -> InputManifest {
        InputManifest {
            albedo: self.albedo.is_some(),
            masks: self.masks.len(),
            labels: self.labels.is_some(),
            accept_truncated,
        }
    }

    /// The files to store, named as [`EncodedInputs::load`] reads them back.
    pub fn into_files(self) -> Vec<(InputKind, Bytes)> {
        let mut files = vec![(InputKind::Image, self.image)];
        files.extend(self.albedo.map(|bytes| (InputKind::Albedo, bytes)));
        files.extend(self.labels.map(|bytes| (InputKind::Labels, bytes)));
        files.extend(
            self.masks
                .into_iter()
                .enumerate()
                .map(|(index, bytes)| (InputKind::Mask(index), bytes)),
        );
        files
    }

    /// Reads back the inputs `manifest` lists; `Ok(None)` when one of them is missing.
    pub fn load<E>(
        manifest: &InputManifest,
        mut read: impl FnMut(InputKind) -> Result<Option<Vec<u8>>, E>,
    ) -> Result<Option<Self>, E> {
        let mut inputs = EncodedInputs {
            image: Bytes::new(),
            albedo: None,
            masks: Vec::with_capacity(manifest.masks),
            labels: None,
        };
        for kind in InputKind::stored(manifest) {
            let Some(bytes) = read(kind)? else {
                return Ok(None);
            };
            let bytes = Bytes::from(bytes);
            match kind {
                InputKind::Image => inputs.image = bytes,
                InputKind::Albedo => inputs.albedo = Some(bytes),
                InputKind::Labels => inputs.labels = Some(bytes),
                InputKind::Mask(_) => inputs.masks.push(bytes),
            }
        }
        Ok(Some(inputs))
    }

    /// Decodes and cross-checks the inputs (CPU work: call off the async runtime).
    /// `accept_truncated`: the client's `accept_truncated` (a JPEG cut short is refused without).
    pub fn decode(
        &self,
        limits: &InputLimits,
        accept_truncated: bool,
    ) -> Result<Inputs, InputError> {
        if !self.masks.is_empty() && self.labels.is_some() {
            return Err(InputError::MasksAndLabels);
        }
        let decode_limits = limits.decoding(accept_truncated);
        let refused = InputError::refused;
        let mut decoded = 0u64;
        let mut count = |bytes: usize| {
            decoded += bytes as u64;
            if decoded > limits.max_decoded_bytes {
                return Err(InputError::TooLarge {
                    limit: limits.max_decoded_bytes,
                    actual: decoded,
                });
            }
            Ok(())
        };
        let image = imageio::decode_image(&self.image, &decode_limits).map_err(refused("image"))?;
        count(image.as_bytes().len())?;
        let albedo = match &self.albedo {
            Some(bytes) => {
                let albedo =
                    imageio::decode_image(bytes, &decode_limits).map_err(refused("albedo"))?;
                count(albedo.as_bytes().len())?;
                Some(albedo)
            }
            None => None,
        };
        let masks = if let Some(labels) = &self.labels {
            let labels =
                imageio::decode_labels(labels, &decode_limits).map_err(refused("label map"))?;
            count(labels.as_bytes().len())?;
            Masks::Labels(labels)
        } else if self.masks.is_empty() {
            Masks::None
        } else {
            let mut binary = Vec::with_capacity(self.masks.len());
            for (index, bytes) in self.masks.iter().enumerate() {
                let name = format!("mask {index}");
                let mask =
                    imageio::decode_mask(&name, bytes, &decode_limits).map_err(refused("mask"))?;
                count(mask.len())?;
                binary.push(mask);
            }
            Masks::Binary(binary)
        };
        let inputs = Inputs {
            image,
            albedo,
            masks,
        };
        inputs.check().map_err(refused("inputs"))?;
        Ok(inputs)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stored_inputs_are_read_back_under_the_names_they_were_written() {
        let inputs = EncodedInputs {
            image: Bytes::from_static(b"i"),
            albedo: Some(Bytes::from_static(b"a")),
            masks: vec![Bytes::from_static(b"m0"), Bytes::from_static(b"m1")],
            labels: None,
        };
        let manifest = inputs.manifest(false);
        let files: std::collections::HashMap<String, Bytes> = inputs
            .into_files()
            .into_iter()
            .map(|(kind, bytes)| (kind.name(), bytes))
            .collect();
        let names: Vec<&str> = {
            let mut names: Vec<&str> = files.keys().map(String::as_str).collect();
            names.sort();
            names
        };
        assert_eq!(
            names,
            [
                "input/albedo",
                "input/image",
                "input/mask-0",
                "input/mask-1"
            ]
        );
        let read = |kind: InputKind| Ok::<_, ()>(files.get(&kind.name()).map(|b| b.to_vec()));
        let loaded = EncodedInputs::load(&manifest, read).unwrap().unwrap();
        assert_eq!(loaded.image, "i");
        assert_eq!(loaded.albedo.as_deref(), Some(&b"a"[..]));
        assert_eq!(loaded.masks, ["m0", "m1"]);
        assert!(loaded.labels.is_none());
        let missing = InputManifest {
            labels: true,
            ..manifest
        };
        assert!(EncodedInputs::load(&missing, read).unwrap().is_none());
    }
}
