//! `covec eval`: runs each image at each budget with each method, writes one CSV row per run and
//! prints a summary table of means per image class (the image's parent directory).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use clap::Args as ClapArgs;

use super::io::{self, IoError};
use covec::edit::EditError;
use covec::eval::drawn::{Drawing, ParseError};
use covec::eval::edits::{self, EditCase, Leakage};
use covec::eval::faces::{self, SkinScores};
use covec::eval::vec::ObjectScores;
use covec::eval::{self, Quality};
use covec::imageio::{self, InputError, Limits, encode_png, resize_rgb, working_size};
use covec::pipeline::{self, Inputs, Masks, Mode, Params, Quiet, ResolvedMode};
use covec::render::Image;
use covec::render::composite::composite;
use covec::scene::Scene;
use covec::svg::{self, SvgOptions};

/// Measure covec (and baselines) on a set of images: MSE, PSNR, SSIM, size, time, memory.
#[derive(ClapArgs, Debug)]
pub struct Args {
    /// Image files, or directories searched recursively for PNG, JPEG and WebP files.
    #[arg(
        required_unless_present_any = ["write_scenes", "write_masks"],
        value_name = "DIR|IMAGE"
    )]
    pub inputs: Vec<PathBuf>,
    /// Path budgets to run, comma-separated.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "16,32,64,128",
        value_name = "N,..."
    )]
    pub paths: Vec<u32>,
    /// Methods to run, comma-separated: covec (auto mode), covec-photo, covec-simple, random
    /// (random paths, reconstruction loss only, same budget and iteration count).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "covec,random",
        value_name = "M,..."
    )]
    pub method: Vec<Method>,
    /// Where to write the CSV (one row per run). Default: standard output.
    #[arg(long, value_name = "results.csv")]
    pub out: Option<PathBuf>,
    /// Working size (long side), as for `covec vectorize`.
    #[arg(long, default_value_t = Params::default().max_size, value_name = "PX")]
    pub max_size: u32,
    /// Seeds to run, comma-separated, each as `covec vectorize --seed`: a figure that moves with
    /// the seed (the skin colour of a small face, an edit's leakage, a Cornell scene's albedo)
    /// wants a few before it is compared. The CSV has a row per seed; the tables' means and
    /// worst cases take every seed's runs.
    #[arg(
        long,
        value_delimiter = ',',
        default_values_t = [Params::default().seed],
        value_name = "SEED,..."
    )]
    pub seed: Vec<u64>,
    /// Multiplies every stage's iteration count (e.g. 0.5 for a quicker, rougher eval).
    #[arg(long, default_value_t = 1.0, value_name = "F")]
    pub iteration_scale: f32,
    /// Score the decomposition instead: each input is a scene directory (or a directory of
    /// them) holding image.png, albedo.png, shade.png, light.png and optionally
    /// cast-shadow.png and edited.png; runs photo mode, photo mode on the old Retinex albedo
    /// map, and simple mode. `--method` is ignored.
    #[arg(long)]
    pub intrinsic: bool,
    /// Write the generated scenes with known layers into this directory, one folder each,
    /// and exit (inputs are ignored).
    #[arg(long, value_name = "DIR")]
    pub write_scenes: Option<PathBuf>,
    /// A directory with one sub-directory of binary semantic masks per image, named by the
    /// image's file stem: adds VeC and the median IoU of albedo paths to masks (docs/design.md,
    /// "Departures from the paper").
    #[arg(long, value_name = "DIR")]
    pub semantic_masks: Option<PathBuf>,
    /// Also give those masks to the pipeline, as `covec vectorize --masks` does.
    #[arg(long, requires = "semantic_masks")]
    pub use_masks: bool,
    /// A file of hand-drawn skin masks (as benches/quality/faces.txt): adds, for each image
    /// it names, the CIEDE2000 between the render's and the photo's mean skin colour and the
    /// mean per-pixel CIEDE2000 inside the skin, and a table of them.
    #[arg(long, value_name = "FILE")]
    pub faces: Option<PathBuf>,
    /// Write the `--faces` file's skin masks into this directory as PNGs (white: skin), each
    /// named by its image and at the size it was drawn at, and exit (inputs are ignored): for
    /// scoring renders made elsewhere, as benches/quality/rd.sh does VTracer's.
    #[arg(long, value_name = "DIR", requires = "faces")]
    pub write_masks: Option<PathBuf>,
    /// A file of hand-drawn object masks, each with a colour (as benches/quality/edits.txt):
    /// for each image it names, recolours the object to that colour's hue by reference (as
    /// `covec edit --reference` does, default thresholds) and adds the mean CIEDE2000 outside the
    /// object between the edited and the unedited render, and inside it between the edited
    /// render and the reference, and a table of them.
    #[arg(long, value_name = "FILE")]
    pub edits: Option<PathBuf>,
    /// Side of the generated scenes, in pixels.
    #[arg(long, default_value_t = 256, value_name = "PX")]
    pub scene_size: usize,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Method {
    Covec,
    CovecPhoto,
    CovecSimple,
    Random,
}

