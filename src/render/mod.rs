//! covec's differentiable rasteriser: exact area coverage, exact gradients, deterministic.
//!
//! Contract (other modules code against exactly this):
//! - [`Image`]: f32 RGB, row-major, interleaved (`data[3 * (y * width + x) + c]`).
//! - [`Rasterizer::render`] paints `paths` back to front with "over" onto a `base` colour
//!   ([`Rasterizer::render_over`]: onto a [`Backdrop`] colour or image);
//!   each path's alpha at a pixel is its exact area coverage × opacity. Non-zero fill.
//! - [`Rasterizer::backward`] takes dLoss/dPixel for that same render and **adds** dLoss/d(points,
//!   colour, opacity) into `grads` (one [`PathGrad`] per path, same shapes as the paths).
//! - [`Rasterizer::backward_of`] is the same backward for a [`PixelGrad`]: the fill colours'
//!   share may come from a second dLoss/dPixel (for a loss whose terms weigh on the colours
//!   otherwise than on geometry and opacity), and both may be multiplied by a factor image
//!   (for a render that is one factor of a product, such as a layer under `multiply`).
//! - Colours are not clamped here (illumination colours may exceed 1); opacities must be in [0, 1].
//! - Results are bit-identical whatever the rayon thread count.
//! - [`Rasterizer::render_over_strips`] renders chosen strips of [`STRIP_ROWS`] rows only, each
//!   exactly as a whole render does; [`Rasterizer::mark_strips`] marks the strips paths can
//!   paint (elsewhere a render is the backdrop), so a caller moving a few paths over a fixed
//!   backdrop renders their rows alone.
//!
//! # How
//! Each cubic is flattened at uniform parameters `t_k = k/n`, `n` chosen from the control polygon
//! so the polyline stays within [`FLATTEN_TOLERANCE`]
//! (0.1 px) of the curve, and at least [`MIN_LINES_PER_CUBIC`] (16) so that the gradients of
//! nearly straight cubics' handles stay accurate. The polyline is scan-converted by signed-area accumulation (as font
//! rasterisers do): the prefix sum of per-cell deltas along a row is the winding-weighted area
//! of the outline inside each pixel, `acc`, and the coverage is `min(1, |acc|)`. That is the
//! exact box-filtered area for outlines that do not overlap themselves inside a pixel; inside
//! doubly wound regions it is exactly 1 (non-zero rule), and only a pixel that contains an edge
//! of a doubly wound region (or of oppositely wound parts) is approximated, as in every
//! accumulation rasteriser. The backward is the exact derivative of this forward: it runs the
//! composite backwards per pixel and pushes dL/d`acc` through the flattened edges with the
//! boundary-integral adjoint (see `raster`), then through the fixed Bernstein weights to the
//! control points.
//!
//! The canvas is processed in strips of [`STRIP_ROWS`] rows with rayon (the caller's current
//! pool); every strip produces its own partial gradients, reduced in strip order, so results do
//! not depend on the thread count. Flattening, and the reduction with the chain to the control
//! points, go path by path on the pool, each path's arithmetic as on one thread. Per-thread
//! buffers live in the [`Rasterizer`] and are reused, so after the first call neither pass
//! allocates. The rasteriser keeps the last few geometries
//! flattened, and the signed areas of the last geometry a forward stored them for, so the
//! backward that follows a render of the same geometry reads them instead of scan-converting
//! again. Work per path is
//! proportional to the rows of its bounding box times the width of its edges' span in each row,
//! never W×H×paths.
//!
//! For finite-difference checks, [`Rasterizer::render_f64`] evaluates the same forward in f64,
//! and [`Flattening::Fixed`] pins the number of lines per cubic.

mod backward;
pub mod composite;
mod flatten;
mod raster;
mod real;

use std::sync::Mutex;

use rayon::prelude::*;

use crate::geom::bezier::FLATTEN_TOLERANCE;
use crate::scene::{Path, Point};
use crate::simd::widest;
use flatten::FlatScene;
use raster::RowSpan;
use real::Real;

