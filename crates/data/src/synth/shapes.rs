//! Mesh builders for the synthetic rooms: tessellated rectangles (with rectangular holes, for
//! walls around windows and doors), boxes, cylinders and cones, ellipsoids. Every shape is
//! written in an object's local frame and placed by a z rotation plus a translation, so
//! furniture is modelled once, facing local +y, and turned to face the room.
//!
//! Large faces are split into patches no bigger than the builder's patch size: later
//! per-vertex labelling and colour variation need vertices every few decimetres, not only at
//! the corners of a 6 m wall. Winding is fixed from an explicit "front" direction, so every
//! triangle is counter-clockwise seen from outside an object (or from inside the room for the
//! shell) whatever order the corners were listed in.

use glam::{Affine3A, Quat, Vec2, Vec3};

use crate::class::SemanticClass;
use crate::mesh::LabeledMesh;

/// sRGB colour with channels in 0..1 (before per-vertex variation and quantisation).
pub(crate) type Rgb = [f32; 3];

/// Faces of a box to leave out (hidden against a wall, the floor or another part), as a bit
/// set of the `SKIP_*` constants.
pub(crate) type Faces = u8;
/// Leave out the face at min x.
pub(crate) const SKIP_NEG_X: Faces = 1;
/// Leave out the face at max x.
pub(crate) const SKIP_POS_X: Faces = 2;
/// Leave out the face at min y.
pub(crate) const SKIP_NEG_Y: Faces = 4;
/// Leave out the face at max y.
pub(crate) const SKIP_POS_Y: Faces = 8;
/// Leave out the face at min z.
pub(crate) const SKIP_NEG_Z: Faces = 16;
/// Leave out the face at max z.
pub(crate) const SKIP_POS_Z: Faces = 32;

/// Smallest triangle area (m²) the builder emits; smaller ones are dropped as degenerate.
pub(crate) const MIN_TRIANGLE_AREA: f32 = 1e-8;

/// Accumulates a [`LabeledMesh`] (positions, colours, normals, vertex and triangle labels).
pub(crate) struct MeshBuilder {
    pub(crate) mesh: LabeledMesh,
    world_from_local: Affine3A,
    patch: f32,
    noise_seed: u64,
    noise_amplitude: f32,
}

/// A placement saved by [`MeshBuilder::push`], restored by [`MeshBuilder::pop`].
pub(crate) struct SavedPlacement(Affine3A);

impl MeshBuilder {
    /// Sets the largest edge of a tessellation cell (metres) for what is emitted next;
    /// returns the previous one.
    pub(crate) fn set_patch(&mut self, patch: f32) -> f32 {
        std::mem::replace(&mut self.patch, patch)
    }

    /// Empty builder; `patch` is the largest edge of a tessellation cell (metres),
    /// `noise_seed` makes the per-vertex colour variation differ between rooms.
    pub(crate) fn new(patch: f32, noise_seed: u64) -> Self {
        Self {
            mesh: LabeledMesh::default(),
            world_from_local: Affine3A::IDENTITY,
            patch,
            noise_seed,
            noise_amplitude: 0.06,
        }
    }

    /// Sets the local frame of the next shapes: rotated by `yaw` about z, origin at `origin`.
    pub(crate) fn place(&mut self, origin: Vec3, yaw: f32) {
        self.world_from_local = world_from_object(origin, yaw);
    }

    /// [`place`](Self::place) with the origin on the floor.
    pub(crate) fn place_on_floor(&mut self, center: Vec2, yaw: f32) {
        self.place(center.extend(0.0), yaw);
    }

    /// Composes a sub-frame (offset and yaw in the current local frame) onto the current
    /// frame; returns the previous frame for [`pop`](Self::pop).
    pub(crate) fn push(&mut self, offset: Vec3, yaw: f32) -> SavedPlacement {
        let saved = SavedPlacement(self.world_from_local);
        self.world_from_local *= world_from_object(offset, yaw);
        saved
    }

    /// Restores a frame saved by [`push`](Self::push).
    pub(crate) fn pop(&mut self, saved: SavedPlacement) {
        self.world_from_local = saved.0;
    }

