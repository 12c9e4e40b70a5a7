//! Floor and ceiling from gravity: with z up, the heights of the voxels whose normals are near
//! vertical pile up at the floor and the ceiling. [`find_planes`] takes the lowest and the
//! highest big horizontal plane with (nearly) nothing beyond them, [`plane_corrections`] tells
//! per voxel whether it lies on one of them and whether its height rules out floor or ceiling,
//! and [`apply_corrections`] writes that into the class probabilities before the vote. Planes
//! that cover too small a share of the room's footprint (a partial scan) are not acted on.

use std::collections::BTreeMap;

use glam::Vec3;
use rayon::prelude::*;
use semrecon_data::SemanticClass;
use semrecon_sparse::Coord;

/// Parameters of the floor and ceiling planes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlaneParams {
    /// A voxel is horizontal when `|n_z|` of its normal is at least this.
    pub normal_z_min: f32,
    /// A plane is big when its horizontal voxels cover at least this many square metres...
    pub min_area_m2: f32,
    /// ...and at least this share of the room's footprint (occupied x-y columns).
    pub min_footprint_share: f32,
    /// At most this share of all voxels may lie below the floor (above the ceiling).
    pub max_share_beyond: f32,
    /// Half thickness of a plane in voxels: a plane at level `l` counts the horizontal
    /// voxels of levels `l - band ..= l + band` when its size is judged...
    pub band: i32,
    /// ...and holds those of the levels with at least this share of level `l`'s count.
    pub member_share: f32,
    /// A voxel labelled floor more than this above the floor (ceiling below the ceiling),
    /// in metres, takes its best other class.
    pub off_plane_m: f32,
    /// The ceiling is at least this high above the floor (metres); with only one of the two
    /// planes found, nothing closer than this to it takes the other's class.
    pub min_room_height_m: f32,
}

impl Default for PlaneParams {
    fn default() -> Self {
        Self {
            normal_z_min: 0.9,
            min_area_m2: 1.0,
            min_footprint_share: 0.2,
            max_share_beyond: 0.05,
            band: 1,
            member_share: 0.3,
            off_plane_m: 0.3,
            min_room_height_m: 2.0,
        }
    }
}

/// A horizontal plane: its fullest level and the levels around it that belong to it (voxel
/// levels along z).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Plane {
    /// The level with the most horizontal voxels.
    pub level: i32,
    /// Lowest level of the plane.
    pub lo: i32,
    /// Highest level of the plane.
    pub hi: i32,
}

/// The floor and ceiling planes.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Planes {
    /// The floor.
    pub floor: Option<Plane>,
    /// The ceiling.
    pub ceiling: Option<Plane>,
}

