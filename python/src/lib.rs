//! `covec._covec`: covec's library with Python types at its edges, for the pure-Python package
//! `covec` (python/covec/), which turns what a user passes (paths, PIL images, numpy arrays)
//! into what these functions take. Everything here calls the library; nothing re-implements it.
//!
//! Work runs with the interpreter released, on a thread of its own: the calling thread waits
//! for it, hands progress to the Python callback and checks for Ctrl-C, which cancels the run.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender};
use std::sync::{Mutex, PoisonError};
use std::time::{Duration, Instant};

use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyString};

use covec::edit::{self, ColorChange, Edit, EditError, ReferenceParams, Target};
use covec::imageio::{self, InputError, Limits, Pixels, Samples, Source};
use covec::output::{self, FileKind, RasterError};
use covec::pipeline::{self, Inputs, Masks, Mode, Observer, Params, Progress};
use covec::render::Image;
use covec::scene::{LayerKind, PathId, Point, Scene as CoreScene};
use covec::svg::{self, SvgOptions};
use image::DynamicImage;

/// The exceptions, defined in Python (covec/_errors.py) so that the input errors are
/// `ValueError`s too.
mod errors {
    pyo3::import_exception!(covec._errors, Error);
    pyo3::import_exception!(covec._errors, InputError);
    pyo3::import_exception!(covec._errors, ParamsError);
    pyo3::import_exception!(covec._errors, EditError);
}

/// How often the waiting thread looks for Ctrl-C, and the least time between two progress
/// reports it hands to Python (a run reports every iteration, thousands of times).
const POLL: Duration = Duration::from_millis(50);

/// An input as the Python layer hands it over: `(name, data)`, the name for error messages,
/// `data` a file's bytes or `(samples, height, width, channels, sample type)`, the samples
/// little-endian `u8`, `u16` or `f32`.
struct Given {
    name: String,
    data: GivenData,
}

/// A file's bytes, or samples with `[width, height, channels]`.
enum GivenData {
    Encoded(Vec<u8>),
    U8(Vec<u8>, [u32; 3]),
    U16(Vec<u16>, [u32; 3]),
    F32(Vec<f32>, [u32; 3]),
}

