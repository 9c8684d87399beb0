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
    pub fn fill_holes(&self) -> Mask {
        if self.is_empty() {
            return self.clone();
        }
        // Flood the background from a one-pixel frame around the bounding box.
        let [x0, y0, x1, y1] = self.bbox;
        let (fw, fh) = (x1 - x0 + 2, y1 - y0 + 2);
        let inside = |fx: usize, fy: usize| {
            (1..fw - 1).contains(&fx)
                && (1..fh - 1).contains(&fy)
                && self.contains(fx - 1 + x0, fy - 1 + y0)
        };
        let mut outside = vec![false; fw * fh];
        let mut stack = vec![(0usize, 0usize)];
        outside[0] = true;
        while let Some((fx, fy)) = stack.pop() {
            let neighbours = [
                (fx.wrapping_sub(1), fy),
                (fx + 1, fy),
                (fx, fy.wrapping_sub(1)),
                (fx, fy + 1),
            ];
            for (nx, ny) in neighbours {
                if nx < fw && ny < fh && !outside[ny * fw + nx] && !inside(nx, ny) {
                    outside[ny * fw + nx] = true;
                    stack.push((nx, ny));
                }
            }
        }
        let mut filled = self.clone();
        for y in y0..y1 {
            for x in x0..x1 {
                if !outside[(y - y0 + 1) * fw + (x - x0 + 1)] {
                    let i = y * self.width + x;
                    filled.words[i / 64] |= 1 << (i % 64);
                }
            }
        }
        filled.recount();
        filled
    }

    /// The 4-connected components of at least `min_area` pixels, largest first (ties in raster
    /// order of their first pixel).
    pub fn components(&self, min_area: usize) -> Vec<Mask> {
        // Visited pixels, over the bounding box only (every component lies inside it).
        let [x0, y0, x1, _] = self.bbox;
        let box_width = x1 - x0;
        let at = |i: usize| (i / self.width - y0) * box_width + i % self.width - x0;
        let mut seen = vec![false; box_width * (self.bbox[3] - y0)];
        let mut components = Vec::new();
        for start in self.indices() {
            if seen[at(start)] {
                continue;
            }
            let mut component = Mask::empty(self.width, self.height);
            let mut stack = vec![start];
            seen[at(start)] = true;
            let mut area = 0;
            while let Some(i) = stack.pop() {
                component.words[i / 64] |= 1 << (i % 64);
                area += 1;
                let (x, y) = (i % self.width, i / self.width);
                let mut visit = |j: usize| {
                    if self.contains_index(j) && !seen[at(j)] {
                        seen[at(j)] = true;
                        stack.push(j);
                    }
                };
                if x > 0 {
                    visit(i - 1);
                }
                if x + 1 < self.width {
                    visit(i + 1);
                }
                if y > 0 {
                    visit(i - self.width);
                }
                if y + 1 < self.height {
                    visit(i + self.width);
                }
            }
            // Small ones are dropped before the whole-canvas recount.
            if area >= min_area {
                component.recount();
                components.push(component);
            }
        }
        // Stable: equal areas keep the raster order of their first pixel.
        components.sort_by_key(|c| std::cmp::Reverse(c.area));
        components
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
        let mut i = start;
        while i < end {
            let bits = self.words[i / 64] >> (i % 64);
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
