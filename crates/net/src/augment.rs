//! The augmentation that makes a few thousand generated rooms look like many more, and like
//! the partial, noisy, real scans the network labels: geometry (rotation, flips, scale,
//! elastic distortion, crops, dropout, a short walk's view, height cuts, a shift), colour
//! (camera colours, whole classes repainted, gain, brightness, noise) and context (ceiling or
//! floor dropped). Each part draws from its own random stream where it was added to a
//! recipe already in use, so that switching it on leaves every other choice of a seed as it
//! was. The recipes are named ([`Augment::RECIPES`]) so that `semrecon train --augment` and
//! docs/model.md name them the same way.

use glam::{Mat3, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use semrecon_data::class::SemanticClass;
use semrecon_data::LabeledPointCloud;

/// Random augmentation of a labelled point cloud. Geometry: rotation about the vertical axis,
/// x/y flips, scaling, elastic distortion, a random box crop (which also imitates partial
/// scans) and point dropout; colour: per-channel gain, brightness and per-point noise.
/// Fields set to zero (or `None`) switch a part off; [`Augment::none`] changes nothing.
#[derive(Debug, Clone, PartialEq)]
pub struct Augment {
    /// Random rotation about z, uniform in `[-max, max]` radians (`PI`: any angle).
    pub rotate_max: f32,
    /// Flip x and y, each with probability 1/2.
    pub flip: bool,
    /// Uniform scale range (`[1, 1]`: none).
    pub scale: [f32; 2],
    /// Elastic distortion: displacement amplitude (metres) of a smooth random field.
    pub elastic_amplitude: f32,
    /// Elastic distortion: grid spacing of the random field (metres).
    pub elastic_spacing: f32,
    /// Probability of cropping to a box.
    pub crop_probability: f32,
    /// Horizontal edge range of the crop box (metres); the box spans all heights.
    pub crop_size: [f32; 2],
    /// Probability of keeping only what a short walk would see
    /// ([`crate::scan_imitation::visible_from_short_walk`]); the box crop is skipped then.
    pub view_probability: f32,
    /// Probability of painting rugs on the floor ([`crate::scan_imitation::paint_rugs`]).
    pub rug_probability: f32,
    /// Probability of covering most of the floor with one carpet or a plain pale floor
    /// ([`crate::scan_imitation::cover_floor`]), before any rugs.
    pub floor_cover_probability: f32,
    /// Fraction of points dropped at random (at most; uniform in `[0, max]`).
    pub dropout_max: f32,
    /// Standard deviation of the per-channel colour gain (around 1).
    pub color_gain: f32,
    /// Brightness offset range, `[-b, b]` on 0..255 values.
    pub brightness: f32,
    /// Per-point colour noise amplitude on 0..255 values.
    pub color_noise: f32,
    /// Random translation, uniform in `[-t, t]` per axis (metres), after everything else.
    /// The strided levels of the network group voxels by their absolute coordinates (four
    /// halvings: a period of 16 voxels, 0.8 m for s20), and generated floors all lie at
    /// z = 0: without a shift the network learns where the floor is from that phase and loses
    /// the floor of a mesh whose floor is elsewhere (Replica office0, floor at z = -1.12 m,
    /// phase 9.5 voxels: 0.1 % floor; the same mesh moved to z = 0 or 0.8: 87 %).
    pub translate: [f32; 3],
    /// Probability of dropping everything above a random height (see
    /// [`height_cut`](Self::height_cut)), in the room's own frame (floor at z = 0). Samples
    /// that get the box crop keep all heights.
    pub height_cut_probability: f32,
    /// Range of the cut height above the floor (metres). A handheld scan at eye height
    /// rarely looks up: it sees the lower 1-2 m of the walls, so a door is a recessed panel
    /// without its head casing. A network that only saw whole doors calls that wall (the
    /// demo room's door, cut at 1.8 m: 10 % IoU, against 65 % whole).
    pub height_cut: [f32; 2],
    /// Probability of repainting the sample as a consumer camera in a real room records it
    /// (white balance, exposure, gamma, saturation, slow lighting;
    /// [`crate::camera_colours::apply_camera_colours`]), before the per-channel jitter.
    pub camera_colour_probability: f32,
    /// Probability of dropping every ceiling point (class 0). Real maps seldom hold a
    /// ceiling: none of the three ScanNet homes in `../shared/data` has one, a handheld scan
    /// at eye height hardly looks up, and S3DIS fragments are objects without their room.
    /// Without a ceiling the network must tell a beam or the top of a wall from the object
    /// itself rather than from what hangs above it.
    pub ceiling_drop_probability: f32,
    /// Probability of dropping every floor point (class 1): furniture without the floor it
    /// stands on, as in an object-level fragment or a scan that never looked down.
    pub floor_drop_probability: f32,
    /// Probability, per class of [`crate::repaint::REPAINTED_CLASSES`], of repainting all of
    /// the class's points in another material ([`crate::repaint::repaint_classes`]), before
    /// the camera colours.
    pub repaint_probability: f32,
    /// Probability of dropping the wall points (class 2) along one to four sides of the
    /// room ([`walls_along_sides`]), keeping everything on those walls: doors, windows,
    /// boards, pictures, bulkheads and columns without the wall around them. Object-level
    /// fragments (the S3DIS annotations of one room cut to a few objects) and the edges of a
    /// partial scan show such things; a network that always saw a door or a board inside a
    /// wall calls a lone dark rectangle wall.
    pub wall_drop_probability: f32,
}

impl Augment {
    /// No augmentation.
    pub fn none() -> Self {
        Self {
            rotate_max: 0.0,
            flip: false,
            scale: [1.0, 1.0],
            elastic_amplitude: 0.0,
            elastic_spacing: 1.0,
            crop_probability: 0.0,
            crop_size: [1.0, 1.0],
            view_probability: 0.0,
            rug_probability: 0.0,
            floor_cover_probability: 0.0,
            dropout_max: 0.0,
            color_gain: 0.0,
            brightness: 0.0,
            color_noise: 0.0,
            translate: [0.0; 3],
            height_cut_probability: 0.0,
            height_cut: [2.0, 2.0],
            camera_colour_probability: 0.0,
            ceiling_drop_probability: 0.0,
            floor_drop_probability: 0.0,
            repaint_probability: 0.0,
            wall_drop_probability: 0.0,
        }
    }

    /// The training recipe of docs/model.md: any rotation, flips, scale 0.9-1.1, elastic
    /// distortion of 4 cm over 0.5 m, crops of 3-5 m half of the time, up to 20 % dropout,
    /// colour gain 8 %, brightness 20, noise 6.
    pub fn training() -> Self {
        Self {
            rotate_max: std::f32::consts::PI,
            flip: true,
            scale: [0.9, 1.1],
            elastic_amplitude: 0.04,
            elastic_spacing: 0.5,
            crop_probability: 0.5,
            crop_size: [3.0, 5.0],
            dropout_max: 0.2,
            color_gain: 0.08,
            brightness: 20.0,
            color_noise: 6.0,
            ..Self::none()
        }
    }

    /// [`Augment::training`] plus the live-map imitations: a short walk's view 40 % of the
    /// time, a wall-to-wall carpet or pale floor 25 % of the time and rugs 30 % of the time
    /// (the fifth and sixth training legs of docs/model.md).
    /// It also shifts samples by up to 0.8 m on each axis (any phase of the coarsest grid).
    pub fn live_maps() -> Self {
        Self {
            view_probability: 0.4,
            rug_probability: 0.3,
            floor_cover_probability: 0.25,
            translate: [0.8; 3],
            ..Self::training()
        }
    }

    /// [`Augment::live_maps`] plus height cuts: 35 % of the samples without a box crop (about
    /// a quarter of all) lose everything above a height drawn from 1.0-2.2 m, as a casual
    /// scan at eye height does (the seventh training leg of docs/model.md).
    pub fn casual_scans() -> Self {
        Self { height_cut_probability: 0.35, height_cut: [1.0, 2.2], ..Self::live_maps() }
    }

    /// [`Augment::casual_scans`] plus camera colours half of the time: the recipe for rooms
    /// furnished from the catalogues (`synth-lib:`), which must carry over to real scans
    /// (the eighth training leg of docs/model.md).
    pub fn real_rooms() -> Self {
        Self { camera_colour_probability: 0.5, ..Self::casual_scans() }
    }

    /// [`Augment::real_rooms`] without the room's context now and then: the ceiling dropped
    /// from half of the samples and the floor from 15 % (the second part of the eighth
    /// training leg of docs/model.md, with reconstructions of rendered scans and
    /// pseudo-labelled real scans in the data).
    pub fn real_scans() -> Self {
        Self { ceiling_drop_probability: 0.5, floor_drop_probability: 0.15, ..Self::real_rooms() }
    }

    /// [`Augment::real_scans`] with whole classes repainted in other materials now and then
    /// (walls, doors, tables, bookcases, chairs, sofas; each 15 % of the samples): wood or
    /// brick walls, white doors and furniture, as real homes have (the eighteenth leg).
    pub fn real_homes() -> Self {
        Self { repaint_probability: 0.15, ..Self::real_scans() }
    }

    /// [`Augment::real_homes`] with the walls along some sides of the room dropped from 20 %
    /// of the samples, so that what hangs on or stands in a wall is told by itself (the
    /// twentieth leg).
    pub fn real_fragments() -> Self {
        Self { wall_drop_probability: 0.2, ..Self::real_homes() }
    }

    /// Names of the recipes [`Augment::from_recipe`] knows (`semrecon train --augment`).
    pub const RECIPES: [&'static str; 7] =
        ["training", "live-maps", "casual-scans", "real-rooms", "real-scans", "real-homes", "real-fragments"];

    /// The recipe of a name in [`Augment::RECIPES`]; `None` for any other name.
    pub fn from_recipe(name: &str) -> Option<Self> {
        match name {
            "training" => Some(Self::training()),
            "live-maps" => Some(Self::live_maps()),
            "casual-scans" => Some(Self::casual_scans()),
            "real-rooms" => Some(Self::real_rooms()),
            "real-scans" => Some(Self::real_scans()),
            "real-homes" => Some(Self::real_homes()),
            "real-fragments" => Some(Self::real_fragments()),
            _ => None,
        }
    }

    /// Applies the augmentation to `cloud` in place, seeded by `seed`.
    pub fn apply(&self, cloud: &mut LabeledPointCloud, seed: u64) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5EED_A06E);
        if cloud.is_empty() {
            return;
        }
        // Geometry about the cloud's horizontal centre, so that rotations keep it in place.
        // The live-map imitations work in the room's own frame (floor down, eye height above
        // it), so they come before any geometric change; they draw from their own stream so
        // that switching them on leaves the other choices of a seed as they were.
        let mut live_rng = ChaCha8Rng::seed_from_u64(seed ^ 0x11FE_5CA7);
        // Own stream too, so that the view and rugs of a seed stay those of the fifth leg.
        let mut cover_rng = ChaCha8Rng::seed_from_u64(seed ^ 0xCA4B_E7F1);
        if self.floor_cover_probability > 0.0 && cover_rng.random::<f32>() < self.floor_cover_probability {
            crate::scan_imitation::cover_floor(cloud, &mut cover_rng);
        }
        if self.rug_probability > 0.0 && live_rng.random::<f32>() < self.rug_probability {
            crate::scan_imitation::paint_rugs(cloud, &mut live_rng);
        }
        let view = (self.view_probability > 0.0 && live_rng.random::<f32>() < self.view_probability)
            .then(|| crate::scan_imitation::visible_from_short_walk(cloud, &mut live_rng))
            .flatten();
        // Own stream: the other choices of a seed stay those of the sixth leg.
        let mut cut_rng = ChaCha8Rng::seed_from_u64(seed ^ 0xC07_4E16);
        let cut_height = (self.height_cut_probability > 0.0 && cut_rng.random::<f32>() < self.height_cut_probability)
            .then(|| {
                let (a, b) = (self.height_cut[0], self.height_cut[1].max(self.height_cut[0]));
                if b > a {
                    cut_rng.random_range(a..=b)
                } else {
                    a
                }
            });
        let below_cut: Option<Vec<bool>> = cut_height.map(|h| cloud.positions.iter().map(|p| p.z <= h).collect());
        // Own stream, and in the room's own frame (its walls along the axes): the other
        // choices of a seed stay those of the real-homes recipe.
        let mut wall_rng = ChaCha8Rng::seed_from_u64(seed ^ 0x3A11_D409);
        let walls_dropped: Option<Vec<bool>> =
            (self.wall_drop_probability > 0.0 && wall_rng.random::<f32>() < self.wall_drop_probability).then(|| {
                // Each side with probability 1/2, at least one.
                let mut sides = [false; 4];
                while !sides.contains(&true) {
                    sides = std::array::from_fn(|_| wall_rng.random_bool(0.5));
                }
                walls_along_sides(cloud, sides)
            });
        let (lo, hi) = bounds(&cloud.positions);
        let centre = Vec3::new((lo.x + hi.x) * 0.5, (lo.y + hi.y) * 0.5, 0.0);
        let angle = if self.rotate_max > 0.0 { rng.random_range(-self.rotate_max..=self.rotate_max) } else { 0.0 };
        let flip_x = self.flip && rng.random_bool(0.5);
        let flip_y = self.flip && rng.random_bool(0.5);
        let s =
            if self.scale[1] > self.scale[0] { rng.random_range(self.scale[0]..=self.scale[1]) } else { self.scale[0] };
        let flips =
            Mat3::from_diagonal(Vec3::new(if flip_x { -1.0 } else { 1.0 }, if flip_y { -1.0 } else { 1.0 }, 1.0));
        let m = Mat3::from_rotation_z(angle) * flips * s;
        let field = (self.elastic_amplitude > 0.0).then(|| ElasticField::new(lo, hi, self.elastic_spacing, &mut rng));
        for p in &mut cloud.positions {
            let mut q = *p;
            if let Some(f) = &field {
                q += f.displacement(q) * self.elastic_amplitude;
            }
            *p = m * (q - centre);
        }
        // Crop a box around a random point, then drop points.
        let viewed = view.is_some();
        let mut keep: Vec<bool> = view.unwrap_or_else(|| vec![true; cloud.len()]);
        let cropped = self.crop_probability > 0.0 && rng.random::<f32>() < self.crop_probability && !viewed;
        // A box-cropped sample keeps all heights (as leg 7 was trained): the crop is a
        // partial scan of its own.
        if let (Some(below), false) = (&below_cut, cropped) {
            for (k, &b) in keep.iter_mut().zip(below) {
                *k &= b;
            }
        }
        if cropped {
            let (a, b) = (self.crop_size[0], self.crop_size[1].max(self.crop_size[0]));
            let sx = if b > a { rng.random_range(a..=b) } else { a };
            let sy = if b > a { rng.random_range(a..=b) } else { a };
            let c = cloud.positions[rng.random_range(0..cloud.len())];
            for (k, p) in keep.iter_mut().zip(&cloud.positions) {
                *k = (p.x - c.x).abs() <= sx * 0.5 && (p.y - c.y).abs() <= sy * 0.5;
            }
        }
        // Own stream: the other choices of a seed stay those of the real-rooms recipe.
        let mut context_rng = ChaCha8Rng::seed_from_u64(seed ^ 0xC0_7E47_D209);
        let drop_ceiling =
            self.ceiling_drop_probability > 0.0 && context_rng.random::<f32>() < self.ceiling_drop_probability;
        let drop_floor = self.floor_drop_probability > 0.0 && context_rng.random::<f32>() < self.floor_drop_probability;
        if drop_ceiling || drop_floor {
            let dropped: Vec<bool> = cloud
                .labels
                .iter()
                .map(|&l| {
                    (drop_ceiling && l == SemanticClass::Ceiling.id()) || (drop_floor && l == SemanticClass::Floor.id())
                })
                .collect();
            drop_context(&mut keep, &dropped);
        }
        if let Some(dropped) = &walls_dropped {
            drop_context(&mut keep, dropped);
        }
        if self.dropout_max > 0.0 {
            let rate = rng.random_range(0.0..=self.dropout_max);
            for k in keep.iter_mut() {
                if rng.random::<f32>() < rate {
                    *k = false;
                }
            }
        }
        if keep.iter().any(|k| !k) {
            let mut i = 0;
            cloud.positions.retain(|_| {
                i += 1;
                keep[i - 1]
            });
            i = 0;
            cloud.colors.retain(|_| {
                i += 1;
                keep[i - 1]
            });
            i = 0;
            cloud.labels.retain(|_| {
                i += 1;
                keep[i - 1]
            });
        }
        // Own stream: the other choices of a seed stay as they were.
        if self.repaint_probability > 0.0 {
            let mut repaint_rng = ChaCha8Rng::seed_from_u64(seed ^ 0x4E9A_1A75);
            crate::repaint::repaint_classes(cloud, self.repaint_probability, &mut repaint_rng);
        }
        // Own stream: the other choices of a seed stay those of the seventh leg.
        let mut camera_rng = ChaCha8Rng::seed_from_u64(seed ^ 0xCA3E_4A00);
        if self.camera_colour_probability > 0.0 && camera_rng.random::<f32>() < self.camera_colour_probability {
            crate::camera_colours::apply_camera_colours(cloud, &mut camera_rng);
        }
        // Colour: gain per channel and brightness per room, noise per point.
        if self.color_gain > 0.0 || self.brightness > 0.0 || self.color_noise > 0.0 {
            let gain: [f32; 3] =
                std::array::from_fn(|_| 1.0 + self.color_gain * (rng.random::<f32>() * 2.0 - 1.0) * 1.7);
            let bright = if self.brightness > 0.0 { rng.random_range(-self.brightness..=self.brightness) } else { 0.0 };
            for c in &mut cloud.colors {
                for (k, v) in c.iter_mut().enumerate() {
                    let noise =
                        if self.color_noise > 0.0 { (rng.random::<f32>() * 2.0 - 1.0) * self.color_noise } else { 0.0 };
                    *v = (f32::from(*v) * gain[k] + bright + noise).round().clamp(0.0, 255.0) as u8;
                }
            }
        }
        if self.translate.iter().any(|&t| t > 0.0) {
            // Own stream: the other choices of a seed stay as they were.
            let mut shift_rng = ChaCha8Rng::seed_from_u64(seed ^ 0x7A45_11F7);
            let shift =
                Vec3::from_array(self.translate.map(|t| if t > 0.0 { shift_rng.random_range(-t..=t) } else { 0.0 }));
            for p in &mut cloud.positions {
                *p += shift;
            }
        }
    }
}

