//! Back-to-front mask groups, after LayerVec's `layer_segmented_masks` (peers.md §2.2).
//!
//! Masks are taken largest first. Each is tested against the groups from the bottom up; within
//! a group, against each mask m in turn (I = overlap, U = union, a0 = |m|, a1 = |u|):
//! 1. I/U > 0.7: a duplicate, dropped;
//! 2. I/a0 ≥ 0.5 and a1 > a0: it swallows m, dropped;
//! 3. I/a1 ≥ 0.5 and a1 < a0: it lies inside m, so it moves on to the next group up (a new top
//!    group if there is none);
//! 4. otherwise, if no mask of the group fired, it joins this group.
//!
//! So masks within a group barely overlap, and nested masks are drawn above their containers.

use super::mask::Mask;

/// Groups of indices into `masks`, bottom group first; masks dropped as duplicates are absent.
/// Within a group, indices are in decreasing area.
pub fn organize(masks: &[Mask]) -> Vec<Vec<usize>> {
    let mut order: Vec<usize> = (0..masks.len()).filter(|&i| !masks[i].is_empty()).collect();
    order.sort_by(|&a, &b| masks[b].area().cmp(&masks[a].area()));
    let mut groups: Vec<Vec<usize>> = Vec::new();
    'masks: for u in order {
        let a1 = masks[u].area();
        let mut level = 0;
        'groups: while level < groups.len() {
            for &m in &groups[level] {
                let a0 = masks[m].area();
                let i = masks[m].intersection_area(&masks[u]);
                let union = a0 + a1 - i;
                if i as f64 > 0.7 * union as f64 || (2 * i >= a0 && a1 > a0) {
                    continue 'masks;
                }
                if 2 * i >= a1 && a1 < a0 {
                    level += 1;
                    continue 'groups;
                }
            }
            groups[level].push(u);
            continue 'masks;
        }
        groups.push(vec![u]);
    }
    groups
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nested_masks_go_up_disjoint_ones_share_and_duplicates_drop() {
        let rect = |x0, y0, x1, y1| {
            Mask::from_fn(20, 20, move |x, y| {
                (x0..x1).contains(&x) && (y0..y1).contains(&y)
            })
        };
        let masks = [
            rect(0, 0, 20, 20),   // canvas
            rect(0, 0, 10, 10),   // inside the canvas
            rect(10, 10, 20, 20), // beside the previous one, inside the canvas
            rect(2, 2, 6, 6),     // inside mask 1
            rect(0, 0, 10, 9),    // near-duplicate of mask 1
        ];
        assert_eq!(organize(&masks), vec![vec![0], vec![1, 2], vec![3]]);
    }
}