impl Given {
    fn extract(given: &Bound<'_, PyAny>) -> PyResult<Self> {
        let (name, data): (String, Bound<'_, PyAny>) = given.extract()?;
        if let Ok(bytes) = data.cast::<PyBytes>() {
            return Ok(Self {
                name,
                data: GivenData::Encoded(bytes.as_bytes().to_vec()),
            });
        }
        let (samples, height, width, channels, kind): (Bound<'_, PyBytes>, u32, u32, u32, String) =
            data.extract()?;
        let (samples, shape) = (samples.as_bytes(), [width, height, channels]);
        let data = match kind.as_str() {
            "u8" => GivenData::U8(samples.to_vec(), shape),
            "u16" => GivenData::U16(
                (samples.chunks_exact(2))
                    .map(|b| u16::from_le_bytes([b[0], b[1]]))
                    .collect(),
                shape,
            ),
            "f32" => GivenData::F32(
                (samples.chunks_exact(4))
                    .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                    .collect(),
                shape,
            ),
            other => return Err(PyValueError::new_err(format!("sample type {other:?}"))),
        };
        Ok(Self { name, data })
    }

    fn source(&self) -> Source<'_> {
        let pixels = |[width, height, channels]: [u32; 3], samples| {
            Source::Pixels(Pixels {
                width,
                height,
                channels,
                samples,
            })
        };
        match &self.data {
            GivenData::Encoded(bytes) => Source::Encoded(bytes),
            GivenData::U8(values, shape) => pixels(*shape, Samples::U8(values)),
            GivenData::U16(values, shape) => pixels(*shape, Samples::U16(values)),
            GivenData::F32(values, shape) => pixels(*shape, Samples::F32(values)),
        }
    }

    /// The input as an image, its error naming it.
    fn image(&self, limits: &Limits) -> Result<DynamicImage, Failure> {
        imageio::load_image(self.source(), limits).map_err(|error| self.refused(error))
    }

    fn refused(&self, error: InputError) -> Failure {
        Failure::Input(format!("{}: {error}", self.name))
    }
}

/// Why work failed, sorted into the Python exception it raises.
enum Failure {
    Input(String),
    Params(String),
    Edit(String),
    Canceled,
    Internal(String),
}

impl From<pipeline::Error> for Failure {
    fn from(error: pipeline::Error) -> Self {
        match error {
            pipeline::Error::Input(_) => Failure::Input(error.to_string()),
            pipeline::Error::Params(_) => Failure::Params(error.to_string()),
            pipeline::Error::Canceled => Failure::Canceled,
            pipeline::Error::Internal(_) => Failure::Internal(error.to_string()),
        }
    }
}

impl From<EditError> for Failure {
    fn from(error: EditError) -> Self {
        match error {
            EditError::Input(_) => Failure::Input(error.to_string()),
            _ => Failure::Edit(error.to_string()),
        }
    }
}

impl From<RasterError> for Failure {
    fn from(error: RasterError) -> Self {
        Failure::Params(error.to_string())
    }
}

impl From<Failure> for PyErr {
    fn from(failure: Failure) -> Self {
        match failure {
            Failure::Input(message) => errors::InputError::new_err(message),
            Failure::Params(message) => errors::ParamsError::new_err(message),
            Failure::Edit(message) => errors::EditError::new_err(message),
            Failure::Canceled => errors::Error::new_err("canceled"),
            Failure::Internal(message) => errors::Error::new_err(message),
        }
    }
}

/// What the worker thread tells the waiting one.
enum Event {
    Progress(Progress),
    Done,
}

/// Sends progress to the waiting thread, at most one report per [`POLL`] within a stage (and
/// every stage's first), and none when nobody listens.
struct Reporter {
    events: Mutex<Sender<Event>>,
    listening: bool,
    last: Mutex<Option<(&'static str, Instant)>>,
}

impl Observer for Reporter {
    fn progress(&self, progress: &Progress) {
        if !self.listening {
            return;
        }
        let mut last = self.last.lock().unwrap_or_else(PoisonError::into_inner);
        let due = match *last {
            Some((stage, at)) => stage != progress.stage || at.elapsed() >= POLL,
            None => true,
        };
        if due {
            *last = Some((progress.stage, Instant::now()));
            let events = self.events.lock().unwrap_or_else(PoisonError::into_inner);
            // The waiting thread outlives the run; a failed send has nobody to tell.
            let _ = events.send(Event::Progress(progress.clone()));
        }
    }

    fn preview(&self, _: &str, _: &Image) {}