/// Rows per strip: the unit of parallel work and of the backward's per-pixel bookkeeping.
pub const STRIP_ROWS: usize = 16;

/// An f32 RGB image, row-major, channels interleaved.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Image {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// `3 · width · height` values: `data[3 * (y * width + x) + c]`.
    pub data: Vec<f32>,
}

impl Image {
    /// A `width × height` image filled with `color`.
    pub fn filled(width: usize, height: usize, color: [f32; 3]) -> Self {
        let mut data = Vec::with_capacity(width * height * 3);
        for _ in 0..width * height {
            data.extend_from_slice(&color);
        }
        Self {
            width,
            height,
            data,
        }
    }

    /// The RGB value at `(x, y)`.
    ///
    /// # Panics
    /// If `(x, y)` is outside the image.
    pub fn pixel(&self, x: usize, y: usize) -> [f32; 3] {
        let i = 3 * (y * self.width + x);
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }

    /// Resizes to `width × height` (keeping the allocation when it is large enough).
    pub fn resize(&mut self, width: usize, height: usize) {
        self.width = width;
        self.height = height;
        self.data.resize(width * height * 3, 0.0);
    }

    /// Whether `data` holds exactly `width × height` pixels.
    fn is_whole(&self) -> bool {
        self.data.len() == self.width * self.height * 3
    }
}

/// What the paths are painted over: a flat colour or a whole image (same size as the render).
#[derive(Clone, Copy, Debug)]
pub enum Backdrop<'a> {
    /// Every pixel starts as this colour.
    Color([f32; 3]),
    /// Every pixel starts as this image's pixel: "over" onto a cached render of frozen paths in
    /// one pass (no gradient flows into the image).
    Image(&'a Image),
}

impl Backdrop<'_> {
    /// Writes the backdrop of the `planes[0].len() / width` rows from `row0` into channel
    /// planes (R…, G…, B…).
    fn fill_planes<T: Real>(&self, row0: usize, width: usize, planes: [&mut [T]; 3]) {
        match self {
            Backdrop::Color(color) => {
                for (plane, &v) in planes.into_iter().zip(color) {
                    plane.fill(T::from_f32(v));
                }
            }
            Backdrop::Image(image) => {
                let [r, g, b] = planes;
                let start = 3 * row0 * width;
                let src = &image.data[start..start + 3 * r.len()];
                for (k, px) in src.chunks_exact(3).enumerate() {
                    (r[k], g[k], b[k]) =
                        (T::from_f32(px[0]), T::from_f32(px[1]), T::from_f32(px[2]));
                }
            }
        }
    }

    /// Panics unless an image backdrop is `width × height`.
    fn check_size(&self, width: usize, height: usize) {
        if let Backdrop::Image(image) = self {
            assert!(
                image.width == width && image.height == height && image.is_whole(),
                "the backdrop must be the render's size"
            );
        }
    }
}

/// dLoss/d(parameters) of one path; `points` matches `Path::points` one to one.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PathGrad {
    /// dLoss/d(control point), one per point.
    pub points: Vec<Point>,
    /// dLoss/d(fill colour).
    pub color: [f32; 3],
    /// dLoss/d(opacity).
    pub opacity: f32,
}

impl PathGrad {
    /// Zero gradients shaped like `paths`.
    pub fn zeros_like(paths: &[Path]) -> Vec<PathGrad> {
        paths
            .iter()
            .map(|p| PathGrad {
                points: vec![Point::default(); p.points.len()],
                color: [0.0; 3],
                opacity: 0.0,
            })
            .collect()
    }
}

/// Fewest lines a cubic is flattened into under [`Flattening::Tolerance`].
///
/// The tolerance alone makes the *image* accurate but not the *gradients*: a nearly straight
/// cubic would become one or two lines, and then its handles would get no gradient at all,
/// although moving them does bend the curve. The flattened vertices carry the Bernstein weights
/// at `t_k = k/n`, so the chained gradient is the true curve gradient up to piecewise-linear
/// interpolation of those weights, an error of order `1/n²`; with 16 lines it is about 1%
/// (measured on the DiffVG fixture: a straight-ish segment's anchor gradient is 0.65× the true
/// value with the tolerance's 2 lines, within 1% of the 64-line value with 16).
pub const MIN_LINES_PER_CUBIC: u32 = 16;

