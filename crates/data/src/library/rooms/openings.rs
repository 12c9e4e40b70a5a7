//! Doors and windows: where they go for the room kind (doors along a corridor, a small
//! window high up in a bathroom), cut into the walls before the shell is built, then
//! filled with a catalogue door or window where one fits and a procedural one elsewhere.
//! Windows are the main light sources of the baked shading.

use glam::Vec3;
use rand::Rng;

use super::categories::is;
use super::pieces::yaw_facing;
use super::placement::ALL_WALLS;
use super::{Home, HomeRoomKind, ModelSource};
use crate::class::SemanticClass;
use crate::synth::layout::footprint;
use crate::synth::palette::{jitter, uniform};
use crate::synth::shell::{self, OpeningKind};

/// Share of doors that stand open.
const OPEN_DOOR_SHARE: f64 = 0.35;

impl<'a, S: ModelSource + ?Sized> Home<'a, S> {
    /// Doors and windows for the kind, catalogue models where they fit.
    pub(super) fn plan_openings(&mut self) {
        let (w, d, h) = (self.layout.width, self.layout.depth, self.layout.height);
        let long = if w >= d { [0usize, 2] } else { [1, 3] };
        let short = if w >= d { [1usize, 3] } else { [0, 2] };
        let (door_walls, n_doors): (Vec<usize>, usize) = match self.kind {
            HomeRoomKind::Corridor => (long.to_vec(), self.rng.random_range(2..=5)),
            HomeRoomKind::LivingRoom | HomeRoomKind::Office | HomeRoomKind::Conference => {
                (ALL_WALLS.to_vec(), self.rng.random_range(1..=2))
            }
            _ => (ALL_WALLS.to_vec(), 1),
        };
        let mut doors = 0;
        let mut tries = 0;
        while (doors < n_doors && tries < 100) || (doors == 0 && tries < 300) {
            tries += 1;
            let k = door_walls[self.rng.random_range(0..door_walls.len())];
            let len = self.layout.walls[k].length;
            let double =
                matches!(self.kind, HomeRoomKind::LivingRoom | HomeRoomKind::Conference) && self.rng.random_bool(0.25);
            let model = if self.rng.random_bool(0.75) {
                self.piece(|m| {
                    m.door_or_window
                        && is(m, &["door"])
                        && m.size.z >= 1.9
                        && m.size.z <= (h - 0.15).min(2.5)
                        && m.size.x >= 0.6
                        && m.size.x <= if double { 1.9 } else { 1.15 }
                })
            } else {
                None
            };
            let (dw, dh) = match &model {
                Some(p) => (p.size.x, p.size.z),
                None => {
                    let dw = if double { uniform(&mut self.rng, 1.4, 1.7) } else { uniform(&mut self.rng, 0.8, 0.95) };
                    (dw, uniform(&mut self.rng, 2.0, 2.15).min(h - 0.15))
                }
            };
            if len < dw + 0.7 {
                continue;
            }
            let s = uniform(&mut self.rng, 0.3 + dw * 0.5, len - 0.3 - dw * 0.5);
            let recess = uniform(&mut self.rng, 0.03, 0.07);
            if shell::try_add_opening(
                &mut self.layout,
                &mut self.openings,
                k,
                s,
                dw,
                0.0,
                dh,
                OpeningKind::Door,
                recess,
            ) {
                let wall = self.layout.walls[k];
                self.layout.add_keepout(footprint(wall.point(s, 0.45), dw + 0.2, 0.9, wall.yaw));
                self.opening_models.push(model);
                doors += 1;
            }
        }
        // Windows.
        let (outside, wanted, small): (Vec<usize>, usize, bool) = match self.kind {
            HomeRoomKind::Corridor => (vec![short[self.rng.random_range(0..2)]], self.rng.random_range(0..=1), false),
            HomeRoomKind::Bathroom => (ALL_WALLS.to_vec(), self.rng.random_range(0..=1), true),
            _ => {
                let first = self.rng.random_range(0..4);
                let walls = if self.rng.random_bool(0.35) { vec![first, (first + 1) % 4] } else { vec![first] };
                (walls, self.rng.random_range(1..=3), false)
            }
        };
        let mut windows = 0;
        let mut tries = 0;
        while windows < wanted && tries < 80 {
            tries += 1;
            let k = outside[self.rng.random_range(0..outside.len())];
            let len = self.layout.walls[k].length;
            let model = if self.rng.random_bool(0.7) {
                self.piece(|m| {
                    m.door_or_window
                        && is(m, &["window"])
                        && m.size.x >= 0.45
                        && m.size.x <= len - 0.8
                        && m.size.z >= 0.5
                        && m.size.y >= 0.05
                        && m.elevation + m.size.z <= h - 0.15
                        && (!small || (m.size.x <= 1.1 && m.size.z <= 1.4))
                })
            } else {
                None
            };
            let (ww, z0, z1) = match &model {
                Some(p) => {
                    let z0 = if p.elevation > 0.05 { p.elevation } else { 0.9 };
                    let z0 = z0.min(h - 0.15 - p.size.z);
                    (p.size.x, z0, z0 + p.size.z)
                }
                None if small => {
                    let z0 = uniform(&mut self.rng, 1.2, 1.5);
                    (uniform(&mut self.rng, 0.5, 0.9), z0, (z0 + uniform(&mut self.rng, 0.5, 0.8)).min(h - 0.2))
                }
                None => {
                    let z0 = uniform(&mut self.rng, 0.6, 1.0);
                    (uniform(&mut self.rng, 0.8, 1.8), z0, uniform(&mut self.rng, 2.0, 2.3).min(h - 0.2))
                }
            };
            if ww > len - 0.8 || z1 - z0 < 0.4 {
                continue;
            }
            let s = uniform(&mut self.rng, 0.4 + ww * 0.5, len - 0.4 - ww * 0.5);
            let recess = uniform(&mut self.rng, 0.08, 0.2);
            if shell::try_add_opening(
                &mut self.layout,
                &mut self.openings,
                k,
                s,
                ww,
                z0,
                z1,
                OpeningKind::Window,
                recess,
            ) {
                self.opening_models.push(model);
                let wall = self.layout.walls[k];
                self.lights.push(wall.point(s, 0.0).extend((z0 + z1) * 0.5));
                windows += 1;
            }
        }
    }

