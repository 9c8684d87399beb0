//! Weight-free perceptual measures beside MSE/PSNR/SSIM: GMSD (Xue, Zhang, Mou & Bovik 2014) and
//! MS-SSIM (Wang, Simoncelli & Bovik 2003). Both need no learned weights, unlike LPIPS. For
//! colour: CIELAB ([`lab`]) and the CIEDE2000 difference ([`ciede2000`]), checked against
//! Sharma, Wu & Dalal's published test pairs.
//!
//! Both compare grey levels on the 0-255 scale, as their authors' reference code does when it is
//! given `rgb2gray` of a colour image; [`Grey::luma`] uses Octave's `rgb2gray` weights. The
//! numbers match the authors' MATLAB code (`GMSD.m`, `msssim.m` + `ssim_index_new.m`) run in
//! GNU Octave to 1e-6 (`tests/pipeline/perceptual_reference.rs`).

use crate::render::Image;
use crate::simd::widest;
use rayon::prelude::*;

/// A grey image, values on the 0-255 scale, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct Grey {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// `width × height` values, row after row.
    pub data: Vec<f64>,
}

/// Octave's `rgb2gray` weights (ITU-R BT.601 luma), as the reference runs used.
const LUMA: [f64; 3] = [0.298936, 0.587043, 0.114021];

impl Grey {
    /// BT.601 luma of an RGB image in [0, 1], scaled to 0-255.
    pub fn luma(image: &Image) -> Self {
        let data = image
            .data
            .chunks_exact(3)
            .map(|px| 255.0 * (0..3).map(|c| LUMA[c] * f64::from(px[c])).sum::<f64>())
            .collect();
        Self {
            width: image.width,
            height: image.height,
            data,
        }
    }

    /// The value at (x, y), or 0 outside the image (MATLAB `conv2`'s zero padding).
    fn zero_padded(&self, x: isize, y: isize) -> f64 {
        if x < 0 || y < 0 || x as usize >= self.width || y as usize >= self.height {
            0.0
        } else {
            self.data[y as usize * self.width + x as usize]
        }
    }

    /// The value at (x, y) with coordinates past the far edges clamped (MATLAB `imfilter`'s
    /// 'symmetric' padding, for the one-pixel overhang a 2×2 filter needs).
    fn edge_clamped(&self, x: usize, y: usize) -> f64 {
        self.data[y.min(self.height - 1) * self.width + x.min(self.width - 1)]
    }

    /// Means of 2×2 blocks at even coordinates (ceil(w/2) × ceil(h/2) values); `value(x, y)`
    /// says what lies past the far edges.
    fn halve(&self, value: impl Fn(&Self, usize, usize) -> f64) -> Self {
        let (width, height) = (self.width.div_ceil(2), self.height.div_ceil(2));
        let mut data = Vec::with_capacity(width * height);
        for y in (0..self.height).step_by(2) {
            for x in (0..self.width).step_by(2) {
                let sum = value(self, x, y)
                    + value(self, x + 1, y)
                    + value(self, x, y + 1)
                    + value(self, x + 1, y + 1);
                data.push(sum / 4.0);
            }
        }
        Self {
            width,
            height,
            data,
        }
    }
}

/// GMSD's stability constant for 0-255 images (the authors' T).
const GMSD_T: f64 = 170.0;

/// Gradient magnitude similarity deviation of `distorted` against `reference`: 0 for equal
/// images, larger is worse (about 0.05-0.25 for good-to-poor vectorisations). As the authors'
/// `GMSD.m`: each luma image is averaged over 2×2 blocks and subsampled by 2, Prewitt gradients
/// (zero padding) give magnitudes m₁, m₂, the similarity map is (2·m₁·m₂ + T) / (m₁² + m₂² + T)
/// and the score its standard deviation (normalised by N − 1).
///
/// # Panics
/// If the two images differ in size.
pub fn gmsd(reference: &Image, distorted: &Image) -> f32 {
    assert_same_size(reference, distorted);
    let m1 = gradient_magnitude(&Grey::luma(reference));
    let m2 = gradient_magnitude(&Grey::luma(distorted));
    let similarity: Vec<f64> = m1
        .data
        .iter()
        .zip(&m2.data)
        .map(|(&a, &b)| (2.0 * a * b + GMSD_T) / (a * a + b * b + GMSD_T))
        .collect();
    let n = similarity.len() as f64;
    if n < 2.0 {
        return 0.0;
    }
    let mean = similarity.iter().sum::<f64>() / n;
    let variance = similarity.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    variance.sqrt() as f32
}