/// How cubics are turned into lines.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Flattening {
    /// As many lines per cubic as needed to stay within this distance (pixels) of the curve,
    /// and at least [`MIN_LINES_PER_CUBIC`].
    Tolerance(f32),
    /// Exactly this many lines per cubic (useful to keep the flattening fixed while
    /// finite-differencing the forward pass).
    Fixed(u32),
}

impl Default for Flattening {
    /// `Tolerance(FLATTEN_TOLERANCE)` = 0.1 px.
    fn default() -> Self {
        Flattening::Tolerance(FLATTEN_TOLERANCE)
    }
}

/// Why a path cannot be drawn. The rasteriser skips such paths (they paint nothing and get
/// zero gradients); callers that take paths from outside should [`check_path`] them first.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum PathError {
    /// Not a positive multiple of 3 points.
    #[error("a path needs 3 points per cubic segment and at least one segment, got {0} points")]
    PointCount(usize),
    /// A point with an infinite or NaN coordinate.
    #[error("path point {0} is not finite")]
    NonFinitePoint(usize),
    /// An infinite or NaN colour or opacity.
    #[error("path colour or opacity is not finite")]
    NonFinitePaint,
}

/// Checks that `path` is drawable: a positive multiple of 3 points, all finite, finite paint.
pub fn check_path(path: &Path) -> Result<(), PathError> {
    if path.points.is_empty() || !path.points.len().is_multiple_of(3) {
        return Err(PathError::PointCount(path.points.len()));
    }
    if let Some(i) = path
        .points
        .iter()
        .position(|p| !(p.x.is_finite() && p.y.is_finite()))
    {
        return Err(PathError::NonFinitePoint(i));
    }
    if !(path.color.iter().all(|c| c.is_finite()) && path.opacity.is_finite()) {
        return Err(PathError::NonFinitePaint);
    }
    Ok(())
}

/// Per-thread working memory, reused across strips and calls.
#[derive(Default)]
struct Scratch {
    coverage: StripCoverage<f32>,
    backward: backward::Workspace,
}

/// dLoss/dPixel of one render, as [`Rasterizer::backward_of`] reads it.
#[derive(Clone, Copy, Debug)]
pub struct PixelGrad<'a> {
    /// For the points and opacities, and for the colours without `colour`.
    pub d: &'a Image,
    /// For the fill colours, when they take a gradient of their own.
    pub colour: Option<&'a Image>,
    /// What `d` and `colour` are multiplied by, value by value, when given: the render is
    /// one factor of a product, whose gradient then needs no image of its own.
    pub factor: Option<&'a Image>,
}

impl<'a> PixelGrad<'a> {
    /// `d` for everything.
    pub fn of(d: &'a Image) -> Self {
        Self {
            d,
            colour: None,
            factor: None,
        }
    }
}

/// Geometries a rasteriser keeps flattened. An optimisation step renders and then
/// differentiates the same geometry (the polish three layers, the reconstruction two, in turn),
/// and the structure loss draws one geometry in two paints, so an unchanged geometry is not
/// flattened again.
const FLAT_CACHE: usize = 3;

/// One flattened geometry and what it was built from: every path's points (and whether it was
/// drawable), in order, and a number no other flattening of this rasteriser had.
#[derive(Default)]
struct CachedFlat {
    flat: FlatScene<f32>,
    source: Vec<Point>,
    shape: Vec<(usize, bool)>,
    id: u64,
}

/// Most signed-area values a rasteriser keeps (64 MiB); a scene whose paths' bounding boxes
/// hold more is scan-converted again in the backward.
const STORED_AREA_LIMIT: f64 = 16.0 * 1024.0 * 1024.0;