    /// Catalogue doors and windows in their openings, the procedural ones elsewhere; some
    /// doors open ([`shell::open_door`]).
    pub(super) fn fill_openings(&mut self) {
        let openings = self.openings.clone();
        let models = std::mem::take(&mut self.opening_models);
        for (o, model) in openings.iter().zip(models) {
            let wall = self.layout.walls[o.wall];
            // A third of the doors stand open (their own random stream: see `extras_rng`).
            if o.kind == OpeningKind::Door && self.extras_rng.random_bool(OPEN_DOOR_SHARE) {
                self.b.place(wall.start.extend(0.0), wall.yaw);
                shell::open_door(&mut self.b, o, &mut self.extras_rng, &self.pal, self.layout.height);
                continue;
            }
            match model {
                Some(p) => {
                    let s = (o.s0 + o.s1) * 0.5;
                    let depth = p.size.y.min(0.35);
                    let scale = Vec3::new((o.s1 - o.s0) / p.size.x, depth / p.size.y, (o.z1 - o.z0) / p.size.z);
                    // The model's front at the wall plane, its body in the wall behind it.
                    let center = wall.point(s, -depth * 0.5);
                    self.emit(&p, center, o.z0, yaw_facing(wall.normal), scale);
                    // A backing behind it: glass, or a closed leaf, for what the model leaves open.
                    let (class, color) = match o.kind {
                        OpeningKind::Window => (SemanticClass::Window, jitter(&mut self.rng, self.pal.glass, 0.05)),
                        OpeningKind::Door => (SemanticClass::Door, jitter(&mut self.rng, self.pal.door, 0.05)),
                    };
                    self.b.place(wall.start.extend(0.0), wall.yaw);
                    self.b.set_noise(0.03);
                    self.b.rect(
                        Vec3::new(o.s0, -depth - 0.01, o.z0),
                        Vec3::X * (o.s1 - o.s0),
                        Vec3::Z * (o.z1 - o.z0),
                        Vec3::Y,
                        class,
                        color,
                    );
                    // Reveals between the wall plane and the backing where the model is thinner.
                    self.b.set_noise(0.06);
                }
                None => {
                    self.b.place(wall.start.extend(0.0), wall.yaw);
                    match o.kind {
                        OpeningKind::Window => shell::window(&mut self.b, o, &mut self.rng, &self.pal),
                        OpeningKind::Door => shell::door(&mut self.b, o, &mut self.rng, &self.pal),
                    }
                }
            }
        }
    }
}
