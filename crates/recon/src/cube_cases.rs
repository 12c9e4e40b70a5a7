//! The marching-cubes case table, generated at first use from the cube's geometry instead of
//! typed in: for each of the 256 sign configurations of a cell's corners, the triangles that
//! separate negative (behind the surface) from non-negative corners.
//!
//! Construction: on each of the six faces, walking the face's corners counter-clockwise seen
//! from outside, the sign changes come in (entry into the negative region, exit) pairs; each
//! negative arc of the face boundary is cut off by one segment joining its exit crossing to
//! its entry crossing. On faces with two diagonal negative corners this separates the negative
//! corners, a choice that depends only on the face's four signs, so two cells sharing a face
//! always cut it the same way and the surface has no cracks. Every crossed edge then has one
//! segment arriving and one leaving (its two faces traverse it in opposite directions), so the
//! segments chain into closed loops, which are triangulated as fans. Loops inherit the faces'
//! orientation, so all triangles wind the same way; the orientation is fixed once so that
//! triangles are counter-clockwise seen from the non-negative side.

use std::sync::OnceLock;

/// Corner `c` of a cell sits at `(c & 1, (c >> 1) & 1, (c >> 2) & 1)`.
/// Edge `e` joins corners `EDGES[e].0 < EDGES[e].1`, which differ along axis `e / 4`.
pub(crate) const EDGES: [(u8, u8); 12] = build_edges();

const fn build_edges() -> [(u8, u8); 12] {
    let mut edges = [(0u8, 0u8); 12];
    let mut n = 0;
    let mut axis = 0;
    while axis < 3 {
        let bit = 1u8 << axis;
        let mut c = 0u8;
        while c < 8 {
            if c & bit == 0 {
                edges[n] = (c, c | bit);
                n += 1;
            }
            c += 1;
        }
        axis += 1;
    }
    edges
}

/// Triangles per case, as cell edge indices.
pub(crate) struct CaseTable {
    /// `offsets[case]..offsets[case + 1]` indexes `triangles`.
    offsets: [u16; 257],
    triangles: Vec<[u8; 3]>,
}

impl CaseTable {
    /// The triangles of `case` (bit `c` set when corner `c` is negative).
    #[inline]
    pub(crate) fn triangles(&self, case: u8) -> &[[u8; 3]] {
        let c = case as usize;
        &self.triangles[self.offsets[c] as usize..self.offsets[c + 1] as usize]
    }
}

/// The table, built on first use.
pub(crate) fn case_table() -> &'static CaseTable {
    static TABLE: OnceLock<CaseTable> = OnceLock::new();
    TABLE.get_or_init(build_table)
}

fn edge_between(a: u8, b: u8) -> usize {
    let (a, b) = if a < b { (a, b) } else { (b, a) };
    EDGES.iter().position(|&e| e == (a, b)).unwrap_or(usize::MAX)
}

/// The six faces, corners counter-clockwise seen from outside the cell.
fn faces() -> Vec<[u8; 4]> {
    let mut faces = Vec::with_capacity(6);
    for axis in 0..3 {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        for side in 0..2u8 {
            let corner = |a: u8, b: u8| (side << axis) | (a << u) | (b << v);
            // Counter-clockwise about +axis because e_u x e_v = e_axis.
            let mut f = [corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1)];
            if side == 0 {
                f.reverse();
            }
            faces.push(f);
        }
    }
    faces
}