/// GMSD's gradient magnitude of a luma image, at half resolution (2×2 block means, subsampled
/// by 2; Prewitt operator with zero padding), as `GMSD.m` computes it.
pub fn gradient_magnitude(grey: &Grey) -> Grey {
    let half = grey.halve(|g, x, y| g.zero_padded(x as isize, y as isize));
    let mut data = Vec::with_capacity(half.data.len());
    for y in 0..half.height as isize {
        for x in 0..half.width as isize {
            let (mut gx, mut gy) = (0.0, 0.0);
            for d in -1..=1 {
                gx += half.zero_padded(x - 1, y + d) - half.zero_padded(x + 1, y + d);
                gy += half.zero_padded(x + d, y - 1) - half.zero_padded(x + d, y + 1);
            }
            data.push((gx * gx + gy * gy).sqrt() / 3.0);
        }
    }
    Grey { data, ..half }
}

/// GMSD's similarity map made a loss for the optimiser: 1 − its mean (the authors' GMSM), 0
/// when the gradient magnitudes agree everywhere. GMSD itself, the map's deviation, is no loss:
/// it falls when good pixels get worse. It runs once per render, so it is built for speed:
/// the target's magnitudes are kept, values are `f32` in buffers with a zero border (the
/// reference's zero padding without a branch), and bands of [`BAND_ROWS`] half-size rows run
/// as rayon tasks. Each band sums alone and the bands in order, so the result does not depend
/// on the thread count.
#[derive(Clone, Debug)]
pub struct GradientSimilarity {
    width: usize,
    height: usize,
    /// The target's magnitudes, [`Padded`] layout.
    reference: Vec<f32>,
}

/// Half-size rows per rayon task: a 256² image (128 half rows) makes 4 tasks; smaller bands
/// cost more in scheduling than they gain.
const BAND_ROWS: usize = 32;

impl GradientSimilarity {
    /// Computes the target's gradient magnitudes (half size, as [`gradient_magnitude`]).
    pub fn new(target: &Image) -> Self {
        let luma = Padded::half_luma(target);
        let mut reference = vec![0.0; luma.values.len()];
        luma.for_each_band(&mut reference, |y, row| {
            let mut gradient = Gradient::new(luma.width);
            luma.prewitt_row(y, &mut gradient);
            for ((out, &gx), &gy) in row.iter_mut().zip(&gradient.x).zip(&gradient.y) {
                *out = (gx * gx + gy * gy).sqrt();
            }
        });
        Self {
            width: target.width,
            height: target.height,
            reference,
        }
    }

    /// Adds `weight` × the loss's dLoss/dPred into `grad` and returns `weight` × the loss.
    ///
    /// # Panics
    /// If `pred` or `grad` is not the target's size.
    pub fn add_loss(&self, pred: &Image, weight: f32, grad: &mut Image) -> f32 {
        assert!(
            (pred.width, pred.height, grad.width, grad.height)
                == (self.width, self.height, self.width, self.height),
            "images differ in size from the target"
        );
        let luma = Padded::half_luma(pred);
        let n = (luma.width * luma.height).max(1) as f32;
        // dLoss/d(gx, gy), Padded layout.
        let mut d_gradient = [vec![0.0; luma.values.len()], vec![0.0; luma.values.len()]];
        let [d_x, d_y] = &mut d_gradient;
        let band_sums: Vec<f64> = luma
            .bands_mut(d_x)
            .zip(luma.bands_mut(d_y))
            .enumerate()
            .map(|(band, (rows_x, rows_y))| {
                let mut sum = 0.0f64;
                let mut row = SimilarityRow::new(luma.width);
                let rows = rows_x.chunks_exact_mut(luma.stride());
                for (r, (d_x, d_y)) in rows.zip(rows_y.chunks_exact_mut(luma.stride())).enumerate()
                {
                    let y = band * BAND_ROWS + r;
                    let reference = &self.reference[luma.index(0, y)..][..luma.width];
                    let d = (&mut d_x[1..=luma.width], &mut d_y[1..=luma.width]);
                    widest!(row.compute(&luma, y, reference, n, d));
                    for &term in &row.terms {
                        sum += f64::from(term);
                    }
                }
                sum
            })
            .collect();
        // The Prewitt operator's transpose is its negation; each half pixel is a 2×2 block.
        let scale: [f32; 3] = LUMA.map(|l| -weight * 255.0 / 4.0 * l as f32);
        let pair_scale = [scale[0], scale[1], scale[2], scale[0], scale[1], scale[2]];
        let width = self.width;
        grad.data
            .par_chunks_mut(3 * width * 2 * BAND_ROWS)
            .enumerate()
            .for_each(|(band, rows)| {
                let mut d_half = vec![0.0; luma.width];
                for (r, pair) in rows.chunks_mut(3 * width * 2).enumerate() {
                    let y = band * BAND_ROWS + r;
                    widest!(luma.prewitt_transpose_row(y, [d_x, d_y], &mut d_half));
                    for row in pair.chunks_mut(3 * width) {
                        widest!(for (px, &d) in row.chunks_mut(6).zip(&d_half) {
                            for (v, &scale) in px.iter_mut().zip(&pair_scale) {
                                *v += scale * d;
                            }
                        })
                    }
                }
            });
        weight * (band_sums.iter().sum::<f64>() / f64::from(n)) as f32
    }
}