    fn wants_previews(&self) -> bool {
        false
    }
}

/// Runs `work` on a thread of its own with the interpreter released, on `threads` threads (a
/// pool of its own) or rayon's global pool, handing its progress to `progress(stage,
/// fraction)` on the calling thread. Ctrl-C, or an exception from `progress`, cancels the run
/// through its cancel flag and is raised once the run has stopped.
fn run_detached<T: Send>(
    py: Python<'_>,
    threads: Option<usize>,
    progress: Option<&Bound<'_, PyAny>>,
    work: impl FnOnce(&dyn Observer, &AtomicBool) -> Result<T, Failure> + Send,
) -> PyResult<T> {
    let pool = match threads {
        Some(0) => return Err(Failure::Params("`threads` must be at least 1".into()).into()),
        Some(n) => Some(
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .map_err(|e| Failure::Internal(format!("cannot start {n} threads: {e}")))?,
        ),
        None => None,
    };
    let (sender, receiver) = mpsc::channel();
    let done = sender.clone();
    let reporter = Reporter {
        events: Mutex::new(sender),
        listening: progress.is_some(),
        last: Mutex::new(None),
    };
    let receiver = Mutex::new(receiver);
    let cancel = AtomicBool::new(false);
    std::thread::scope(|scope| {
        let worker = scope.spawn(|| {
            let job = || catch_unwind(AssertUnwindSafe(|| work(&reporter, &cancel)));
            // A run called from outside a pool hands every parallel loop to the pool and
            // sleeps until it is done; run on a pool thread, it joins them (cli/mod.rs, in_pool).
            let outcome = match &pool {
                Some(pool) => pool.install(job),
                None => rayon::scope(|_| job()),
            };
            let _ = done.send(Event::Done);
            outcome
        });
        let mut callback = Callback {
            callback: progress,
            stage: "",
            fraction: 0.0,
        };
        let stopped = wait(py, &receiver, &mut callback);
        if stopped.is_err() {
            cancel.store(true, Ordering::Relaxed);
        }
        let outcome = py.detach(|| worker.join());
        stopped?;
        match outcome {
            Ok(Ok(result)) => {
                let result = result?;
                callback.finish()?;
                Ok(result)
            }
            Ok(Err(panic)) | Err(panic) => {
                let message = (panic.downcast_ref::<&str>().map(|s| s.to_string()))
                    .or_else(|| panic.downcast_ref::<String>().cloned())
                    .unwrap_or_default();
                Err(Failure::Internal(format!("internal error: covec panicked: {message}")).into())
            }
        }
    })
}

/// Waits for the worker's [`Event::Done`], handing its progress to `progress` and checking
/// for Ctrl-C every [`POLL`].
fn wait(
    py: Python<'_>,
    receiver: &Mutex<Receiver<Event>>,
    progress: &mut Callback<'_, '_>,
) -> PyResult<()> {
    loop {
        let (reports, finished) = py.detach(|| {
            let receiver = receiver.lock().unwrap_or_else(PoisonError::into_inner);
            let first = match receiver.recv_timeout(POLL) {
                Ok(event) => event,
                Err(RecvTimeoutError::Timeout) => return (Vec::new(), false),
                Err(RecvTimeoutError::Disconnected) => return (Vec::new(), true),
            };
            let mut reports = Vec::new();
            let mut finished = false;
            for event in std::iter::once(first).chain(receiver.try_iter()) {
                match event {
                    Event::Progress(p) => reports.push(p),
                    Event::Done => finished = true,
                }
            }
            (reports, finished)
        });
        progress.report(&reports)?;
        if finished {
            return Ok(());
        }
        py.check_signals()?;
    }
}

/// The user's `progress(stage, fraction)` and what it was last told.
struct Callback<'a, 'py> {
    callback: Option<&'a Bound<'py, PyAny>>,
    stage: &'static str,
    fraction: f32,
}

impl Callback<'_, '_> {
    /// Calls back with the last report of each stage in `reports`, never with a fraction
    /// below one already given (stages report from several threads at once).
    fn report(&mut self, reports: &[Progress]) -> PyResult<()> {
        let Some(callback) = self.callback else {
            return Ok(());
        };
        for (k, report) in reports.iter().enumerate() {
            let last_of_stage = (reports.get(k + 1)).is_none_or(|next| next.stage != report.stage);
            let fraction = report.fraction();
            if last_of_stage && fraction >= self.fraction {
                (self.stage, self.fraction) = (report.stage, fraction);
                callback.call1((report.stage, fraction))?;
            }
        }
        Ok(())
    }

