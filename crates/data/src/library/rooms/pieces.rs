//! The things a room is furnished with: a [`Piece`] is a catalogue model with its mesh, or
//! a procedural stand-in from [`crate::synth`] where the catalogues lack a kind of
//! furniture; a [`Placed`] is one in the room. Picking a model at random, loading it (and
//! measuring the surface on its top that things can stand on), and copying it into the
//! room's mesh: turned, moved, scaled, its colours varied ([`Paint`]), its labels kept,
//! within the room's triangle budget.

use std::f32::consts::PI;
use std::sync::Arc;

use glam::{Vec2, Vec3};
use rand::Rng;

use super::categories::is;
use super::materials::to_u8;
use super::{Home, HomeSpan, ModelSource, MAX_TRIANGLES};
use crate::class::UNLABELED;
use crate::home_class::{home_class_of_fine, HomeClass};
use crate::library::LibraryModel;
use crate::mesh::LabeledMesh;
use crate::synth::clutter::{self, FloorItem};
use crate::synth::furniture::{self, ChairStyle};
use crate::synth::palette::uniform;
use crate::synth::shapes::{world_from_object, Rgb};

/// A thing to place: a catalogue model with its mesh, or a procedural stand-in.
#[derive(Clone)]
pub(super) struct Piece<'a> {
    pub(super) src: Src<'a>,
    /// Unscaled size (x width, y depth, z height).
    pub(super) size: Vec3,
    /// Height of the surface things can stand on, above the piece's bottom (unscaled).
    pub(super) top: f32,
    /// Elevation of the bottom above the floor the catalogue gives.
    pub(super) elevation: f32,
    /// Upholstered: sometimes recoloured.
    fabric: bool,
}

/// Where a piece's geometry comes from.
#[derive(Clone)]
pub(super) enum Src<'a> {
    Model { model: &'a LibraryModel, mesh: Arc<LabeledMesh>, lo: Vec3 },
    Proc(Proc),
}

/// A procedural stand-in: which furniture of [`crate::synth`] it is.
#[derive(Clone, Copy)]
pub(super) enum Proc {
    Table,
    Desk,
    Chair(ChairStyle),
    Sofa,
    Bookcase,
    Cabinet,
    Plant,
    Lamp,
}

/// A piece in the room.
#[derive(Debug, Clone, Copy)]
pub(super) struct Placed {
    pub(super) center: Vec2,
    pub(super) yaw: f32,
    /// Scaled size.
    pub(super) size: Vec3,
    /// World z of the bottom.
    pub(super) z: f32,
    /// World z of the surface on top.
    pub(super) top: f32,
    /// Wall and position along it, when against a wall.
    pub(super) wall: Option<(usize, f32)>,
}

/// Yaw that turns a model's front (local -y) to face `dir`.
pub(super) fn yaw_facing(dir: Vec2) -> f32 {
    dir.x.atan2(-dir.y)
}

/// `v` turned by `yaw` about z.
pub(super) fn rot(v: Vec2, yaw: f32) -> Vec2 {
    Vec2::from_angle(yaw).rotate(v)
}