/// Prewitt gradients (divided by 3) of one half-size row.
struct Gradient {
    x: Vec<f32>,
    y: Vec<f32>,
}

impl Gradient {
    fn new(width: usize) -> Self {
        Self {
            x: vec![0.0; width],
            y: vec![0.0; width],
        }
    }
}

/// One half-size row of the gradient-similarity loss, in buffers reused from row to row.
struct SimilarityRow {
    gradient: Gradient,
    /// Each pixel's `1 − GMS`, summed in order by the caller.
    terms: Vec<f32>,
}

impl SimilarityRow {
    fn new(width: usize) -> Self {
        Self {
            gradient: Gradient::new(width),
            terms: vec![0.0; width],
        }
    }

    /// Row `y`'s terms against the target's magnitudes `reference`, and dLoss/d(gx, gy) over
    /// `n` terms into `d` (zero where the magnitude is zero).
    #[inline(always)]
    fn compute(
        &mut self,
        luma: &Padded,
        y: usize,
        reference: &[f32],
        n: f32,
        (d_x, d_y): (&mut [f32], &mut [f32]),
    ) {
        let t = GMSD_T as f32;
        luma.prewitt_row(y, &mut self.gradient);
        let Gradient { x: gx, y: gy } = &self.gradient;
        let outs = self.terms.iter_mut().zip(d_x.iter_mut().zip(d_y));
        let ins = reference.iter().zip(gx.iter().zip(gy));
        for ((term, (d_x, d_y)), (&a, (&gx, &gy))) in outs.zip(ins) {
            let b = (gx * gx + gy * gy).sqrt();
            let (num, den) = (2.0 * a * b + t, a * a + b * b + t);
            *term = 1.0 - num / den;
            let d_b = (2.0 * b * num - 2.0 * a * den) / (den * den) / n;
            let moving = b > 0.0;
            *d_x = if moving { d_b * gx / b } else { 0.0 };
            *d_y = if moving { d_b * gy / b } else { 0.0 };
        }
    }
}

/// A half-size luma image (0-255, 2×2 block means with zero padding, as `GMSD.m` starts) in a
/// buffer with a one-value zero border, so the Prewitt operator needs no bounds checks.
struct Padded {
    width: usize,
    height: usize,
    values: Vec<f32>,
}

impl Padded {
    fn half_luma(image: &Image) -> Self {
        let (width, height) = (image.width.div_ceil(2), image.height.div_ceil(2));
        let mut out = Self {
            width,
            height,
            values: vec![0.0; (width + 2) * (height + 2)],
        };
        let weights: [f32; 3] = LUMA.map(|l| 255.0 / 4.0 * l as f32);
        let luma = |px: &[f32]| weights[0] * px[0] + weights[1] * px[1] + weights[2] * px[2];
        let row_of = |y: usize| {
            (y < image.height).then(|| &image.data[3 * y * image.width..3 * (y + 1) * image.width])
        };
        let mut values = std::mem::take(&mut out.values);
        out.for_each_band(&mut values, |y, row| {
            for source in [row_of(2 * y), row_of(2 * y + 1)].into_iter().flatten() {
                for (v, block) in row.iter_mut().zip(source.chunks(6)) {
                    *v += block.chunks_exact(3).map(luma).sum::<f32>();
                }
            }
        });
        out.values = values;
        out
    }

    fn stride(&self) -> usize {
        self.width + 2
    }

    fn index(&self, x: usize, y: usize) -> usize {
        (y + 1) * self.stride() + x + 1
    }

