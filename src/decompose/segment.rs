//! Classical substitute for SAM: a segmentation of the albedo map at every scale.
//!
//! Felzenszwalb-Huttenlocher graph segmentation (IJCV 2004) cuts the image into superpixels
//! that follow edges; those are then merged pairwise, adjacent regions only, always the pair
//! whose merge raises the flat-colour squared error least (Ward's criterion). Replaying the
//! merges backwards splits the canvas into 2, 3, 4, … regions: every scale at once. Each split
//! yields a candidate mask (the smaller side, or with [`Sides::Both`] both sides) scored by the
//! error it removes, so the most useful masks come first whatever the budget.

use std::cmp::Reverse;
use std::collections::{BTreeSet, BinaryHeap};

use rayon::prelude::*;

use super::mask::Mask;
use crate::imageio::halve_image;
use crate::render::Image;

/// A candidate mask and how much squared error (sum over pixels and RGB channels) painting it
/// in its own flat colour removes.
#[derive(Clone, Debug)]
pub struct Candidate {
    pub mask: Mask,
    pub gain: f32,
}

/// Superpixel granularity of the Felzenszwalb stage (colour distances in [0, √3]).
const FELZENSZWALB_K: f32 = 0.6;

/// Which sides of a Ward merge become candidates.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sides {
    /// The smaller side alone: the larger one is its parent region less it, which a path
    /// below the smaller one already paints, so the masks nest as painted paths do.
    Smaller,
    /// Both sides, less a larger side that reaches all four edges of the canvas. A region that
    /// only ever merges with smaller neighbours (a face that takes in its neck, then the
    /// backdrop, then the flag) is never a smaller side, so `Smaller` offers it only inside
    /// its parent; a ranking that scores overlap itself wants it alone. A larger side that
    /// spans the canvas is background, which the canvas-wide base path already paints: offered
    /// too, it put a second background path under kodim04's hat and curtain that the edit of
    /// the hat recoloured, and extra edges that the flattened SVG draws less exactly.
    Both,
}

/// Candidate masks of `image` from its last `count` Ward merges, most useful first: per merge
/// the smaller side, then with [`Sides::Both`] the larger one, both scored by the merge's cost.
pub fn segment(image: &Image, count: usize, sides: Sides) -> Vec<Candidate> {
    let (w, h) = (image.width, image.height);
    let labels = superpixels(image, FELZENSZWALB_K, 3000);
    let (merges, regions) = ward_merges(image, &labels);
    // The pixels of each superpixel, grouped by a counting sort: a mask then costs its own
    // area to build, not the canvas's.
    let superpixels = labels.iter().max().map_or(0, |&m| m as usize + 1);
    let mut starts = vec![0usize; superpixels + 1];
    for &label in &labels {
        starts[label as usize + 1] += 1;
    }
    for s in 0..superpixels {
        starts[s + 1] += starts[s];
    }
    let mut pixels = vec![0usize; labels.len()];
    let mut fill = starts.clone();
    for (i, &label) in labels.iter().enumerate() {
        pixels[fill[label as usize]] = i;
        fill[label as usize] += 1;
    }
    let candidate = |region: usize, gain| Candidate {
        mask: Mask::from_indices(
            w,
            h,
            regions[region]
                .iter()
                .flat_map(|&label| &pixels[starts[label as usize]..starts[label as usize + 1]]),
        ),
        gain,
    };
    // The masks built on rayon's pool, in the merges' order.
    let last: Vec<&Merge> = merges.iter().rev().take(count).collect();
    last.into_par_iter()
        .flat_map_iter(|m| {
            let larger = (sides == Sides::Both)
                .then(|| candidate(m.larger, m.cost))
                .filter(|c| c.mask.bbox() != [0, 0, w, h]);
            std::iter::once(candidate(m.smaller, m.cost)).chain(larger)
        })
        .collect()
}

/// One merge of the Ward hierarchy: its two sides (region ids, see [`ward_merges`]) and its
/// cost.
struct Merge {
    smaller: usize,
    larger: usize,
    cost: f32,
}

/// Long side above which [`superpixels`] are found on a half-size copy. Felzenszwalb's passes
/// over the edges wait on memory, on one thread, and dominated the decompose stage at 1024²;
/// from half size it is faster at no loss (docs/history.md, "Decomposition"). Up to 512²
/// nothing changes.
const SUPERPIXEL_SIDE: usize = 512;