/// The signed areas a forward computed for one geometry, kept for its backward: every
/// optimisation step renders a geometry and then differentiates it, and the signed areas depend
/// on the geometry alone, so the backward need not scan-convert every path again. One set per
/// rasteriser, not one per cached geometry: every loop differentiates the geometry it rendered
/// last, and a set per geometry held up to [`FLAT_CACHE`] times the memory, most of it for
/// geometries an optimisation step had already left.
#[derive(Default)]
struct StoredAreas {
    /// The [`CachedFlat::id`] and canvas size they were computed for; `None` until a forward
    /// stores them.
    owner: Option<(u64, usize, usize)>,
    strips: Vec<StripAreas<f32>>,
}

/// One strip's signed areas: for each drawable path meeting the strip (in paint order), one
/// row span per row of the strip and the offset in `area` of its values, kept for the span's
/// whole groups ([`RowSpan::groups`]: zeros where the groups overhang the span).
#[derive(Default)]
pub(crate) struct StripAreas<T> {
    pub paths: Vec<u32>,
    pub spans: Vec<RowSpan>,
    pub offsets: Vec<u32>,
    pub area: Vec<T>,
}

impl<T> StripAreas<T> {
    fn clear(&mut self) {
        self.paths.clear();
        self.spans.clear();
        self.offsets.clear();
        self.area.clear();
    }
}

impl CachedFlat {
    /// Whether this is the flattening of exactly `paths`' geometry.
    fn holds(&self, paths: &[Path]) -> bool {
        self.shape.len() == paths.len()
            && paths
                .iter()
                .zip(&self.shape)
                .all(|(p, &(n, ok))| p.points.len() == n && check_path(p).is_ok() == ok)
            && paths.iter().flat_map(|p| &p.points).eq(self.source.iter())
    }

    fn fill(&mut self, paths: &[Path], flattening: Flattening, id: u64) {
        self.flat.build(paths, flattening);
        self.id = id;
        self.source.clear();
        self.source
            .extend(paths.iter().flat_map(|p| p.points.iter().copied()));
        self.shape.clear();
        self.shape.extend(
            paths
                .iter()
                .map(|p| (p.points.len(), check_path(p).is_ok())),
        );
    }
}

/// Reusable rasteriser: keeps its buffers between calls so optimisation loops don't allocate.
#[derive(Default)]
pub struct Rasterizer {
    flattening: Flattening,
    /// The last [`FLAT_CACHE`] geometries flattened, the current one first.
    flats: Vec<CachedFlat>,
    /// How many flattenings this rasteriser has made: the next one's [`CachedFlat::id`].
    flattened: u64,
    areas: StoredAreas,
    pool: Mutex<Vec<Scratch>>,
    bands: Vec<backward::BandGrads>,
}

impl Rasterizer {
    /// A rasteriser flattening cubics to [`FLATTEN_TOLERANCE`] (the default).
    pub fn new() -> Self {
        Self::default()
    }

    /// A rasteriser that flattens cubics as `flattening` says.
    pub fn with_flattening(flattening: Flattening) -> Self {
        Self {
            flattening,
            ..Self::default()
        }
    }

    /// How this rasteriser flattens cubics.
    pub fn flattening(&self) -> Flattening {
        self.flattening
    }

    /// Renders `paths` over `base` into `out`, which is resized to `width × height`.
    pub fn render(
        &mut self,
        paths: &[Path],
        base: [f32; 3],
        width: usize,
        height: usize,
        out: &mut Image,
    ) {
        self.render_over(paths, Backdrop::Color(base), width, height, out);
    }

    /// Renders `paths` over `backdrop` into `out`, which is resized to `width × height`.
    ///
    /// # Panics
    /// If an image backdrop is not `width × height`.
    pub fn render_over(
        &mut self,
        paths: &[Path],
        backdrop: Backdrop,
        width: usize,
        height: usize,
        out: &mut Image,
    ) {
        backdrop.check_size(width, height);
        out.resize(width, height);
        self.render_strips(paths, backdrop, out, None);
    }