    /// The rows of `buffer` (this layout, border rows left out) in bands of [`BAND_ROWS`], for
    /// rayon.
    fn bands_mut<'a>(&self, buffer: &'a mut [f32]) -> rayon::slice::ChunksMut<'a, f32> {
        let stride = self.stride();
        buffer[stride..stride * (self.height + 1)].par_chunks_mut(stride * BAND_ROWS)
    }

    /// Runs `f(y, interior of row y)` over every row of `buffer` (this layout), in parallel
    /// bands of [`BAND_ROWS`].
    fn for_each_band(&self, buffer: &mut [f32], f: impl Fn(usize, &mut [f32]) + Sync) {
        let stride = self.stride();
        self.bands_mut(buffer).enumerate().for_each(|(band, rows)| {
            for (r, row) in rows.chunks_exact_mut(stride).enumerate() {
                f(band * BAND_ROWS + r, &mut row[1..=self.width]);
            }
        });
    }

    /// Row `y`'s rows above, at and below it, each from the column left of the first to the
    /// one right of the last (`width + 2` values).
    #[inline(always)]
    fn neighbourhood<'a>(&self, src: &'a [f32], y: usize) -> [&'a [f32]; 3] {
        let (s, w) = (self.stride(), self.width + 2);
        let start = self.index(0, y) - 1;
        [
            &src[start - s..][..w],
            &src[start..][..w],
            &src[start + s..][..w],
        ]
    }

    /// The Prewitt gradient (x, y) of row `y`, divided by 3.
    #[inline(always)]
    fn prewitt_row(&self, y: usize, out: &mut Gradient) {
        let [above, at, below] = self.neighbourhood(&self.values, y);
        let column = |k: usize| above[k] + at[k] + below[k];
        let across = |row: &[f32], k: usize| row[k] + row[k + 1] + row[k + 2];
        let width = self.width.min(out.x.len()).min(out.y.len());
        for x in 0..width {
            out.x[x] = (column(x) - column(x + 2)) / 3.0;
            out.y[x] = (across(above, x) - across(below, x)) / 3.0;
        }
    }

    /// The Prewitt operator's transpose (divided by 3) applied to dLoss/d(gx, gy) (this
    /// layout), for row `y` into `out`.
    #[inline(always)]
    fn prewitt_transpose_row(&self, y: usize, [d_x, d_y]: [&[f32]; 2], out: &mut [f32]) {
        let [x_above, x_at, x_below] = self.neighbourhood(d_x, y);
        let [y_above, _, y_below] = self.neighbourhood(d_y, y);
        let column = |k: usize| x_above[k] + x_at[k] + x_below[k];
        let across = |row: &[f32], k: usize| row[k] + row[k + 1] + row[k + 2];
        for (x, out) in out.iter_mut().enumerate().take(self.width) {
            *out = (column(x) - column(x + 2) + across(y_above, x) - across(y_below, x)) / 3.0;
        }
    }
}

/// MS-SSIM's per-scale exponents (Wang et al. 2003), finest scale first.
pub const MS_SSIM_WEIGHTS: [f64; 5] = [0.0448, 0.2856, 0.3001, 0.2363, 0.1333];
/// SSIM's window: 11 × 11 Gaussian, σ = 1.5.
const SSIM_RADIUS: usize = 5;
const SSIM_SIGMA: f64 = 1.5;

/// Multi-scale SSIM of `distorted` against `reference` on luma: 1 for equal images, lower is
/// worse. As the authors' `msssim.m` with its defaults: 5 scales, 11 × 11 Gaussian window
/// (σ 1.5) over the valid region, K = (0.01, 0.03), L = 255, 2×2 mean and subsampling between
/// scales, result Π cs_j^w_j (j < 5) · ssim_5^w_5. Departures, only where the reference gives no
/// number: an image whose short side is under 176 px gets as many scales as keep the window
/// inside (short side / 2^(scales−1) ≥ 11), with those scales' weights rescaled to sum to 1;
/// negative contrast-structure means count as 0 (a real power of a negative number does not
/// exist). `None` when the short side is under 11 px.
///
/// # Panics
/// If the two images differ in size.
pub fn ms_ssim(reference: &Image, distorted: &Image) -> Option<f32> {
    assert_same_size(reference, distorted);
    let window = 2 * SSIM_RADIUS + 1;
    let short = reference.width.min(reference.height);
    let scales = (1..=MS_SSIM_WEIGHTS.len())
        .rev()
        .find(|&s| short as f64 / f64::from(1u32 << (s - 1)) >= window as f64)?;
    let weights = &MS_SSIM_WEIGHTS[..scales];
    // The published weights sum to 1.0001; only a shortened set is rescaled.
    let total: f64 = if scales == MS_SSIM_WEIGHTS.len() {
        1.0
    } else {
        weights.iter().sum()
    };
    let kernel = gaussian_kernel(SSIM_RADIUS, SSIM_SIGMA);
    let (c1, c2) = ((0.01f64 * 255.0).powi(2), (0.03f64 * 255.0).powi(2));
    let (mut x, mut y) = (Grey::luma(reference), Grey::luma(distorted));
    let mut score = 1.0f64;
    for (scale, &weight) in weights.iter().enumerate() {
        let means = ssim_means(&x.data, &y.data, x.width, x.height, &kernel, c1, c2);
        let exponent = weight / total;
        if scale + 1 == scales {
            score *= means.ssim.max(0.0).powf(exponent);
        } else {
            score *= means.contrast_structure.max(0.0).powf(exponent);
            x = x.halve(|g, x, y| g.edge_clamped(x, y));
            y = y.halve(|g, x, y| g.edge_clamped(x, y));
        }
    }
    Some(score as f32)
}

