//! `cargo bench --bench render`: covec's rasteriser against tiny-skia's anti-aliased fill and
//! against DiffVG's CPU figures (shared/notes/diffvg-bench.md), same scenes.
//!
//! Prints medians of `COVEC_BENCH_RUNS` runs (default 21) after one warm-up, on 1 and 2 rayon
//! threads. As in the DiffVG note, 1-thread figures are CPU time of the (single) worker thread,
//! which a busy shared machine barely disturbs, and 2-thread figures are wall time. tiny-skia is
//! single-threaded (CPU time). Each round times tiny-skia, our forward and our forward +
//! backward in turn, and every ratio printed is the median of the rounds' ratios: a shared
//! machine's speed drifts between rounds, far less within one.

use std::hint::black_box;
use std::time::Instant;

use covec::render::{Image, PathGrad, Rasterizer};
use covec::scene::{Path, Point};

/// SplitMix64, exactly as the DiffVG note specifies.
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn uniform(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.uniform()
    }
}

/// The bar scenes: `n` smooth random blobs of 4-8 cubics around centres anywhere on the canvas,
/// radius 5-30% of the size, colour uniform, opacity 0.3-1 (the scene of rendering.md §5.3).
fn blob_scene(size: usize, n: usize, seed: u64) -> Vec<Path> {
    let mut rng = SplitMix64(seed);
    let s = size as f32;
    (0..n)
        .map(|_| {
            let (cx, cy) = (rng.uniform() * s, rng.uniform() * s);
            let r = rng.range(0.05, 0.3) * s;
            let segs = 4 + (rng.next_u64() % 5) as usize;
            let anchors: Vec<(f32, f32)> = (0..segs)
                .map(|k| {
                    let a =
                        (k as f32 + rng.range(-0.25, 0.25)) / segs as f32 * std::f32::consts::TAU;
                    (a, r * rng.range(0.6, 1.2))
                })
                .collect();
            let handle = 4.0 / 3.0 * (std::f32::consts::PI / (2.0 * segs as f32)).tan();
            let mut points = Vec::with_capacity(3 * segs);
            for k in 0..segs {
                let (a0, r0) = anchors[k];
                let (a1, r1) = anchors[(k + 1) % segs];
                let p0 = Point::new(cx + r0 * a0.cos(), cy + r0 * a0.sin());
                let p1 = Point::new(cx + r1 * a1.cos(), cy + r1 * a1.sin());
                points.push(p0);
                points.push(Point::new(
                    p0.x - a0.sin() * r0 * handle,
                    p0.y + a0.cos() * r0 * handle,
                ));
                points.push(Point::new(
                    p1.x + a1.sin() * r1 * handle,
                    p1.y - a1.cos() * r1 * handle,
                ));
            }
            let color = [rng.uniform(), rng.uniform(), rng.uniform()];
            Path {
                points,
                color,
                opacity: rng.range(0.3, 1.0),
            }
        })
        .collect()
}

/// DiffVG's benchmark scene (diffvg-bench.md): 12 uniform points per path, colour, opacity 0.7.
fn diffvg_scene(size: usize, n: usize) -> Vec<Path> {
    let mut rng = SplitMix64(1234);
    let s = size as f32;
    (0..n)
        .map(|_| {
            let points = (0..12)
                .map(|_| {
                    let x = rng.uniform() * s;
                    Point::new(x, rng.uniform() * s)
                })
                .collect();
            Path {
                points,
                color: [rng.uniform(), rng.uniform(), rng.uniform()],
                opacity: 0.7,
            }
        })
        .collect()
}