impl Method {
    fn name(self) -> &'static str {
        match self {
            Method::Covec => "covec",
            Method::CovecPhoto => "covec-photo",
            Method::CovecSimple => "covec-simple",
            Method::Random => "random",
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Io(#[from] IoError),
    #[error("{path}: {source}")]
    Input { path: PathBuf, source: InputError },
    #[error("{path}: {source}")]
    Pipeline {
        path: PathBuf,
        source: pipeline::Error,
    },
    #[error("no images found in the given inputs")]
    NoImages,
    #[error("{0}")]
    Truth(String),
    #[error("no scene directories (with image.png and albedo.png) in the given inputs")]
    NoScenes,
    #[error(transparent)]
    Masks(#[from] Box<super::vectorize::Error>),
    #[error("{path}: {source}")]
    Drawn { path: PathBuf, source: ParseError },
    #[error("{path}: {source}")]
    Edit { path: PathBuf, source: EditError },
    #[error("{path}: `{image}` is drawn at {width} × {height}, outside 1 to {max} pixels")]
    MaskSize {
        path: PathBuf,
        image: String,
        width: usize,
        height: usize,
        max: u64,
    },
}

/// One run's measurements.
struct Row {
    image: String,
    class: String,
    method: &'static str,
    mode: &'static str,
    budget: u32,
    seed: u64,
    paths: [usize; 3],
    segments: usize,
    svg_bytes: usize,
    quality: Quality,
    seconds: f64,
    peak_mb: Option<f64>,
    objects: Option<ObjectScores>,
    /// Skin colour, for an image the `--faces` file draws.
    skin: Option<SkinScores>,
    /// Edit leakage, for an image the `--edits` file draws.
    edit: Option<Leakage>,
    /// Why the mode (as the job record and the CLI say it).
    mode_reason: String,
}

const CSV_HEADER: &str = "image,class,method,mode,budget,seed,albedo_paths,shade_paths,light_paths,segments,svg_bytes,mse,psnr,ssim,gmsd,ms_ssim,seconds,peak_mb,vec,median_iou,skin_mean_de,skin_pixel_de,edit_paths,edit_outside_de,edit_inside_de,mode_reason";

impl Row {
    fn csv(&self) -> String {
        format!(
            "{},{},{},{},{},{},{},{},{},{},{},{:.6},{:.3},{:.4},{:.4},{},{:.3},{},{},{},{},{},{},{},{},\"{}\"",
            self.image,
            self.class,
            self.method,
            self.mode,
            self.budget,
            self.seed,
            self.paths[0],
            self.paths[1],
            self.paths[2],
            self.segments,
            self.svg_bytes,
            self.quality.mse,
            self.quality.psnr,
            self.quality.ssim,
            self.quality.gmsd,
            self.quality
                .ms_ssim
                .map(|v| format!("{v:.4}"))
                .unwrap_or_default(),
            self.seconds,
            self.peak_mb.map(|m| format!("{m:.1}")).unwrap_or_default(),
            optional(self.objects.and_then(|o| o.vec)),
            optional(self.objects.and_then(|o| o.median_iou)),
            optional(self.skin.map(|s| s.mean_colour)),
            optional(self.skin.map(|s| s.per_pixel)),
            self.edit.map(|e| e.changed.to_string()).unwrap_or_default(),
            optional(self.edit.map(|e| e.outside)),
            optional(self.edit.map(|e| e.inside)),
            self.mode_reason.replace('"', "'"),
        )
    }
}

/// Scores covec on images (`--intrinsic` and `--write-scenes` are [`super::intrinsic`]'s;
/// [`super::eval`] picks).
pub fn run(args: &Args) -> Result<(), Error> {
    let mut images = Vec::new();
    for input in &args.inputs {
        collect_images(input, &mut images)?;
    }
    images.sort();
    if images.is_empty() {
        return Err(Error::NoImages);
    }
    let face_masks = match &args.faces {
        Some(path) => read_drawn(path, faces::parse)?,
        None => Vec::new(),
    };
    let edit_cases = match &args.edits {
        Some(path) => read_drawn(path, edits::parse)?,
        None => Vec::new(),
    };
    let mut csv = String::from(CSV_HEADER);
    csv.push('\n');
    let mut rows = Vec::new();
    let total = images.len() * args.paths.len() * args.method.len() * args.seed.len();
    for image_path in &images {
        let bytes = io::read(image_path)?;
        let drawn = Drawn {
            face: face_masks.iter().find(|f| f.image == stem(image_path)),
            edit: edit_cases
                .iter()
                .find(|e| e.object.image == stem(image_path)),
        };
        for &budget in &args.paths {
            for &method in &args.method {
                for &seed in &args.seed {
                    let run = RunKey {
                        method,
                        budget,
                        seed,
                    };
                    let row = run_one(image_path, &bytes, run, drawn, args)?;
                    eprintln!(
                        "[{}/{total}] {} {} {} paths, seed {seed}: MSE {:.5}, PSNR {:.2}, SSIM {:.4}, GMSD {:.4}, {:.1} s, {} MB",
                        rows.len() + 1,
                        row.image,
                        row.method,
                        budget,
                        row.quality.mse,
                        row.quality.psnr,
                        row.quality.ssim,
                        row.quality.gmsd,
                        row.seconds,
                        row.peak_mb
                            .map(|m| format!("{m:.0}"))
                            .unwrap_or_else(|| "?".into()),
                    );
                    csv.push_str(&row.csv());
                    csv.push('\n');
                    rows.push(row);
                }
            }
        }
    }
    match &args.out {
        Some(path) => io::write(path, csv.as_bytes())?,
        None => print!("{csv}"),
    }
    eprint!("{}", summary(&rows));
    if rows.iter().any(|r| r.skin.is_some()) {
        eprint!("{}", skin_table(&rows));
    }
    if rows.iter().any(|r| r.edit.is_some()) {
        eprint!("{}", edit_table(&rows));
    }
    Ok(())
}

/// Writes the skin masks of `faces` (a `--faces` file) into `dir/<image>.png`.
pub fn write_masks(faces: &Path, dir: &Path) -> Result<(), Error> {
    let drawings = read_drawn(faces, faces::parse)?;
    io::create_dir(dir)?;
    for face in &drawings {
        let (width, height) = face.drawn_size();
        let max = Limits::default().max_pixels;
        if !(1..=max).contains(&(width as u64 * height as u64)) {
            return Err(Error::MaskSize {
                path: faces.to_path_buf(),
                image: face.image.clone(),
                width,
                height,
                max,
            });
        }
        let data = face
            .rasterize(width, height)
            .into_iter()
            .flat_map(|skin| [f32::from(u8::from(skin)); 3])
            .collect();
        let mask = Image {
            width,
            height,
            data,
        };
        io::write(&dir.join(format!("{}.png", face.image)), &encode_png(&mask))?;
    }
    eprintln!("wrote {} skin masks to {}", drawings.len(), dir.display());
    Ok(())
}

/// A masks file of `path`, read by `parse`.
fn read_drawn<T>(
    path: &Path,
    parse: impl Fn(&str) -> Result<Vec<T>, ParseError>,
) -> Result<Vec<T>, Error> {
    parse(&String::from_utf8_lossy(&io::read(path)?)).map_err(|source| Error::Drawn {
        path: path.to_path_buf(),
        source,
    })
}

/// What the `--faces` and `--edits` files draw on one image.
#[derive(Clone, Copy)]
struct Drawn<'a> {
    face: Option<&'a Drawing>,
    edit: Option<&'a EditCase>,
}

/// One run of an image: its method, path budget and seed.
#[derive(Clone, Copy)]
struct RunKey {
    method: Method,
    budget: u32,
    seed: u64,
}

fn run_one(
    path: &Path,
    bytes: &[u8],
    run: RunKey,
    drawn: Drawn,
    args: &Args,
) -> Result<Row, Error> {
    let RunKey {
        method,
        budget,
        seed,
    } = run;
    let input_error = |source| Error::Input {
        path: path.to_path_buf(),
        source,
    };
    let pipeline_error = |source| Error::Pipeline {
        path: path.to_path_buf(),
        source,
    };
    let mut params = params_for(args, budget, seed);
    eval::reset_peak_memory();
    let started = Instant::now();
    let image = imageio::decode_image(bytes, &Limits::default()).map_err(input_error)?;
    let (w, h) = working_size(image.width(), image.height(), args.max_size);
    let target = resize_rgb(&image, w, h);
    let cancel = AtomicBool::new(false);
    let semantic = match &args.semantic_masks {
        Some(dir) => Some(semantic_masks(&dir.join(stem(path)))?),
        None => None,
    };
    let (scene, mode, mode_reason): (Scene, ResolvedMode, String) = match method {
        Method::Random => {
            let mut scene =
                eval::random_baseline(&target, &params, &Quiet, &cancel).map_err(pipeline_error)?;
            (scene.original_width, scene.original_height) = (image.width(), image.height());
            (scene, ResolvedMode::Simple, "random baseline".into())
        }
        _ => {
            params.mode = match method {
                Method::CovecPhoto => Mode::Photo,
                Method::CovecSimple => Mode::Simple,
                _ => Mode::Auto,
            };
            let inputs = Inputs {
                image,
                albedo: None,
                masks: match &semantic {
                    Some(masks) if args.use_masks => Masks::Binary(masks.clone()),
                    _ => Masks::None,
                },
            };
            let output =
                pipeline::run(&inputs, &params, &Quiet, &cancel).map_err(pipeline_error)?;
            (output.scene, output.mode, output.mode_reason)
        }
    };
    let svg_bytes = svg::to_svg(&scene, &SvgOptions::default()).len();
    let seconds = started.elapsed().as_secs_f64();
    let peak_mb = eval::peak_memory_bytes().map(|b| b as f64 / (1024.0 * 1024.0));
    let render = composite(&scene);
    let quality = eval::quality(&render, &target);
    let skin = drawn.face.and_then(|face| {
        let mask = face.rasterize(target.width, target.height);
        faces::skin_scores(&render, &target, &mask)
    });
    let edit = match drawn.edit {
        Some(case) => edits::leakage(&scene, &target, case).map_err(|source| Error::Edit {
            path: path.to_path_buf(),
            source,
        })?,
        None => None,
    };
    let objects = semantic.map(|masks| {
        let (w, h) = (scene.width, scene.height);
        let at_working_size: Vec<Vec<bool>> = masks
            .iter()
            .map(|m| {
                let m = image::imageops::resize(m, w, h, image::imageops::FilterType::Nearest);
                m.as_raw().iter().map(|&v| v > 0).collect()
            })
            .collect();
        eval::vec::object_scores(&scene, &at_working_size)
    });
    Ok(Row {
        image: stem(path),
        class: path
            .parent()
            .and_then(Path::file_name)
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default(),
        method: method.name(),
        mode: mode.name(),
        budget,
        seed,
        paths: [
            scene.albedo.paths.len(),
            scene.shade.paths.len(),
            scene.light.paths.len(),
        ],
        segments: scene.segment_count(),
        svg_bytes,
        quality,
        seconds,
        peak_mb,
        objects,
        skin,
        edit,
        mode_reason,
    })
}

fn stem(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// The binary masks in `dir` (as `covec vectorize --masks` reads them).
fn semantic_masks(dir: &Path) -> Result<Vec<image::GrayImage>, Error> {
    super::vectorize::read_mask_dir(dir, &Limits::default()).map_err(|e| Error::Masks(Box::new(e)))
}

/// A value with 4 decimals, or blank.
fn optional(value: Option<f32>) -> String {
    value.map(|v| format!("{v:.4}")).unwrap_or_default()
}

/// The run parameters for `budget` paths and `seed`: the command's size and iteration scale.
pub fn params_for(args: &Args, budget: u32, seed: u64) -> Params {
    let mut params = Params {
        paths: budget,
        max_size: args.max_size,
        seed,
        ..Params::default()
    };
    let scale = |n: u32| ((n as f32 * args.iteration_scale).round() as u32).max(u32::from(n > 0));
    let it = &mut params.iterations;
    (it.structure, it.reconstruction, it.refine, it.polish) = (
        scale(it.structure),
        scale(it.reconstruction),
        scale(it.refine),
        scale(it.polish),
    );
    params
}

/// Mean of an object score over the rows that have it, blank if none has.
fn mean_of(rows: &[&Row], score: impl Fn(&ObjectScores) -> Option<f32>) -> String {
    let values: Vec<f32> = rows
        .iter()
        .filter_map(|r| r.objects.as_ref().and_then(&score))
        .collect();
    optional((!values.is_empty()).then(|| values.iter().sum::<f32>() / values.len() as f32))
}

/// Mean MS-SSIM of the rows that have one (images of at least 11 px), blank if none has.
fn mean_ms_ssim(rows: &[&Row]) -> String {
    let values: Vec<f64> = rows
        .iter()
        .filter_map(|r| r.quality.ms_ssim)
        .map(f64::from)
        .collect();
    if values.is_empty() {
        return String::new();
    }
    format!("{:.4}", values.iter().sum::<f64>() / values.len() as f64)
}

fn collect_images(path: &Path, out: &mut Vec<PathBuf>) -> Result<(), Error> {
    if path.is_dir() {
        for entry in io::list_dir(path)? {
            collect_images(&entry, out)?;
        }
    } else if io::is_image_file(path) {
        out.push(path.to_path_buf());
    } else if !path.exists() {
        return Err(IoError::Read {
            path: path.to_path_buf(),
            source: std::io::ErrorKind::NotFound.into(),
        }
        .into());
    }
    Ok(())
}

/// Markdown table of the skin colour per face, method, budget and seed, and its means over the
/// faces and seeds of each method and budget.
fn skin_table(rows: &[Row]) -> String {
    let mut out = String::from(
        "\n| face | method | paths | seed | mean skin colour ΔE00 | mean ΔE00 per pixel |\n|---|---|---|---|---|---|\n",
    );
    let scored: Vec<(&Row, SkinScores)> =
        rows.iter().filter_map(|r| r.skin.map(|s| (r, s))).collect();
    for (r, s) in &scored {
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} | {:.2} | {:.2} |",
            r.image, r.method, r.budget, r.seed, s.mean_colour, s.per_pixel
        );
    }
    let mut keys: Vec<(&str, u32)> = scored.iter().map(|(r, _)| (r.method, r.budget)).collect();
    keys.sort_unstable();
    keys.dedup();
    let seeds = seeds(rows);
    for (method, budget) in keys {
        let group: Vec<&SkinScores> = scored
            .iter()
            .filter(|(r, _)| r.method == method && r.budget == budget)
            .map(|(_, s)| s)
            .collect();
        let n = group.len() as f32;
        let worst = group.iter().map(|s| s.mean_colour).fold(0.0, f32::max);
        let _ = writeln!(
            out,
            "| mean of {} (worst {worst:.2}) | {method} | {budget} | {seeds} | {:.2} | {:.2} |",
            group.len(),
            group.iter().map(|s| s.mean_colour).sum::<f32>() / n,
            group.iter().map(|s| s.per_pixel).sum::<f32>() / n,
        );
    }
    out
}

/// Markdown table of the edit leakage per image, method, budget and seed.
fn edit_table(rows: &[Row]) -> String {
    let mut out = String::from(
        "\n| image | method | paths | seed | paths recoloured | outside ΔE00 (edited vs unedited) | inside ΔE00 (edited vs reference) |\n|---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        if let Some(e) = r.edit {
            let _ = writeln!(
                out,
                "| {} | {} | {} | {} | {} | {:.2} | {:.2} |",
                r.image, r.method, r.budget, r.seed, e.changed, e.outside, e.inside
            );
        }
    }
    out
}

