//! `covec vectorize`: an image (plus optional albedo map and masks) to a layered SVG.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use clap::Args as ClapArgs;
use indicatif::{ProgressBar, ProgressStyle};

use super::io::{self, IoError};
use covec::imageio::{self, Limits};
use covec::output::{self, FileKind, RESULT_FILES};
use covec::pipeline::{self, Inputs, Masks, Mode, Observer, Params, Progress};
use covec::render::Image;
use covec::svg::{self, SvgOptions};

/// Vectorize an image into a layered SVG (albedo × shade + light), or many images and
/// directories into an output directory (`covec vectorize a.jpg b.png photos/ -o out/`).
#[derive(ClapArgs, Clone, Debug)]
pub struct Args {
    /// The image: PNG, JPEG or WebP; 8 or 16 bit; grey, RGB or RGBA (alpha is composited over
    /// white); `-`: standard input. Several images, or directories (their image files, not
    /// recursively), make a batch: each becomes `<name>.svg` and `<name>.json` in the output
    /// directory.
    #[arg(required = true, value_name = "INPUT")]
    pub inputs: Vec<PathBuf>,
    /// Where to write the layered SVG (flattened with --flatten), or with a `.png` extension a
    /// PNG drawn by covec's own renderer (see --width), with `.pdf` a vector PDF of the
    /// flattened picture, with `.json` the JSON scene alone (see --format). `-`: standard output.
    /// Default: the input path with the extension `.svg` (standard output when the input is
    /// `-`). For a batch: the output directory (required; created if missing).
    #[arg(short, long, value_name = "OUT.svg|OUT.png|OUT.pdf|OUT.json|-|DIR")]
    pub output: Option<PathBuf>,
    /// What to write to the output, whatever its extension. Default: from the output's
    /// extension, SVG when it names none of these (or is `-`).
    #[arg(long, value_enum, value_name = "FORMAT")]
    pub format: Option<io::Format>,
    /// Batch: pipeline threads in total, shared out among the images run at once.
    /// Default: the number of cores.
    #[arg(long, value_name = "N")]
    pub threads: Option<usize>,
    /// Batch: images run at once. Default: as many as threads (one thread each), at most the
    /// number of images.
    #[arg(long, value_name = "N")]
    pub jobs: Option<usize>,
    /// Width of a PNG output in pixels; the height keeps the aspect ratio. Default: the input's
    /// width.
    #[arg(long, value_name = "PX")]
    pub width: Option<u32>,
    /// Where to write the JSON scene (layers → paths → points, colour, opacity), which the
    /// service and editor load back losslessly. Default: the output path with the extension
    /// `.json` (none when the output is `-`).
    #[arg(long, value_name = "SCENE.json")]
    pub json: Option<PathBuf>,
    /// An albedo map with the image's aspect ratio, e.g. from an intrinsic-decomposition
    /// network. Default: a classical intrinsic decomposition (surfaces grouped by chromaticity,
    /// one lit colour each; docs/design.md).
    #[arg(long, value_name = "A.png")]
    pub albedo: Option<PathBuf>,
    /// A directory of binary mask images (0 and one other value), one per segment, e.g. from
    /// SAM; read in file-name order. Default: covec segments the albedo map itself.
    #[arg(long, value_name = "DIR", conflicts_with = "labels")]
    pub masks: Option<PathBuf>,
    /// One label-map image: each distinct value is a segment. Alternative to --masks.
    #[arg(long, value_name = "L.png")]
    pub labels: Option<PathBuf>,
    /// Total path budget over all layers, base path included (8-1024).
    #[arg(long, default_value_t = Params::default().paths, value_name = "N")]
    pub paths: u32,
    /// photo: albedo, shade and light layers; simple: albedo only, for emoji, icons and flat
    /// artwork; auto: looks at the part of the image that is not flat colour: photo when it
    /// holds smooth shading or photographic texture (however much flat background surrounds
    /// it), else simple. The summary line says why.
    #[arg(long, value_enum, default_value_t = Params::default().mode)]
    pub mode: Mode,
    /// Working size: the long side is scaled down to this many pixels, never up (16-4096).
    /// The SVG keeps the original size through its viewBox.
    #[arg(long, default_value_t = Params::default().max_size, value_name = "PX")]
    pub max_size: u32,
    /// Seed for every random choice of the optimisation stages (initialisation itself is
    /// deterministic); equal inputs and seed give byte-identical output.
    #[arg(long, default_value_t = Params::default().seed)]
    pub seed: u64,
    /// Write preview PNGs of each stage (input, albedo map, masks, layers, composite) here.
    #[arg(long, value_name = "DIR")]
    pub previews: Option<PathBuf>,
    /// Also write each layer as a standalone SVG here (albedo.svg, shade.svg, light.svg).
    #[arg(long, value_name = "DIR")]
    pub layers: Option<PathBuf>,
    /// Write the SVG flattened: the same picture as plain opaque paths, without blend modes or
    /// opacities, for programs that lack `multiply` or `plus-lighter` (larger file, not layered).
    #[arg(long)]
    pub flatten: bool,
    /// Decimals of the SVGs' coordinates in working-canvas pixels (0-6). Default: a
    /// quarter-pixel grid (a tenth with --flatten). The JSON scene always keeps full precision.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(0..=i64::from(svg::MAX_PRECISION)))]
    pub precision: Option<u32>,
    /// Refuse images (and masks, and PNG outputs) of more pixels than this.
    #[arg(long, default_value_t = Limits::default().max_pixels, value_name = "N")]
    pub max_pixels: u64,
    /// Refuse more masks (files in --masks, or distinct values in --labels) than this.
    #[arg(long, default_value_t = Limits::default().max_masks, value_name = "N")]
    pub max_masks: usize,
    /// Use a JPEG cut short (its missing part decodes as grey) instead of refusing it.
    #[arg(long)]
    pub accept_truncated: bool,
    /// After the run, print on standard error each stage's optimisation steps, seconds and
    /// last loss: where a run spends its time. One image only.
    #[arg(long)]
    pub stages: bool,
}

