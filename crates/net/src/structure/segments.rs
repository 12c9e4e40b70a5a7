//! Segments and their vote: Felzenszwalb-Huttenlocher graph segmentation over the voxel
//! adjacency, with edge weights from the angle between the normals and the colour difference
//! ([`voxel_edges`], [`felzenszwalb`]), then one class per segment from its members' summed
//! probabilities ([`vote`]). Objects are made of smooth, similarly coloured patches, so the
//! segments rarely cross an object boundary and the vote keeps a chair from being half chair,
//! half sofa. The edges are visited in a stable counting-sort order and the union-find runs in
//! that order: the segments are the same for any number of threads.

use glam::Vec3;
use rayon::prelude::*;

use super::argmax_rows;
use super::neighbours::NO_NEIGHBOUR;

/// Parameters of the graph segmentation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SegmentParams {
    /// Felzenszwalb-Huttenlocher's `k`: a segment of `s` voxels absorbs an edge up to
    /// `k / s` heavier than its heaviest internal edge (larger: larger segments).
    pub k: f32,
    /// Weight of the colour difference (Euclidean, RGB in `[0, 1]`) against the normal term
    /// `1 - |n_i . n_j|`.
    pub color_weight: f32,
    /// Segments smaller than this many voxels merge into a neighbour (lightest edge first).
    pub min_size: usize,
}

impl Default for SegmentParams {
    fn default() -> Self {
        Self { k: 0.4, color_weight: 2.0, min_size: 10 }
    }
}

/// The undirected edges of the voxel adjacency with their weights
/// `(1 - |n_i . n_j|) + color_weight * |c_i - c_j|` (colours in `[0, 1]`; a missing normal
/// counts as perpendicular), each pair once as `(i, j)` with `j` a following neighbour of `i`,
/// in order of `i` then offset.
///
/// # Shapes
/// `neighbours`, `normals`: `[n]`; `features`: `[n, 3]` network colour features in `[-1, 1]`.
pub fn voxel_edges(neighbours: &[[u32; 26]], normals: &[Vec3], features: &[f32], color_weight: f32) -> Vec<Edge> {
    neighbours
        .par_iter()
        .enumerate()
        .flat_map_iter(|(i, nb)| {
            nb[13..].iter().filter(|&&j| j != NO_NEIGHBOUR).map(move |&j| {
                let ju = j as usize;
                let dot = normals[i].dot(normals[ju]).abs().min(1.0);
                let dc =
                    (0..3).map(|ch| (features[i * 3 + ch] - features[ju * 3 + ch]) * 0.5).map(|d| d * d).sum::<f32>();
                Edge { a: i as u32, b: j, w: (1.0 - dot) + color_weight * dc.sqrt() }
            })
        })
        .collect()
}

/// An undirected weighted edge of a graph over `0..n`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Edge {
    /// One end.
    pub a: u32,
    /// The other end.
    pub b: u32,
    /// Dissimilarity (lower: more alike).
    pub w: f32,
}

/// Weight buckets of [`edge_order`].
const WEIGHT_BUCKETS: usize = 1 << 16;

/// The order in which [`felzenszwalb`] visits `edges`: by weight quantised to 1/65536 of the
/// largest weight, ties in input order (a counting sort: linear, stable, the same for any
/// thread count). Negative and NaN weights count as 0.
pub fn edge_order(edges: &[Edge]) -> Vec<u32> {
    let clean = |w: f32| if w.is_nan() { 0.0 } else { w.max(0.0) };
    let top = edges.iter().map(|e| clean(e.w)).filter(|w| w.is_finite()).fold(0.0f32, f32::max);
    let scale = if top > 0.0 { (WEIGHT_BUCKETS - 1) as f32 / top } else { 0.0 };
    let bucket: Vec<u16> = edges
        .par_iter()
        .map(|e| {
            let w = clean(e.w);
            if w.is_finite() {
                (w * scale).min((WEIGHT_BUCKETS - 1) as f32) as u16
            } else {
                (WEIGHT_BUCKETS - 1) as u16
            }
        })
        .collect();
    let mut start = vec![0u32; WEIGHT_BUCKETS + 1];
    for &b in &bucket {
        start[b as usize + 1] += 1;
    }
    for i in 0..WEIGHT_BUCKETS {
        start[i + 1] += start[i];
    }
    let mut order = vec![0u32; edges.len()];
    for (i, &b) in bucket.iter().enumerate() {
        order[start[b as usize] as usize] = i as u32;
        start[b as usize] += 1;
    }
    order
}