/// Felzenszwalb superpixels of `image` (blurred first), components under 1/`min_share` of the
/// canvas (at least 4 pixels) merged into a neighbour; dense labels 0..n. Above
/// [`SUPERPIXEL_SIDE`] they are those of the image halved (until it fits), each label
/// covering its 2×2 block: the granularity a 512² working size gets.
pub(super) fn superpixels(image: &Image, k: f32, min_share: usize) -> Vec<u32> {
    let (w, h) = (image.width, image.height);
    if w.max(h) <= SUPERPIXEL_SIDE {
        return felzenszwalb(&blur(image), k, (w * h / min_share).max(4));
    }
    let half = halve_image(image);
    let hw = half.width;
    let labels = superpixels(&half, k, min_share);
    (0..w * h)
        .map(|i| labels[(i / w / 2) * hw + (i % w) / 2])
        .collect()
}

/// 3-tap binomial blur per axis, to keep Felzenszwalb from cutting along noise.
pub(super) fn blur(image: &Image) -> Image {
    let (w, h) = (image.width, image.height);
    // Row by row on rayon's pool: at 1024² the two passes were a tenth of the decompose
    // stage, on one thread.
    let pass = |src: &Image, dx: usize, dy: usize| {
        let mut out = src.clone();
        out.data
            .par_chunks_mut(3 * w.max(1))
            .enumerate()
            .for_each(|(y, row)| {
                for x in 0..w {
                    let prev = (x.saturating_sub(dx), y.saturating_sub(dy));
                    let next = ((x + dx).min(w - 1), (y + dy).min(h - 1));
                    for c in 0..3 {
                        row[3 * x + c] = 0.25 * src.data[3 * (prev.1 * w + prev.0) + c]
                            + 0.5 * src.data[3 * (y * w + x) + c]
                            + 0.25 * src.data[3 * (next.1 * w + next.0) + c];
                    }
                }
            });
        out
    };
    pass(&pass(image, 1, 0), 0, 1)
}

/// Felzenszwalb-Huttenlocher segmentation on the 8-neighbour grid; returns dense labels 0..n.
///
/// Edges are taken in order of weight, equal weights in the order they are listed (pixel by
/// pixel, then right, down, down-right, down-left). At 1024² that is 4 million edges, so they
/// are sorted as packed keys (see [`EdgeKey`]) by a radix sort, and the union-find keeps
/// 32-bit links: the passes over the edges wait on memory, not on arithmetic.
pub(super) fn felzenszwalb(image: &Image, k: f32, min_size: usize) -> Vec<u32> {
    let (w, h) = (image.width, image.height);
    let colour_distance = |a: usize, b: usize| {
        (0..3)
            .map(|c| (image.data[3 * a + c] - image.data[3 * b + c]).powi(2))
            .sum::<f32>()
            .sqrt()
    };
    let steps = EdgeKey::steps(w);
    // Row by row on rayon's pool, in listing order: the distances' square roots took about
    // a third of this function's time on one thread.
    let edges: Vec<EdgeKey> = (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            (0..w).flat_map(move |x| {
                let i = y * w + x;
                let present = [
                    x + 1 < w,
                    y + 1 < h,
                    y + 1 < h && x + 1 < w,
                    y + 1 < h && x > 0,
                ];
                (0..4)
                    .filter(move |&d| present[d])
                    .map(move |d| EdgeKey::new(colour_distance(i, i + steps[d]), i, d))
            })
        })
        .collect();
    let edges = EdgeKey::sort(edges);
    let mut sets = DisjointSets::new(w * h);
    let mut threshold = vec![k; w * h];
    for &edge in &edges {
        let (a, b) = edge.ends(&steps);
        let (ra, rb) = (sets.find(a), sets.find(b));
        let weight = edge.weight();
        if ra != rb && weight <= threshold[ra] && weight <= threshold[rb] {
            let root = sets.union(ra, rb);
            threshold[root] = weight + k / sets.size(root) as f32;
        }
    }
    for &edge in &edges {
        let (a, b) = edge.ends(&steps);
        let (ra, rb) = (sets.find(a), sets.find(b));
        if ra != rb && (sets.size(ra) < min_size || sets.size(rb) < min_size) {
            sets.union(ra, rb);
        }
    }
    let mut dense = vec![u32::MAX; w * h];
    let mut next = 0;
    (0..w * h)
        .map(|i| {
            let root = sets.find(i);
            if dense[root] == u32::MAX {
                dense[root] = next;
                next += 1;
            }
            dense[root]
        })
        .collect()
}

