//! Same inputs, bit-identical image and gradients, whatever the rayon thread count (and whether
//! the rasteriser's buffers are fresh or reused).

use crate::render_support;

use covec::render::{Backdrop, Image, PathGrad, Rasterizer, STRIP_ROWS};
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

#[test]
fn a_render_of_chosen_strips_is_the_whole_render_there_and_the_backward_follows() {
    // 61 px: four strips, the last one partial; small blobs leave some strips unpainted.
    let size = 61;
    let mut rng = SplitMix64(11);
    let paths: Vec<_> = (0..3)
        .map(|_| {
            let (cx, cy) = (rng.range(8.0, 53.0), rng.range(20.0, 30.0));
            let points = blob(&mut rng, cx, cy, 4.0, 4);
            paint(&mut rng, points)
        })
        .collect();
    let backdrop = Image {
        width: size,
        height: size,
        data: (0..size * size * 3).map(|_| rng.uniform()).collect(),
    };
    let mut raster = Rasterizer::new();
    let mut whole = Image::default();
    raster.render_over(&paths, Backdrop::Image(&backdrop), size, size, &mut whole);
    let mut marks = Vec::new();
    raster.mark_strips(&paths, size, size, &mut marks);
    assert_eq!(marks.len(), 4);
    assert!(
        marks.iter().any(|&m| !m),
        "some strip is unpainted: {marks:?}"
    );
    let strip = 3 * STRIP_ROWS * size;
    for (s, &marked) in marks.iter().enumerate() {
        let values = s * strip..((s + 1) * strip).min(whole.data.len());
        if !marked {
            assert_eq!(
                whole.data[values.clone()],
                backdrop.data[values],
                "strip {s}"
            );
        }
    }

    // Chosen strips over a copy of the backdrop: the whole render, bit for bit.
    let mut part = backdrop.clone();
    let mut fresh = Rasterizer::new();
    fresh.render_over_strips(&paths, Backdrop::Image(&backdrop), &marks, &mut part);
    assert_eq!(bits(&part, &[]), bits(&whole, &[]));
    // A strip left out keeps what `out` held.
    let mut odd = backdrop.clone();
    let first = marks.iter().position(|&m| m).expect("a painted strip");
    let mut fewer = marks.clone();
    fewer[first] = false;
    fresh.render_over_strips(&paths, Backdrop::Image(&backdrop), &fewer, &mut odd);
    let values = first * strip..(first + 1) * strip;
    assert_eq!(odd.data[values.clone()], backdrop.data[values]);

    // The backward after a render of the marked strips is the one after a whole render.
    let d_out = Image {
        width: size,
        height: size,
        data: (0..size * size * 3).map(|_| rng.uniform() - 0.5).collect(),
    };
    let backward = |raster: &mut Rasterizer| {
        let mut grads = zero_grads(&paths);
        raster.backward_over(&paths, Backdrop::Image(&backdrop), &d_out, &mut grads);
        bits(&Image::default(), &grads)
    };
    let after_part = {
        let mut raster = Rasterizer::new();
        let mut part = backdrop.clone();
        raster.render_over_strips(&paths, Backdrop::Image(&backdrop), &marks, &mut part);
        backward(&mut raster)
    };
    let mut raster = Rasterizer::new();
    raster.render_over(&paths, Backdrop::Image(&backdrop), size, size, &mut whole);
    assert_eq!(after_part, backward(&mut raster));
}