    /// Calls back with 1 for a finished run whose last report fell short of it (a stage that
    /// stopped early, or a report left out as too soon after the one before).
    fn finish(&mut self) -> PyResult<()> {
        match self.callback {
            Some(callback) if self.fraction < 1.0 => {
                self.fraction = 1.0;
                callback.call1((self.stage, 1.0)).map(drop)
            }
            _ => Ok(()),
        }
    }
}

/// `covec.vectorize` (python/covec/__init__.py documents the arguments).
#[pyfunction]
#[pyo3(signature = (image, *, albedo, masks, labels, paths, mode, seed, max_size, threads, progress, max_pixels, max_masks, accept_truncated))]
#[allow(clippy::too_many_arguments)]
fn vectorize(
    py: Python<'_>,
    image: &Bound<'_, PyAny>,
    albedo: Option<&Bound<'_, PyAny>>,
    masks: Option<Vec<Bound<'_, PyAny>>>,
    labels: Option<&Bound<'_, PyAny>>,
    paths: u32,
    mode: &str,
    seed: u64,
    max_size: u32,
    threads: Option<usize>,
    progress: Option<&Bound<'_, PyAny>>,
    max_pixels: u64,
    max_masks: usize,
    accept_truncated: bool,
) -> PyResult<(Scene, &'static str, String)> {
    let mode: Mode = serde_json::from_value(serde_json::Value::from(mode)).map_err(|_| {
        Failure::Params(format!(
            "`mode` must be \"auto\", \"photo\" or \"simple\", not {mode:?}"
        ))
    })?;
    let params = Params {
        paths,
        mode,
        max_size,
        seed,
        ..Params::default()
    };
    let limits = Limits {
        max_pixels,
        max_masks,
        accept_truncated,
    };
    let image = Given::extract(image)?;
    let albedo = albedo.map(Given::extract).transpose()?;
    let masks = (masks.iter().flatten())
        .map(Given::extract)
        .collect::<PyResult<Vec<_>>>()?;
    let labels = labels.map(Given::extract).transpose()?;
    let output = run_detached(py, threads, progress, move |observer, cancel| {
        let masks = if !masks.is_empty() {
            imageio::check_mask_count(masks.len(), &limits)
                .map_err(|error| Failure::Input(error.to_string()))?;
            let mask = |given: &Given| {
                imageio::load_mask(&given.name, given.source(), &limits).map_err(|error| {
                    match error {
                        // Its message names the mask already.
                        InputError::NonBinaryMask { .. } => Failure::Input(error.to_string()),
                        _ => Failure::Input(format!("mask {}: {error}", given.name)),
                    }
                })
            };
            Masks::Binary(masks.iter().map(mask).collect::<Result<_, _>>()?)
        } else if let Some(labels) = &labels {
            Masks::Labels(
                imageio::load_labels(labels.source(), &limits)
                    .map_err(|error| labels.refused(error))?,
            )
        } else {
            Masks::None
        };
        let inputs = Inputs {
            image: image.image(&limits)?,
            albedo: albedo.map(|a| a.image(&limits)).transpose()?,
            masks,
        };
        Ok(pipeline::run(&inputs, &params, observer, cancel)?)
    })?;
    Ok((
        Scene::new(output.scene, Vec::new()),
        output.mode.name(),
        output.mode_reason,
    ))
}

/// A scene and what the edit that made it changed (`covec.Scene` wraps it).
#[pyclass(frozen, module = "covec._covec")]
struct Scene {
    scene: CoreScene,
    changed: Vec<edit::Changed>,
}

impl Scene {
    fn new(scene: CoreScene, changed: Vec<edit::Changed>) -> Self {
        Self { scene, changed }
    }

    fn from_edit(edit: Edit) -> Self {
        Self::new(edit.scene, edit.changed)
    }

    /// The file of `kind`.
    fn artefact(&self, kind: FileKind, options: &SvgOptions) -> Vec<u8> {
        let mut files = output::artefacts_with(&self.scene, &[kind], options);
        files.pop().expect("one file per kind").bytes
    }

    fn svg_text(&self, py: Python<'_>, kind: FileKind, precision: Option<u32>) -> PyResult<String> {
        if let Some(precision) = precision.filter(|&p| p > svg::MAX_PRECISION) {
            return Err(Failure::Params(format!(
                "`precision` must be within 0-{}, not {precision}",
                svg::MAX_PRECISION
            ))
            .into());
        }
        let options = SvgOptions { precision };
        let bytes = py.detach(|| self.artefact(kind, &options));
        Ok(String::from_utf8(bytes).expect("an SVG is UTF-8"))
    }
}

#[pymethods]
impl Scene {
    /// A scene from its JSON form, refused unless its canvas can be drawn within `max_pixels`.
    #[staticmethod]
    fn from_json(json: &[u8], max_pixels: u64) -> PyResult<Self> {
        let scene: CoreScene = serde_json::from_slice(json)
            .map_err(|e| Failure::Input(format!("not a covec scene: {e}")))?;
        output::check_canvas(&scene, max_pixels).map_err(|e| Failure::Input(e.to_string()))?;
        Ok(Self::new(scene, Vec::new()))
    }

    /// The JSON scene (full precision; loads back losslessly).
    fn json(&self, py: Python<'_>) -> String {
        let bytes = py.detach(|| self.artefact(FileKind::SceneJson, &SvgOptions::default()));
        String::from_utf8(bytes).expect("JSON is UTF-8")
    }