/// The floor and ceiling of a room with z up: among the levels (z coordinates) of the
/// horizontal voxels (`|n_z| >= normal_z_min`), a plane at level `l` counts the horizontal
/// voxels of levels `l - band ..= l + band`; it is big when they cover `min_area_m2` and
/// `min_footprint_share` of the footprint (the occupied x-y columns). The floor is the
/// lowest big plane if at most `max_share_beyond` of all voxels lie below it; the ceiling is
/// the highest big plane if it is at least `min_room_height_m` above the floor (with no
/// floor: above the lowest voxel) and at most `max_share_beyond` of the voxels lie above it.
/// A plane's level is the fullest of its band, and it spans the neighbouring levels (within
/// the band) that hold at least `member_share` as many horizontal voxels (a noisy or
/// half-voxel-offset floor spreads over two levels; a sofa's underside 5 cm above the floor
/// does not make the floor thicker).
///
/// # Shapes
/// `coords`, `normals`: `[n]`.
pub fn find_planes(coords: &[Coord], normals: &[Vec3], voxel_size: f32, params: &PlaneParams) -> Planes {
    let n = coords.len();
    if n == 0 {
        return Planes::default();
    }
    // Voxel counts per level, all and horizontal, indexed from the lowest level.
    let z0 = coords.iter().map(|c| c[2]).min().unwrap_or(0);
    let z1 = coords.iter().map(|c| c[2]).max().unwrap_or(0);
    let levels = (i64::from(z1) - i64::from(z0) + 1) as usize;
    let mut all_count = vec![0usize; levels];
    let mut horizontal_count = vec![0usize; levels];
    let mut columns: Vec<(i32, i32, i32)> = Vec::with_capacity(n);
    for (c, nrm) in coords.iter().zip(normals) {
        let l = (c[2] - z0) as usize;
        all_count[l] += 1;
        if nrm.z.abs() >= params.normal_z_min {
            horizontal_count[l] += 1;
        }
        columns.push((c[0], c[1], c[3]));
    }
    let all: BTreeMap<i32, usize> =
        all_count.iter().enumerate().filter(|(_, &c)| c > 0).map(|(l, &c)| (z0 + l as i32, c)).collect();
    let horizontal: BTreeMap<i32, usize> =
        horizontal_count.iter().enumerate().filter(|(_, &c)| c > 0).map(|(l, &c)| (z0 + l as i32, c)).collect();
    columns.par_sort_unstable();
    columns.dedup();
    let cell = f64::from(voxel_size) * f64::from(voxel_size);
    let need = (f64::from(params.min_area_m2)).max(f64::from(params.min_footprint_share) * columns.len() as f64 * cell);
    let band = params.band.max(0);
    let h = |l: i32| horizontal.get(&l).copied().unwrap_or(0);
    let band_count = |l: i32| (l - band..=l + band).map(h).sum::<usize>();
    let big = |l: i32| band_count(l) as f64 * cell >= need;
    let max_beyond = f64::from(params.max_share_beyond) * n as f64;
    let lowest = *all.keys().next().unwrap_or(&0);
    let room = (params.min_room_height_m / voxel_size).round() as i32;
    let plane_at = |peak: i32| {
        let member = |l: i32| h(l) as f64 >= f64::from(params.member_share) * h(peak) as f64;
        let mut lo = peak;
        while lo > peak - band && member(lo - 1) {
            lo -= 1;
        }
        let mut hi = peak;
        while hi < peak + band && member(hi + 1) {
            hi += 1;
        }
        Plane { level: peak, lo, hi }
    };

    let mut planes = Planes::default();
    if let Some(l) = horizontal.keys().copied().find(|&l| big(l)) {
        // The fullest level of the band (the lowest on ties).
        let peak = (l - band..=l + band).fold(l - band, |best, x| if h(x) > h(best) { x } else { best });
        let plane = plane_at(peak);
        let below = all.range(..plane.lo).map(|(_, &c)| c).sum::<usize>();
        if below as f64 <= max_beyond {
            planes.floor = Some(plane);
        }
    }
    if let Some(l) = horizontal.keys().rev().copied().find(|&l| big(l)) {
        let peak = (l - band..=l + band).rev().fold(l + band, |best, x| if h(x) > h(best) { x } else { best });
        let plane = plane_at(peak);
        let base = planes.floor.map_or(lowest, |f| f.level);
        let above = all.range(plane.hi + 1..).map(|(_, &c)| c).sum::<usize>();
        if peak - base >= room && above as f64 <= max_beyond {
            planes.ceiling = Some(plane);
        }
    }
    planes
}

/// Where a voxel lies with respect to the planes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlaneMember {
    /// On neither plane.
    No,
    /// A horizontal voxel within the floor's band.
    Floor,
    /// A horizontal voxel within the ceiling's band.
    Ceiling,
}

/// What the planes say about every voxel.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PlaneCorrections {
    /// Membership of each voxel.
    pub kind: Vec<PlaneMember>,
    /// The voxel cannot be floor: more than `off_plane_m` above the floor, or (without a
    /// floor) closer than `min_room_height_m` below the ceiling.
    pub no_floor: Vec<bool>,
    /// The voxel cannot be ceiling: more than `off_plane_m` below the ceiling, or (without a
    /// ceiling) closer than `min_room_height_m` above the floor.
    pub no_ceiling: Vec<bool>,
}

/// Plane membership and the classes ruled out by height, per voxel (see
/// [`PlaneCorrections`]).
///
/// # Shapes
/// `coords`, `normals`: `[n]`; result vectors `[n]`.
pub fn plane_corrections(
    coords: &[Coord],
    normals: &[Vec3],
    planes: &Planes,
    voxel_size: f32,
    params: &PlaneParams,
) -> PlaneCorrections {
    let off = (params.off_plane_m / voxel_size).round() as i32;
    let room = (params.min_room_height_m / voxel_size).round() as i32;
    let mut out = PlaneCorrections::default();
    for (c, nrm) in coords.iter().zip(normals) {
        let z = c[2];
        let horizontal = nrm.z.abs() >= params.normal_z_min;
        let on = |p: &Option<Plane>| p.is_some_and(|p| (p.lo..=p.hi).contains(&z));
        let kind = if horizontal && on(&planes.floor) {
            PlaneMember::Floor
        } else if horizontal && on(&planes.ceiling) {
            PlaneMember::Ceiling
        } else {
            PlaneMember::No
        };
        let no_floor = match (planes.floor, planes.ceiling) {
            (Some(f), _) => z > f.hi + off,
            (None, Some(cl)) => z > cl.level - room,
            (None, None) => false,
        };
        let no_ceiling = match (planes.ceiling, planes.floor) {
            (Some(cl), _) => z < cl.lo - off,
            (None, Some(f)) => z < f.level + room,
            (None, None) => false,
        };
        out.kind.push(kind);
        out.no_floor.push(no_floor);
        out.no_ceiling.push(no_ceiling);
    }
    out
}