/// Clears `keep` where `dropped` is set, unless that would leave under a tenth of the kept
/// points: a sample that is (nearly) all ceiling, floor or wall keeps them.
fn drop_context(keep: &mut [bool], dropped: &[bool]) {
    let left = keep.iter().zip(dropped).filter(|&(&k, &d)| k && !d).count();
    if left * 10 >= keep.iter().filter(|&&k| k).count() {
        for (k, &d) in keep.iter_mut().zip(dropped) {
            *k &= !d;
        }
    }
}

/// Which points are wall (class 2) on the chosen sides of the room: `sides` are the
/// bounding box's low x, high x, low y and high y; a wall point belongs to the side it is
/// nearest to, so a room's inner walls go with the outer wall they face.
pub fn walls_along_sides(cloud: &LabeledPointCloud, sides: [bool; 4]) -> Vec<bool> {
    let (lo, hi) = bounds(&cloud.positions);
    let wall = SemanticClass::Wall.id();
    cloud
        .positions
        .iter()
        .zip(&cloud.labels)
        .map(|(p, &l)| {
            if l != wall {
                return false;
            }
            let distances = [p.x - lo.x, hi.x - p.x, p.y - lo.y, hi.y - p.y];
            let nearest = (1..4).fold(0, |best, i| if distances[i] < distances[best] { i } else { best });
            sides[nearest]
        })
        .collect()
}