    /// Sets the strength of the per-vertex brightness variation (0.06 by default): matte
    /// fabric and plaster vary more than glass.
    pub(crate) fn set_noise(&mut self, amplitude: f32) {
        self.noise_amplitude = amplitude;
    }

    fn vertex(&mut self, p_local: Vec3, n_local: Vec3, class: SemanticClass, color: Rgb) -> u32 {
        let p = self.world_from_local.transform_point3(p_local);
        let n = self.world_from_local.transform_vector3(n_local).normalize_or_zero();
        let index = self.mesh.positions.len() as u32;
        self.mesh.positions.push(p);
        self.mesh.normals.push(n);
        self.mesh.colors.push(vary(color, p, self.noise_seed, self.noise_amplitude));
        self.mesh.vertex_labels.push(class.id());
        index
    }

    /// Emits triangle `a b c`, flipped if needed so that it faces `front_world`.
    fn triangle(&mut self, a: u32, b: u32, c: u32, front_world: Vec3, class: SemanticClass) {
        let [pa, pb, pc] = [a, b, c].map(|i| self.mesh.positions[i as usize]);
        let n = (pb - pa).cross(pc - pa);
        if n.length() * 0.5 < MIN_TRIANGLE_AREA {
            return;
        }
        let tri = if n.dot(front_world) >= 0.0 { [a, b, c] } else { [a, c, b] };
        self.mesh.triangles.push(tri);
        self.mesh.triangle_labels.push(class.id());
    }

    fn quad(&mut self, v: [u32; 4], front_world: Vec3, class: SemanticClass) {
        self.triangle(v[0], v[1], v[2], front_world, class);
        self.triangle(v[0], v[2], v[3], front_world, class);
    }

    /// Planar rectangle `corner + a*u + b*v` (a, b in 0..1) facing `front` (local frame),
    /// tessellated into patches.
    pub(crate) fn rect(&mut self, corner: Vec3, u: Vec3, v: Vec3, front: Vec3, class: SemanticClass, color: Rgb) {
        self.rect_with_holes(corner, u, v, front, &[], class, color);
    }