/// A grid edge as one `u64`: the weight's bits above, `4 × pixel + direction` below. Weights
/// are distances (≥ +0), whose bits order as the numbers do, so ordering the keys orders by
/// weight, then by listing order: what a stable sort by weight gives.
#[derive(Clone, Copy, Debug)]
struct EdgeKey(u64);

impl EdgeKey {
    /// The pixel offsets of the four directions: right, down, down-right, down-left.
    fn steps(width: usize) -> [usize; 4] {
        [1, width, width + 1, width.saturating_sub(1)]
    }

    fn new(weight: f32, pixel: usize, direction: usize) -> Self {
        debug_assert!(weight >= 0.0 && 4 * pixel + direction <= u32::MAX as usize);
        Self((u64::from(weight.to_bits()) << 32) | (4 * pixel + direction) as u64)
    }

    fn weight(self) -> f32 {
        f32::from_bits((self.0 >> 32) as u32)
    }

    fn ends(self, steps: &[usize; 4]) -> (usize, usize) {
        let slot = (self.0 & u64::from(u32::MAX)) as usize;
        (slot / 4, slot / 4 + steps[slot % 4])
    }

    /// `edges`, listed in increasing slot order, ordered by weight then slot: zero weights
    /// (flat areas, most of an albedo map's edges) are already in order and go first; the rest
    /// by a least significant digit radix sort on the weight's bits, stable, so slots stay in
    /// order. Two buffers of the edges' size, as a radix sort of all of them needs.
    fn sort(edges: Vec<Self>) -> Vec<Self> {
        let is_zero = |e: &Self| e.0 >> 32 == 0;
        let zeros = edges.iter().filter(|e| is_zero(e)).count();
        let mut sorted = vec![Self(0); edges.len()];
        let (mut next_zero, mut next_weighted) = (0, zeros);
        for &e in &edges {
            let next = if is_zero(&e) {
                &mut next_zero
            } else {
                &mut next_weighted
            };
            sorted[*next] = e;
            *next += 1;
        }
        let mut spare = edges;
        let (mut from, mut to) = (&mut sorted[zeros..], &mut spare[zeros..]);
        let mut in_spare = false;
        for shift in (32..64).step_by(8) {
            let digit = |e: &Self| (e.0 >> shift) as usize & 0xff;
            let mut starts = [0usize; 257];
            for e in from.iter() {
                starts[digit(e) + 1] += 1;
            }
            if starts.contains(&from.len()) {
                continue; // every key has this digit: the pass would not move anything
            }
            for d in 0..256 {
                starts[d + 1] += starts[d];
            }
            for &e in from.iter() {
                let d = digit(&e);
                to[starts[d]] = e;
                starts[d] += 1;
            }
            std::mem::swap(&mut from, &mut to);
            in_spare = !in_spare;
        }
        if in_spare {
            sorted[zeros..].copy_from_slice(&spare[zeros..]);
        }
        sorted
    }
}

/// Union-find with path halving and union by size, on 32-bit links (half the memory of
/// `usize` ones, and these arrays are walked at random).
pub(super) struct DisjointSets {
    parent: Vec<u32>,
    size: Vec<u32>,
}

impl DisjointSets {
    /// # Panics
    /// If `n` does not fit in a `u32` (a canvas is at most 4096², 2^24 pixels).
    pub(super) fn new(n: usize) -> Self {
        let n = u32::try_from(n).expect("set count fits in u32");
        Self {
            parent: (0..n).collect(),
            size: vec![1; n as usize],
        }
    }

    pub(super) fn find(&mut self, i: usize) -> usize {
        let mut i = i as u32;
        while self.parent[i as usize] != i {
            let grandparent = self.parent[self.parent[i as usize] as usize];
            self.parent[i as usize] = grandparent;
            i = grandparent;
        }
        i as usize
    }

    /// The size of the set whose root is `root`.
    pub(super) fn size(&self, root: usize) -> usize {
        self.size[root] as usize
    }

    /// Joins two roots; returns the new root.
    pub(super) fn union(&mut self, a: usize, b: usize) -> usize {
        let (big, small) = if self.size[a] >= self.size[b] {
            (a, b)
        } else {
            (b, a)
        };
        self.parent[small] = big as u32;
        self.size[big] += self.size[small];
        big
    }
}

/// Region statistics during Ward merging.
struct Region {
    sum: [f64; 3],
    count: f64,
    neighbours: BTreeSet<usize>,
    superpixels: BTreeSet<u32>,
    alive: bool,
}

/// The squared error added by merging two flat-colour regions.
fn ward_cost(a: &Region, b: &Region) -> f64 {
    let d2: f64 = (0..3)
        .map(|c| (a.sum[c] / a.count - b.sum[c] / b.count).powi(2))
        .sum();
    a.count * b.count / (a.count + b.count) * d2
}