/// A normalised 1-D Gaussian of `2·radius + 1` taps (its outer product is MATLAB's
/// `fspecial('gaussian', 2·radius + 1, sigma)`).
pub fn gaussian_kernel(radius: usize, sigma: f64) -> Vec<f64> {
    let taps: Vec<f64> = (0..=2 * radius)
        .map(|i| (-((i as f64 - radius as f64).powi(2)) / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum: f64 = taps.iter().sum();
    taps.iter().map(|t| t / sum).collect()
}

/// Means over the valid region of SSIM's map and of its contrast-structure factor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SsimMeans {
    /// Mean SSIM.
    pub ssim: f64,
    /// Mean of the contrast-structure factor (MS-SSIM's coarse-scale term).
    pub contrast_structure: f64,
}

/// SSIM (Wang et al. 2004) of two `w × h` single-channel images with the separable window
/// `kernel`, over the region where the window fits entirely ("valid"), with stabilisers `c1`,
/// `c2` for the images' value range.
pub fn ssim_means(
    x: &[f64],
    y: &[f64],
    w: usize,
    h: usize,
    kernel: &[f64],
    c1: f64,
    c2: f64,
) -> SsimMeans {
    let size = kernel.len();
    let (ow, oh) = (w + 1 - size, h + 1 - size);
    let blur = |src: &[f64]| -> Vec<f64> {
        let mut rows = vec![0.0; ow * h];
        for r in 0..h {
            for i in 0..ow {
                rows[r * ow + i] = (0..size).map(|k| kernel[k] * src[r * w + i + k]).sum();
            }
        }
        let mut out = vec![0.0; ow * oh];
        for r in 0..oh {
            for i in 0..ow {
                out[r * ow + i] = (0..size).map(|k| kernel[k] * rows[(r + k) * ow + i]).sum();
            }
        }
        out
    };
    let product =
        |a: &[f64], b: &[f64]| -> Vec<f64> { a.iter().zip(b).map(|(p, q)| p * q).collect() };
    let (mx, my) = (blur(x), blur(y));
    let (sxx, syy, sxy) = (
        blur(&product(x, x)),
        blur(&product(y, y)),
        blur(&product(x, y)),
    );
    let (mut ssim, mut cs) = (0.0, 0.0);
    for i in 0..mx.len() {
        let (vx, vy, cov) = (
            sxx[i] - mx[i] * mx[i],
            syy[i] - my[i] * my[i],
            sxy[i] - mx[i] * my[i],
        );
        let contrast_structure = (2.0 * cov + c2) / (vx + vy + c2);
        cs += contrast_structure;
        ssim +=
            contrast_structure * (2.0 * mx[i] * my[i] + c1) / (mx[i] * mx[i] + my[i] * my[i] + c1);
    }
    let n = mx.len().max(1) as f64;
    SsimMeans {
        ssim: ssim / n,
        contrast_structure: cs / n,
    }
}

/// CIE XYZ of the D65 white (2° observer), Y = 1: the sRGB white.
const D65_WHITE: [f64; 3] = [0.950_47, 1.0, 1.088_83];

/// CIELAB (D65 white) of an sRGB colour with channels in [0, 1]: L in [0, 100].
pub fn lab(rgb: [f32; 3]) -> [f64; 3] {
    let linear = rgb.map(|v| {
        let v = f64::from(v).clamp(0.0, 1.0);
        if v <= 0.040_45 {
            v / 12.92
        } else {
            ((v + 0.055) / 1.055).powf(2.4)
        }
    });
    let [r, g, b] = linear;
    let xyz = [
        0.412_456_4 * r + 0.357_576_1 * g + 0.180_437_5 * b,
        0.212_672_9 * r + 0.715_152_2 * g + 0.072_175_0 * b,
        0.019_333_9 * r + 0.119_192_0 * g + 0.950_304_1 * b,
    ];
    let f = |t: f64| {
        const DELTA: f64 = 6.0 / 29.0;
        if t > DELTA * DELTA * DELTA {
            t.cbrt()
        } else {
            t / (3.0 * DELTA * DELTA) + 4.0 / 29.0
        }
    };
    let [fx, fy, fz] = [0, 1, 2].map(|c| f(xyz[c] / D65_WHITE[c]));
    [116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)]
}