    /// Like [`rect`](Self::rect) with rectangular holes, each `[s0, s1, t0, t1]` in metres
    /// along `u` and `v` from `corner`. Hole edges become tessellation lines, so the cut is
    /// exact.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn rect_with_holes(
        &mut self,
        corner: Vec3,
        u: Vec3,
        v: Vec3,
        front: Vec3,
        holes: &[[f32; 4]],
        class: SemanticClass,
        color: Rgb,
    ) {
        let (lu, lv) = (u.length(), v.length());
        if lu < 1e-5 || lv < 1e-5 {
            return;
        }
        let (du, dv) = (u / lu, v / lv);
        let su = breakpoints(lu, holes.iter().flat_map(|h| [h[0], h[1]]), self.patch);
        let sv = breakpoints(lv, holes.iter().flat_map(|h| [h[2], h[3]]), self.patch);
        let normal = front.normalize_or_zero();
        let front_world = self.world_from_local.transform_vector3(normal);
        let mut ids: Vec<Option<u32>> = vec![None; su.len() * sv.len()];
        for j in 0..sv.len() - 1 {
            for i in 0..su.len() - 1 {
                let (cu, cv) = ((su[i] + su[i + 1]) * 0.5, (sv[j] + sv[j + 1]) * 0.5);
                if holes.iter().any(|h| cu > h[0] && cu < h[1] && cv > h[2] && cv < h[3]) {
                    continue;
                }
                let mut corners = [0u32; 4];
                for (k, (ii, jj)) in [(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)].into_iter().enumerate() {
                    let slot = jj * su.len() + ii;
                    corners[k] = match ids[slot] {
                        Some(id) => id,
                        None => {
                            let p = corner + du * su[ii] + dv * sv[jj];
                            let id = self.vertex(p, normal, class, color);
                            ids[slot] = Some(id);
                            id
                        }
                    };
                }
                self.quad(corners, front_world, class);
            }
        }
    }

    /// Axis-aligned box (local frame) with outward faces, minus the faces in `skip`. The
    /// bottom face is left out automatically when it rests on the floor.
    pub(crate) fn cuboid(&mut self, min: Vec3, max: Vec3, skip: Faces, class: SemanticClass, color: Rgb) {
        let e = max - min;
        let mut skip = skip;
        if self.world_from_local.transform_point3(min).z.abs() < 1e-4 {
            skip |= SKIP_NEG_Z;
        }
        let faces: [(Faces, Vec3, Vec3, Vec3, Vec3); 6] = [
            (SKIP_NEG_X, min, Vec3::Y * e.y, Vec3::Z * e.z, -Vec3::X),
            (SKIP_POS_X, Vec3::new(max.x, min.y, min.z), Vec3::Y * e.y, Vec3::Z * e.z, Vec3::X),
            (SKIP_NEG_Y, min, Vec3::X * e.x, Vec3::Z * e.z, -Vec3::Y),
            (SKIP_POS_Y, Vec3::new(min.x, max.y, min.z), Vec3::X * e.x, Vec3::Z * e.z, Vec3::Y),
            (SKIP_NEG_Z, min, Vec3::X * e.x, Vec3::Y * e.y, -Vec3::Z),
            (SKIP_POS_Z, Vec3::new(min.x, min.y, max.z), Vec3::X * e.x, Vec3::Y * e.y, Vec3::Z),
        ];
        for (bit, corner, u, v, n) in faces {
            if skip & bit == 0 {
                self.rect(corner, u, v, n, class, color);
            }
        }
    }

    /// Cylinder or cone frustum around the local z axis through `base` (bottom centre):
    /// radius `r0` at the bottom, `r1` at `base.z + height`, `segments` around, with
    /// optional bottom and top caps (a zero radius end needs no cap).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn frustum(
        &mut self,
        base: Vec3,
        height: f32,
        r0: f32,
        r1: f32,
        segments: usize,
        caps: (bool, bool),
        class: SemanticClass,
        color: Rgb,
    ) {
        let segments = segments.max(3);
        let rows = ((height / self.patch).ceil() as usize).max(1);
        let ring = |k: usize| {
            let a = std::f32::consts::TAU * k as f32 / segments as f32;
            Vec2::new(a.cos(), a.sin())
        };
        let slope = (r0 - r1) / height.max(1e-6);
        let mut grid = Vec::with_capacity((rows + 1) * segments);
        for row in 0..=rows {
            let f = row as f32 / rows as f32;
            let r = r0 + (r1 - r0) * f;
            for k in 0..segments {
                let d = ring(k);
                let p = base + (d * r).extend(height * f);
                let n = d.extend(slope).normalize_or_zero();
                grid.push(self.vertex(p, n, class, color));
            }
        }
        for row in 0..rows {
            for k in 0..segments {
                let k1 = (k + 1) % segments;
                let mid = (ring(k) + ring(k1)).normalize_or_zero().extend(slope);
                let front = self.world_from_local.transform_vector3(mid);
                let v = [
                    grid[row * segments + k],
                    grid[row * segments + k1],
                    grid[(row + 1) * segments + k1],
                    grid[(row + 1) * segments + k],
                ];
                self.quad(v, front, class);
            }
        }
        for (wanted, z, r, n) in [(caps.0, 0.0, r0, -Vec3::Z), (caps.1, height, r1, Vec3::Z)] {
            if !wanted || r < 1e-4 {
                continue;
            }
            let front = self.world_from_local.transform_vector3(n);
            let c = self.vertex(base + Vec3::Z * z, n, class, color);
            let rim: Vec<u32> =
                (0..segments).map(|k| self.vertex(base + (ring(k) * r).extend(z), n, class, color)).collect();
            for k in 0..segments {
                self.triangle(c, rim[k], rim[(k + 1) % segments], front, class);
            }
        }
    }

    /// Closed ellipsoid with semi-axes `radii` around `center` (local frame).
    pub(crate) fn ellipsoid(
        &mut self,
        center: Vec3,
        radii: Vec3,
        segments: usize,
        rings: usize,
        class: SemanticClass,
        color: Rgb,
    ) {
        let (segments, rings) = (segments.max(3), rings.max(2));
        let point = |ring: usize, k: usize| {
            let theta = std::f32::consts::PI * ring as f32 / rings as f32;
            let phi = std::f32::consts::TAU * k as f32 / segments as f32;
            Vec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos())
        };
        let top = self.vertex(center + Vec3::Z * radii.z, Vec3::Z, class, color);
        let bottom = self.vertex(center - Vec3::Z * radii.z, -Vec3::Z, class, color);
        let mut grid = Vec::with_capacity((rings - 1) * segments);
        for ring in 1..rings {
            for k in 0..segments {
                let d = point(ring, k);
                let n = (d / radii).normalize_or_zero();
                grid.push(self.vertex(center + d * radii, n, class, color));
            }
        }
        let center_world = self.world_from_local.transform_point3(center);
        let outward = |mesh: &LabeledMesh, ids: &[u32]| {
            let c: Vec3 = ids.iter().map(|&i| mesh.positions[i as usize]).sum::<Vec3>() / ids.len() as f32;
            c - center_world
        };
        for k in 0..segments {
            let k1 = (k + 1) % segments;
            let (a, b) = (grid[k], grid[k1]);
            let f = outward(&self.mesh, &[top, a, b]);
            self.triangle(top, a, b, f, class);
            let last = (rings - 2) * segments;
            let (a, b) = (grid[last + k], grid[last + k1]);
            let f = outward(&self.mesh, &[bottom, a, b]);
            self.triangle(bottom, a, b, f, class);
            for ring in 0..rings - 2 {
                let v = [
                    grid[ring * segments + k],
                    grid[ring * segments + k1],
                    grid[(ring + 1) * segments + k1],
                    grid[(ring + 1) * segments + k],
                ];
                let f = outward(&self.mesh, &v);
                self.quad(v, f, class);
            }
        }
    }

    /// The finished mesh.
    pub(crate) fn finish(self) -> LabeledMesh {
        self.mesh
    }
}