    /// [`render_over`](Self::render_over) of the strips ([`STRIP_ROWS`] rows each, from the
    /// top) that `strips[s]` selects: their pixels become exactly what a whole render writes
    /// there, and the other strips of `out` are left as they are. A caller that knows those
    /// (they hold the backdrop where [`mark_strips`](Self::mark_strips) marks no path, or a
    /// render of the same paths) pays for the selected rows only.
    ///
    /// # Panics
    /// If `out` or an image backdrop is not `width × height`, or `strips` has fewer entries
    /// than the canvas has strips.
    pub fn render_over_strips(
        &mut self,
        paths: &[Path],
        backdrop: Backdrop,
        strips: &[bool],
        out: &mut Image,
    ) {
        let (width, height) = (out.width, out.height);
        backdrop.check_size(width, height);
        assert!(out.is_whole(), "out must be width × height × 3");
        assert!(
            strips.len() >= height.div_ceil(STRIP_ROWS),
            "one entry per strip"
        );
        self.render_strips(paths, backdrop, out, Some(strips));
    }

    /// Marks in `marks` (resized to the strip count, marks already set kept) every strip a
    /// drawable path of `paths` can paint on a `width × height` canvas; the others a render
    /// leaves exactly as the backdrop.
    pub fn mark_strips(
        &mut self,
        paths: &[Path],
        width: usize,
        height: usize,
        marks: &mut Vec<bool>,
    ) {
        marks.resize(height.div_ceil(STRIP_ROWS), false);
        self.build(paths);
        mark_met_strips(&self.flats[0].flat, width, height, marks);
    }

    /// The forward into `out` (already `width × height`), of every strip or of the selected.
    fn render_strips(
        &mut self,
        paths: &[Path],
        backdrop: Backdrop,
        out: &mut Image,
        strips: Option<&[bool]>,
    ) {
        let (width, height) = (out.width, out.height);
        if width == 0 || height == 0 {
            return;
        }
        self.build(paths);
        let CachedFlat { flat, id, .. } = &self.flats[0];
        let (areas, owner) = (&mut self.areas, Some((*id, width, height)));
        let strip_count = height.div_ceil(STRIP_ROWS);
        // A selection stores the signed areas only when it holds every strip a path meets
        // (the others store none), so that the backward can read them for every band.
        let complete = strips.is_none_or(|selected| {
            (0..strip_count).all(|s| selected[s] || !strip_met(flat, s, width, height))
        });
        let store = complete
            && areas.owner != owner
            && backward::covered_area(flat, width, height) <= STORED_AREA_LIMIT;
        if store && areas.strips.len() < strip_count {
            areas.strips.resize_with(strip_count, Default::default);
        }
        let selected = |s: usize| strips.is_none_or(|selected| selected[s]);
        let pool = &self.pool;
        let strip = |s: usize, pixels: &mut [f32], store: Option<&mut StripAreas<f32>>| {
            let mut scratch = take(pool);
            let job = StripJob {
                flat,
                paths,
                backdrop,
                width,
                height,
                strip: s,
            };
            job.render(pixels, &mut scratch.coverage, store);
            give(pool, scratch);
        };
        let chunks = out.data.par_chunks_mut(STRIP_ROWS * width * 3);
        if store {
            chunks
                .zip(areas.strips[..strip_count].par_iter_mut())
                .enumerate()
                .for_each(|(s, (pixels, stored))| {
                    if selected(s) {
                        strip(s, pixels, Some(stored));
                    } else {
                        stored.clear();
                    }
                });
            areas.owner = owner;
        } else {
            chunks
                .enumerate()
                .filter(|(s, _)| selected(*s))
                .for_each(|(s, pixels)| strip(s, pixels, None));
        }
    }