/// The sRGB colour of a CIELAB colour (D65 white), each channel clipped to [0, 1]: the inverse
/// of [`lab`] inside the sRGB gamut.
pub fn srgb_of_lab([l, a, b]: [f64; 3]) -> [f32; 3] {
    const DELTA: f64 = 6.0 / 29.0;
    let f_inverse = |t: f64| {
        if t > DELTA {
            t * t * t
        } else {
            3.0 * DELTA * DELTA * (t - 4.0 / 29.0)
        }
    };
    let fy = (l + 16.0) / 116.0;
    let f = [fy + a / 500.0, fy, fy - b / 200.0];
    let [x, y, z] = [0, 1, 2].map(|c| f_inverse(f[c]) * D65_WHITE[c]);
    let linear = [
        3.240_454_2 * x - 1.537_138_5 * y - 0.498_531_4 * z,
        -0.969_266_0 * x + 1.876_010_8 * y + 0.041_556_0 * z,
        0.055_643_4 * x - 0.204_025_9 * y + 1.057_225_2 * z,
    ];
    linear.map(|v| {
        let v = v.clamp(0.0, 1.0);
        let encoded = if v <= 0.003_130_8 {
            12.92 * v
        } else {
            1.055 * v.powf(1.0 / 2.4) - 0.055
        };
        encoded as f32
    })
}

/// The CIEDE2000 difference of two CIELAB colours (Sharma, Wu & Dalal 2005, with
/// kL = kC = kH = 1): about 1 is a just noticeable difference, 2.3 the JND often quoted.
pub fn ciede2000(one: [f64; 3], two: [f64; 3]) -> f64 {
    const POW25_7: f64 = 6_103_515_625.0; // 25^7
    let [l1, a1, b1] = one;
    let [l2, a2, b2] = two;
    let mean_c = 0.5 * (a1.hypot(b1) + a2.hypot(b2));
    let g = 0.5 * (1.0 - (mean_c.powi(7) / (mean_c.powi(7) + POW25_7)).sqrt());
    let (a1, a2) = ((1.0 + g) * a1, (1.0 + g) * a2);
    let (c1, c2) = (a1.hypot(b1), a2.hypot(b2));
    let hue = |a: f64, b: f64| {
        if a == 0.0 && b == 0.0 {
            0.0
        } else {
            b.atan2(a).to_degrees().rem_euclid(360.0)
        }
    };
    let (h1, h2) = (hue(a1, b1), hue(a2, b2));
    let chroma_product = c1 * c2;
    let dh = if chroma_product == 0.0 {
        0.0
    } else if (h2 - h1).abs() <= 180.0 {
        h2 - h1
    } else if h2 > h1 {
        h2 - h1 - 360.0
    } else {
        h2 - h1 + 360.0
    };
    let (dl, dc) = (l2 - l1, c2 - c1);
    let d_big_h = 2.0 * chroma_product.sqrt() * (0.5 * dh).to_radians().sin();
    let mean_l = 0.5 * (l1 + l2);
    let mean_c = 0.5 * (c1 + c2);
    let mean_h = if chroma_product == 0.0 {
        h1 + h2
    } else if (h1 - h2).abs() <= 180.0 {
        0.5 * (h1 + h2)
    } else if h1 + h2 < 360.0 {
        0.5 * (h1 + h2 + 360.0)
    } else {
        0.5 * (h1 + h2 - 360.0)
    };
    let cos = |degrees: f64| degrees.to_radians().cos();
    let t =
        1.0 - 0.17 * cos(mean_h - 30.0) + 0.24 * cos(2.0 * mean_h) + 0.32 * cos(3.0 * mean_h + 6.0)
            - 0.20 * cos(4.0 * mean_h - 63.0);
    let d_theta = 30.0 * (-((mean_h - 275.0) / 25.0).powi(2)).exp();
    let r_c = 2.0 * (mean_c.powi(7) / (mean_c.powi(7) + POW25_7)).sqrt();
    let l50 = (mean_l - 50.0).powi(2);
    let s_l = 1.0 + 0.015 * l50 / (20.0 + l50).sqrt();
    let s_c = 1.0 + 0.045 * mean_c;
    let s_h = 1.0 + 0.015 * mean_c * t;
    let r_t = -(2.0 * d_theta).to_radians().sin() * r_c;
    let (l, c, h) = (dl / s_l, dc / s_c, d_big_h / s_h);
    (l * l + c * c + h * h + r_t * c * h).max(0.0).sqrt()
}

