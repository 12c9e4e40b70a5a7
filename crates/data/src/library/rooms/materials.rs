//! The shell and its materials: the floor covering (planks, laminate, tiles with grout,
//! carpet, plain), the ceiling, walls (painted, sometimes an accent wall, or another finish:
//! [`super::wall_finish`]), tiles on the lower
//! walls of bathrooms and some kitchens, skirting boards; and the light baked into every
//! colour once the room is furnished (darker in corners, brighter near windows and lamps,
//! a white balance per room).

use glam::Vec3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::wall_finish::{along_wall, draw_finishes};
use super::{Home, HomeRoomKind, ModelSource};
use crate::class::SemanticClass;
use crate::synth::palette::{jitter, jitter_pick, pick, uniform};
use crate::synth::shapes::{splitmix, MeshBuilder, Rgb, SKIP_NEG_Y};
use crate::synth::shell;

impl<'a, S: ModelSource + ?Sized> Home<'a, S> {
    /// Floor, ceiling, walls with their holes, skirting; returns the number of shell
    /// vertices (they get the material patterns).
    pub(super) fn build_shell(&mut self) -> usize {
        let (w, d, h) = (self.layout.width, self.layout.depth, self.layout.height);
        let kind = self.kind;
        let rng = &mut self.rng;
        let b = &mut self.b;
        b.place(Vec3::ZERO, 0.0);
        // Floor.
        let floor = FloorMaterial::draw(rng, kind);
        floor.build(b, rng, w, d);
        // Ceiling: white mostly.
        let ceiling = if rng.random_bool(0.85) {
            jitter(rng, [0.93, 0.93, 0.91], 0.03)
        } else {
            jitter_pick(rng, &[[0.85, 0.83, 0.78], [0.80, 0.82, 0.84]], 0.03)
        };
        b.set_noise(0.02);
        b.rect(Vec3::Z * h, Vec3::X * w, Vec3::Y * d, -Vec3::Z, SemanticClass::Ceiling, ceiling);
        // Walls: one paint, sometimes an accent wall.
        let paint = wall_paint(rng);
        let accent = if rng.random_bool(0.2) {
            let k = rng.random_range(0..4);
            Some((k, wall_paint(rng)))
        } else {
            None
        };
        b.set_noise(0.025);
        let finishes = draw_finishes(&mut self.finish_rng, kind, h);
        for (k, finish) in finishes.iter().enumerate() {
            let color = match accent {
                Some((a, c)) if a == k => c,
                _ => paint,
            };
            let first = b.mesh.positions.len();
            let patch = finish.patch().map(|p| b.set_patch(p));
            shell::wall_with_openings(b, &self.layout, k, &self.openings, color);
            if let Some(p) = patch {
                b.set_patch(p);
            }
            let wall = self.layout.walls[k];
            let m = &mut b.mesh;
            for i in first..m.positions.len() {
                let p = m.positions[i];
                let s = along_wall(wall.start, wall.dir, p.truncate());
                let hash =
                    splitmix(((p * 1000.0).round().as_i64vec3().dot(glam::I64Vec3::new(1, 1 << 20, 1 << 40))) as u64);
                if let Some(c) = finish.color_at(s, p.z, hash) {
                    m.colors[i] = to_u8(c);
                }
            }
        }
        let shell_end = b.mesh.positions.len();
        // Tiles on the lower walls of bathrooms and some kitchens.
        let tiles = match kind {
            HomeRoomKind::Bathroom => rng.random_bool(0.8),
            HomeRoomKind::Kitchen => rng.random_bool(0.3),
            _ => false,
        };
        if tiles {
            let band = if kind == HomeRoomKind::Bathroom { uniform(rng, 1.2, h) } else { uniform(rng, 1.4, 1.7) };
            let t = uniform(rng, 0.1, 0.3);
            let tile = pick(
                rng,
                &[[0.93, 0.93, 0.92], [0.85, 0.88, 0.90], [0.80, 0.85, 0.82], [0.75, 0.72, 0.68], [0.35, 0.45, 0.55]],
            );
            let tile = jitter(rng, tile, 0.04);
            let seed: u64 = rng.random();
            let m = &mut b.mesh;
            for i in 0..shell_end {
                if m.vertex_labels[i] != SemanticClass::Wall.id() || m.positions[i].z > band {
                    continue;
                }
                let p = m.positions[i];
                let along = if m.normals[i].x.abs() > 0.5 { p.y } else { p.x };
                let cell = splitmix(
                    seed ^ ((along / t).floor() as i64 as u64).wrapping_mul(31)
                        ^ ((p.z / t).floor() as i64 as u64) << 20,
                );
                let c = scale_rgb(tile, 1.0 + 0.08 * (unit(cell) - 0.5));
                m.colors[i] = to_u8(c);
            }
        }
        // Skirting boards along the walls, except across door openings.
        if kind != HomeRoomKind::Bathroom && rng.random_bool(0.75) {
            let sk_h = uniform(rng, 0.05, 0.1);
            let sk_t = uniform(rng, 0.01, 0.02);
            let sk_c =
                if rng.random_bool(0.6) { jitter(rng, [0.92, 0.92, 0.9], 0.03) } else { scale_rgb(floor.base, 0.8) };
            b.set_noise(0.02);
            for k in 0..4 {
                let wall = self.layout.walls[k];
                let mut cuts: Vec<(f32, f32)> = self
                    .openings
                    .iter()
                    .filter(|o| o.wall == k && o.z0 < sk_h)
                    .map(|o| (o.s0 - 0.1, o.s1 + 0.1))
                    .collect();
                cuts.sort_by(|a, b| a.0.total_cmp(&b.0));
                let mut s = 0.0;
                b.place(wall.start.extend(0.0), wall.yaw);
                for (a, c) in cuts.into_iter().chain(std::iter::once((wall.length, wall.length))) {
                    if a - s > 0.05 {
                        b.cuboid(
                            Vec3::new(s, 0.0, 0.0),
                            Vec3::new(a, sk_t, sk_h),
                            SKIP_NEG_Y,
                            SemanticClass::Wall,
                            sk_c,
                        );
                    }
                    s = s.max(c);
                }
            }
        }
        b.set_noise(0.06);
        shell_end
    }