    /// The same forward as [`render`](Self::render) evaluated entirely in f64 (flattening,
    /// coverage and compositing): the reference for finite-difference checks of the gradients,
    /// where f32 rounding of the forward would swamp small steps. Returns the
    /// interleaved RGB values. Slower and allocating; not for the optimisation loop.
    pub fn render_f64(
        &self,
        paths: &[Path],
        base: [f32; 3],
        width: usize,
        height: usize,
    ) -> Vec<f64> {
        let mut out = vec![0.0f64; width * height * 3];
        if width == 0 || height == 0 {
            return out;
        }
        let mut flat = FlatScene::<f64>::default();
        flat.build(paths, self.flattening);
        out.par_chunks_mut(STRIP_ROWS * width * 3)
            .enumerate()
            .for_each_init(StripCoverage::<f64>::default, |coverage, (s, pixels)| {
                let job = StripJob {
                    flat: &flat,
                    paths,
                    backdrop: Backdrop::Color(base),
                    width,
                    height,
                    strip: s,
                };
                job.render(pixels, coverage, None);
            });
        out
    }

    /// Adds dLoss/dparams of the render of `paths` over `base` into `grads`, given
    /// `d_out` = dLoss/dPixel of that render (same size).
    ///
    /// # Panics
    /// If `d_out.data` does not hold `width × height × 3` values or `grads` has fewer entries
    /// than `paths` or an entry whose `points` is shorter than its path's.
    pub fn backward(
        &mut self,
        paths: &[Path],
        base: [f32; 3],
        d_out: &Image,
        grads: &mut [PathGrad],
    ) {
        self.backward_over(paths, Backdrop::Color(base), d_out, grads);
    }

    /// [`backward`](Self::backward) for `grad`: the points and opacities get `grad.d`'s
    /// gradient and the colours `grad.colour`'s (`grad.d`'s without one), in one pass, both
    /// times `grad.factor` when it is given.
    ///
    /// # Panics
    /// As [`backward`](Self::backward), and if `grad.colour` or `grad.factor` is not
    /// `grad.d`'s size.
    pub fn backward_of(
        &mut self,
        paths: &[Path],
        base: [f32; 3],
        grad: PixelGrad,
        grads: &mut [PathGrad],
    ) {
        let (width, height) = (grad.d.width, grad.d.height);
        for other in grad.colour.iter().chain(&grad.factor) {
            assert!(
                (other.width, other.height) == (width, height) && other.is_whole(),
                "a PixelGrad's images must be one size"
            );
        }
        self.backward_in(paths, Backdrop::Color(base), grad, grads);
    }

    /// [`backward`](Self::backward) of [`render_over`](Self::render_over) with `backdrop`.
    ///
    /// # Panics
    /// As [`backward`](Self::backward), and if an image backdrop is not `d_out`'s size.
    pub fn backward_over(
        &mut self,
        paths: &[Path],
        backdrop: Backdrop,
        d_out: &Image,
        grads: &mut [PathGrad],
    ) {
        self.backward_in(paths, backdrop, PixelGrad::of(d_out), grads);
    }

    /// The backward of `grad` (its images checked to be one size).
    fn backward_in(
        &mut self,
        paths: &[Path],
        backdrop: Backdrop,
        grad: PixelGrad,
        grads: &mut [PathGrad],
    ) {
        let d_out = grad.d;
        let (width, height) = (d_out.width, d_out.height);
        backdrop.check_size(width, height);
        assert!(d_out.is_whole(), "d_out must be width × height × 3");
        assert!(grads.len() >= paths.len(), "one PathGrad per path");
        if width == 0 || height == 0 {
            return;
        }
        self.build(paths);
        let band_count = height.div_ceil(STRIP_ROWS);
        if self.bands.len() < band_count {
            self.bands.resize_with(band_count, Default::default);
        }
        let CachedFlat { flat, id, .. } = &self.flats[0];
        let areas = &self.areas;
        let stored =
            (areas.owner == Some((*id, width, height))).then(|| &areas.strips[..band_count]);
        let rows_per_pass = backward::rows_per_pass(flat, width, height);
        let pool = &self.pool;
        self.bands[..band_count]
            .par_iter_mut()
            .enumerate()
            .for_each(|(band, grads)| {
                let mut scratch = take(pool);
                let job = backward::Band {
                    flat,
                    paths,
                    backdrop,
                    d_out,
                    d_colour: grad.colour,
                    factor: grad.factor,
                    band,
                    rows_per_pass,
                    stored: stored.map(|strips| &strips[band]),
                };
                job.run(grads, &mut scratch.backward, &mut scratch.coverage);
                give(pool, scratch);
            });
        // Then path by path: the bands' sums, chained to the control points.
        let bands = &self.bands[..band_count];
        grads[..paths.len()]
            .par_chunks_mut(backward::PATHS_PER_TASK)
            .enumerate()
            .for_each(|(chunk, grads)| {
                let mut scratch = take(pool);
                let first = chunk * backward::PATHS_PER_TASK;
                backward::add_bands_into(flat, bands, first, grads, &mut scratch.backward);
                give(pool, scratch);
            });
    }
}

