//! Same inputs, bit-identical image and gradients, whatever the rayon thread count (and whether
//! the rasteriser's buffers are fresh or reused).

mod render_support;

use covec::render::{Image, PathGrad, Rasterizer};
use render_support::*;

fn bits(image: &Image, grads: &[PathGrad]) -> Vec<u32> {
    let mut v: Vec<u32> = image.data.iter().map(|x| x.to_bits()).collect();
    for g in grads {
        v.extend(g.points.iter().flat_map(|p| [p.x.to_bits(), p.y.to_bits()]));
        v.extend(g.color.iter().map(|c| c.to_bits()));
        v.push(g.opacity.to_bits());
    }
    v
}

#[test]
fn output_and_gradients_are_bit_identical_across_thread_counts() {
    // 61 px: several strips, the last one partial.
    let size = 61;
    let mut rng = SplitMix64(5);
    let paths = mixed_scene(&mut rng, size as f32, 10, 4);
    let (target, weights) = (
        (0..size * size * 3)
            .map(|_| rng.uniform())
            .collect::<Vec<_>>(),
        vec![1.0; size * size * 3],
    );

    let run = |raster: &mut Rasterizer| {
        let image = render(raster, &paths, [1.0, 0.9, 0.8], size);
        let (_, d_out) = weighted_sq_loss(&image, &target, &weights);
        let mut grads = zero_grads(&paths);
        raster.backward(&paths, [1.0, 0.9, 0.8], &d_out, &mut grads);
        bits(&image, &grads)
    };
    let mut results = Vec::new();
    for threads in [1, 2, 3] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool");
        let mut raster = Rasterizer::new();
        results.push(pool.install(|| run(&mut raster)));
        // The same rasteriser again, buffers reused.
        results.push(pool.install(|| run(&mut raster)));
    }
    for (i, r) in results.iter().enumerate() {
        assert!(
            r == &results[0],
            "run {i} differs from the single-threaded one"
        );
    }
}