/// Why `covec vectorize` failed; printed as one line.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Io(#[from] IoError),
    #[error("{path}: no mask images (.png, .jpg, .jpeg, .webp) in this directory")]
    NoMasks { path: PathBuf },
    #[error(transparent)]
    Pipeline(#[from] pipeline::Error),
    #[error("--width sets the size of a PNG output; give -o a .png path")]
    WidthWithoutPng,
    #[error("--threads and --jobs apply to a batch (several images or a directory)")]
    BatchOptionForOneImage,
    #[error(
        "--flatten applies to an SVG output (a PDF is always flat, a PNG or JSON has no paths)"
    )]
    FlattenWithoutSvg,
    #[error("--json names the scene's file, but the output is the JSON scene already")]
    JsonTwice,
}

/// Vectorises one image file (a batch is [`super::batch::run`]; [`super::vectorize`] picks).
pub fn run(input: &Path, args: &Args) -> Result<(), Error> {
    if args.threads.is_some() || args.jobs.is_some() {
        return Err(Error::BatchOptionForOneImage);
    }
    let observer = CliObserver::new(args.previews.clone(), args.stages);
    if let Some(dir) = &args.previews {
        io::create_dir(dir)?;
    }
    let result = vectorize_file(input, args, &observer);
    observer.finish();
    // After a run only: a failure stays one line.
    if let (Ok(_), Some(stages)) = (&result, &observer.stages) {
        eprint!("{}", stages.lock().expect("not poisoned").table());
    }
    if let Some(error) = observer.write_error.into_inner().expect("not poisoned") {
        return Err(error.into());
    }
    let (output_path, output) = result?;
    if std::io::stderr().is_terminal() {
        let scene = &output.scene;
        eprintln!(
            "{}: {} mode ({}), {} paths ({} albedo, {} shade, {} light), {} segments",
            output_path.display(),
            output.mode.name(),
            output.mode_reason,
            scene.path_count(),
            scene.albedo.paths.len(),
            scene.shade.paths.len(),
            scene.light.paths.len(),
            scene.segment_count()
        );
    }
    Ok(())
}