/// Applies [`PlaneCorrections`] to probabilities: plane members become one-hot floor /
/// ceiling, classes ruled out at a voxel get probability 0 (the rest is left unnormalised).
pub(super) fn apply_corrections(probs: &mut [f32], k: usize, c: &PlaneCorrections) {
    let floor = SemanticClass::Floor.id() as usize;
    let ceiling = SemanticClass::Ceiling.id() as usize;
    for (i, row) in probs.chunks_exact_mut(k).enumerate() {
        match c.kind[i] {
            PlaneMember::Floor | PlaneMember::Ceiling => {
                let keep = if c.kind[i] == PlaneMember::Floor { floor } else { ceiling };
                row.iter_mut().enumerate().for_each(|(j, v)| *v = if j == keep { 1.0 } else { 0.0 });
            }
            PlaneMember::No => {
                if c.no_floor[i] {
                    row[floor] = 0.0;
                }
                if c.no_ceiling[i] {
                    row[ceiling] = 0.0;
                }
            }
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
pub(super) mod tests {
    use super::*;
    use crate::structure::{voxel_neighbours, voxel_normals};

    /// A synthetic room: a floor at level 0, a ceiling at level 50 (2.5 m at 5 cm), four
    /// walls and a table top at level 15.
    pub(in crate::structure) fn box_room() -> Vec<Coord> {
        let mut v = Vec::new();
        for x in 0..80 {
            for y in 0..60 {
                v.push([x, y, 0, 0]);
                v.push([x, y, 50, 0]);
            }
        }
        for z in 1..50 {
            for x in 0..80 {
                v.push([x, 0, z, 0]);
                v.push([x, 59, z, 0]);
            }
            for y in 1..59 {
                v.push([0, y, z, 0]);
                v.push([79, y, z, 0]);
            }
        }
        for x in 30..50 {
            for y in 20..36 {
                v.push([x, y, 15, 0]);
            }
        }
        v
    }

    #[test]
    fn planes_of_a_box_room_and_of_partial_scans() {
        let params = PlaneParams::default();
        let room = box_room();
        let normals = voxel_normals(&room, &voxel_neighbours(&room));
        let level = |p: Planes| (p.floor.map(|f| f.level), p.ceiling.map(|c| c.level));
        let planes = find_planes(&room, &normals, 0.05, &params);
        assert_eq!(level(planes), (Some(0), Some(50)));
        assert_eq!(planes.floor, Some(Plane { level: 0, lo: 0, hi: 0 }));
        // Without its ceiling: the floor alone; without the floor either: nothing (the table
        // top is too small a share of the footprint).
        let open: Vec<Coord> = room.iter().copied().filter(|c| c[2] < 50).collect();
        let normals = voxel_normals(&open, &voxel_neighbours(&open));
        assert_eq!(level(find_planes(&open, &normals, 0.05, &params)), (Some(0), None));
        let walls: Vec<Coord> = open.iter().copied().filter(|c| c[2] > 0).collect();
        let normals = voxel_normals(&walls, &voxel_neighbours(&walls));
        assert_eq!(find_planes(&walls, &normals, 0.05, &params), Planes::default());
        // A low "ceiling" 1 m above the floor is not one.
        let low: Vec<Coord> = room.iter().copied().filter(|c| c[2] <= 20).collect();
        let normals = voxel_normals(&low, &voxel_neighbours(&low));
        assert_eq!(find_planes(&low, &normals, 0.05, &params).ceiling, None);
    }

    #[test]
    fn plane_detection_finds_the_floor_of_a_generated_room_at_zero() {
        use semrecon_data::synth::{generate_room, RoomConfig};
        let room = generate_room(&RoomConfig { seed: 2_000_003, style: None });
        let cloud = crate::surface::sample_surface(&room.mesh, crate::dataset::points_per_m2(0.05), 0);
        let sample = crate::sample::VoxelSample::from_cloud(&cloud, 0.05).unwrap();
        let normals = voxel_normals(&sample.coords, &voxel_neighbours(&sample.coords));
        let planes = find_planes(&sample.coords, &normals, 0.05, &PlaneParams::default());
        let floor = planes.floor.expect("a floor").level;
        assert!((-1..=0).contains(&floor), "floor at level {floor}");
        let top = sample.coords.iter().map(|c| c[2]).max().unwrap();
        let ceiling = planes.ceiling.expect("a ceiling").level;
        assert!((top - 2..=top).contains(&ceiling), "ceiling at level {ceiling}, top {top}");
    }
}
