//! Beam faces: the vertical face of a beam or bulkhead takes the class of the beam's underside.
//!
//! A bulkhead (a boxed beam along the ceiling) shows two kinds of surface: a horizontal
//! underside, high above the floor with open air below it, and vertical faces that rise from
//! the underside's edge to the ceiling. The network tells the underside apart (no wall is
//! horizontal at 2.2 m), but a face alone looks like the strip of wall above a doorway, and it
//! calls the face wall; S3DIS labels it beam. Geometry separates the two. A segment labelled
//! wall is a beam's face when
//! - it is vertical, and most of its lower edge (at least `min_contact_voxels` voxels, and
//!   `min_contact_share` of the edge) touches horizontal beam segments high above the room's
//!   lowest voxel, or faces already converted in its own plane: a face rises from the
//!   underside along the beam's length, where a wall piece above a beam's end is as short as
//!   the beam is wide;
//! - it reaches no lower than that underside;
//! - no wall of its own plane goes on below it within `walk_levels` under its lower edge: a
//!   wall hidden behind a bulkhead (a generated room samples it) is the top of the wall
//!   below, while a real face has open air under it.
//!
//! The rule runs after the segment vote on whole segments, in rounds (a round decides from
//! the previous round's faces, so the visiting order does not matter). It was designed on the
//! one labelled real room we have (the S3DIS fragment, whose bulkhead face was the last class
//! under 50 % IoU), so that room no longer measures it independently; on every generated and
//! unlabelled real set it changes nothing or almost nothing (docs/model.md, "Beam faces").

use glam::Vec3;

use super::neighbours::NO_NEIGHBOUR;

/// What [`beam_faces`] treats as vertical and horizontal, and how far below the underside a
/// face may reach.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BeamFaceParams {
    /// A segment is vertical when the mean `|n_z|` of its voxels' normals is below this.
    pub vertical_max_nz: f32,
    /// A segment is horizontal when the mean `|n_z|` is above this.
    pub horizontal_min_nz: f32,
    /// A face may reach this many voxel levels below the underside's lowest level (the
    /// corner voxels along the edge belong to either).
    pub below_levels: i32,
    /// The underside must be at least this high above the room's lowest voxel (metres): a
    /// table top is not a beam.
    pub min_underside_height_m: f32,
    /// Two vertical segments are one face when the cosine of their doubled horizontal normal
    /// angles is at least this (0.64: within about 25 degrees).
    pub coplanar_min_cos: f32,
    /// A segment rests on another when at least this share of the voxels along its lower edge
    /// touch the other: a face rises from its underside's edge along its whole
    /// length, while the strip of wall under a ceiling touches a beam only where the beam
    /// meets the wall.
    pub min_contact_share: f32,
    /// ... and at least this many of them: a beam's face runs along the beam, while the piece
    /// of wall where a beam's end meets a wall is as short as the beam is wide.
    pub min_contact_voxels: u32,
    /// How far (voxel levels) below a face's lower edge a wall of the same plane makes the
    /// face that wall's top: the strip of a wall hidden behind a bulkhead is cut from the wall
    /// below by the underside's own voxels, a beam's face has open air under it.
    pub walk_levels: usize,
}

impl Default for BeamFaceParams {
    fn default() -> Self {
        Self {
            vertical_max_nz: 0.35,
            horizontal_min_nz: 0.8,
            below_levels: 1,
            min_underside_height_m: 1.8,
            coplanar_min_cos: 0.64,
            min_contact_share: 0.5,
            min_contact_voxels: 16,
            walk_levels: 6,
        }
    }
}

/// The first nine of the 26 neighbour offsets lie one level below the voxel
/// ([`super::NEIGHBOUR_OFFSETS`] is ordered by `dz` first).
const BELOW: usize = 9;
/// The neighbour straight below, `(0, 0, -1)`, among them.
const STRAIGHT_DOWN: usize = 4;