/// Vectorizes one image as `args` say (their inputs aside) and writes the files; returns the
/// output path and the pipeline's output.
pub(super) fn vectorize_file(
    input: &Path,
    args: &Args,
    observer: &impl Observer,
) -> Result<(PathBuf, pipeline::Output), Error> {
    let output_path = args.output.clone().unwrap_or_else(|| {
        if io::is_stdio(input) {
            input.to_path_buf()
        } else {
            input.with_extension("svg")
        }
    });
    let format = args
        .format
        .or_else(|| io::Format::of_path(&output_path))
        .unwrap_or(io::Format::Svg);
    if args.width.is_some() && format != io::Format::Png {
        return Err(Error::WidthWithoutPng);
    }
    if args.flatten && format != io::Format::Svg {
        return Err(Error::FlattenWithoutSvg);
    }
    if args.json.is_some() && format == io::Format::Json {
        return Err(Error::JsonTwice);
    }
    let limits = Limits {
        max_pixels: args.max_pixels,
        max_masks: args.max_masks,
        accept_truncated: args.accept_truncated,
    };
    let decode = |path: &Path| io::decode_image(path, &limits);
    let image = decode(input)?;
    let albedo = args.albedo.as_deref().map(decode).transpose()?;
    let masks = if let Some(dir) = &args.masks {
        Masks::Binary(read_mask_dir(dir, &limits)?)
    } else if let Some(path) = &args.labels {
        let bytes = io::read(path)?;
        Masks::Labels(
            imageio::decode_labels(&bytes, &limits).map_err(|source| IoError::Input {
                path: path.clone(),
                source,
            })?,
        )
    } else {
        Masks::None
    };
    let params = Params {
        paths: args.paths,
        mode: args.mode,
        max_size: args.max_size,
        seed: args.seed,
        ..Params::default()
    };
    let output = pipeline::run(
        &Inputs {
            image,
            albedo,
            masks,
        },
        &params,
        observer,
        &AtomicBool::new(false),
    )?;

    let json_path = match format {
        io::Format::Json => Some(output_path.clone()),
        _ if args.json.is_some() => args.json.clone(),
        _ if io::is_stdio(&output_path) => None,
        _ => Some(output_path.with_extension("json")),
    };
    if let Some(dir) = &args.layers {
        io::create_dir(dir)?;
    }
    let svg_options = SvgOptions {
        precision: args.precision,
    };
    // The kind written to the output path (none for a PNG, drawn below).
    let main = match format {
        io::Format::Svg if args.flatten => Some(FileKind::FlatSvg),
        io::Format::Svg => Some(FileKind::LayeredSvg),
        io::Format::Pdf => Some(FileKind::Pdf),
        io::Format::Json => Some(FileKind::SceneJson),
        io::Format::Png => None,
    };
    let mut kinds = RESULT_FILES.to_vec();
    kinds.extend(main.filter(|kind| !kinds.contains(kind)));
    let artefacts = output::artefacts_with(&output.scene, &kinds, &svg_options);
    io::write_artefacts(&artefacts, |kind| match kind {
        FileKind::SceneJson => json_path.clone(),
        FileKind::Layer(layer) => {
            (args.layers.as_ref()).map(|dir| dir.join(format!("{}.svg", layer.name())))
        }
        _ => (main == Some(kind)).then(|| output_path.clone()),
    })?;
    if format == io::Format::Png {
        io::write_png(&output_path, &output.scene, args.width, args.max_pixels)?;
    }
    Ok((output_path, output))
}

/// The image files of a directory, in file-name order, decoded as binary masks.
pub(super) fn read_mask_dir(dir: &Path, limits: &Limits) -> Result<Vec<image::GrayImage>, Error> {
    let paths: Vec<PathBuf> = io::list_dir(dir)?
        .into_iter()
        .filter(|path| io::is_image_file(path))
        .collect();
    if paths.is_empty() {
        return Err(Error::NoMasks { path: dir.into() });
    }
    let files = paths
        .iter()
        .map(|p| Ok((p.display().to_string(), io::read(p)?)))
        .collect::<Result<Vec<_>, IoError>>()?;
    imageio::decode_masks(
        files
            .iter()
            .map(|(name, bytes)| (name.as_str(), bytes.as_slice())),
        limits,
    )
    .map_err(|source| {
        IoError::Input {
            path: dir.into(),
            source,
        }
        .into()
    })
}