fn assert_same_size(a: &Image, b: &Image) {
    assert!(
        (a.width, a.height) == (b.width, b.height),
        "images differ in size: {}×{} and {}×{}",
        a.width,
        a.height,
        b.width,
        b.height
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optim::rng::Rng;

    /// Pairs from Sharma, Wu & Dalal (2005), Table 1: the hue wrap-around, the neutral axis
    /// and the rotation term near blue.
    #[test]
    fn ciede2000_matches_the_published_test_pairs() {
        let pairs = [
            ([50.0, 2.6772, -79.7751], [50.0, 0.0, -82.7485], 2.0425),
            ([50.0, 3.1571, -77.2803], [50.0, 0.0, -82.7485], 2.8615),
            ([50.0, 0.0, 0.0], [50.0, -1.0, 2.0], 2.3669),
            ([50.0, 2.49, -0.001], [50.0, -2.49, 0.0009], 7.1792),
            ([50.0, 2.49, -0.001], [50.0, -2.49, 0.0011], 7.2195),
            ([50.0, 2.5, 0.0], [73.0, 25.0, -18.0], 27.1492),
            ([50.0, 2.5, 0.0], [50.0, 3.1736, 0.5854], 1.0000),
            (
                [60.2574, -34.0099, 36.2677],
                [60.4626, -34.1751, 39.4387],
                1.2644,
            ),
            (
                [22.7233, 20.0904, -46.694],
                [23.0331, 14.973, -42.5619],
                2.0373,
            ),
            (
                [90.8027, -2.0831, 1.441],
                [91.1528, -1.6435, 0.0447],
                1.4441,
            ),
            ([2.0776, 0.0795, -1.135], [0.9033, -0.0636, -0.5514], 0.9082),
        ];
        for (one, two, expected) in pairs {
            for (a, b) in [(one, two), (two, one)] {
                let got = ciede2000(a, b);
                assert!(
                    (got - expected).abs() < 5e-5,
                    "{a:?} {b:?}: {got}, not {expected}"
                );
            }
        }
    }

    #[test]
    fn lab_of_white_black_and_srgb_red() {
        let close = |a: [f64; 3], b: [f64; 3]| (0..3).all(|c| (a[c] - b[c]).abs() < 0.01);
        assert!(
            close(lab([1.0; 3]), [100.0, 0.0, 0.0]),
            "{:?}",
            lab([1.0; 3])
        );
        assert!(close(lab([0.0; 3]), [0.0, 0.0, 0.0]));
        // sRGB red, D65: L 53.24, a 80.09, b 67.20.
        let red = lab([1.0, 0.0, 0.0]);
        assert!(close(red, [53.24, 80.09, 67.20]), "{red:?}");
    }

    #[test]
    fn srgb_of_lab_undoes_lab() {
        for colour in [
            [0.0; 3],
            [1.0; 3],
            [0.9, 0.2, 0.1],
            [0.1, 0.5, 0.8],
            [0.02, 0.03, 0.01],
        ] {
            let back = srgb_of_lab(lab(colour));
            assert!(
                (0..3).all(|c| (back[c] - colour[c]).abs() < 1e-4),
                "{colour:?} -> {back:?}"
            );
        }
        // Outside the gamut each channel is clipped.
        assert_eq!(srgb_of_lab([50.0, 200.0, 0.0])[1], 0.0);
    }

    fn noisy(image: &Image, amount: f32, seed: u64) -> Image {
        let mut rng = Rng::new(seed, 7);
        let mut out = image.clone();
        out.data
            .iter_mut()
            .for_each(|v| *v = (*v + rng.range(-amount, amount)).clamp(0.0, 1.0));
        out
    }

    #[test]
    fn equal_images_score_perfectly_and_noise_scores_worse() {
        let image = crate::synth::generate(64, 64, 3).image;
        assert_eq!(gmsd(&image, &image), 0.0);
        assert!((ms_ssim(&image, &image).unwrap() - 1.0).abs() < 1e-9);
        let (light, heavy) = (noisy(&image, 0.05, 1), noisy(&image, 0.3, 1));
        let (g1, g2) = (gmsd(&image, &light), gmsd(&image, &heavy));
        assert!(0.0 < g1 && g1 < g2, "{g1} {g2}");
        let (s1, s2) = (
            ms_ssim(&image, &light).unwrap(),
            ms_ssim(&image, &heavy).unwrap(),
        );
        assert!(1.0 > s1 && s1 > s2 && s2 > 0.0, "{s1} {s2}");
    }

    /// A lost edge is a large gradient difference; as in the reference, the zero padding makes
    /// the image border an edge too, so two flat images of different levels differ only there.
    #[test]
    fn gmsd_sees_a_lost_edge_more_than_a_flat_offset() {
        let a = Image::filled(32, 32, [0.2; 3]);
        let mut edge = a.clone();
        for y in 0..32 {
            for x in 16..32 {
                edge.data[3 * (y * 32 + x)..3 * (y * 32 + x) + 3].copy_from_slice(&[0.9; 3]);
            }
        }
        let offset = gmsd(&a, &Image::filled(32, 32, [0.25; 3]));
        assert!(gmsd(&edge, &a) > 0.1 && gmsd(&edge, &a) > 2.0 * offset);
    }

    /// The loss is 1 − the mean of the map [`gmsd`] takes the deviation of, and its gradient
    /// matches finite differences: odd width (a padded block), 65 half rows (three bands, the
    /// last short).
    #[test]
    fn gradient_similarity_is_the_gmsd_map_mean_with_its_gradient() {
        let (w, h) = (67, 130);
        let target = crate::synth::generate(w, h, 4).image;
        let pred = noisy(&target, 0.2, 3);
        let similarity = GradientSimilarity::new(&target);
        let loss = |p: &Image| {
            let mut grad = Image::filled(w, h, [0.0; 3]);
            let value = similarity.add_loss(p, 2.0, &mut grad);
            (f64::from(value), grad)
        };
        let (m1, m2) = (
            gradient_magnitude(&Grey::luma(&target)),
            gradient_magnitude(&Grey::luma(&pred)),
        );
        let map_mean = m1
            .data
            .iter()
            .zip(&m2.data)
            .map(|(&a, &b)| (2.0 * a * b + GMSD_T) / (a * a + b * b + GMSD_T))
            .sum::<f64>()
            / m1.data.len() as f64;
        let (value, grad) = loss(&pred);
        assert!(
            (value - 2.0 * (1.0 - map_mean)).abs() < 1e-5,
            "{value} {map_mean}"
        );
        assert!(loss(&target).0.abs() < 1e-6);
        let h = 1e-2;
        for i in (0..pred.data.len()).step_by(37) {
            let at = |v: f32| {
                let mut p = pred.clone();
                p.data[i] = v;
                loss(&p).0
            };
            let v = pred.data[i];
            let fd = (at(v + h) - at(v - h)) / (2.0 * f64::from(h));
            let analytic = f64::from(grad.data[i]);
            assert!(
                (fd - analytic).abs() < 1e-6 + 0.05 * analytic.abs(),
                "value {i}: fd {fd} vs analytic {analytic}"
            );
        }
    }

    #[test]
    fn small_images_use_fewer_scales_and_tiny_ones_none() {
        // 64 px: 64/4 = 16 ≥ 11 but 64/8 = 8 < 11, so 3 scales.
        let image = crate::synth::generate(64, 48, 1).image;
        let score = ms_ssim(&image, &noisy(&image, 0.1, 2)).unwrap();
        assert!(score.is_finite() && score < 1.0);
        let tiny = Image::filled(10, 40, [0.5; 3]);
        assert_eq!(ms_ssim(&tiny, &tiny), None);
    }

    #[test]
    fn halving_averages_blocks_with_the_reference_padding() {
        let g = Grey {
            width: 3,
            height: 1,
            data: vec![4.0, 8.0, 12.0],
        };
        // Zero padding (conv2 'same'): (4+8+0+0)/4, (12+0+0+0)/4.
        assert_eq!(
            g.halve(|g, x, y| g.zero_padded(x as isize, y as isize))
                .data,
            vec![3.0, 3.0]
        );
        // Edge clamping (imfilter 'symmetric'): (4+8+4+8)/4, (12·4)/4.
        assert_eq!(
            g.halve(|g, x, y| g.edge_clamped(x, y)).data,
            vec![6.0, 12.0]
        );
    }
}
