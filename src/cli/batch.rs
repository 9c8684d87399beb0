//! `covec vectorize a.jpg b.png photos/ -o out/`: many images into an output directory.
//!
//! Images run in parallel within a thread budget: `--jobs` runners, each with its own rayon
//! pool of `threads / jobs` threads (as the service's workers: in one shared pool a thread
//! waiting inside one image's parallel loop could pick up another whole image). One progress
//! bar covers the batch; a summary table goes to stdout. An image that fails does not stop the
//! others; the command then exits non-zero.

use std::io::IsTerminal;
use std::panic::AssertUnwindSafe;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};

use super::io::{self, IoError};
use super::vectorize::{self, Args};
use covec::pipeline::{Observer, Progress};
use covec::render::Image;

/// Why a batch could not run, or did not fully succeed; printed as one line.
#[derive(Debug, thiserror::Error)]
pub enum BatchError {
    #[error("a batch (several images or a directory) needs -o DIR, the output directory")]
    NoOutputDirectory,
    #[error(
        "{0} applies to one image; a batch writes <name>.svg and <name>.json into the -o directory"
    )]
    PerImageOption(&'static str),
    #[error("{first} and {second} would both be written as {name}.svg")]
    NameClash {
        first: PathBuf,
        second: PathBuf,
        name: String,
    },
    #[error("no image files (.png, .jpg, .jpeg, .webp) in the inputs")]
    NoImages,
    #[error("{failed} of {total} images failed (the others were written; see the summary)")]
    Failed { failed: usize, total: usize },
    #[error(transparent)]
    Io(#[from] IoError),
    #[error("thread pool: {0}")]
    Pool(#[from] rayon::ThreadPoolBuildError),
}

/// One image's line of the summary.
struct Row {
    input: PathBuf,
    seconds: f32,
    outcome: Result<Done, String>,
}

struct Done {
    output: PathBuf,
    mode: &'static str,
    paths: usize,
}

pub fn run(args: &Args) -> Result<(), BatchError> {
    let directory = args.output.clone().ok_or(BatchError::NoOutputDirectory)?;
    let per_image = [
        ("--albedo", args.albedo.is_some()),
        ("--masks", args.masks.is_some()),
        ("--labels", args.labels.is_some()),
        ("--json", args.json.is_some()),
        ("--previews", args.previews.is_some()),
        ("--layers", args.layers.is_some()),
        ("--width", args.width.is_some()),
        ("--flatten", args.flatten),
        ("--stages", args.stages),
        ("--format", args.format.is_some()),
        (
            "- (standard input)",
            args.inputs.iter().any(|input| io::is_stdio(input)),
        ),
    ];
    if let Some((option, _)) = per_image.iter().find(|(_, given)| *given) {
        return Err(BatchError::PerImageOption(option));
    }
    let files = image_files(&args.inputs)?;
    let outputs = output_paths(&files, &directory)?;
    io::create_dir(&directory)?;

    let threads = args
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
        .max(1);
    let jobs = args.jobs.unwrap_or(threads).clamp(1, files.len());
    let pools = (0..jobs)
        .map(|_| {
            rayon::ThreadPoolBuilder::new()
                .num_threads((threads / jobs).max(1))
                .build()
        })
        .collect::<Result<Vec<_>, _>>()?;

    let progress = BatchProgress::new(files.len());
    let next = AtomicUsize::new(0);
    let rows: Mutex<Vec<Option<Row>>> = Mutex::new((0..files.len()).map(|_| None).collect());
    std::thread::scope(|scope| {
        for pool in &pools {
            let (files, outputs, progress, next, rows) =
                (&files, &outputs, &progress, &next, &rows);
            scope.spawn(move || {
                loop {
                    let index = next.fetch_add(1, Ordering::SeqCst);
                    let Some(input) = files.get(index) else { break };
                    let started = Instant::now();
                    let file_args = Args {
                        output: Some(outputs[index].clone()),
                        ..args.clone()
                    };
                    let observer = ImageProgress {
                        batch: progress,
                        index,
                    };
                    let result = std::panic::catch_unwind(AssertUnwindSafe(|| {
                        pool.install(|| vectorize::vectorize_file(input, &file_args, &observer))
                    }));
                    let outcome = match result {
                        Ok(Ok((output, run))) => Ok(Done {
                            output,
                            mode: run.mode.name(),
                            paths: run.scene.path_count(),
                        }),
                        Ok(Err(error)) => Err(error.to_string()),
                        Err(_) => Err("the pipeline crashed (a bug: please report it)".into()),
                    };
                    progress.finished(index, outcome.is_ok());
                    rows.lock().expect("not poisoned")[index] = Some(Row {
                        input: input.clone(),
                        seconds: started.elapsed().as_secs_f32(),
                        outcome,
                    });
                }
            });
        }
    });
    progress.finish();
    let rows: Vec<Row> = rows
        .into_inner()
        .expect("not poisoned")
        .into_iter()
        .map(|row| row.expect("every image is run"))
        .collect();
    print!("{}", summary(&rows, progress.started.elapsed()));
    let failed = rows.iter().filter(|row| row.outcome.is_err()).count();
    if failed > 0 {
        return Err(BatchError::Failed {
            failed,
            total: rows.len(),
        });
    }
    Ok(())
}

/// The files named, and the image files of the directories named (in file-name order, not
/// recursively). A named file is kept whatever its extension: if it cannot be decoded, its row
/// says so.
fn image_files(inputs: &[PathBuf]) -> Result<Vec<PathBuf>, BatchError> {
    let mut files = Vec::new();
    for input in inputs {
        if input.is_dir() {
            files.extend(
                io::list_dir(input)?
                    .into_iter()
                    .filter(|path| path.is_file() && io::is_image_file(path)),
            );
        } else {
            files.push(input.clone());
        }
    }
    if files.is_empty() {
        return Err(BatchError::NoImages);
    }
    Ok(files)
}

/// `<directory>/<file stem>.svg` for each file; two files with one stem are refused before
/// anything runs (one would overwrite the other).
fn output_paths(files: &[PathBuf], directory: &Path) -> Result<Vec<PathBuf>, BatchError> {
    let mut seen: std::collections::HashMap<String, &PathBuf> = Default::default();
    files
        .iter()
        .map(|file| {
            let name = file
                .file_stem()
                .map(|stem| stem.to_string_lossy().into_owned())
                .unwrap_or_default();
            if let Some(first) = seen.insert(name.clone(), file) {
                return Err(BatchError::NameClash {
                    first: first.clone(),
                    second: file.clone(),
                    name,
                });
            }
            Ok(directory.join(format!("{name}.svg")))
        })
        .collect()
}

/// The summary table: one line per image in input order, then the totals.
fn summary(rows: &[Row], elapsed: Duration) -> String {
    let cells: Vec<[String; 6]> = rows
        .iter()
        .map(|row| match &row.outcome {
            Ok(done) => [
                row.input.display().to_string(),
                "ok".into(),
                done.mode.into(),
                done.paths.to_string(),
                format!("{:.1}", row.seconds),
                done.output.display().to_string(),
            ],
            Err(error) => [
                row.input.display().to_string(),
                "failed".into(),
                "-".into(),
                "-".into(),
                format!("{:.1}", row.seconds),
                error.clone(),
            ],
        })
        .collect();
    let header = [
        "input",
        "status",
        "mode",
        "paths",
        "seconds",
        "output or error",
    ]
    .map(String::from);
    let mut widths = [0; 6];
    for line in std::iter::once(&header).chain(&cells) {
        for (width, cell) in widths.iter_mut().zip(line) {
            *width = (*width).max(cell.chars().count());
        }
    }
    let mut text = String::new();
    for line in std::iter::once(&header).chain(&cells) {
        let padded: Vec<String> = line
            .iter()
            .zip(widths)
            .enumerate()
            .map(|(column, (cell, width))| match column {
                5 => cell.clone(),
                3 | 4 => format!("{cell:>width$}"),
                _ => format!("{cell:<width$}"),
            })
            .collect();
        text.push_str(padded.join("  ").trim_end());
        text.push('\n');
    }
    let failed = rows.iter().filter(|row| row.outcome.is_err()).count();
    text.push_str(&format!(
        "{} images: {} written, {failed} failed, {:.1} s\n",
        rows.len(),
        rows.len() - failed,
        elapsed.as_secs_f32()
    ));
    text
}

/// Per mille of each image done; one bar over the sum (on a terminal only).
const STEPS: u64 = 1000;

struct BatchProgress {
    bar: Option<ProgressBar>,
    done: Vec<AtomicU64>,
    finished: AtomicUsize,
    failed: AtomicUsize,
    started: Instant,
}

impl BatchProgress {
    fn new(images: usize) -> Self {
        let bar = std::io::stderr().is_terminal().then(|| {
            let bar = ProgressBar::new(images as u64 * STEPS);
            bar.set_style(
                ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {msg} (eta {eta})")
                    .expect("valid template"),
            );
            bar.set_message(format!("0/{images} images"));
            bar
        });
        Self {
            bar,
            done: (0..images).map(|_| AtomicU64::new(0)).collect(),
            finished: AtomicUsize::new(0),
            failed: AtomicUsize::new(0),
            started: Instant::now(),
        }
    }

    fn set(&self, index: usize, steps: u64) {
        self.done[index].store(steps.min(STEPS), Ordering::Relaxed);
        if let Some(bar) = &self.bar {
            bar.set_position(self.done.iter().map(|d| d.load(Ordering::Relaxed)).sum());
        }
    }

    fn finished(&self, index: usize, ok: bool) {
        let finished = self.finished.fetch_add(1, Ordering::SeqCst) + 1;
        if !ok {
            self.failed.fetch_add(1, Ordering::SeqCst);
        }
        self.set(index, STEPS);
        if let Some(bar) = &self.bar {
            let failed = self.failed.load(Ordering::SeqCst);
            let failed = if failed > 0 {
                format!(", {failed} failed")
            } else {
                String::new()
            };
            bar.set_message(format!("{finished}/{} images{failed}", self.done.len()));
        }
    }

    fn finish(&self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
    }
}

/// One image's share of the batch bar.
struct ImageProgress<'a> {
    batch: &'a BatchProgress,
    index: usize,
}

impl Observer for ImageProgress<'_> {
    fn progress(&self, p: &Progress) {
        self.batch
            .set(self.index, (p.fraction() * STEPS as f32) as u64);
    }

    fn preview(&self, _name: &str, _image: &Image) {}

    fn wants_previews(&self) -> bool {
        false
    }
}