/// Per-segment figures that the rule reads.
#[derive(Debug, Clone, Copy)]
struct SegmentShape {
    voxels: u32,
    sum_abs_nz: f32,
    z_min: i32,
    class: u8,
    /// The mean over the voxels of the horizontal normal's doubled angle
    /// `(n_x^2 - n_y^2, 2 n_x n_y)`, normalised: the same for a normal and its opposite, so
    /// two faces of one plane agree whatever sign PCA gave their normals.
    facing: glam::Vec2,
}

/// Relabels, in place, the wall segments that are faces of a beam (the module's rule) as
/// beam, and returns the number of voxels changed.
///
/// # Shapes
/// `coords`, `neighbours`, `normals`, `segment`, `labels`: `[n]`; coordinates are voxel
/// indices with z (index 2) up.
#[allow(clippy::too_many_arguments)]
pub fn beam_faces(
    coords: &[semrecon_sparse::Coord],
    neighbours: &[[u32; 26]],
    normals: &[Vec3],
    segment: &[u32],
    labels: &mut [u8],
    voxel_size: f32,
    wall: u8,
    beam: u8,
    params: &BeamFaceParams,
) -> usize {
    let n = coords.len();
    if n == 0 {
        return 0;
    }
    let m = segment.iter().map(|&s| s as usize + 1).max().unwrap_or(0);
    let mut shapes =
        vec![SegmentShape { voxels: 0, sum_abs_nz: 0.0, z_min: i32::MAX, class: 0, facing: glam::Vec2::ZERO }; m];
    for i in 0..n {
        let s = &mut shapes[segment[i] as usize];
        s.voxels += 1;
        s.sum_abs_nz += normals[i].z.abs();
        s.z_min = s.z_min.min(coords[i][2]);
        // After the vote every member holds its segment's class.
        s.class = labels[i];
        let (x, y) = (normals[i].x, normals[i].y);
        s.facing += glam::Vec2::new(x * x - y * y, 2.0 * x * y);
    }
    for s in &mut shapes {
        s.facing = s.facing.normalize_or_zero();
    }
    let mean_nz = |s: &SegmentShape| s.sum_abs_nz / s.voxels.max(1) as f32;
    let room_z0 = coords.iter().map(|c| c[2]).min().unwrap_or(0);
    let min_levels = (params.min_underside_height_m / voxel_size).floor() as i32;
    let underside =
        |s: &SegmentShape| s.class == beam && mean_nz(s) > params.horizontal_min_nz && s.z_min - room_z0 >= min_levels;
    let face = |s: &SegmentShape| s.class == wall && mean_nz(s) < params.vertical_max_nz;

    // The voxels of each segment's lower edge: no voxel of its own among the nine below.
    let lower_edge: Vec<bool> = (0..n)
        .map(|i| !neighbours[i][..BELOW].iter().any(|&j| j != NO_NEIGHBOUR && segment[j as usize] == segment[i]))
        .collect();
    let mut edge = vec![0u32; m];
    for i in 0..n {
        edge[segment[i] as usize] += u32::from(lower_edge[i]);
    }

    // `support[s]`: the level of the underside that segment `s` belongs to or rises from
    // (the undersides first, then the faces converted in earlier rounds).
    let mut support: Vec<Option<i32>> = shapes.iter().map(|s| underside(s).then_some(s.z_min)).collect();
    loop {
        // For every candidate face: its lower-edge voxels that touch a support, the lowest
        // support level touched, and whether it touches an underside or a converted face in
        // its own plane. Sums and minima: the same whatever the visiting order.
        let mut contact = vec![0u32; m];
        let mut level = vec![i32::MAX; m];
        let mut anchored = vec![false; m];
        let mut wall_below = vec![i32::MAX; m];
        for i in 0..n {
            let f = segment[i] as usize;
            if !lower_edge[i] || support[f].is_some() || !face(&shapes[f]) {
                continue;
            }
            let mut touched = false;
            for &j in &neighbours[i] {
                if j == NO_NEIGHBOUR {
                    continue;
                }
                let g = segment[j as usize] as usize;
                let Some(z) = support[g] else { continue };
                let same_plane = shapes[f].facing.dot(shapes[g].facing) >= params.coplanar_min_cos;
                touched = true;
                level[f] = level[f].min(z);
                anchored[f] |= underside(&shapes[g]) || same_plane;
            }
            contact[f] += u32::from(touched);
            // Down from the lower edge through the surface (straight down where a voxel is
            // there, else the first of the nine below): a wall of the same plane met within
            // `walk_levels` is this wall's lower part.
            let mut j = i;
            for _ in 0..params.walk_levels {
                let below = &neighbours[j][..BELOW];
                let next = [STRAIGHT_DOWN].into_iter().chain(0..BELOW).map(|b| below[b]).find(|&k| k != NO_NEIGHBOUR);
                let Some(k) = next else { break };
                j = k as usize;
                let g = segment[j] as usize;
                if g != f
                    && face(&shapes[g])
                    && support[g].is_none()
                    && shapes[f].facing.dot(shapes[g].facing) >= params.coplanar_min_cos
                {
                    wall_below[f] = wall_below[f].min(shapes[g].z_min);
                }
            }
        }
        let mut grew = false;
        for f in 0..m {
            let rests = contact[f] >= params.min_contact_voxels
                && contact[f] as f32 >= params.min_contact_share * edge[f] as f32;
            // A wall of the same plane that goes on below the underside makes this one the
            // top of that wall (the strip behind a bulkhead), whatever rests on what.
            let continues = wall_below[f] < level[f] - params.below_levels;
            if rests && anchored[f] && !continues && shapes[f].z_min >= level[f] - params.below_levels {
                support[f] = Some(level[f]);
                grew = true;
            }
        }
        if !grew {
            break;
        }
    }
    // Supports of class wall are the converted faces (undersides are beam).
    let converted: Vec<bool> = (0..m).map(|f| support[f].is_some() && shapes[f].class == wall).collect();
    let mut changed = 0;
    for i in 0..n {
        if converted[segment[i] as usize] {
            labels[i] = beam;
            changed += 1;
        }
    }
    changed
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::structure::{voxel_neighbours, voxel_normals};
    use semrecon_sparse::Coord;

    const WALL: u8 = 2;
    const BEAM: u8 = 3;
    const CEILING: u8 = 0;

    /// A room corner with a bulkhead, as voxels, with hand-made segments and classes:
    /// 0 the floor (z = 0), 1 a wall at x = 0 from the floor to the top (z = 60), 2 the
    /// bulkhead's underside (z = 44, x 1..=10), 3 and 4 its face at x = 10 (z 45..=52 and
    /// 53..=60, cut in two as a colour change cuts a real face), 5 a wall at y = 0 beside the
    /// face (x 11..=20, z 53..=60): high and touching the face, but in another plane.
    fn bulkhead(underside_class: u8) -> (Vec<Coord>, Vec<u32>, Vec<u8>) {
        let mut coords = Vec::new();
        let mut segment = Vec::new();
        let mut labels = Vec::new();
        let mut put = |c: Coord, s: u32, l: u8| {
            coords.push(c);
            segment.push(s);
            labels.push(l);
        };
        for y in 1..40 {
            for x in 0..40 {
                put([x, y, 0, 0], 0, 1);
            }
            for z in 1..=60 {
                put([0, y, z, 0], 1, WALL);
            }
            for x in 1..=10 {
                put([x, y, 44, 0], 2, underside_class);
            }
            for z in 45..=60 {
                put([10, y, z, 0], if z <= 52 { 3 } else { 4 }, WALL);
            }
        }
        for x in 11..=20 {
            for z in 53..=60 {
                put([x, 0, z, 0], 5, WALL);
            }
        }
        (coords, segment, labels)
    }

    /// [`beam_faces`] at 5 cm on hand-made segments, normals from the voxels.
    fn apply(coords: &[Coord], segment: &[u32], labels: &mut [u8], params: &BeamFaceParams) -> usize {
        let neighbours = voxel_neighbours(coords);
        let normals = voxel_normals(coords, &neighbours);
        beam_faces(coords, &neighbours, &normals, segment, labels, 0.05, WALL, BEAM, params)
    }

    fn run(underside_class: u8) -> (Vec<u32>, Vec<u8>, usize) {
        let (coords, segment, mut labels) = bulkhead(underside_class);
        let changed = apply(&coords, &segment, &mut labels, &BeamFaceParams::default());
        (segment, labels, changed)
    }

    #[test]
    fn a_face_that_rises_from_a_beam_underside_is_beam_and_walls_that_reach_the_floor_are_not() {
        let (segment, labels, changed) = run(BEAM);
        let class_of = |s: u32| {
            let mut classes: Vec<u8> = segment.iter().zip(&labels).filter(|(&g, _)| g == s).map(|(_, &l)| l).collect();
            classes.dedup();
            classes
        };
        assert_eq!(class_of(0), vec![1], "floor");
        assert_eq!(class_of(1), vec![WALL], "the wall reaches the floor");
        assert_eq!(class_of(2), vec![BEAM], "underside");
        assert_eq!(class_of(3), vec![BEAM], "the face's lower part touches the underside");
        assert_eq!(class_of(4), vec![BEAM], "the face's upper part is in the same plane");
        assert_eq!(class_of(5), vec![WALL], "a perpendicular wall is not the face");
        assert_eq!(changed, segment.iter().filter(|&&s| s == 3 || s == 4).count());
    }

    #[test]
    fn the_short_piece_of_wall_above_a_beam_end_stays_wall() {
        // A wall at y = 0 cut into its lower part (segment 0, from the floor) and the piece
        // above a cross beam's end (segment 1, x 10..=15, z 51..=60); the beam's underside
        // (segment 2, z = 50) runs across the room from that wall.
        let mut coords = Vec::new();
        let mut segment = Vec::new();
        for x in 0..40 {
            for z in 1..=60 {
                let piece = (10..=15).contains(&x) && z > 50;
                coords.push([x, 0, z, 0]);
                segment.push(u32::from(piece));
            }
        }
        for x in 10..=15 {
            for y in 1..30 {
                coords.push([x, y, 50, 0]);
                segment.push(2);
            }
        }
        let mut labels: Vec<u8> = segment.iter().map(|&s| if s == 2 { BEAM } else { WALL }).collect();
        let before = labels.clone();
        assert_eq!(apply(&coords, &segment, &mut labels, &BeamFaceParams::default()), 0);
        assert_eq!(labels, before);
    }

    #[test]
    fn the_wall_hidden_behind_a_bulkhead_is_the_top_of_its_wall() {
        // A generated room samples the wall behind a bulkhead: the wall at x = 0 is cut at
        // the underside's level into its lower part (segment 0, from the floor, z 1..=43), a
        // band along the underside (segment 1, z 44..=45, where the normals bend) and the
        // hidden strip (segment 3, z 46..=60); the underside (segment 2, z = 44, x 1..=10)
        // runs along it. The strip rests on the underside along its whole length, but its
        // wall goes on below it: it stays wall.
        let mut coords = Vec::new();
        let mut segment = Vec::new();
        for y in 0..40 {
            for z in 1..=60 {
                coords.push([0, y, z, 0]);
                segment.push(match z {
                    ..=43 => 0,
                    44..=45 => 1,
                    _ => 3,
                });
            }
            for x in 1..=10 {
                coords.push([x, y, 44, 0]);
                segment.push(2);
            }
        }
        let mut labels: Vec<u8> = segment.iter().map(|&s| if s == 2 { BEAM } else { WALL }).collect();
        let before = labels.clone();
        let params = BeamFaceParams::default();
        assert_eq!(apply(&coords, &segment, &mut labels, &params), 0);
        assert_eq!(labels, before);
        // Without the walk down, the strip would be taken for a face.
        let blind = BeamFaceParams { walk_levels: 0, ..params };
        let changed = apply(&coords, &segment, &mut labels, &blind);
        assert!(changed > 0);
    }

    #[test]
    fn without_a_beam_underside_nothing_changes() {
        let before = bulkhead(CEILING).2;
        let (_, labels, changed) = run(CEILING);
        assert_eq!(changed, 0);
        assert_eq!(labels, before);
    }
}