/// Closed loops of crossed edges for one case.
fn case_loops(case: u8, faces: &[[u8; 4]]) -> Vec<Vec<usize>> {
    let negative = |c: u8| (case >> c) & 1 == 1;
    let mut next = [usize::MAX; 12];
    for f in faces {
        // (edge, is_entry) in boundary order.
        let mut crossings = Vec::with_capacity(4);
        for k in 0..4 {
            let (a, b) = (f[k], f[(k + 1) % 4]);
            if negative(a) != negative(b) {
                crossings.push((edge_between(a, b), negative(b)));
            }
        }
        let n = crossings.len();
        for j in 0..n {
            let (entry, is_entry) = crossings[j];
            if is_entry {
                let (exit, _) = crossings[(j + 1) % n];
                next[exit] = entry;
            }
        }
    }
    let mut seen = [false; 12];
    let mut loops = Vec::new();
    for start in 0..12 {
        if next[start] == usize::MAX || seen[start] {
            continue;
        }
        let mut lp = Vec::new();
        let mut e = start;
        while !seen[e] {
            seen[e] = true;
            lp.push(e);
            e = next[e];
        }
        loops.push(lp);
    }
    loops
}

fn build_table() -> CaseTable {
    let faces = faces();
    let mut per_case: Vec<Vec<[u8; 3]>> = (0..=255u8)
        .map(|case| {
            let mut tris = Vec::new();
            for lp in case_loops(case, &faces) {
                for i in 1..lp.len().saturating_sub(1) {
                    tris.push([lp[0] as u8, lp[i] as u8, lp[i + 1] as u8]);
                }
            }
            tris
        })
        .collect();
    // Orient: in case 1 only corner 0 is negative; its triangle must face away from it.
    let mid = |e: u8| {
        let (a, b) = EDGES[e as usize];
        let p = |c: u8| [(c & 1) as f32, ((c >> 1) & 1) as f32, ((c >> 2) & 1) as f32];
        let (pa, pb) = (p(a), p(b));
        [(pa[0] + pb[0]) / 2.0, (pa[1] + pb[1]) / 2.0, (pa[2] + pb[2]) / 2.0]
    };
    let [a, b, c] = per_case[1][0].map(mid);
    let (u, v) = ([b[0] - a[0], b[1] - a[1], b[2] - a[2]], [c[0] - a[0], c[1] - a[1], c[2] - a[2]]);
    let n = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
    if n[0] + n[1] + n[2] < 0.0 {
        for tris in &mut per_case {
            for t in tris.iter_mut() {
                t.swap(1, 2);
            }
        }
    }
    let mut offsets = [0u16; 257];
    let mut triangles = Vec::new();
    for (case, tris) in per_case.iter().enumerate() {
        triangles.extend_from_slice(tris);
        offsets[case + 1] = triangles.len() as u16;
    }
    CaseTable { offsets, triangles }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn edges_join_neighbouring_corners() {
        for (e, &(a, b)) in EDGES.iter().enumerate() {
            assert_eq!(b - a, 1 << (e / 4), "edge {e}");
            assert_eq!(a & (1 << (e / 4)), 0);
        }
    }

    #[test]
    fn every_case_uses_exactly_the_crossed_edges_and_complements_mirror() {
        let t = case_table();
        assert!(t.triangles(0).is_empty() && t.triangles(255).is_empty());
        let mut max = 0;
        for case in 0..=255u8 {
            let crossed: Vec<usize> = (0..12)
                .filter(|&e| {
                    let (a, b) = EDGES[e];
                    ((case >> a) & 1) != ((case >> b) & 1)
                })
                .collect();
            let mut used: Vec<usize> = t.triangles(case).iter().flatten().map(|&e| e as usize).collect();
            used.sort_unstable();
            used.dedup();
            assert_eq!(used, crossed, "case {case}");
            max = max.max(t.triangles(case).len());
            // Inside each case the directed edges of the triangles cancel except along the
            // cell faces: every interior edge is used once in each direction.
            let mut directed = std::collections::HashMap::new();
            for tri in t.triangles(case) {
                for k in 0..3 {
                    *directed.entry((tri[k], tri[(k + 1) % 3])).or_insert(0i32) += 1;
                }
            }
            for (&(a, b), &n) in &directed {
                let back = directed.get(&(b, a)).copied().unwrap_or(0);
                assert!(n == 1 && back <= 1, "case {case}: edge {a}->{b} used {n} times");
            }
        }
        assert!(max <= 12, "at most {max} triangles per cell");
    }
}