/// The seeds of `rows`, in their first order, for a table row that pools them.
fn seeds(rows: &[Row]) -> String {
    let mut seen: Vec<u64> = Vec::new();
    for r in rows {
        if !seen.contains(&r.seed) {
            seen.push(r.seed);
        }
    }
    seen.iter()
        .map(u64::to_string)
        .collect::<Vec<_>>()
        .join(", ")
}

/// Markdown table of means per class, method and budget over every seed's runs (`n` of them),
/// plus an "all" row per method and budget.
fn summary(rows: &[Row]) -> String {
    let mut keys: Vec<(String, &'static str, u32)> = Vec::new();
    for r in rows {
        for class in [r.class.clone(), "all".to_string()] {
            let key = (class, r.method, r.budget);
            if !keys.contains(&key) {
                keys.push(key);
            }
        }
    }
    keys.sort_by(|a, b| {
        (a.0 == "all")
            .cmp(&(b.0 == "all"))
            .then(a.0.cmp(&b.0))
            .then(a.2.cmp(&b.2))
            .then(a.1.cmp(b.1))
    });
    let mut out = String::from(
        "\n| class | method | paths | seeds | n | MSE | PSNR | SSIM | GMSD | MS-SSIM | segments | SVG KB | seconds (median) | peak MB (max) | VeC | IoU (median) |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    let seeds = seeds(rows);
    for (class, method, budget) in keys {
        let group: Vec<&Row> = rows
            .iter()
            .filter(|r| {
                (class == "all" || r.class == class) && r.method == method && r.budget == budget
            })
            .collect();
        let n = group.len() as f64;
        let mean = |f: &dyn Fn(&Row) -> f64| group.iter().map(|r| f(r)).sum::<f64>() / n;
        let mut seconds: Vec<f64> = group.iter().map(|r| r.seconds).collect();
        seconds.sort_by(f64::total_cmp);
        let median = seconds[seconds.len() / 2];
        let peak = group.iter().filter_map(|r| r.peak_mb).fold(0.0, f64::max);
        let _ = writeln!(
            out,
            "| {class} | {method} | {budget} | {seeds} | {} | {:.5} | {:.2} | {:.4} | {:.4} | {} | {:.0} | {:.1} | {:.1} | {:.0} | {} | {} |",
            group.len(),
            mean(&|r| f64::from(r.quality.mse)),
            mean(&|r| f64::from(r.quality.psnr)),
            mean(&|r| f64::from(r.quality.ssim)),
            mean(&|r| f64::from(r.quality.gmsd)),
            mean_ms_ssim(&group),
            mean(&|r| r.segments as f64),
            mean(&|r| r.svg_bytes as f64 / 1024.0),
            median,
            peak,
            mean_of(&group, |o| o.vec),
            mean_of(&group, |o| o.median_iou),
        );
    }
    out
}