impl<'a, S: ModelSource + ?Sized> Home<'a, S> {
    fn pick(&mut self, pred: impl Fn(&LibraryModel) -> bool) -> Option<&'a LibraryModel> {
        let c: Vec<&'a LibraryModel> = self.pool.iter().copied().filter(|m| pred(m)).collect();
        if c.is_empty() {
            return None;
        }
        Some(c[self.rng.random_range(0..c.len())])
    }

    fn load(&self, model: &'a LibraryModel, fabric: bool) -> Option<Piece<'a>> {
        let mesh = self.lib.mesh(model).ok()?;
        let (lo, hi) = mesh.bounds()?;
        if !lo.is_finite() || !hi.is_finite() || mesh.triangles.is_empty() {
            return None;
        }
        let size = (hi - lo).max(Vec3::splat(0.002));
        let top = support_top(&mesh, lo, size);
        Some(Piece { src: Src::Model { model, mesh, lo }, size, top, elevation: model.elevation, fabric })
    }

    /// A random model satisfying `pred`, loaded.
    pub(super) fn piece(&mut self, pred: impl Fn(&LibraryModel) -> bool) -> Option<Piece<'a>> {
        let m = self.pick(pred)?;
        let fabric = is(m, &["sofa", "sofa_bed", "armchair", "chair", "bed"]);
        self.load(m, fabric)
    }

    pub(super) fn proc_piece(&mut self, kind: Proc) -> Piece<'a> {
        let rng = &mut self.rng;
        let size = match kind {
            Proc::Table => Vec3::new(uniform(rng, 1.2, 1.8), uniform(rng, 0.8, 0.95), furniture::table_height(rng)),
            Proc::Desk => Vec3::new(uniform(rng, 1.2, 1.6), uniform(rng, 0.6, 0.8), furniture::table_height(rng)),
            Proc::Chair(style) => Vec3::new(style.size, style.size, 0.9),
            Proc::Sofa => Vec3::new(uniform(rng, 1.6, 2.2), uniform(rng, 0.8, 0.95), 0.85),
            Proc::Bookcase => Vec3::new(uniform(rng, 0.7, 1.2), uniform(rng, 0.3, 0.4), uniform(rng, 1.0, 2.0)),
            Proc::Cabinet => Vec3::new(uniform(rng, 0.4, 0.9), uniform(rng, 0.45, 0.6), uniform(rng, 0.6, 1.1)),
            Proc::Plant => {
                let r = uniform(rng, 0.3, 0.55);
                Vec3::new(r, r, uniform(rng, 0.6, 1.5))
            }
            Proc::Lamp => {
                let r = uniform(rng, 0.3, 0.45);
                Vec3::new(r, r, uniform(rng, 1.4, 1.8))
            }
        };
        let top = match kind {
            Proc::Chair(_) | Proc::Sofa => 0.45,
            _ => size.z,
        };
        Piece { src: Src::Proc(kind), size, top, elevation: 0.0, fabric: false }
    }

    pub(super) fn chair_style(&mut self, swivel: bool) -> Proc {
        Proc::Chair(ChairStyle::draw(&mut self.rng, &self.pal, swivel))
    }

    /// A scale jitter for a catalogue piece: ±10 % half of the time.
    pub(super) fn scale_for(&mut self, p: &Piece) -> f32 {
        match p.src {
            Src::Model { .. } if self.rng.random_bool(0.5) => uniform(&mut self.rng, 0.9, 1.1),
            _ => 1.0,
        }
    }

    /// Appends the piece, its bottom-centre at `center` and height `z`, turned by `yaw`,
    /// scaled by `scale` (per axis). Returns false when over the triangle budget.
    pub(super) fn emit(&mut self, p: &Piece, center: Vec2, z: f32, yaw: f32, scale: Vec3) -> bool {
        match &p.src {
            Src::Model { model, mesh, lo } => {
                let src: &LabeledMesh = mesh;
                if self.b.mesh.triangles.len() + src.triangles.len() > MAX_TRIANGLES {
                    return false;
                }
                let xf = world_from_object(center.extend(z), yaw);
                let origin = Vec3::new(lo.x + p.size.x * 0.5, lo.y + p.size.y * 0.5, lo.z);
                let paint = self.paint(p.fabric);
                let class = model.class;
                let m = &mut self.b.mesh;
                let base = m.positions.len() as u32;
                let home = match home_class_of_fine(&model.fine) {
                    Some(mapping) => mapping.label(),
                    None => UNLABELED,
                };
                self.home_spans.push(HomeSpan {
                    vertices: base..base + src.positions.len() as u32,
                    label: home,
                    counter_top: model.fine == "kitchen_cabinet",
                });
                for (i, q) in src.positions.iter().enumerate() {
                    m.positions.push(xf.transform_point3((*q - origin) * scale));
                    m.colors.push(paint.apply(src.colors.get(i).copied().unwrap_or([180, 180, 180])));
                    m.vertex_labels.push(src.vertex_labels.get(i).copied().unwrap_or(class));
                    let n =
                        src.normals.get(i).map_or(Vec3::ZERO, |n| xf.transform_vector3(*n / scale).normalize_or_zero());
                    m.normals.push(n);
                }
                for (t, tri) in src.triangles.iter().enumerate() {
                    m.triangles.push(tri.map(|i| i + base));
                    m.triangle_labels.push(src.triangle_labels.get(t).copied().unwrap_or(class));
                }
                self.used.insert(model.id.clone());
                true
            }
            Src::Proc(kind) => {
                if self.b.mesh.triangles.len() > MAX_TRIANGLES {
                    return false;
                }
                let s = p.size * scale;
                let start = self.b.mesh.positions.len() as u32;
                // Procedural furniture faces local +y.
                self.b.place(center.extend(z), yaw + PI);
                let (b, rng, pal) = (&mut self.b, &mut self.rng, &self.pal);
                match *kind {
                    Proc::Table => {
                        furniture::table(b, rng, pal, s.x, s.y, s.z);
                    }
                    Proc::Desk => {
                        furniture::desk(b, rng, pal, s.x, s.y, s.z);
                    }
                    Proc::Chair(style) => furniture::chair(b, rng, &style),
                    Proc::Sofa => furniture::sofa(b, rng, pal, s.x, s.y),
                    Proc::Bookcase => furniture::bookcase(b, rng, pal, s.x, s.y, s.z),
                    Proc::Cabinet => clutter::floor_item(b, rng, pal, FloorItem::Cabinet, s.x, s.y, s.z),
                    Proc::Plant => clutter::floor_item(b, rng, pal, FloorItem::Plant, s.x, s.y, s.z),
                    Proc::Lamp => clutter::floor_item(b, rng, pal, FloorItem::Lamp, s.x, s.y, s.z),
                }
                let label = match *kind {
                    Proc::Table => HomeClass::Table.id(),
                    Proc::Desk => HomeClass::Desk.id(),
                    Proc::Chair(_) => HomeClass::Chair.id(),
                    Proc::Sofa => HomeClass::Sofa.id(),
                    Proc::Bookcase => HomeClass::Bookshelf.id(),
                    Proc::Cabinet => HomeClass::Cabinet.id(),
                    Proc::Plant | Proc::Lamp => UNLABELED,
                };
                let end = self.b.mesh.positions.len() as u32;
                self.home_spans.push(HomeSpan { vertices: start..end, label, counter_top: false });
                true
            }
        }
    }

    fn paint(&mut self, fabric: bool) -> Paint {
        let gain = uniform(&mut self.rng, 0.9, 1.1);
        let hue = (fabric && self.rng.random_bool(0.4))
            .then(|| (self.rng.random::<f32>(), uniform(&mut self.rng, 0.6, 1.8), uniform(&mut self.rng, 0.0, 0.25)));
        Paint { gain, hue }
    }
}