    /// `(width, height, original_width, original_height)`.
    fn size(&self) -> (u32, u32, u32, u32) {
        let s = &self.scene;
        (s.width, s.height, s.original_width, s.original_height)
    }

    /// The layered SVG, or the flattened one.
    #[pyo3(signature = (flatten, precision))]
    fn svg(&self, py: Python<'_>, flatten: bool, precision: Option<u32>) -> PyResult<String> {
        let kind = if flatten {
            FileKind::FlatSvg
        } else {
            FileKind::LayeredSvg
        };
        self.svg_text(py, kind, precision)
    }

    /// Each layer alone, as `(name, svg)`.
    #[pyo3(signature = (precision))]
    fn layers(
        &self,
        py: Python<'_>,
        precision: Option<u32>,
    ) -> PyResult<Vec<(&'static str, String)>> {
        (LayerKind::ALL.iter())
            .map(|&kind| -> PyResult<_> {
                Ok((
                    kind.name(),
                    self.svg_text(py, FileKind::Layer(kind), precision)?,
                ))
            })
            .collect()
    }

    /// The vector PDF of the flattened picture.
    fn pdf<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        let bytes = py.detach(|| self.artefact(FileKind::Pdf, &SvgOptions::default()));
        PyBytes::new(py, &bytes)
    }

    /// A PNG drawn by covec's renderer, `width` pixels wide (default: the original's).
    #[pyo3(signature = (width, max_pixels))]
    fn png<'py>(
        &self,
        py: Python<'py>,
        width: Option<u32>,
        max_pixels: u64,
    ) -> PyResult<Bound<'py, PyBytes>> {
        let bytes = py
            .detach(|| output::png(&self.scene, width, max_pixels))
            .map_err(Failure::from)?;
        Ok(PyBytes::new(py, &bytes))
    }

    /// The picture [`Scene::png`] encodes, as `(RGB bytes, height, width)`.
    #[pyo3(signature = (width, max_pixels))]
    fn pixels<'py>(
        &self,
        py: Python<'py>,
        width: Option<u32>,
        max_pixels: u64,
    ) -> PyResult<(Bound<'py, PyBytes>, usize, usize)> {
        let (bytes, height, width) = py
            .detach(|| {
                output::raster(&self.scene, width, max_pixels)
                    .map(|image| (imageio::to_rgb8(&image), image.height, image.width))
            })
            .map_err(Failure::from)?;
        Ok((PyBytes::new(py, &bytes), height, width))
    }

    /// Every path back to front, layer by layer: `(layer, id, fill, opacity, d, points)`, `d`
    /// as the layered SVG writes it (whole quarter pixels, which its group scales by 0.25),
    /// `points` in canvas pixels.
    #[allow(clippy::type_complexity)]
    fn paths(&self) -> Vec<(&'static str, String, String, f32, String, Vec<(f32, f32)>)> {
        let units = SvgOptions::default().units_per_pixel();
        LayerKind::ALL
            .iter()
            .flat_map(|&layer| {
                (self.scene.layer(layer).paths.iter().enumerate()).map(move |(index, path)| {
                    (
                        layer.name(),
                        PathId { layer, index }.to_string(),
                        svg::hex_colour(path.color),
                        path.opacity.clamp(0.0, 1.0),
                        svg::path_data(path, units),
                        path.points.iter().map(|p| (p.x, p.y)).collect(),
                    )
                })
            })
            .collect()
    }

    /// What the edit that made this scene changed: `(path, old fill, new fill, old opacity,
    /// new opacity)`.
    fn changed(&self) -> Vec<(String, String, String, f32, f32)> {
        (self.changed.iter())
            .map(|c| {
                (
                    c.path.to_string(),
                    svg::hex_colour(c.old_color),
                    svg::hex_colour(c.new_color),
                    c.old_opacity,
                    c.new_opacity,
                )
            })
            .collect()
    }

    /// Recolours paths: `changes` holds `(target, colour)`, the target a path id (`albedo-3`)
    /// or a point `(x, y)` in canvas pixels, the colour `#rrggbb` or three floats in [0, 1].
    fn recolor(&self, py: Python<'_>, changes: Vec<Bound<'_, PyAny>>) -> PyResult<Scene> {
        let changes = (changes.iter())
            .map(|change| {
                let (target, colour): (Bound<'_, PyAny>, Bound<'_, PyAny>) = change.extract()?;
                Ok(ColorChange {
                    target: target_of(&target)?,
                    color: colour_of(&colour)?,
                    opacity: None,
                })
            })
            .collect::<PyResult<Vec<_>>>()?;
        let edit = py
            .detach(|| edit::recolor_paths(&self.scene, &changes))
            .map_err(Failure::from)?;
        Ok(Scene::from_edit(edit))
    }

    /// The reference edit (paper Appendix D) from an edited copy of the original image.
    #[pyo3(signature = (reference, original, k, tau, gamma, delta, epsilon, max_pixels))]
    #[allow(clippy::too_many_arguments)]
    fn recolor_by_reference(
        &self,
        py: Python<'_>,
        reference: &Bound<'_, PyAny>,
        original: Option<&Bound<'_, PyAny>>,
        k: usize,
        tau: f32,
        gamma: f32,
        delta: f32,
        epsilon: f32,
        max_pixels: u64,
    ) -> PyResult<Scene> {
        let params = ReferenceParams {
            k,
            tau,
            gamma,
            delta,
            epsilon,
        };
        let limits = Limits {
            max_pixels,
            ..Limits::default()
        };
        let reference = Given::extract(reference)?;
        let original = original.map(Given::extract).transpose()?;
        let edit = run_detached(py, None, None, |_, _| {
            let original = original.map(|o| o.image(&limits)).transpose()?;
            Ok(edit::recolor_by_reference_images(
                &self.scene,
                &reference.image(&limits)?,
                original.as_ref(),
                &params,
            )?)
        })?;
        Ok(Scene::from_edit(edit))
    }
}

