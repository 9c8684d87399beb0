//! Classical substitute for SAM: a segmentation of the albedo map at every scale.
//!
//! Felzenszwalb-Huttenlocher graph segmentation (IJCV 2004) cuts the image into superpixels
//! that follow edges; those are then merged pairwise, adjacent regions only, always the pair
//! whose merge raises the flat-colour squared error least (Ward's criterion). Replaying the
//! merges backwards splits the canvas into 2, 3, 4, … regions: every scale at once. Each split
//! yields one candidate mask (the smaller side) scored by the error it removes, so the most
//! useful masks come first whatever the budget.

use std::cmp::Reverse;
use std::collections::{BTreeSet, BinaryHeap};

use super::mask::Mask;
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

/// Up to `count` candidate masks of `image`, most useful first: the smaller sides of the last
/// `count` Ward merges.
pub fn segment(image: &Image, count: usize) -> Vec<Candidate> {
    let (w, h) = (image.width, image.height);
    let min_size = (w * h / 3000).max(4);
    let labels = felzenszwalb(&blur(image), FELZENSZWALB_K, min_size);
    let merges = ward_merges(image, &labels);
    // Per merge a table of the superpixels on its smaller side: an index per pixel, not a
    // set lookup per pixel.
    let superpixels = labels.iter().max().map_or(0, |&m| m as usize + 1);
    let mut smaller = vec![false; superpixels];
    merges
        .iter()
        .rev()
        .take(count)
        .map(|m| {
            smaller.fill(false);
            for &label in &m.smaller {
                smaller[label as usize] = true;
            }
            Candidate {
                mask: Mask::from_fn(w, h, |x, y| smaller[labels[y * w + x] as usize]),
                gain: m.cost,
            }
        })
        .collect()
}

/// One merge of the Ward hierarchy: the superpixels of its smaller side, and its cost.
struct Merge {
    smaller: BTreeSet<u32>,
    cost: f32,
}

/// 3-tap binomial blur per axis, to keep Felzenszwalb from cutting along noise.
pub(super) fn blur(image: &Image) -> Image {
    let (w, h) = (image.width, image.height);
    let pass = |src: &Image, dx: usize, dy: usize| {
        let mut out = src.clone();
        for y in 0..h {
            for x in 0..w {
                let prev = (x.saturating_sub(dx), y.saturating_sub(dy));
                let next = ((x + dx).min(w - 1), (y + dy).min(h - 1));
                for c in 0..3 {
                    out.data[3 * (y * w + x) + c] = 0.25 * src.data[3 * (prev.1 * w + prev.0) + c]
                        + 0.5 * src.data[3 * (y * w + x) + c]
                        + 0.25 * src.data[3 * (next.1 * w + next.0) + c];
                }
            }
        }
        out
    };
    pass(&pass(image, 1, 0), 0, 1)
}

/// Felzenszwalb-Huttenlocher segmentation on the 8-neighbour grid; returns dense labels 0..n.
pub(super) fn felzenszwalb(image: &Image, k: f32, min_size: usize) -> Vec<u32> {
    let (w, h) = (image.width, image.height);
    let colour_distance = |a: usize, b: usize| {
        (0..3)
            .map(|c| (image.data[3 * a + c] - image.data[3 * b + c]).powi(2))
            .sum::<f32>()
            .sqrt()
    };
    let mut edges = Vec::with_capacity(w * h * 4);
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let mut push = |j: usize| edges.push((colour_distance(i, j), i as u32, j as u32));
            if x + 1 < w {
                push(i + 1);
            }
            if y + 1 < h {
                push(i + w);
                if x + 1 < w {
                    push(i + w + 1);
                }
                if x > 0 {
                    push(i + w - 1);
                }
            }
        }
    }
    edges.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut sets = DisjointSets::new(w * h);
    let mut threshold = vec![k; w * h];
    for &(weight, a, b) in &edges {
        let (ra, rb) = (sets.find(a as usize), sets.find(b as usize));
        if ra != rb && weight <= threshold[ra] && weight <= threshold[rb] {
            let root = sets.union(ra, rb);
            threshold[root] = weight + k / sets.size[root] as f32;
        }
    }
    for &(_, a, b) in &edges {
        let (ra, rb) = (sets.find(a as usize), sets.find(b as usize));
        if ra != rb && (sets.size[ra] < min_size || sets.size[rb] < min_size) {
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

pub(super) struct DisjointSets {
    parent: Vec<usize>,
    size: Vec<usize>,
}

impl DisjointSets {
    pub(super) fn new(n: usize) -> Self {
        Self {
            parent: (0..n).collect(),
            size: vec![1; n],
        }
    }

    pub(super) fn find(&mut self, mut i: usize) -> usize {
        while self.parent[i] != i {
            self.parent[i] = self.parent[self.parent[i]];
            i = self.parent[i];
        }
        i
    }

    /// Joins two roots; returns the new root.
    pub(super) fn union(&mut self, a: usize, b: usize) -> usize {
        let (big, small) = if self.size[a] >= self.size[b] {
            (a, b)
        } else {
            (b, a)
        };
        self.parent[small] = big;
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

/// Merges adjacent regions cheapest first until one is left; returns the merges in order.
fn ward_merges(image: &Image, labels: &[u32]) -> Vec<Merge> {
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
            smaller: regions[small].superpixels.clone(),
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
    merges
}

#[cfg(test)]
mod tests {
    use super::*;

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
        let candidates = segment(&image, 2);
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
}
