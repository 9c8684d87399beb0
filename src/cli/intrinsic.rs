//! `covec eval --intrinsic` and `--write-scenes`: the decomposition scored against known layers
//! (`covec::eval::intrinsic`). One CSV row per scene, method, budget and seed; a markdown summary per scene on
//! standard error.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use super::eval::{Args, Error, params_for};
use super::io;
use covec::eval::intrinsic::{self, AlbedoEstimate, LayerScores, TRUTH_FILES, Truth};
use covec::eval::vec::{ObjectScores, object_scores};
use covec::pipeline::{self, Inputs, Masks, Mode, Quiet};
use covec::render::composite::composite;
use covec::synth::{self, scenes};

/// The runs compared on each scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Run {
    /// Photo mode on the bare image: covec's own intrinsic decomposition.
    Photo,
    /// Photo mode given the grey Retinex albedo map covec used before, as a client's map.
    PhotoRetinex,
    /// The albedo-only variant: the no-decomposition baseline.
    Simple,
    /// Photo mode given the scene's true object labels as masks, when known.
    PhotoLabels,
}

const RUNS: [Run; 4] = [Run::Photo, Run::PhotoRetinex, Run::Simple, Run::PhotoLabels];

impl Run {
    fn name(self) -> &'static str {
        match self {
            Run::Photo => "photo",
            Run::PhotoRetinex => "photo-retinex",
            Run::Simple => "simple",
            Run::PhotoLabels => "photo-labels",
        }
    }
}

/// Writes every generated scene's truth files into `dir/<scene name>/`.
pub fn write_scenes(dir: &Path, size: usize) -> Result<(), Error> {
    for (index, name) in scenes::scene_names().iter().enumerate() {
        let folder = dir.join(name);
        io::create_dir(&folder)?;
        for (file, bytes) in Truth::from(scenes::scene(index, size)).to_pngs() {
            io::write(&folder.join(file), &bytes)?;
        }
    }
    eprintln!(
        "wrote {} scenes of {size}² to {}",
        scenes::scene_names().len(),
        dir.display()
    );
    Ok(())
}

/// One run's scores.
struct Row {
    scene: String,
    run: Run,
    budget: u32,
    seed: u64,
    /// The image's own error against the true albedo.
    image_error: f32,
    scores: LayerScores,
    /// How paths keep to the true objects, when they are known.
    objects: Option<ObjectScores>,
    mse: f32,
    seconds: f64,
}

const CSV_HEADER: &str = "scene,method,budget,seed,image_albedo_simse,albedo_simse,albedo_ratio,shade_simse,light_simse,highlight_coverage,shadow_in_albedo,edit_mse,mse,seconds,vec,median_iou";

fn optional(v: Option<f32>) -> String {
    v.map(|v| format!("{v:.4}")).unwrap_or_default()
}

impl Row {
    fn csv(&self) -> String {
        let s = &self.scores;
        format!(
            "{},{},{},{},{:.6},{:.6},{:.3},{:.6},{:.6},{},{},{},{:.6},{:.2},{},{}",
            self.scene,
            self.run.name(),
            self.budget,
            self.seed,
            self.image_error,
            s.albedo,
            s.albedo / self.image_error,
            s.shade,
            s.light,
            optional(s.highlight_coverage),
            optional(s.shadow_in_albedo),
            s.edit.map(|v| format!("{v:.6}")).unwrap_or_default(),
            self.mse,
            self.seconds,
            optional(self.objects.and_then(|o| o.vec)),
            optional(self.objects.and_then(|o| o.median_iou)),
        )
    }
}

/// Scene directories among `inputs`: each input that holds the required truth files, else its
/// subdirectories that do, in name order.
fn scene_dirs(inputs: &[PathBuf]) -> Result<Vec<PathBuf>, Error> {
    let is_scene = |dir: &Path| TRUTH_FILES[..4].iter().all(|f| dir.join(f).is_file());
    let mut out = Vec::new();
    for input in inputs {
        if is_scene(input) {
            out.push(input.clone());
        } else if input.is_dir() {
            out.extend(io::list_dir(input)?.into_iter().filter(|d| is_scene(d)));
        } else {
            return Err(Error::Truth(format!(
                "{}: not a directory",
                input.display()
            )));
        }
    }
    if out.is_empty() {
        return Err(Error::NoScenes);
    }
    Ok(out)
}