    /// Bakes slow light variation into every colour: darker towards corners and the
    /// ceiling edges and away from windows and lamps, with a white balance per room.
    pub(super) fn bake_light(&mut self, _shell_end: usize) {
        let (w, d, h) = (self.layout.width, self.layout.depth, self.layout.height);
        let exposure = uniform(&mut self.rng, 0.85, 1.08);
        let warm = uniform(&mut self.rng, -0.05, 0.06);
        let balance = [1.0 + warm, 1.0, 1.0 - warm];
        let lights = self.lights.clone();
        let m = &mut self.b.mesh;
        for (p, c) in m.positions.iter().zip(m.colors.iter_mut()) {
            let dx = p.x.min(w - p.x).max(0.0);
            let dy = p.y.min(d - p.y).max(0.0);
            let dz_c = (h - p.z).max(0.0);
            let corner = 0.14 * (-(dx + dy) / 0.35).exp()
                + 0.08 * (-(dx.min(dy) + dz_c) / 0.3).exp()
                + 0.06 * (-(dx.min(dy) + p.z) / 0.25).exp();
            let mut lit = 0.0f32;
            for l in &lights {
                lit = lit.max((-(*p - *l).length() / 3.0).exp());
            }
            let f = exposure * (0.8 + 0.25 * lit) * (1.0 - corner);
            for k in 0..3 {
                c[k] = (c[k] as f32 * f * balance[k]).round().clamp(0.0, 255.0) as u8;
            }
        }
    }
}

/// A floor covering.
struct FloorMaterial {
    kind: FloorKind,
    base: Rgb,
}

#[derive(Clone, Copy, PartialEq)]
enum FloorKind {
    Planks,
    Laminate,
    Tiles,
    Carpet,
    Plain,
}

