//! Binary masks on the working canvas: a bitset with its area and bounding box.

use crate::geom::contour;
use crate::scene::Point;

/// A set of canvas pixels. Cheap intersection counts (64 pixels per word) keep the pairwise
/// tests of mask organisation fast.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Mask {
    width: usize,
    height: usize,
    words: Vec<u64>,
    area: usize,
    /// `[x0, y0, x1, y1)`; all zero when empty.
    bbox: [usize; 4],
}

impl Mask {
    /// The empty mask.
    pub fn empty(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            words: vec![0; (width * height).div_ceil(64)],
            area: 0,
            bbox: [0; 4],
        }
    }

    /// The whole canvas.
    pub fn full(width: usize, height: usize) -> Self {
        Self::from_fn(width, height, |_, _| true)
    }

    /// The pixels where `inside(x, y)` holds.
    pub fn from_fn(
        width: usize,
        height: usize,
        mut inside: impl FnMut(usize, usize) -> bool,
    ) -> Self {
        let mut mask = Self::empty(width, height);
        for y in 0..height {
            for x in 0..width {
                if inside(x, y) {
                    mask.words[(y * width + x) / 64] |= 1 << ((y * width + x) % 64);
                }
            }
        }
        mask.recount();
        mask
    }

    /// The pixels `i` (`y * width + x`) listed by `indices`, in any order: work in
    /// proportion to their number, not the canvas's.
    ///
    /// # Panics
    /// If an index is past the canvas.
    pub fn from_indices<'a>(
        width: usize,
        height: usize,
        indices: impl IntoIterator<Item = &'a usize>,
    ) -> Self {
        let mut mask = Self::empty(width, height);
        for &i in indices {
            assert!(i < width * height, "pixel {i} is past the canvas");
            mask.words[i / 64] |= 1 << (i % 64);
        }
        mask.recount();
        mask
    }

    /// One mask per label `0..count`, in one pass: mask `k` holds the pixels `i` with
    /// `labels[i] == k` (a pixel with a label past `count` is in none).
    pub fn from_labels(width: usize, height: usize, labels: &[usize], count: usize) -> Vec<Self> {
        let mut masks = vec![Self::empty(width, height); count];
        for (i, &k) in labels.iter().enumerate().take(width * height) {
            if let Some(mask) = masks.get_mut(k) {
                mask.words[i / 64] |= 1 << (i % 64);
            }
        }
        masks.iter_mut().for_each(Self::recount);
        masks
    }

    /// The pixels `i` (`y * width + x`) of the mask for which `keep(i)` holds: work in
    /// proportion to the mask's area, not the canvas's.
    pub fn filter(&self, mut keep: impl FnMut(usize) -> bool) -> Self {
        let mut out = Self::empty(self.width, self.height);
        for i in self.indices().filter(|&i| keep(i)) {
            out.words[i / 64] |= 1 << (i % 64);
        }
        out.recount();
        out
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    /// Number of pixels in the mask.
    pub fn area(&self) -> usize {
        self.area
    }

    /// `[x0, y0, x1, y1)`, all zero when empty.
    pub fn bbox(&self) -> [usize; 4] {
        self.bbox
    }

    pub fn is_empty(&self) -> bool {
        self.area == 0
    }

    pub fn contains(&self, x: usize, y: usize) -> bool {
        let i = y * self.width + x;
        self.words[i / 64] >> (i % 64) & 1 == 1
    }

    /// Whether pixel `i = y * width + x` is in the mask.
    pub fn contains_index(&self, i: usize) -> bool {
        self.words[i / 64] >> (i % 64) & 1 == 1
    }

    /// Pixel indices (`y * width + x`) in raster order.
    pub fn indices(&self) -> impl Iterator<Item = usize> + '_ {
        self.words.iter().enumerate().flat_map(|(w, &word)| {
            let mut bits = word;
            std::iter::from_fn(move || {
                (bits != 0).then(|| {
                    let b = bits.trailing_zeros() as usize;
                    bits &= bits - 1;
                    w * 64 + b
                })
            })
        })
    }

    /// |self ∩ other|.
    pub fn intersection_area(&self, other: &Mask) -> usize {
        let [ax0, ay0, ax1, ay1] = self.bbox;
        let [bx0, by0, bx1, by1] = other.bbox;
        if self.is_empty()
            || other.is_empty()
            || ax0.max(bx0) >= ax1.min(bx1)
            || ay0.max(by0) >= ay1.min(by1)
        {
            return 0;
        }
        let first = ay0.max(by0) * self.width / 64;
        let last = (ay1.min(by1) * self.width).div_ceil(64);
        self.words[first..last]
            .iter()
            .zip(&other.words[first..last])
            .map(|(a, b)| (a & b).count_ones() as usize)
            .sum()
    }

    /// The mask with every hole (background not 4-connected to the canvas border) filled.
    /// Background inside the bounding box is a hole unless its component reaches the box's
    /// edge; filling adds pixels inside the box only, so the box stays.
    pub fn fill_holes(&self) -> Mask {
        if self.is_empty() {
            return self.clone();
        }
        let [x0, y0, x1, y1] = self.bbox;
        let gaps = self.labelled_runs(false);
        let mut outside = vec![false; gaps.count];
        for (run, &label) in gaps.runs.iter().zip(&gaps.labels) {
            if run.y == y0 || run.y + 1 == y1 || run.x0 == x0 || run.x1 == x1 {
                outside[label] = true;
            }
        }
        let mut filled = self.clone();
        for (run, &label) in gaps.runs.iter().zip(&gaps.labels) {
            if !outside[label] {
                filled.set_run(run);
                filled.area += run.x1 - run.x0;
            }
        }
        filled
    }

    /// The 4-connected components of at least `min_area` pixels, largest first (ties in raster
    /// order of their first pixel).
    pub fn components(&self, min_area: usize) -> Vec<Mask> {
        let parts = self.labelled_runs(true);
        let mut areas = vec![0; parts.count];
        let mut boxes = vec![[usize::MAX, usize::MAX, 0, 0]; parts.count];
        for (run, &label) in parts.runs.iter().zip(&parts.labels) {
            areas[label] += run.x1 - run.x0;
            let b = &mut boxes[label];
            *b = [
                b[0].min(run.x0),
                b[1].min(run.y),
                b[2].max(run.x1),
                run.y + 1,
            ];
        }
        // Small ones get no mask of their own: at 1024² each costs a whole canvas of words.
        let mut slot = vec![usize::MAX; parts.count];
        let mut components = Vec::new();
        for label in (0..parts.count).filter(|&l| areas[l] >= min_area) {
            slot[label] = components.len();
            let mut component = Mask::empty(self.width, self.height);
            component.area = areas[label];
            component.bbox = boxes[label];
            components.push(component);
        }
        for (run, &label) in parts.runs.iter().zip(&parts.labels) {
            if let Some(component) = components.get_mut(slot[label]) {
                component.set_run(run);
            }
        }
        // Labels follow the raster order of first pixels, and the sort is stable.
        components.sort_by_key(|c| std::cmp::Reverse(c.area));
        components
    }

    /// The runs of pixels inside the bounding box that are in the mask (`inside`) or not, and
    /// their 4-connected components: runs of adjacent rows that share a column are joined.
    /// Work in proportion to the runs, not the pixels (a flood fill pixel by pixel took most
    /// of the decompose and init stages' time at 1024²).
    fn labelled_runs(&self, inside: bool) -> LabelledRuns {
        let [x0, y0, x1, y1] = self.bbox;
        let mut runs = Vec::new();
        let mut parent: Vec<usize> = Vec::new();
        let find = |parent: &mut Vec<usize>, mut i: usize| {
            while parent[i] != i {
                parent[i] = parent[parent[i]];
                i = parent[i];
            }
            i
        };
        let mut previous = 0..0;
        for y in y0..y1 {
            let (row, end) = (y * self.width, y * self.width + x1);
            let current = runs.len();
            let mut i = row + x0;
            while let Some(start) = self.first_with(i, end, inside) {
                let stop = self.first_with(start, end, !inside).unwrap_or(end);
                runs.push(Run {
                    y,
                    x0: start - row,
                    x1: stop - row,
                });
                parent.push(parent.len());
                i = stop;
            }
            let (mut a, mut b) = (previous.start, current);
            while a < previous.end && b < runs.len() {
                let (up, down) = (runs[a], runs[b]);
                if up.x0 < down.x1 && down.x0 < up.x1 {
                    let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
                    parent[ra.max(rb)] = ra.min(rb);
                }
                if up.x1 < down.x1 {
                    a += 1;
                } else {
                    b += 1;
                }
            }
            previous = current..runs.len();
        }
        let mut label_of_root = vec![usize::MAX; runs.len()];
        let mut count = 0;
        let labels = (0..runs.len())
            .map(|r| {
                let root = find(&mut parent, r);
                if label_of_root[root] == usize::MAX {
                    label_of_root[root] = count;
                    count += 1;
                }
                label_of_root[root]
            })
            .collect();
        LabelledRuns {
            runs,
            labels,
            count,
        }
    }

    /// Adds a run's pixels (the area and bounding box are the caller's to keep).
    fn set_run(&mut self, run: &Run) {
        let row = run.y * self.width;
        for i in row + run.x0..row + run.x1 {
            self.words[i / 64] |= 1 << (i % 64);
        }
    }

    /// The outer boundary (as pixel-edge midpoints, clockwise on screen) of the 4-connected
    /// component holding the mask's first pixel in raster order; empty for an empty mask.
    pub fn outer_boundary(&self) -> Vec<Point> {
        let Some(first) = self.indices().next() else {
            return Vec::new();
        };
        let (w, h) = (self.width as i64, self.height as i64);
        let start = ((first % self.width) as i64, (first / self.width) as i64);
        contour::trace_outer_boundary(start, |x, y| {
            (0..w).contains(&x) && (0..h).contains(&y) && self.contains(x as usize, y as usize)
        })
    }

    /// Recomputes area and bounding box from the bits: word-wise, O(words + rows).
    fn recount(&mut self) {
        self.area = self.words.iter().map(|w| w.count_ones() as usize).sum();
        let mut bbox = [usize::MAX, usize::MAX, 0, 0];
        if self.area > 0 {
            for y in 0..self.height {
                let (start, end) = (y * self.width, (y + 1) * self.width);
                let Some(first) = self.first_set(start, end) else {
                    continue;
                };
                let last = self.last_set(start, end).expect("row has a pixel");
                bbox = [
                    bbox[0].min(first - start),
                    bbox[1].min(y),
                    bbox[2].max(last - start + 1),
                    y + 1,
                ];
            }
        } else {
            bbox = [0; 4];
        }
        self.bbox = bbox;
    }

    /// The first pixel index in `start..end` that is in the mask.
    fn first_set(&self, start: usize, end: usize) -> Option<usize> {
        self.first_with(start, end, true)
    }

    /// The first pixel index in `start..end` that is in the mask (`inside`) or not.
    fn first_with(&self, start: usize, end: usize, inside: bool) -> Option<usize> {
        let mut i = start;
        while i < end {
            let word = if inside {
                self.words[i / 64]
            } else {
                !self.words[i / 64]
            };
            let bits = word >> (i % 64);
            if bits != 0 {
                let found = i + bits.trailing_zeros() as usize;
                return (found < end).then_some(found);
            }
            i = (i / 64 + 1) * 64;
        }
        None
    }

    /// The last pixel index in `start..end` that is in the mask.
    fn last_set(&self, start: usize, end: usize) -> Option<usize> {
        let mut j = end;
        while j > start {
            let (word, top) = ((j - 1) / 64, (j - 1) % 64);
            let bits = self.words[word] & (u64::MAX >> (63 - top));
            if bits != 0 {
                let found = word * 64 + 63 - bits.leading_zeros() as usize;
                return (found >= start).then_some(found);
            }
            j = word * 64;
        }
        None
    }
}