/// `world_from_object` for an object turned by `yaw` about z with its origin at `origin`.
/// Quarter turns are built exactly so that furniture against walls stays axis-aligned to the
/// last bit.
pub(crate) fn world_from_object(origin: Vec3, yaw: f32) -> Affine3A {
    let quarter = yaw / std::f32::consts::FRAC_PI_2;
    let rotation = if (quarter - quarter.round()).abs() < 1e-6 {
        let (s, c) = match (quarter.round() as i64).rem_euclid(4) {
            0 => (0.0, 1.0),
            1 => (1.0, 0.0),
            2 => (0.0, -1.0),
            _ => (-1.0, 0.0),
        };
        glam::Mat3A::from_cols(Vec3::new(c, s, 0.0).into(), Vec3::new(-s, c, 0.0).into(), glam::Vec3A::Z)
    } else {
        glam::Mat3A::from_quat(Quat::from_rotation_z(yaw))
    };
    Affine3A { matrix3: rotation, translation: origin.into() }
}

/// Sorted tessellation coordinates on `[0, length]`: the ends, the hole edges, and enough
/// points between them that no cell is longer than `patch`. Near-duplicates are merged so
/// that no cell is degenerate.
fn breakpoints(length: f32, cuts: impl Iterator<Item = f32>, patch: f32) -> Vec<f32> {
    let mut edges: Vec<f32> =
        std::iter::once(0.0).chain(cuts.filter(|c| *c > 0.0 && *c < length)).chain(std::iter::once(length)).collect();
    edges.sort_by(f32::total_cmp);
    edges.dedup_by(|a, b| (*a - *b).abs() < 1e-3);
    if let Some(last) = edges.last_mut() {
        *last = length;
    }
    let mut out = vec![0.0];
    for w in edges.windows(2) {
        let n = ((w[1] - w[0]) / patch).ceil().max(1.0) as usize;
        for k in 1..=n {
            out.push(w[0] + (w[1] - w[0]) * k as f32 / n as f32);
        }
    }
    out
}