impl Rasterizer {
    /// Makes `flats[0]` the flattening of `paths`: a cached one if it holds this geometry,
    /// else the least recently used slot refilled.
    fn build(&mut self, paths: &[Path]) {
        let k = match self.flats.iter().position(|c| c.holds(paths)) {
            Some(k) => k,
            None => {
                if self.flats.len() < FLAT_CACHE {
                    self.flats.push(CachedFlat::default());
                }
                let last = self.flats.len() - 1;
                self.flattened += 1;
                self.flats[last].fill(paths, self.flattening, self.flattened);
                last
            }
        };
        self.flats[..=k].rotate_right(1);
    }
}

fn take(pool: &Mutex<Vec<Scratch>>) -> Scratch {
    pool.lock()
        .map(|mut p| p.pop())
        .ok()
        .flatten()
        .unwrap_or_default()
}

fn give(pool: &Mutex<Vec<Scratch>>, scratch: Scratch) {
    if let Ok(mut p) = pool.lock() {
        p.push(scratch);
    }
}

/// Rows `row0..row0 + rows` of strip `s`.
fn strip_rows(s: usize, height: usize) -> (usize, usize) {
    let row0 = s * STRIP_ROWS;
    (row0, STRIP_ROWS.min(height - row0))
}

/// Whether the path's polyline can cover any pixel of the strip.
fn meets_strip(bbox: [f32; 4], row0: usize, rows: usize, width: usize) -> bool {
    bbox[3] > row0 as f32
        && bbox[1] < (row0 + rows) as f32
        && bbox[2] > 0.0
        && bbox[0] < width as f32
}

/// Whether a drawable path of `flat` meets strip `s` ([`meets_strip`]).
fn strip_met(flat: &FlatScene<f32>, s: usize, width: usize, height: usize) -> bool {
    let (row0, rows) = strip_rows(s, height);
    flat.paths
        .iter()
        .any(|fp| !fp.verts.is_empty() && meets_strip(fp.bbox, row0, rows, width))
}

/// Sets `marks[s]` for every strip `s` a drawable path of `flat` meets.
fn mark_met_strips(flat: &FlatScene<f32>, width: usize, height: usize, marks: &mut [bool]) {
    for (s, mark) in marks.iter_mut().enumerate() {
        *mark |= strip_met(flat, s, width, height);
    }
}

/// One path's signed-area deltas over a strip (row stride `width + 2`; its signed areas once
/// summed) and its row spans, and the strip's pixels as channel planes.
#[derive(Default)]
struct StripCoverage<T> {
    delta: Vec<T>,
    spans: Vec<RowSpan>,
    planes: Vec<T>,
}

impl<T: Real> StripCoverage<T> {
    /// Sizes the buffers for a canvas `width` wide; `delta` is all zero afterwards (every user
    /// clears what it touched).
    fn prepare(&mut self, width: usize) {
        let len = STRIP_ROWS * (width + 2);
        if self.delta.len() != len {
            self.delta.clear();
            self.delta.resize(len, T::ZERO);
        }
        self.spans.resize(STRIP_ROWS, RowSpan::EMPTY);
    }
}

/// One strip of a forward render.
struct StripJob<'a, T> {
    flat: &'a FlatScene<T>,
    paths: &'a [Path],
    backdrop: Backdrop<'a>,
    width: usize,
    height: usize,
    strip: usize,
}