/// Colour change of one placed model: brightness, and optionally a new hue.
struct Paint {
    gain: f32,
    /// (new hue in turns, saturation factor, strength of the pull of grey towards it).
    hue: Option<(f32, f32, f32)>,
}

impl Paint {
    fn apply(&self, c: [u8; 3]) -> [u8; 3] {
        let rgb = c.map(|x| x as f32 / 255.0);
        let out = match self.hue {
            None => rgb,
            Some((hue, sat, pull)) => {
                let (_, s, v) = rgb_to_hsv(rgb);
                let s2 = (s * sat).max(pull).min(1.0);
                hsv_to_rgb(hue, s2, v)
            }
        };
        to_u8(out.map(|x| x * self.gain))
    }
}

pub(super) fn rgb_to_hsv(c: Rgb) -> (f32, f32, f32) {
    let (r, g, b) = (c[0], c[1], c[2]);
    let max = r.max(g).max(b);
    let min = r.min(g).min(b);
    let delta = max - min;
    let h = if delta < 1e-6 {
        0.0
    } else if max == r {
        ((g - b) / delta).rem_euclid(6.0) / 6.0
    } else if max == g {
        ((b - r) / delta + 2.0) / 6.0
    } else {
        ((r - g) / delta + 4.0) / 6.0
    };
    let s = if max > 1e-6 { delta / max } else { 0.0 };
    (h, s, max)
}

pub(super) fn hsv_to_rgb(h: f32, s: f32, v: f32) -> Rgb {
    let h6 = h.rem_euclid(1.0) * 6.0;
    let c = v * s;
    let x = c * (1.0 - (h6 % 2.0 - 1.0).abs());
    let (r, g, b) = match h6 as u32 {
        0 => (c, x, 0.0),
        1 => (x, c, 0.0),
        2 => (0.0, c, x),
        3 => (0.0, x, c),
        4 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    let m = v - c;
    [r + m, g + m, b + m]
}

/// Height above the bottom of the highest large horizontal surface of a mesh (a table's
/// top, a counter, a shelf's top board): what things placed on it stand on.
fn support_top(mesh: &LabeledMesh, lo: Vec3, size: Vec3) -> f32 {
    const BIN: f32 = 0.02;
    let n = (size.z / BIN).ceil() as usize + 1;
    let mut area = vec![0.0f32; n];
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
        let cr = (b - a).cross(c - a);
        let len = cr.length();
        if len < 1e-12 || cr.z.abs() < 0.9 * len {
            continue;
        }
        let z = (a.z + b.z + c.z) / 3.0 - lo.z;
        let k = ((z / BIN) as usize).min(n - 1);
        area[k] += 0.5 * len;
    }
    let need = 0.2 * size.x * size.y;
    for k in (0..n).rev() {
        if area[k] >= need {
            return ((k as f32 + 1.0) * BIN).min(size.z);
        }
    }
    size.z
}