/// A row's run of pixels `x0..x1`.
#[derive(Clone, Copy, Debug)]
struct Run {
    y: usize,
    x0: usize,
    x1: usize,
}

/// Runs in raster order, each with its component's label (`0..count`, in the raster order of
/// the components' first pixels).
struct LabelledRuns {
    runs: Vec<Run>,
    labels: Vec<usize>,
    count: usize,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The word-wise bounding box equals a pixel-by-pixel one, for rows that straddle words.
    #[test]
    fn bounding_boxes_match_a_pixel_scan() {
        let mut state = 12345u64;
        for case in 0..200 {
            let (w, h) = (1 + case % 97, 1 + (case * 7) % 41);
            let [cx, cy] = [case % w, (case * 3) % h];
            let mask = Mask::from_fn(w, h, |x, y| {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                x.abs_diff(cx) + y.abs_diff(cy) < 1 + case % 9 && state >> 62 != 0
            });
            let mut naive = [usize::MAX, usize::MAX, 0, 0];
            for y in 0..h {
                for x in (0..w).filter(|&x| mask.contains(x, y)) {
                    naive = [
                        naive[0].min(x),
                        naive[1].min(y),
                        naive[2].max(x + 1),
                        naive[3].max(y + 1),
                    ];
                }
            }
            if mask.is_empty() {
                naive = [0; 4];
            }
            assert_eq!(mask.bbox(), naive, "case {case}");
        }
    }