impl FloorMaterial {
    fn draw(rng: &mut ChaCha8Rng, kind: HomeRoomKind) -> Self {
        use FloorKind::*;
        let options: &[FloorKind] = match kind {
            HomeRoomKind::Bathroom => &[Tiles, Tiles, Tiles, Tiles, Plain],
            HomeRoomKind::Kitchen => &[Tiles, Tiles, Tiles, Laminate, Planks, Plain],
            HomeRoomKind::Bedroom => &[Planks, Planks, Laminate, Carpet, Carpet],
            HomeRoomKind::LivingRoom | HomeRoomKind::Studio => &[Planks, Planks, Laminate, Tiles, Carpet],
            HomeRoomKind::Office | HomeRoomKind::Conference => &[Carpet, Carpet, Laminate, Plain, Tiles],
            HomeRoomKind::Corridor => &[Tiles, Planks, Laminate, Plain, Carpet],
        };
        let fk = pick(rng, options);
        let base = match fk {
            Planks | Laminate => jitter_pick(
                rng,
                &[[0.72, 0.55, 0.36], [0.58, 0.40, 0.24], [0.42, 0.28, 0.17], [0.80, 0.68, 0.50], [0.62, 0.55, 0.48]],
                0.05,
            ),
            Tiles => jitter_pick(
                rng,
                &[[0.85, 0.84, 0.80], [0.62, 0.62, 0.60], [0.75, 0.68, 0.58], [0.35, 0.35, 0.37], [0.55, 0.42, 0.32]],
                0.05,
            ),
            Carpet => jitter_pick(
                rng,
                &[[0.45, 0.45, 0.47], [0.30, 0.32, 0.40], [0.55, 0.50, 0.42], [0.35, 0.30, 0.28], [0.62, 0.60, 0.55]],
                0.05,
            ),
            Plain => jitter_pick(rng, &[[0.60, 0.60, 0.58], [0.70, 0.68, 0.64], [0.48, 0.50, 0.52]], 0.05),
        };
        Self { kind: fk, base }
    }