impl<T: Real> StripJob<'_, T> {
    /// Paints the strip into `pixels`; with `store`, also keeps every drawable path's signed
    /// areas there (those of paths with zero opacity too: the backward needs them). Compiled
    /// for the widest vector unit the processor has ([`widest!`]).
    fn render(
        &self,
        pixels: &mut [T],
        scratch: &mut StripCoverage<T>,
        store: Option<&mut StripAreas<T>>,
    ) {
        widest!(self.render_in(pixels, scratch, store))
    }

    #[inline(always)]
    fn render_in(
        &self,
        pixels: &mut [T],
        scratch: &mut StripCoverage<T>,
        mut store: Option<&mut StripAreas<T>>,
    ) {
        let (flat, width) = (self.flat, self.width);
        let (row0, rows) = strip_rows(self.strip, self.height);
        scratch.prepare(width);
        if let Some(stored) = store.as_deref_mut() {
            stored.clear();
        }
        // The strip as channel planes (R…, G…, B…), so each path's rows composite as plain
        // vector loops; interleaved again at the end.
        let n = rows * width;
        scratch.planes.resize(3 * n, T::ZERO);
        let (pr, rest) = scratch.planes.split_at_mut(n);
        let (pg, pb) = rest.split_at_mut(n);
        self.backdrop
            .fill_planes(row0, width, [&mut *pr, &mut *pg, &mut *pb]);
        for (i, (path, fp)) in self.paths.iter().zip(&flat.paths).enumerate() {
            let paints = path.opacity > 0.0;
            if fp.verts.is_empty()
                || !(paints || store.is_some())
                || !meets_strip(fp.bbox, row0, rows, width)
            {
                continue;
            }
            let spans = &mut scratch.spans[..rows];
            raster::accumulate(
                flat.outline(i),
                row0 as i32,
                rows,
                width,
                &mut scratch.delta,
                spans,
            );
            raster::prefix_rows(&mut scratch.delta, spans, width);
            let stride = width + 2;
            if let Some(stored) = store.as_deref_mut() {
                stored.paths.push(i as u32);
                for (r, &span) in spans.iter().enumerate() {
                    stored.spans.push(span);
                    stored.offsets.push(stored.area.len() as u32);
                    if span.len() > 0 {
                        let row = &scratch.delta[r * stride..r * stride + width];
                        raster::push_groups(row, span, &mut stored.area);
                    }
                }
            }
            if paints {
                let (op, c) = (T::from_f32(path.opacity), path.color.map(T::from_f32));
                for (r, &span) in spans.iter().enumerate() {
                    let (lo, end) = (span.lo as usize, span.end as usize);
                    let (at, to) = (r * width + lo, r * width + end);
                    composite_run(
                        &scratch.delta[r * stride + lo..r * stride + end],
                        op,
                        c,
                        [&mut pr[at..to], &mut pg[at..to], &mut pb[at..to]],
                    );
                }
            }
            raster::clear_rows(&mut scratch.delta, spans, width);
        }
        for (k, px) in pixels.chunks_exact_mut(3).enumerate() {
            (px[0], px[1], px[2]) = (pr[k], pg[k], pb[k]);
        }
    }
}

/// "Over" of one path along a run of pixels (channel planes), alpha `min(1, |area|) · opacity`.
#[inline(always)]
fn composite_run<T: Real>(area: &[T], opacity: T, color: [T; 3], planes: [&mut [T]; 3]) {
    let n = area.len();
    let [r, g, b] = planes;
    let (r, g, b) = (&mut r[..n], &mut g[..n], &mut b[..n]);
    for x in 0..n {
        // `min(1, |area|)` as a select, which vectorises (and equals `min` for every input).
        let v = area[x].abs();
        let a = if v < T::ONE { v } else { T::ONE } * opacity;
        r[x] += a * (color[0] - r[x]);
        g[x] += a * (color[1] - g[x]);
        b[x] += a * (color[2] - b[x]);
    }
}