    /// Pixel-by-pixel flood fills: what the run-based [`Mask::fill_holes`] and
    /// [`Mask::components`] must equal, fields and order.
    fn flood(mask: &Mask, start: usize, want: bool, seen: &mut [bool]) -> Vec<usize> {
        let (w, h) = (mask.width(), mask.height());
        let mut stack = vec![start];
        let mut out = Vec::new();
        seen[start] = true;
        while let Some(i) = stack.pop() {
            out.push(i);
            let (x, y) = (i % w, i / w);
            let around = [
                (x > 0).then(|| i - 1),
                (x + 1 < w).then(|| i + 1),
                (y > 0).then(|| i - w),
                (y + 1 < h).then(|| i + w),
            ];
            for j in around.into_iter().flatten() {
                if mask.contains_index(j) == want && !seen[j] {
                    seen[j] = true;
                    stack.push(j);
                }
            }
        }
        out
    }

    #[test]
    fn runs_give_what_pixel_flood_fills_give() {
        let mut state = 99u64;
        let (mut parts, mut filled_pixels) = (0, 0);
        for case in 0..300 {
            let (w, h) = (1 + case % 131, 1 + (case * 7) % 53);
            let density = [1u64, 2, 3][case % 3];
            let mask = Mask::from_fn(w, h, |x, y| {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (x + y) % 11 != 0 && state >> 62 < density + 1 - u64::from(case % 5 == 0)
            });
            let mut seen = vec![false; w * h];
            let mut expected = Vec::new();
            for i in mask.indices() {
                if !seen[i] {
                    expected.push(Mask::from_indices(w, h, &flood(&mask, i, true, &mut seen)));
                }
            }
            let min_area = case % 4;
            expected.retain(|c| c.area() >= min_area);
            expected.sort_by_key(|c| std::cmp::Reverse(c.area()));
            assert_eq!(mask.components(min_area), expected, "case {case}");
            parts += expected.len();

            let mut seen = vec![false; w * h];
            let mut holes = Vec::new();
            for i in (0..w * h).filter(|&i| !mask.contains_index(i)) {
                if !seen[i] {
                    let part = flood(&mask, i, false, &mut seen);
                    let touches = part.iter().any(|&j| {
                        let (x, y) = (j % w, j / w);
                        let [x0, y0, x1, y1] = mask.bbox();
                        !(x0 < x && x + 1 < x1 && y0 < y && y + 1 < y1)
                    });
                    if !touches {
                        holes.extend(part);
                    }
                }
            }
            let filled = if mask.is_empty() {
                mask.clone()
            } else {
                Mask::from_indices(w, h, &mask.indices().chain(holes).collect::<Vec<_>>())
            };
            assert_eq!(mask.fill_holes(), filled, "case {case}");
            filled_pixels += filled.area() - mask.area();
        }
        assert!(
            parts > 1000 && filled_pixels > 1000,
            "{parts} {filled_pixels}"
        );
    }

    #[test]
    fn a_ring_fills_to_a_square_and_splits_from_a_far_dot() {
        let ring =
            |x: usize, y: usize| (2..7).contains(&x) && (2..7).contains(&y) && !(x == 4 && y == 4);
        let mask = Mask::from_fn(10, 10, |x, y| ring(x, y) || (x, y) == (9, 9));
        assert_eq!(mask.area(), 25);
        let filled = mask.fill_holes();
        assert_eq!(filled.area(), 26);
        let parts = filled.components(1);
        assert_eq!(
            parts.iter().map(Mask::area).collect::<Vec<_>>(),
            vec![25, 1]
        );
        assert_eq!(parts[0].bbox(), [2, 2, 7, 7]);
        assert_eq!(filled.components(2).len(), 1);
    }

    #[test]
    fn intersections_count_shared_pixels() {
        let a = Mask::from_fn(100, 3, |x, _| x < 70);
        let b = Mask::from_fn(100, 3, |x, y| x >= 60 && y == 1);
        assert_eq!(a.intersection_area(&b), 10);
    }
}