/// Merges adjacent regions cheapest first until one is left. Returns the merges in order and
/// the superpixels of every region by id: the superpixels first, then each merge's result.
/// Merges name their sides by id rather than holding copies of their sets: every merge
/// happens, but only the last few become candidates.
fn ward_merges(image: &Image, labels: &[u32]) -> (Vec<Merge>, Vec<BTreeSet<u32>>) {
    let (w, h) = (image.width, image.height);
    let n = labels.iter().max().map_or(0, |&m| m as usize + 1);
    let mut regions: Vec<Region> = (0..n)
        .map(|i| Region {
            sum: [0.0; 3],
            count: 0.0,
            neighbours: BTreeSet::new(),
            superpixels: BTreeSet::from([i as u32]),
            alive: true,
        })
        .collect();
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let r = &mut regions[labels[i] as usize];
            for c in 0..3 {
                r.sum[c] += f64::from(image.data[3 * i + c]);
            }
            r.count += 1.0;
            for j in [(x + 1 < w).then(|| i + 1), (y + 1 < h).then(|| i + w)]
                .into_iter()
                .flatten()
            {
                let (a, b) = (labels[i] as usize, labels[j] as usize);
                if a != b {
                    regions[a].neighbours.insert(b);
                    regions[b].neighbours.insert(a);
                }
            }
        }
    }
    // Min-heap on (cost, a, b); ties broken by ids for determinism. Stale entries are skipped.
    let mut heap = BinaryHeap::new();
    let key = |c: f64| Reverse(c.to_bits());
    for a in 0..n {
        for &b in regions[a].neighbours.range(a + 1..) {
            heap.push((
                key(ward_cost(&regions[a], &regions[b])),
                Reverse(a),
                Reverse(b),
            ));
        }
    }
    let mut merges = Vec::new();
    while let Some((Reverse(bits), Reverse(a), Reverse(b))) = heap.pop() {
        if !regions[a].alive || !regions[b].alive {
            continue;
        }
        let cost = f64::from_bits(bits);
        let small = if regions[a].count <= regions[b].count {
            a
        } else {
            b
        };
        merges.push(Merge {
            smaller: small,
            larger: a + b - small,
            cost: cost as f32,
        });
        // The merged region takes a fresh id, so heap entries naming a or b go stale.
        regions[a].alive = false;
        regions[b].alive = false;
        let id = regions.len();
        let mut neighbours: BTreeSet<usize> = &regions[a].neighbours | &regions[b].neighbours;
        neighbours.remove(&a);
        neighbours.remove(&b);
        let merged = Region {
            sum: [0, 1, 2].map(|c| regions[a].sum[c] + regions[b].sum[c]),
            count: regions[a].count + regions[b].count,
            neighbours,
            superpixels: &regions[a].superpixels | &regions[b].superpixels,
            alive: true,
        };
        for &m in &merged.neighbours {
            regions[m].neighbours.remove(&a);
            regions[m].neighbours.remove(&b);
            regions[m].neighbours.insert(id);
        }
        let costs: Vec<_> = merged
            .neighbours
            .iter()
            .map(|&m| (ward_cost(&merged, &regions[m]), m))
            .collect();
        regions.push(merged);
        for (cost, m) in costs {
            heap.push((key(cost), Reverse(m), Reverse(id)));
        }
    }
    let superpixels = regions.into_iter().map(|r| r.superpixels).collect();
    (merges, superpixels)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The radix sort of packed keys orders edges as a stable sort by weight does, ties (many,
    /// as in flat regions) in listing order.
    #[test]
    fn edge_keys_sort_as_a_stable_sort_by_weight() {
        let mut state = 7u64;
        let listed: Vec<(f32, usize, usize)> = (0..5000)
            .map(|i| {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                let weight = match state >> 60 {
                    0..=5 => 0.0,
                    6..=9 => (state >> 40 & 0xf) as f32 / 16.0,
                    _ => f32::from_bits((state >> 33) as u32 & 0x3fff_ffff),
                };
                (weight, i / 4, i % 4)
            })
            .collect();
        let mut stable = listed.clone();
        stable.sort_by(|a, b| a.0.total_cmp(&b.0));
        let keys = listed
            .iter()
            .map(|&(weight, pixel, direction)| EdgeKey::new(weight, pixel, direction));
        let sorted = EdgeKey::sort(keys.collect());
        let steps = EdgeKey::steps(100);
        let unpacked: Vec<(f32, usize, usize)> = sorted
            .iter()
            .map(|&e| {
                let (a, b) = e.ends(&steps);
                (
                    e.weight(),
                    a,
                    steps.iter().position(|&s| s == b - a).unwrap(),
                )
            })
            .collect();
        assert_eq!(unpacked, stable);
    }

    /// Above [`SUPERPIXEL_SIDE`], each label covers a 2×2 block of the halved image's (the
    /// last column of an odd width too), and an edge still separates two labels.
    #[test]
    fn a_large_image_takes_the_superpixels_of_its_half_size_copy() {
        let (w, h) = (SUPERPIXEL_SIDE * 2 + 1, 6);
        let image = Image {
            width: w,
            height: h,
            data: (0..w * h)
                .flat_map(|i| [if i % w < 700 { 0.2 } else { 0.8 }; 3])
                .collect(),
        };
        let labels = superpixels(&image, 0.5, 100);
        let half = superpixels(&halve_image(&image), 0.5, 100);
        let hw = w.div_ceil(2);
        for (i, &label) in labels.iter().enumerate() {
            assert_eq!(label, half[(i / w / 2) * hw + (i % w) / 2], "pixel {i}");
        }
        assert_ne!(labels[10], labels[w - 10]);
    }

    #[test]
    fn three_flat_regions_split_in_order_of_error() {
        // Left half dark, right half light, with a mid-grey square inside the right half.
        let (w, h) = (40, 20);
        let mut image = Image::filled(w, h, [0.1; 3]);
        for y in 0..h {
            for x in w / 2..w {
                let v = if (25..35).contains(&x) && (5..15).contains(&y) {
                    0.6
                } else {
                    0.9
                };
                image.data[3 * (y * w + x)..3 * (y * w + x) + 3].copy_from_slice(&[v; 3]);
            }
        }
        let candidates = segment(&image, 2, Sides::Smaller);
        assert!(candidates[0].gain > candidates[1].gain);
        // The last merge joins the two halves; the one before, the square to the light half.
        // Blurred edge pixels may end on either side, hence the slack.
        assert!(
            (380..=420).contains(&candidates[0].mask.area()),
            "{}",
            candidates[0].mask.area()
        );
        let square = &candidates[1].mask;
        assert!((90..=144).contains(&square.area()), "{}", square.area());
        let [x0, y0, x1, y1] = square.bbox();
        assert!(
            x0 >= 24 && y0 >= 4 && x1 <= 36 && y1 <= 16,
            "{:?}",
            square.bbox()
        );
    }

    #[test]
    fn both_sides_offer_a_region_that_only_takes_in_smaller_neighbours() {
        // A dark backdrop; on its right an inset of a light "face" above a slightly darker
        // "neck" and a mid-grey "backdrop": the face merges with the neck, then with the inset's
        // backdrop, then the inset with the dark backdrop, and is the larger side every time.
        let (w, h) = (60, 40);
        let mut image = Image::filled(w, h, [0.1; 3]);
        for y in 0..h {
            for x in 36..w {
                let v = match y {
                    0..20 => 0.8,
                    20..24 => 0.7,
                    _ => 0.5,
                };
                image.data[3 * (y * w + x)..3 * (y * w + x) + 3].copy_from_slice(&[v; 3]);
            }
        }
        let is_face = |c: &Candidate| {
            let [x0, y0, x1, y1] = c.mask.bbox();
            (400..=560).contains(&c.mask.area()) && x0 >= 35 && y0 == 0 && x1 == w && y1 <= 22
        };
        assert!(!segment(&image, 100, Sides::Smaller).iter().any(is_face));
        assert!(segment(&image, 100, Sides::Both).iter().any(is_face));
    }

    #[test]
    fn both_sides_leave_out_a_larger_side_that_spans_the_canvas() {
        // A light square on a dark backdrop: the backdrop is the larger side of the last merge,
        // and it reaches all four edges, where the canvas-wide base path paints it already.
        let (w, h) = (40, 40);
        let mut image = Image::filled(w, h, [0.1; 3]);
        for y in 12..28 {
            for x in 12..28 {
                image.data[3 * (y * w + x)..3 * (y * w + x) + 3].copy_from_slice(&[0.9; 3]);
            }
        }
        let candidates = segment(&image, 10, Sides::Both);
        assert!(candidates.iter().any(|c| c.mask.area() >= 200));
        assert!(candidates.iter().all(|c| c.mask.bbox() != [0, 0, w, h]));
    }
}