    /// Emits the floor rectangle `[0, w] x [0, d]` (z = 0, facing up) in this material:
    /// planks and tiles as separate pieces with their own tone, grout between tiles.
    fn build(&self, b: &mut MeshBuilder, rng: &mut ChaCha8Rng, w: f32, d: f32) {
        let class = SemanticClass::Floor;
        match self.kind {
            FloorKind::Planks | FloorKind::Laminate => {
                let laminate = self.kind == FloorKind::Laminate;
                let along_x = rng.random_bool(0.5);
                let (len_u, len_v) = if along_x { (w, d) } else { (d, w) };
                let pw = if laminate { uniform(rng, 0.18, 0.22) } else { uniform(rng, 0.1, 0.2) };
                let pl = if laminate { uniform(rng, 1.2, 1.4) } else { uniform(rng, 0.6, 1.6) };
                let var = if laminate { 0.06 } else { 0.14 };
                b.set_noise(if laminate { 0.02 } else { 0.04 });
                let mut v = 0.0;
                while v < len_v - 1e-4 {
                    let v1 = (v + pw).min(len_v);
                    let mut u = -uniform(rng, 0.0, pl);
                    while u < len_u - 1e-4 {
                        let this = if laminate { pl } else { pl * uniform(rng, 0.6, 1.4) };
                        let (u0, u1) = (u.max(0.0), (u + this).min(len_u));
                        let tone = 1.0 + var * (rng.random::<f32>() * 2.0 - 1.0);
                        let mut c = scale_rgb(self.base, tone);
                        c[0] = (c[0] + uniform(rng, -0.02, 0.02)).clamp(0.0, 1.0);
                        let (corner, du, dv) = if along_x {
                            (Vec3::new(u0, v, 0.0), Vec3::X * (u1 - u0), Vec3::Y * (v1 - v))
                        } else {
                            (Vec3::new(v, u0, 0.0), Vec3::Y * (u1 - u0), Vec3::X * (v1 - v))
                        };
                        if u1 - u0 > 1e-3 {
                            b.rect(corner, du, dv, Vec3::Z, class, c);
                        }
                        u += this;
                    }
                    v = v1;
                }
            }
            FloorKind::Tiles => {
                let t = uniform(rng, 0.3, 0.6);
                let g = 0.008;
                let checker = rng.random_bool(0.15);
                let second = jitter(rng, scale_rgb(self.base, 0.6), 0.05);
                let grout = jitter(rng, scale_rgb(self.base, 0.72), 0.04);
                b.set_noise(0.02);
                let (nx, ny) = ((w / t).ceil() as usize, (d / t).ceil() as usize);
                for j in 0..ny {
                    let (y0, y1) = (j as f32 * t, ((j + 1) as f32 * t).min(d));
                    for i in 0..nx {
                        let (x0, x1) = (i as f32 * t, ((i + 1) as f32 * t).min(w));
                        let base = if checker && (i + j) % 2 == 1 { second } else { self.base };
                        let c = scale_rgb(base, 1.0 + uniform(rng, -0.04, 0.04));
                        // The tile, inset by half the grout on inner edges; the grout strips fill the rest.
                        let a0 = if i > 0 { x0 + g * 0.5 } else { x0 };
                        let a1 = if x1 < w { x1 - g * 0.5 } else { x1 };
                        let c0 = if j > 0 { y0 + g * 0.5 } else { y0 };
                        let c1 = if y1 < d { y1 - g * 0.5 } else { y1 };
                        if a1 - a0 > 1e-3 && c1 - c0 > 1e-3 {
                            b.rect(Vec3::new(a0, c0, 0.0), Vec3::X * (a1 - a0), Vec3::Y * (c1 - c0), Vec3::Z, class, c);
                        }
                        // Grout to the right of this tile and above it.
                        if x1 < w {
                            b.rect(Vec3::new(a1, c0, 0.0), Vec3::X * g, Vec3::Y * (c1 - c0), Vec3::Z, class, grout);
                        }
                        if y1 < d {
                            let e1 = if x1 < w { x1 + g * 0.5 } else { x1 };
                            b.rect(Vec3::new(a0, c1, 0.0), Vec3::X * (e1 - a0), Vec3::Y * g, Vec3::Z, class, grout);
                        }
                    }
                }
            }
            FloorKind::Carpet => {
                b.set_noise(0.09);
                b.rect(Vec3::ZERO, Vec3::X * w, Vec3::Y * d, Vec3::Z, class, self.base);
            }
            FloorKind::Plain => {
                b.set_noise(0.05);
                b.rect(Vec3::ZERO, Vec3::X * w, Vec3::Y * d, Vec3::Z, class, self.base);
            }
        }
        b.set_noise(0.06);
    }
}

/// A wall paint: white or off-white most of the time, a pastel sometimes, a colour rarely.
fn wall_paint(rng: &mut ChaCha8Rng) -> Rgb {
    match rng.random_range(0..10) {
        0..=5 => jitter_pick(
            rng,
            &[[0.93, 0.93, 0.91], [0.90, 0.88, 0.83], [0.88, 0.86, 0.80], [0.91, 0.91, 0.93], [0.84, 0.83, 0.80]],
            0.03,
        ),
        6..=8 => jitter_pick(
            rng,
            &[
                [0.86, 0.82, 0.70],
                [0.78, 0.86, 0.84],
                [0.84, 0.80, 0.86],
                [0.88, 0.80, 0.74],
                [0.80, 0.84, 0.74],
                [0.76, 0.80, 0.86],
            ],
            0.04,
        ),
        _ => jitter_pick(
            rng,
            &[[0.45, 0.55, 0.62], [0.60, 0.35, 0.30], [0.35, 0.45, 0.38], [0.70, 0.60, 0.35], [0.40, 0.40, 0.45]],
            0.05,
        ),
    }
}

fn scale_rgb(c: Rgb, f: f32) -> Rgb {
    c.map(|x| (x * f).clamp(0.0, 1.0))
}

pub(super) fn to_u8(c: Rgb) -> [u8; 3] {
    c.map(|x| (x.clamp(0.0, 1.0) * 255.0).round() as u8)
}

fn unit(bits: u64) -> f32 {
    (bits & 0xFFFF) as f32 / 65535.0
}