pub fn run(args: &Args) -> Result<(), Error> {
    let dirs = scene_dirs(&args.inputs)?;
    let mut rows = Vec::new();
    let mut maps =
        String::from("\n| scene | image | Retinex map | intrinsic map |\n|---|---|---|---|\n");
    for dir in &dirs {
        let truth = Truth::read(dir).map_err(Error::Truth)?;
        let name = dir
            .file_name()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let image_error = intrinsic::image_error(&truth);
        let retinex = AlbedoEstimate::Retinex.map(&truth.image);
        let _ = writeln!(
            maps,
            "| {name} | {image_error:.5} | {:.5} | {:.5} |",
            intrinsic::map_error(&retinex, &truth),
            intrinsic::map_error(&AlbedoEstimate::Intrinsic.map(&truth.image), &truth),
        );
        let labels = truth.label_map();
        let object_masks = truth.object_masks();
        for (&budget, &seed) in args
            .paths
            .iter()
            .flat_map(|b| args.seed.iter().map(move |s| (b, s)))
        {
            for run in RUNS {
                if run == Run::PhotoLabels && labels.is_none() {
                    continue;
                }
                let mut params = params_for(args, budget, seed);
                params.max_size = params
                    .max_size
                    .max(truth.image.width.max(truth.image.height) as u32);
                params.mode = if run == Run::Simple {
                    Mode::Simple
                } else {
                    Mode::Photo
                };
                let rgb = |image| image::DynamicImage::ImageRgb8(synth::to_rgb8(image));
                let inputs = Inputs {
                    image: rgb(&truth.image),
                    albedo: (run == Run::PhotoRetinex).then(|| rgb(&retinex)),
                    masks: match (&labels, run) {
                        (Some(labels), Run::PhotoLabels) => Masks::Labels(labels.clone()),
                        _ => Masks::None,
                    },
                };
                let started = Instant::now();
                let output = pipeline::run(&inputs, &params, &Quiet, &AtomicBool::new(false))
                    .map_err(|source| Error::Pipeline {
                        path: dir.clone(),
                        source,
                    })?;
                let seconds = started.elapsed().as_secs_f64();
                let scores = intrinsic::score(&output.scene, &truth);
                let mse = covec::eval::quality(&composite(&output.scene), &truth.image).mse;
                let objects =
                    (!object_masks.is_empty()).then(|| object_scores(&output.scene, &object_masks));
                let row = Row {
                    scene: name.clone(),
                    run,
                    budget,
                    seed,
                    image_error,
                    scores,
                    objects,
                    mse,
                    seconds,
                };
                eprintln!("{}", row.csv());
                rows.push(row);
            }
        }
    }
    let mut csv = format!("{CSV_HEADER}\n");
    for row in &rows {
        csv.push_str(&row.csv());
        csv.push('\n');
    }
    match &args.out {
        Some(path) => io::write(path, csv.as_bytes())?,
        None => print!("{csv}"),
    }
    eprint!("{maps}{}", summary(&rows));
    Ok(())
}

/// Per scene, budget and seed: the albedo ratio, highlight coverage, shadow share and edit error of
/// each run side by side.
fn summary(rows: &[Row]) -> String {
    let mut out = String::from(
        "\n| scene | paths | seed | albedo siMSE ×image (photo / Retinex / simple) | highlights covered | shadow in albedo (photo / Retinex) | edit MSE K=4 (photo / Retinex / simple) |\n|---|---|---|---|---|---|---|\n",
    );
    // The same scene, budget and seed as `photo`, in another run.
    let partner = |photo: &Row, run: Run| {
        rows.iter().find(|r| {
            r.run == run
                && r.scene == photo.scene
                && r.budget == photo.budget
                && r.seed == photo.seed
        })
    };
    for photo in rows.iter().filter(|r| r.run == Run::Photo) {
        let find = |run: Run| partner(photo, run);
        let (Some(retinex), Some(simple)) = (find(Run::PhotoRetinex), find(Run::Simple)) else {
            continue;
        };
        let ratio = |r: &Row| r.scores.albedo / r.image_error;
        let percent = |v: Option<f32>| v.map(|v| format!("{:.0}%", 100.0 * v)).unwrap_or_default();
        let edit = |r: &Row| r.scores.edit.map(|v| format!("{v:.5}")).unwrap_or_default();
        let _ = writeln!(
            out,
            "| {} | {} | {} | {:.2} / {:.2} / {:.2} | {} | {} / {} | {} / {} / {} |",
            photo.scene,
            photo.budget,
            photo.seed,
            ratio(photo),
            ratio(retinex),
            ratio(simple),
            percent(photo.scores.highlight_coverage),
            percent(photo.scores.shadow_in_albedo),
            percent(retinex.scores.shadow_in_albedo),
            edit(photo),
            edit(retinex),
            edit(simple),
        );
    }
    out.push_str(
        "\n| scene | paths | seed | VeC (bare / labels) | albedo path IoU, median (bare / labels) | MSE (bare / labels) |\n|---|---|---|---|---|---|\n",
    );
    for photo in rows.iter().filter(|r| r.run == Run::Photo) {
        let Some(labelled) = partner(photo, Run::PhotoLabels) else {
            continue;
        };
        let score = |r: &Row, f: fn(&ObjectScores) -> Option<f32>| {
            r.objects
                .as_ref()
                .and_then(f)
                .map(|v| format!("{v:.2}"))
                .unwrap_or_default()
        };
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} / {} | {} / {} | {:.5} / {:.5} |",
            photo.scene,
            photo.budget,
            photo.seed,
            score(photo, |o| o.vec),
            score(labelled, |o| o.vec),
            score(photo, |o| o.median_iou),
            score(labelled, |o| o.median_iou),
            photo.mse,
            labelled.mse,
        );
    }
    out
}