/// Union-find with union by size (ties: the smaller index becomes the root).
struct Forest {
    parent: Vec<u32>,
    size: Vec<u32>,
}

impl Forest {
    fn new(n: usize) -> Self {
        Self { parent: (0..n as u32).collect(), size: vec![1; n] }
    }

    fn find(&mut self, mut x: u32) -> u32 {
        while self.parent[x as usize] != x {
            let p = self.parent[x as usize];
            self.parent[x as usize] = self.parent[p as usize];
            x = p;
        }
        x
    }

    /// Joins two roots; returns the new root.
    fn union(&mut self, a: u32, b: u32) -> u32 {
        let (sa, sb) = (self.size[a as usize], self.size[b as usize]);
        let (root, child) = if sa > sb || (sa == sb && a < b) { (a, b) } else { (b, a) };
        self.parent[child as usize] = root;
        self.size[root as usize] = sa + sb;
        root
    }
}

/// Felzenszwalb-Huttenlocher graph segmentation: edges in increasing weight (ties in input
/// order, [`edge_order`]) join two components when the edge is no heavier than either component's largest
/// internal edge plus `k / size`; then components smaller than `min_size` are joined along
/// the remaining edges in the same order. Returns the component of every node, numbered
/// `0..m` in order of each component's first node.
///
/// # Shapes
/// `edges` over nodes `0..n`; result `[n]`.
pub fn felzenszwalb(n: usize, edges: &[Edge], k: f32, min_size: usize) -> Vec<u32> {
    let order = edge_order(edges);
    let valid = |e: &Edge| (e.a as usize) < n && (e.b as usize) < n;
    let mut forest = Forest::new(n);
    let mut threshold = vec![k; n];
    for &i in &order {
        let e = edges[i as usize];
        if !valid(&e) {
            continue;
        }
        let (ra, rb) = (forest.find(e.a), forest.find(e.b));
        if ra != rb && e.w <= threshold[ra as usize] && e.w <= threshold[rb as usize] {
            let r = forest.union(ra, rb);
            threshold[r as usize] = e.w + k / forest.size[r as usize] as f32;
        }
    }
    if min_size > 1 {
        for &i in &order {
            let e = edges[i as usize];
            if !valid(&e) {
                continue;
            }
            let (ra, rb) = (forest.find(e.a), forest.find(e.b));
            if ra != rb && (forest.size[ra as usize] < min_size as u32 || forest.size[rb as usize] < min_size as u32) {
                forest.union(ra, rb);
            }
        }
    }
    let mut id = vec![u32::MAX; n];
    let mut next = 0;
    let mut out = vec![0u32; n];
    for (i, o) in out.iter_mut().enumerate() {
        let r = forest.find(i as u32) as usize;
        if id[r] == u32::MAX {
            id[r] = next;
            next += 1;
        }
        *o = id[r];
    }
    out
}