/// SHA-256 (FIPS 180-4), for the scene check hash of the DiffVG note.
fn sha256(data: &[u8]) -> String {
    const K: [u32; 64] = [
        0x428a2f98, 0x71374491, 0xb5c0fbcf, 0xe9b5dba5, 0x3956c25b, 0x59f111f1, 0x923f82a4,
        0xab1c5ed5, 0xd807aa98, 0x12835b01, 0x243185be, 0x550c7dc3, 0x72be5d74, 0x80deb1fe,
        0x9bdc06a7, 0xc19bf174, 0xe49b69c1, 0xefbe4786, 0x0fc19dc6, 0x240ca1cc, 0x2de92c6f,
        0x4a7484aa, 0x5cb0a9dc, 0x76f988da, 0x983e5152, 0xa831c66d, 0xb00327c8, 0xbf597fc7,
        0xc6e00bf3, 0xd5a79147, 0x06ca6351, 0x14292967, 0x27b70a85, 0x2e1b2138, 0x4d2c6dfc,
        0x53380d13, 0x650a7354, 0x766a0abb, 0x81c2c92e, 0x92722c85, 0xa2bfe8a1, 0xa81a664b,
        0xc24b8b70, 0xc76c51a3, 0xd192e819, 0xd6990624, 0xf40e3585, 0x106aa070, 0x19a4c116,
        0x1e376c08, 0x2748774c, 0x34b0bcb5, 0x391c0cb3, 0x4ed8aa4a, 0x5b9cca4f, 0x682e6ff3,
        0x748f82ee, 0x78a5636f, 0x84c87814, 0x8cc70208, 0x90befffa, 0xa4506ceb, 0xbef9a3f7,
        0xc67178f2,
    ];
    let mut h: [u32; 8] = [
        0x6a09e667, 0xbb67ae85, 0x3c6ef372, 0xa54ff53a, 0x510e527f, 0x9b05688c, 0x1f83d9ab,
        0x5be0cd19,
    ];
    let mut msg = data.to_vec();
    msg.push(0x80);
    while msg.len() % 64 != 56 {
        msg.push(0);
    }
    msg.extend_from_slice(&((data.len() as u64) * 8).to_be_bytes());
    for block in msg.chunks_exact(64) {
        let mut w = [0u32; 64];
        for i in 0..16 {
            w[i] = u32::from_be_bytes(block[4 * i..4 * i + 4].try_into().unwrap());
        }
        for i in 16..64 {
            let s0 = w[i - 15].rotate_right(7) ^ w[i - 15].rotate_right(18) ^ (w[i - 15] >> 3);
            let s1 = w[i - 2].rotate_right(17) ^ w[i - 2].rotate_right(19) ^ (w[i - 2] >> 10);
            w[i] = w[i - 16]
                .wrapping_add(s0)
                .wrapping_add(w[i - 7])
                .wrapping_add(s1);
        }
        let mut v = h;
        for i in 0..64 {
            let s1 = v[4].rotate_right(6) ^ v[4].rotate_right(11) ^ v[4].rotate_right(25);
            let ch = (v[4] & v[5]) ^ (!v[4] & v[6]);
            let t1 = v[7]
                .wrapping_add(s1)
                .wrapping_add(ch)
                .wrapping_add(K[i])
                .wrapping_add(w[i]);
            let s0 = v[0].rotate_right(2) ^ v[0].rotate_right(13) ^ v[0].rotate_right(22);
            let maj = (v[0] & v[1]) ^ (v[0] & v[2]) ^ (v[1] & v[2]);
            let t2 = s0.wrapping_add(maj);
            v = [
                t1.wrapping_add(t2),
                v[0],
                v[1],
                v[2],
                v[3].wrapping_add(t1),
                v[4],
                v[5],
                v[6],
            ];
        }
        for i in 0..8 {
            h[i] = h[i].wrapping_add(v[i]);
        }
    }
    h.iter().map(|x| format!("{x:08x}")).collect()
}

const DIFFVG_SCENE_HASH: &str = "6d71ae41acbddd17973d9a9125a21a84c3aa9a81b5c58b328bcc9e263ab33ed7";

