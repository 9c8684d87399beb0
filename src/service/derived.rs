//! Files derived from a stored scene (the flattened SVG, the PDF, a PNG of some width), of a
//! job or of an edit: drawn on first request, then stored beside the scene and served from
//! storage, so any API replica answers later requests for the same file without drawing it.
//!
//! A derived file depends only on its scene, its kind (and width) and the covec version that
//! draws it, so it is stored under a name made of those, `<scene folder>/derived/<version>/
//! <file>`, with its SHA-256 in `<file>.sha256` written after it. A copy whose digest is missing
//! or wrong (a write cut short, a race between two replicas drawing the same file) is not
//! served: it is drawn and stored again. Derived files go with the job's other files (deletion,
//! retention); nothing else needs backing up.

use crate::output::{self, FileKind, RasterError};
use crate::scene::Scene;

use super::queue::{Queue, Refusal};
use super::store::digest;

/// Renders of derived files at once per process: a PNG at the pixel limit holds four f32 RGB
/// images (12 bytes a pixel each, 768 MB at the default 16 Mpx), so concurrent first requests
/// wait rather than add up; a stored copy needs no render and no turn.
pub const RENDERS: usize = 1;

/// A file made from a scene.
#[derive(Clone, Copy, Debug)]
pub enum Derived {
    /// The flattened SVG ([`FileKind::FlatSvg`]) or the PDF ([`FileKind::Pdf`]).
    Flat(FileKind),
    /// A PNG this wide (default: the original width).
    Png(Option<u32>),
}

/// Why a derived file could not be made.
#[derive(Debug, thiserror::Error)]
pub enum DerivedError {
    /// Reading the scene.
    #[error(transparent)]
    Refused(#[from] Refusal),
    /// The width asked for.
    #[error(transparent)]
    Raster(RasterError),
    /// A stored scene that does not parse.
    #[error("stored scene: {0}")]
    Scene(String),
}

impl Derived {
    /// What the file's bytes depend on besides the scene: its kind, its width, and the covec
    /// version that draws it (part of its validator and of its stored name).
    pub fn key(self) -> String {
        let kind = match self {
            Derived::Flat(kind) => kind.name(),
            Derived::Png(width) => format!("png:{width:?}"),
        };
        format!("{kind}/{}", env!("CARGO_PKG_VERSION"))
    }

    pub fn media_type(self) -> &'static str {
        match self {
            Derived::Flat(kind) => kind.media_type(),
            Derived::Png(_) => "image/png",
        }
    }

    /// The download name's suffix after the stem: `-flat.svg`, `.pdf`, `.png`.
    pub fn download_suffix(self) -> String {
        match self {
            Derived::Flat(kind) => kind.download_suffix(),
            Derived::Png(_) => ".png".to_owned(),
        }
    }

    /// Where the file is stored, under the scene's folder `prefix` (`""` or `edits/<id>/`).
    fn stored_name(self, prefix: &str) -> String {
        let file = match self {
            Derived::Flat(kind) => kind.name(),
            Derived::Png(Some(width)) => format!("png-{width}.png"),
            Derived::Png(None) => "png-original.png".to_owned(),
        };
        format!("{prefix}derived/{}/{file}", env!("CARGO_PKG_VERSION"))
    }
}

/// The stored scene of `job` under `prefix`, as stored (checked against its digest).
/// Blocking.
pub fn scene_bytes(queue: &Queue, job: &str, prefix: &str) -> Result<Option<Vec<u8>>, Refusal> {
    queue.read_result(job, &format!("{prefix}{}", FileKind::SceneJson.name()))
}

/// The stored copy of `file`, when there is a whole one. Blocking.
pub fn stored(
    queue: &Queue,
    job: &str,
    prefix: &str,
    file: Derived,
) -> Result<Option<Vec<u8>>, Refusal> {
    let name = file.stored_name(prefix);
    let store = queue.store();
    let Some(recorded) = store.read_artefact(job, &digest_name(&name))? else {
        return Ok(None);
    };
    let Some(bytes) = store.read_artefact(job, &name)? else {
        return Ok(None);
    };
    if recorded != digest(&bytes).as_bytes() {
        tracing::warn!(job_id = %job, name, "a stored derived file does not match its digest; drawing it again");
        return Ok(None);
    }
    Ok(Some(bytes))
}

/// Draws `file` from `scene` (the stored scene's bytes) and stores it for later requests; a
/// failure to store is logged, and the file is served all the same. Blocking and CPU-bound:
/// call it on the render pool.
pub fn render(
    queue: &Queue,
    job: &str,
    prefix: &str,
    scene: &[u8],
    file: Derived,
    max_pixels: u64,
) -> Result<Vec<u8>, DerivedError> {
    let scene: Scene =
        serde_json::from_slice(scene).map_err(|error| DerivedError::Scene(error.to_string()))?;
    let bytes = match file {
        Derived::Flat(kind) => {
            output::artefacts(&scene, &[kind])
                .pop()
                .expect("one file asked for")
                .bytes
        }
        Derived::Png(width) => {
            output::png(&scene, width, max_pixels).map_err(DerivedError::Raster)?
        }
    };
    let name = file.stored_name(prefix);
    let store = queue.store();
    let saved = store
        .write_artefact(job, &name, &bytes)
        .and_then(|()| store.write_artefact(job, &digest_name(&name), digest(&bytes).as_bytes()));
    if let Err(error) = saved {
        tracing::warn!(job_id = %job, name, %error, "storing a derived file; it is drawn again next time");
    }
    Ok(bytes)
}

/// Where the digest of the stored file `name` is kept.
fn digest_name(name: &str) -> String {
    format!("{name}.sha256")
}

/// The threads renders run on: as many as the job threads, below the HTTP threads' priority
/// (as the pipeline's are), so polls stay fast while a large PNG is drawn.
pub fn render_pool(threads: usize) -> std::io::Result<rayon::ThreadPool> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads.max(1))
        .thread_name(|thread| format!("covec-render-{thread}"))
        .start_handler(|_| super::runner::lower_thread_priority())
        .build()
        .map_err(std::io::Error::other)
}