/// The class of every node from its segment: the segment's members each vote for their
/// argmax class, and the segment takes, among the classes voted for, the one with the
/// largest summed probability (ties: the smaller id). A class no member voted for is never
/// chosen.
///
/// # Shapes
/// `segment`: `[n]` ids `0..m`; `probs`: `[n, k]`; result `[n]`.
pub fn vote(segment: &[u32], probs: &[f32], k: usize) -> Vec<u8> {
    let own = argmax_rows(probs, k);
    let m = segment.iter().map(|&s| s as usize + 1).max().unwrap_or(0);
    let mut sums = vec![0f64; m * k];
    let mut voted = vec![false; m * k];
    for (i, &s) in segment.iter().enumerate() {
        let s = s as usize;
        for (acc, &p) in sums[s * k..(s + 1) * k].iter_mut().zip(&probs[i * k..(i + 1) * k]) {
            *acc += f64::from(p);
        }
        voted[s * k + own[i] as usize] = true;
    }
    let class: Vec<u8> = (0..m)
        .map(|s| {
            let mut best: Option<usize> = None;
            for c in 0..k {
                if voted[s * k + c] && best.is_none_or(|b| sums[s * k + c] > sums[s * k + b]) {
                    best = Some(c);
                }
            }
            best.unwrap_or(0) as u8
        })
        .collect();
    segment.iter().map(|&s| class[s as usize]).collect()
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::structure::{softmax_rows, voxel_neighbours};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use semrecon_sparse::Coord;

    /// Plain reference of Felzenszwalb-Huttenlocher: explicit member lists, a merge
    /// relabels every member.
    fn felzenszwalb_reference(n: usize, edges: &[Edge], k: f32, min_size: usize) -> Vec<usize> {
        let mut sorted = edges.to_vec();
        // Stable: ties keep the input order.
        sorted.sort_by(|x, y| x.w.total_cmp(&y.w));
        let mut comp: Vec<usize> = (0..n).collect();
        let mut internal = vec![0f32; n];
        let size = |comp: &[usize], c: usize| comp.iter().filter(|&&x| x == c).count();
        for e in &sorted {
            let (ca, cb) = (comp[e.a as usize], comp[e.b as usize]);
            if ca == cb {
                continue;
            }
            let (sa, sb) = (size(&comp, ca), size(&comp, cb));
            if e.w <= internal[ca] + k / sa as f32 && e.w <= internal[cb] + k / sb as f32 {
                comp.iter_mut().filter(|x| **x == cb).for_each(|x| *x = ca);
                internal[ca] = e.w;
            }
        }
        for e in &sorted {
            let (ca, cb) = (comp[e.a as usize], comp[e.b as usize]);
            if ca != cb && (size(&comp, ca) < min_size || size(&comp, cb) < min_size) {
                comp.iter_mut().filter(|x| **x == cb).for_each(|x| *x = ca);
            }
        }
        comp
    }

    /// Connected components by breadth-first search.
    fn components(n: usize, edges: &[Edge]) -> Vec<usize> {
        let mut adj = vec![Vec::new(); n];
        for e in edges {
            adj[e.a as usize].push(e.b as usize);
            adj[e.b as usize].push(e.a as usize);
        }
        let mut comp = vec![usize::MAX; n];
        for s in 0..n {
            if comp[s] != usize::MAX {
                continue;
            }
            comp[s] = s;
            let mut queue = std::collections::VecDeque::from([s]);
            while let Some(u) = queue.pop_front() {
                for &v in &adj[u] {
                    if comp[v] == usize::MAX {
                        comp[v] = s;
                        queue.push_back(v);
                    }
                }
            }
        }
        comp
    }

    /// Whether two labellings describe the same partition.
    fn same_partition<A: Copy + Eq + std::hash::Hash, B: Copy + Eq + std::hash::Hash>(a: &[A], b: &[B]) -> bool {
        let mut ab = std::collections::HashMap::new();
        let mut ba = std::collections::HashMap::new();
        a.iter().zip(b).all(|(&x, &y)| *ab.entry(x).or_insert(y) == y && *ba.entry(y).or_insert(x) == x)
    }

    fn random_graph(rng: &mut ChaCha8Rng) -> (usize, Vec<Edge>) {
        let n = rng.random_range(1..40);
        let m = rng.random_range(0..n * 2);
        let edges = (0..m)
            .map(|_| {
                let a = rng.random_range(0..n as u32);
                let b = rng.random_range(0..n as u32);
                // Quantised weights: ties happen and must be broken the same way.
                Edge { a, b, w: rng.random_range(0..20) as f32 * 0.05 }
            })
            .filter(|e| e.a != e.b)
            .collect();
        (n, edges)
    }

    #[test]
    fn segmentation_matches_the_plain_reference_and_connected_components() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for _ in 0..400 {
            let (n, edges) = random_graph(&mut rng);
            let k = rng.random_range(0.0..2.0);
            let min_size = rng.random_range(0..6);
            let got = felzenszwalb(n, &edges, k, min_size);
            let want = felzenszwalb_reference(n, &edges, k, min_size);
            assert!(same_partition(&got, &want), "n {n} k {k} min {min_size}: {got:?} vs {want:?}");
            // Numbered in order of first node.
            let mut next = 0;
            for &s in &got {
                assert!(s <= next);
                next = next.max(s + 1);
            }
            // A huge k, or a minimum size above n, joins every connected component whole.
            let cc = components(n, &edges);
            assert!(same_partition(&felzenszwalb(n, &edges, 1e9, 0), &cc));
            assert!(same_partition(&felzenszwalb(n, &edges, 0.0, n + 1), &cc));
            // Segments never join nodes of different components.
            assert!(got.iter().zip(&cc).all(|(&s, &c)| got.iter().zip(&cc).all(|(&s2, &c2)| s != s2 || c == c2)));
        }
    }

    #[test]
    fn vote_takes_a_voted_class_with_the_largest_sum() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for _ in 0..300 {
            let n = rng.random_range(1..30);
            let k = rng.random_range(1..6);
            let m = rng.random_range(1..=n) as u32;
            let segment: Vec<u32> =
                (0..n).map(|i| if (i as u32) < m { i as u32 } else { rng.random_range(0..m) }).collect();
            let mut probs: Vec<f32> = (0..n * k).map(|_| rng.random_range(0.0..1.0)).collect();
            softmax_rows(&mut probs, k);
            let got = vote(&segment, &probs, k);
            let own = argmax_rows(&probs, k);
            for s in 0..m {
                let members: Vec<usize> = (0..n).filter(|&i| segment[i] == s).collect();
                let voted: Vec<u8> = members.iter().map(|&i| own[i]).collect();
                let class = got[members[0]];
                assert!(members.iter().all(|&i| got[i] == class));
                assert!(voted.contains(&class), "class {class} not among the votes {voted:?}");
                let sum = |c: usize| members.iter().map(|&i| f64::from(probs[i * k + c])).sum::<f64>();
                for &v in &voted {
                    assert!(sum(class as usize) >= sum(v as usize));
                }
            }
        }
        // The case that an unrestricted sum gets wrong: class 2 has the largest sum but no
        // member's vote.
        let probs = [0.45, 0.1, 0.45 - 1e-3, 0.1, 0.45, 0.45 - 1e-3];
        let got = vote(&[0, 0], &probs, 3);
        assert!(got[0] == 0 || got[0] == 1, "{got:?}");
    }

    #[test]
    fn edges_list_each_neighbour_pair_once_with_its_weight() {
        let coords: Vec<Coord> = (0..27).map(|i| [i % 3, (i / 3) % 3, i / 9, 0]).collect();
        let nb = voxel_neighbours(&coords);
        let normals = vec![Vec3::Z; 27];
        let features: Vec<f32> = (0..27 * 3).map(|i| (i % 7) as f32 * 0.1 - 0.3).collect();
        let edges = voxel_edges(&nb, &normals, &features, 2.0);
        // Pairs at Chebyshev distance 1 in a 3x3x3 block.
        let mut want = 0;
        for i in 0..27 {
            for j in i + 1..27 {
                let d = (0..3).map(|a| (coords[i][a] - coords[j][a]).abs()).max().unwrap_or(0);
                if d == 1 {
                    want += 1;
                }
            }
        }
        assert_eq!(edges.len(), want);
        for e in &edges {
            let (a, b) = (e.a as usize, e.b as usize);
            let dc: f32 =
                (0..3).map(|c| ((features[a * 3 + c] - features[b * 3 + c]) / 2.0).powi(2)).sum::<f32>().sqrt();
            assert!((e.w - 2.0 * dc).abs() < 1e-6);
        }
    }
}