fn check_diffvg_generator() {
    let mut rng = SplitMix64(1234);
    let first = [rng.next_u64(), rng.next_u64(), rng.next_u64()];
    assert_eq!(
        first,
        [0xbb0cf61b2f181cdb, 0x97c7a1364df06524, 0x33befae49bc025da],
        "SplitMix64 check values"
    );
    let mut bytes = Vec::new();
    for p in diffvg_scene(256, 256) {
        for q in &p.points {
            bytes.extend_from_slice(&q.x.to_le_bytes());
            bytes.extend_from_slice(&q.y.to_le_bytes());
        }
        for v in [p.color[0], p.color[1], p.color[2], p.opacity] {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    let hash = sha256(&bytes);
    assert_eq!(hash, DIFFVG_SCENE_HASH, "DiffVG scene hash");
    println!("DiffVG scene generator: check values and SHA-256 {hash} match the note.");
}

/// CPU time of the calling thread, in ms.
fn thread_cpu_ms() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid timespec to write into.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    assert_eq!(rc, 0, "clock_gettime(CLOCK_THREAD_CPUTIME_ID)");
    ts.tv_sec as f64 * 1e3 + ts.tv_nsec as f64 * 1e-6
}

/// One call of `f`, in ms: CPU time of the calling thread when `cpu`, wall time otherwise.
fn time_ms(cpu: bool, f: impl FnOnce()) -> f64 {
    if cpu {
        let t = thread_cpu_ms();
        f();
        thread_cpu_ms() - t
    } else {
        let t = Instant::now();
        f();
        t.elapsed().as_secs_f64() * 1e3
    }
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

fn tiny_skia_paths(paths: &[Path]) -> Vec<(tiny_skia::Path, tiny_skia::Paint<'static>)> {
    paths
        .iter()
        .filter_map(|p| {
            let mut pb = tiny_skia::PathBuilder::new();
            let n = p.segment_count();
            pb.move_to(p.points[0].x, p.points[0].y);
            for k in 0..n {
                let c = p.segment(k);
                pb.cubic_to(c[1].x, c[1].y, c[2].x, c[2].y, c[3].x, c[3].y);
            }
            pb.close();
            let mut paint = tiny_skia::Paint::default();
            paint.set_color_rgba8(
                (p.color[0] * 255.0).round() as u8,
                (p.color[1] * 255.0).round() as u8,
                (p.color[2] * 255.0).round() as u8,
                (p.opacity * 255.0).round() as u8,
            );
            paint.anti_alias = true;
            Some((pb.finish()?, paint))
        })
        .collect()
}

/// Medians over the rounds of a scene's times (ms) and of each round's ratios.
struct Timing {
    forward: f64,
    forward_backward: f64,
    tiny_skia: f64,
    /// forward / tiny-skia, (forward + backward) / tiny-skia, backward / forward.
    forward_ratio: f64,
    forward_backward_ratio: f64,
    backward_ratio: f64,
}

/// `runs` rounds after one warm-up, each timing tiny-skia's fill, our forward, and our forward
/// and backward (with an MSE-style d_out against a gradient target) one after the other, so
/// that each ratio compares runs a moment apart and a shared machine's drifts cancel. Ours run on the
/// current rayon pool (CPU time of this thread on a pool of one, wall time otherwise);
/// tiny-skia, single-threaded, on this thread, CPU time.
fn time_scene(paths: &[Path], size: usize, runs: usize) -> Timing {
    let cpu = rayon::current_num_threads() == 1;
    let base = [1.0; 3];
    let mut raster = Rasterizer::new();
    let mut image = Image::default();
    let mut d_out = Image::filled(size, size, [0.0; 3]);
    let mut grads = PathGrad::zeros_like(paths);
    let shapes = tiny_skia_paths(paths);
    let mut pixmap = tiny_skia::Pixmap::new(size as u32, size as u32).expect("pixmap");
    // The MSE gradient against DiffVG's target (R = x ramp, G = y ramp, B = ½), as an
    // optimisation step computes it.
    let scale = 2.0 / (3 * size * size) as f32;
    let ramp = |i: usize| i as f32 / (size - 1) as f32;
    let target: Vec<f32> = (0..size * size)
        .flat_map(|i| [ramp(i % size), ramp(i / size), 0.5])
        .collect();
    let mut round = || {
        let skia = time_ms(true, || {
            pixmap.fill(tiny_skia::Color::WHITE);
            for (path, paint) in &shapes {
                pixmap.fill_path(
                    path,
                    paint,
                    tiny_skia::FillRule::Winding,
                    tiny_skia::Transform::identity(),
                    None,
                );
            }
            black_box(&pixmap);
        });
        let forward = time_ms(cpu, || {
            raster.render(paths, base, size, size, &mut image);
            black_box(&image);
        });
        let forward_backward = time_ms(cpu, || {
            raster.render(paths, base, size, size, &mut image);
            for ((d, &v), &t) in d_out.data.iter_mut().zip(&image.data).zip(&target) {
                *d = scale * (v - t);
            }
            for g in grads.iter_mut() {
                g.points.fill(Point::default());
                g.color = [0.0; 3];
                g.opacity = 0.0;
            }
            raster.backward(paths, base, &d_out, &mut grads);
            black_box(&grads);
        });
        [skia, forward, forward_backward]
    };
    round();
    let rounds: Vec<[f64; 3]> = (0..runs).map(|_| round()).collect();
    let of = |f: fn(&[f64; 3]) -> f64| median(rounds.iter().map(f).collect());
    Timing {
        tiny_skia: of(|r| r[0]),
        forward: of(|r| r[1]),
        forward_backward: of(|r| r[2]),
        forward_ratio: of(|r| r[1] / r[0]),
        forward_backward_ratio: of(|r| r[2] / r[0]),
        backward_ratio: of(|r| (r[2] - r[1]) / r[1]),
    }
}

fn pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .expect("thread pool")
}

fn main() {
    // `cargo bench --bench render -- WORD` runs only the scenes whose name contains WORD
    // (`cargo bench` itself passes `--bench`, which is skipped).
    let filter: Option<String> = std::env::args().skip(1).find(|a| !a.starts_with("--"));
    let wanted = |name: &str| filter.as_deref().is_none_or(|f| name.contains(f));
    let runs: usize = std::env::var("COVEC_BENCH_RUNS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(21);
    check_diffvg_generator();
    println!(
        "medians of {runs} rounds after one warm-up, each round tiny-skia, covec fwd, covec fwd+bwd in turn; ratios are medians of each round's; ms; 1 thread: CPU time, 2 threads: wall time; tiny-skia: fill_path AA, non-zero, 1 thread (CPU time)\n"
    );

    println!(
        "| scene | threads | covec fwd | covec fwd+bwd | tiny-skia fill | fwd / tiny-skia | fwd+bwd / tiny-skia | bwd / fwd |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|---:|");
    for (size, n) in [(256usize, 64usize), (512, 256)] {
        if !wanted(&format!("blobs-{size}-{n}")) {
            continue;
        }
        let paths = blob_scene(size, n, 42);
        for threads in [1, 2] {
            let t = pool(threads).install(|| time_scene(&paths, size, runs));
            println!(
                "| blobs {size}² × {n} | {threads} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} |",
                t.forward,
                t.forward_backward,
                t.tiny_skia,
                t.forward_ratio,
                t.forward_backward_ratio,
                t.backward_ratio
            );
        }
    }

    // DiffVG's figures (ms, 2×2 MC, the pydiffvg default) from diffvg-bench.md:
    // (size, n) → (1 thr fwd, 1 thr bwd, 2 thr fwd, 2 thr bwd).
    let diffvg = [
        ((256usize, 64usize), [3790.0, 20802.0, 2263.0, 10405.0]),
        ((512, 256), [67844.0, 349059.0, 44775.0, 210275.0]),
    ];
    println!(
        "\nDiffVG scenes (SplitMix64 seed 1234; covec fills non-zero, DiffVG even-odd: same geometry and work, different images)\n"
    );
    println!(
        "| scene | threads | covec fwd | covec fwd+bwd | tiny-skia fill | bwd / fwd | DiffVG fwd (2×2) | DiffVG fwd+bwd (2×2) | DiffVG / covec (fwd+bwd) |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|---:|---:|");
    for ((size, n), d) in diffvg {
        if !wanted(&format!("diffvg-{size}-{n}")) {
            continue;
        }
        let paths = diffvg_scene(size, n);
        for (threads, (df, db)) in [(1, (d[0], d[1])), (2, (d[2], d[3]))] {
            let t = pool(threads).install(|| time_scene(&paths, size, runs));
            println!(
                "| DiffVG {size}² × {n} | {threads} | {:.1} | {:.1} | {:.1} | {:.2} | {df:.0} | {:.0} | {:.0}× |",
                t.forward,
                t.forward_backward,
                t.tiny_skia,
                t.backward_ratio,
                df + db,
                (df + db) / t.forward_backward
            );
        }
    }
}