/// Deterministic per-vertex colour variation: a brightness and tint change hashed from the
/// vertex position (so coincident vertices of neighbouring parts agree) and the room seed.
fn vary(color: Rgb, p: Vec3, seed: u64, amplitude: f32) -> [u8; 3] {
    let q = (p * 1000.0).round();
    let mut h = seed ^ 0x9E37_79B9_7F4A_7C15;
    for c in [q.x, q.y, q.z] {
        h = splitmix((h ^ (c as i64 as u64)).wrapping_add(0x632B_E59B_D9B4_E019));
    }
    let unit = |bits: u64| (bits & 0xFFFF) as f32 / 65535.0 - 0.5;
    let brightness = 1.0 + 2.0 * amplitude * unit(h);
    let mut out = [0u8; 3];
    for (k, o) in out.iter_mut().enumerate() {
        let tint = 0.5 * amplitude * unit(h >> (16 * (k + 1)));
        *o = ((color[k] * brightness + tint).clamp(0.0, 1.0) * 255.0).round() as u8;
    }
    out
}

/// SplitMix64 finaliser: a cheap, well-mixed 64-bit hash step.
pub(crate) fn splitmix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn signed_volume(m: &LabeledMesh) -> f32 {
        m.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| m.positions[i as usize]);
                a.dot(b.cross(c)) / 6.0
            })
            .sum()
    }

    #[test]
    fn closed_shapes_face_outward_with_the_right_volume() {
        let mut b = MeshBuilder::new(0.3, 1);
        b.place(Vec3::new(1.0, 2.0, 0.5), 0.7);
        b.cuboid(Vec3::new(-0.5, -0.25, 0.0), Vec3::new(0.5, 0.25, 1.0), 0, SemanticClass::Table, [0.5; 3]);
        let v = signed_volume(&b.mesh);
        assert!((v - 0.5).abs() < 1e-4, "box volume {v}");

        let mut b = MeshBuilder::new(0.3, 1);
        b.place(Vec3::new(-1.0, 0.0, 0.2), 0.0);
        b.frustum(Vec3::ZERO, 1.0, 0.5, 0.5, 64, (true, true), SemanticClass::Column, [0.5; 3]);
        let v = signed_volume(&b.mesh);
        assert!((v - std::f32::consts::PI * 0.25).abs() < 0.01, "cylinder volume {v}");

        let mut b = MeshBuilder::new(0.3, 1);
        b.ellipsoid(Vec3::new(0.0, 0.0, 2.0), Vec3::splat(1.0), 48, 24, SemanticClass::Clutter, [0.5; 3]);
        let v = signed_volume(&b.mesh);
        assert!((v - 4.0 / 3.0 * std::f32::consts::PI).abs() < 0.1, "sphere volume {v}");
    }

    #[test]
    fn holes_are_cut_exactly_and_patches_are_small() {
        let mut b = MeshBuilder::new(0.5, 1);
        b.rect_with_holes(
            Vec3::ZERO,
            Vec3::X * 4.0,
            Vec3::Z * 3.0,
            -Vec3::Y,
            &[[1.0, 2.0, 0.0, 2.1], [2.5, 3.5, 0.9, 2.0]],
            SemanticClass::Wall,
            [0.8; 3],
        );
        let area: f32 = b
            .mesh
            .triangles
            .iter()
            .map(|t| {
                let [p, q, r] = t.map(|i| b.mesh.positions[i as usize]);
                let n = (q - p).cross(r - p);
                assert!(n.dot(-Vec3::Y) > 0.0, "winding");
                for (x, y) in [(p, q), (q, r), (r, p)] {
                    assert!((x - y).length() <= 0.5 * std::f32::consts::SQRT_2 + 1e-4);
                }
                n.length() * 0.5
            })
            .sum();
        assert!((area - (12.0 - 2.1 - 1.1)).abs() < 1e-4, "area {area}");
    }

    #[test]
    fn quarter_turns_are_exact() {
        let m = world_from_object(Vec3::new(3.0, 0.0, 0.0), std::f32::consts::FRAC_PI_2);
        assert_eq!(m.transform_point3(Vec3::X), Vec3::new(3.0, 1.0, 0.0));
    }
}