/// A progress bar on a terminal (silent otherwise), preview PNGs into a directory, and the
/// stages' times when asked.
struct CliObserver {
    bar: Option<ProgressBar>,
    previews: Option<PathBuf>,
    /// The first preview that could not be written; reported after the run.
    write_error: Mutex<Option<IoError>>,
    stages: Option<Mutex<StageTimes>>,
}

/// Per stage, from its progress reports: the optimisation steps it ran (the distinct
/// iteration numbers it reported, so early stops show), when its last report came and its
/// last loss.
#[derive(Default)]
struct StageTimes {
    rows: Vec<StageTime>,
}

struct StageTime {
    name: &'static str,
    steps: u32,
    last_iteration: u32,
    end: Duration,
    loss: Option<f32>,
}

impl StageTimes {
    fn record(&mut self, p: &Progress) {
        if self.rows.last().is_none_or(|row| row.name != p.stage) {
            self.rows.push(StageTime {
                name: p.stage,
                steps: 0,
                last_iteration: 0,
                end: p.elapsed,
                loss: None,
            });
        }
        let row = self.rows.last_mut().expect("pushed above");
        if p.iteration > row.last_iteration {
            row.steps += 1;
            row.last_iteration = p.iteration;
        }
        row.end = p.elapsed;
        row.loss = p.loss.or(row.loss);
    }

    /// A stage's seconds run from the report that ended the stage before it.
    fn table(&self) -> String {
        let mut out = format!(
            "{:<12} {:>6} {:>8}  {}\n",
            "stage", "steps", "seconds", "loss"
        );
        let mut start = Duration::ZERO;
        for row in &self.rows {
            let loss = row.loss.map(|l| format!("{l:.6}")).unwrap_or_default();
            let seconds = row.end.saturating_sub(start).as_secs_f64();
            out += &format!("{:<12} {:>6} {seconds:>8.3}  {loss}\n", row.name, row.steps);
            start = row.end;
        }
        out + &format!("{:<12} {:>6} {:>8.3}\n", "run", "", start.as_secs_f64())
    }
}

impl CliObserver {
    fn new(previews: Option<PathBuf>, stages: bool) -> Self {
        let bar = std::io::stderr().is_terminal().then(|| {
            let bar = ProgressBar::new(1);
            bar.set_style(
                ProgressStyle::with_template("{elapsed_precise} [{bar:30}] stage {msg}")
                    .expect("valid template"),
            );
            bar
        });
        Self {
            bar,
            previews,
            write_error: Mutex::new(None),
            stages: stages.then(Mutex::default),
        }
    }

    fn finish(&self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
    }
}

impl Observer for CliObserver {
    fn progress(&self, p: &Progress) {
        if let Some(stages) = &self.stages {
            stages.lock().expect("not poisoned").record(p);
        }
        if let Some(bar) = &self.bar {
            bar.set_length(1000);
            bar.set_position((p.fraction() * 1000.0) as u64);
            let loss = p.loss.map(|l| format!(", loss {l:.5}")).unwrap_or_default();
            bar.set_message(format!(
                "{}/{} {} {}/{}{loss}",
                p.stage_index + 1,
                p.stage_count,
                p.stage,
                p.iteration,
                p.iterations
            ));
        }
    }

    fn preview(&self, name: &str, image: &Image) {
        let Some(dir) = &self.previews else { return };
        let path = dir.join(format!("{name}.png"));
        if let Err(source) = std::fs::write(&path, imageio::encode_png(image)) {
            let mut slot = self.write_error.lock().expect("not poisoned");
            slot.get_or_insert(IoError::Write { path, source });
        }
    }

    fn wants_previews(&self) -> bool {
        self.previews.is_some()
    }
}