fn bounds(points: &[Vec3]) -> (Vec3, Vec3) {
    points.iter().fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(lo, hi), p| (lo.min(*p), hi.max(*p)))
}

/// A smooth random displacement field: unit-variance random vectors on a coarse grid,
/// interpolated trilinearly (the elastic distortion of SparseConvNet's recipes, one scale).
struct ElasticField {
    origin: Vec3,
    spacing: f32,
    dims: [usize; 3],
    vectors: Vec<Vec3>,
}

impl ElasticField {
    fn new(lo: Vec3, hi: Vec3, spacing: f32, rng: &mut ChaCha8Rng) -> Self {
        let spacing = spacing.max(0.05);
        let dims = [0, 1, 2].map(|a| (((hi[a] - lo[a]) / spacing).ceil().max(0.0) as usize + 2).min(512));
        let n = dims[0] * dims[1] * dims[2];
        let vectors = (0..n)
            .map(|_| {
                Vec3::new(
                    rng.random::<f32>() * 2.0 - 1.0,
                    rng.random::<f32>() * 2.0 - 1.0,
                    rng.random::<f32>() * 2.0 - 1.0,
                )
            })
            .collect();
        Self { origin: lo, spacing, dims, vectors }
    }

    fn displacement(&self, p: Vec3) -> Vec3 {
        let g = (p - self.origin) / self.spacing;
        let mut i = [0usize; 3];
        let mut f = [0f32; 3];
        for a in 0..3 {
            let x = g[a].clamp(0.0, (self.dims[a] - 1) as f32 - 1e-3);
            i[a] = x.floor() as usize;
            f[a] = x - i[a] as f32;
        }
        let mut d = Vec3::ZERO;
        for corner in 0..8 {
            let mut w = 1.0;
            let mut idx = [0usize; 3];
            for a in 0..3 {
                let hi = (corner >> a) & 1 == 1;
                idx[a] = (i[a] + usize::from(hi)).min(self.dims[a] - 1);
                w *= if hi { f[a] } else { 1.0 - f[a] };
            }
            d += self.vectors[(idx[2] * self.dims[1] + idx[1]) * self.dims[0] + idx[0]] * w;
        }
        d
    }
}