/// A path id (`albedo-3`) or a point `(x, y)`.
fn target_of(target: &Bound<'_, PyAny>) -> PyResult<Target> {
    if let Ok(id) = target.cast::<PyString>() {
        let id = id.to_str()?;
        return id.parse::<PathId>().map(Target::Path).map_err(|()| {
            Failure::Edit(format!("`{id}` is not a path id (e.g. albedo-3)")).into()
        });
    }
    let (x, y): (f32, f32) = target.extract().map_err(|_| {
        Failure::Edit(format!(
            "{target} is neither a path id (e.g. \"albedo-3\") nor a point (x, y)"
        ))
    })?;
    Ok(Target::AlbedoAt(Point::new(x, y)))
}

/// `#rrggbb` or three floats.
fn colour_of(colour: &Bound<'_, PyAny>) -> PyResult<[f32; 3]> {
    if let Ok(text) = colour.cast::<PyString>() {
        let text = text.to_str()?;
        return svg::parse_hex_colour(text).ok_or_else(|| {
            Failure::Edit(format!("`{text}` is not a colour (expected #rrggbb)")).into()
        });
    }
    let (r, g, b): (f32, f32, f32) = colour.extract().map_err(|_| {
        Failure::Edit(format!(
            "{colour} is not a colour (expected \"#rrggbb\" or three floats in [0, 1])"
        ))
    })?;
    Ok([r, g, b])
}

/// covec's defaults as JSON, which the Python layer's signatures show: `params`
/// ([`Params`]), `reference` ([`ReferenceParams`]) and `limits` (`max_pixels`, `max_masks`).
#[pyfunction]
fn defaults() -> String {
    let limits = Limits::default();
    serde_json::json!({
        "params": Params::default(),
        "reference": ReferenceParams::default(),
        "limits": {"max_pixels": limits.max_pixels, "max_masks": limits.max_masks},
    })
    .to_string()
}

/// The extension module.
#[pymodule]
mod _covec {
    #[pymodule_export]
    use super::{Scene, defaults, vectorize};

    /// The package's version, that of the covec crate it was built from.
    #[pymodule_export]
    const VERSION: &str = env!("CARGO_PKG_VERSION");
}
