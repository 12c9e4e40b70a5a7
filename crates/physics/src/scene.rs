//! The AR physics scene: the room's collision regions as static rapier triangle meshes and
//! virtual balls thrown into it, stepped at a fixed time step with continuous collision
//! detection, recording each ball's trajectory and bounces.
//!
//! Materials are per triangle: every region is one collider, and a contact-modification
//! hook looks up the class of the triangle a contact manifold touches (rapier makes one
//! manifold per triangle of a mesh and reports its index as the manifold's sub-shape) and
//! sets that manifold's friction. Compared with one collider per (region, class), this
//! keeps each region one connected mesh, so `FIX_INTERNAL_EDGES` also smooths the edges
//! between classes, and a change of labels needs no re-split. Rapier's contact clustering,
//! which merges the manifolds of coplanar triangles and with them the triangle index, is
//! turned off; a ball touches only a few triangles, so it costs little.
//!
//! Restitution is applied here, not by rapier. Rapier's restitution pass drives each
//! manifold's normal velocity to its target one manifold after the other; on a scanned
//! surface a ball lands on several triangles whose normals differ by noise, the successive
//! projections add up, and the ball leaves faster than it came (measured: rebounds 5-25 %
//! above e^2 h on floors with 1-2 mm noise, whatever the flags and step). So rapier solves
//! mesh contacts as perfectly inelastic (restitution 0; it still prevents penetration and
//! applies friction), and after the step the scene adds the elastic part once per ball
//! along one normal, the direction of the total contact impulse: the normal velocity
//! becomes `e * approach speed`, with `e` of the triangle that took the largest impulse.
//! Exact on flat surfaces, and a bounce can never gain energy.
//!
//! Determinism: rapier is built without its `parallel` feature, every container iterated
//! here is ordered, and time advances in whole steps, so a throw gives the same bits on
//! every run.

use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;

use glam::Vec3;
use rapier3d::prelude::{
    ActiveHooks, ColliderBuilder, ColliderHandle, ContactModificationContext, PhysicsHooks, PhysicsWorld,
    RigidBodyBuilder, RigidBodyHandle, TriMeshFlags, Vector,
};
use semrecon_data::class::UNLABELED;
use semrecon_data::{LabeledMesh, MeshGravity, SemanticClass};
use serde::{Deserialize, Serialize};

use crate::collision_mesh::{CollisionMesh, CollisionMeshConfig, CollisionRegion, RegionKey};
use crate::error::{PhysicsError, Result};
use crate::materials::MaterialTable;

/// Standard gravity, m/s^2, along the opposite of [`SceneConfig::up`].
pub const GRAVITY: f32 = 9.81;

/// Largest accepted coordinate magnitude (m), speed (m/s) and duration (s): beyond these
/// an input is a mistake, and f32 positions would lose the precision contacts need.
pub const MAX_COORDINATE: f32 = 10_000.0;
/// See [`MAX_COORDINATE`].
pub const MAX_SPEED: f32 = 200.0;
/// See [`MAX_COORDINATE`].
pub const MAX_SECONDS: f32 = 600.0;

/// Simulation settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneConfig {
    /// Fixed time step, seconds (default 1/240).
    pub dt: f32,
    /// Trajectories keep one sample every this many steps (default 4: 60 Hz at 1/240 s).
    pub record_every: u32,
    /// Ball radius, metres (default 0.04).
    pub ball_radius: f32,
    /// Ball density, kg/m^3 (default 400, a tennis ball); only matters for ball-ball hits.
    pub ball_density: f32,
    /// Angular damping of balls (1/s, default 0.5): stands in for rolling resistance, so
    /// a ball rolling on the floor comes to rest instead of rolling for ever.
    pub angular_damping: f32,
    /// How the visual mesh becomes collision geometry.
    pub collision: CollisionMeshConfig,
    /// The scene's up direction (unit length; gravity pulls along its opposite). Default z:
    /// generated rooms and S3DIS/ScanNet meshes are z up. A reconstruction keeps the frame
    /// of its dataset or first camera (7-Scenes' world is nearly y down), so its mesh file
    /// carries the up direction ([`semrecon_data::read_ply_with_gravity`]), and scenes built
    /// from it take that.
    pub up: Vec3,
    /// Height along `up` of the room's floor, metres, when known: a ground plane
    /// [`FLOOR_PLANE_DROP`] below it, with the floor's material, catches balls where the
    /// scanned floor has holes (patches no frame saw, under furniture), through which they
    /// would otherwise fall for ever. `None`: no plane (generated rooms are closed).
    pub floor_height: Option<f32>,
}

/// How far below [`SceneConfig::floor_height`] the ground plane lies, metres: the scanned
/// floor takes the contacts where it exists (its noise is a few millimetres), the plane only
/// where it has a hole.
pub const FLOOR_PLANE_DROP: f32 = 0.02;

impl Default for SceneConfig {
    fn default() -> Self {
        Self {
            dt: 1.0 / 240.0,
            record_every: 4,
            ball_radius: 0.04,
            ball_density: 400.0,
            angular_damping: 0.5,
            collision: CollisionMeshConfig::default(),
            up: Vec3::Z,
            floor_height: None,
        }
    }
}

impl SceneConfig {
    /// These settings in the frame a mesh file records (its up and floor, see
    /// [`semrecon_data::read_ply_with_gravity`]); `None` keeps +z and no ground plane.
    pub fn with_gravity(self, gravity: Option<MeshGravity>) -> Self {
        match gravity {
            Some(g) => Self { up: g.up.normalize_or(Vec3::Z), floor_height: g.floor_height, ..self },
            None => self,
        }
    }

    /// Checks every value is finite and in a sensible range.
    pub fn validate(&self) -> Result<()> {
        let bad = |what: &str, v: f32, range: &str| {
            Err(PhysicsError::InvalidArgument(format!("{what} {v} must be finite and within {range}")))
        };
        if !(self.dt.is_finite() && (1e-4..=0.05).contains(&self.dt)) {
            return bad("time step", self.dt, "1e-4..=0.05 s");
        }
        if self.record_every == 0 {
            return Err(PhysicsError::InvalidArgument("record_every must be at least 1".into()));
        }
        if !(self.ball_radius.is_finite() && (0.001..=1.0).contains(&self.ball_radius)) {
            return bad("ball radius", self.ball_radius, "0.001..=1 m");
        }
        if !(self.ball_density.is_finite() && (1.0..=1e5).contains(&self.ball_density)) {
            return bad("ball density", self.ball_density, "1..=1e5 kg/m^3");
        }
        if !(self.angular_damping.is_finite() && (0.0..=100.0).contains(&self.angular_damping)) {
            return bad("angular damping", self.angular_damping, "0..=100");
        }
        if let Some(h) = self.floor_height {
            if !(h.is_finite() && h.abs() <= MAX_COORDINATE) {
                return bad("floor height", h, "a finite +-10 km");
            }
        }
        if !(self.up.is_finite() && (self.up.length() - 1.0).abs() <= 1e-3) {
            return Err(PhysicsError::InvalidArgument(format!(
                "up direction {} must be a finite unit vector",
                self.up
            )));
        }
        self.collision.validate()
    }
}

/// One bounce of a ball: the first step of a new touch of the room's surface.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Contact {
    /// Scene time, seconds.
    pub time: f32,
    /// Contact point on the surface, world frame, metres.
    pub position: [f32; 3],
    /// Class name of the triangle touched, or `unlabelled`.
    pub class: String,
    /// Restitution used for this contact.
    pub restitution: f32,
    /// Friction used for this contact.
    pub friction: f32,
}

/// A ball's trajectory: the JSON of `semrecon throw`.
///
/// # Shapes
/// `times` and `positions` have one entry per sample (ball centre, world frame, metres).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Throw {
    /// Ball radius, metres.
    pub radius: f32,
    /// Sample times, seconds.
    pub times: Vec<f32>,
    /// Ball centre per sample, `[x, y, z]`.
    pub positions: Vec<[f32; 3]>,
    /// Every bounce, in time order.
    pub contacts: Vec<Contact>,
    /// Things the user should know (e.g. a mesh without labels); empty when all is well.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
}

/// Handle of a ball in an [`ArScene`] (index in throw order).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct BallId(pub usize);

/// What [`ArScene::replace_mesh`] changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RegionDiff {
    /// Regions that did not exist before.
    pub added: usize,
    /// Regions whose content changed (collider rebuilt).
    pub replaced: usize,
    /// Regions that no longer exist.
    pub removed: usize,
    /// Regions left untouched (same content hash).
    pub unchanged: usize,
}

struct RegionCollider {
    handle: ColliderHandle,
    hash: u64,
}

struct Ball {
    body: RigidBodyHandle,
    collider: ColliderHandle,
    touching: bool,
    /// Velocity before the current step, m/s.
    velocity: Vec3,
    record: Throw,
}

/// Approach speeds below this (m/s) are resting or rolling contact, not a bounce: about
/// four steps of gravity at 1/240 s; a rebound from it would be under a millimetre.
pub const BOUNCE_MIN_SPEED: f32 = 0.15;

/// A physics scene: static room regions and dynamic balls.
pub struct ArScene {
    world: PhysicsWorld,
    config: SceneConfig,
    materials: MaterialTable,
    regions: BTreeMap<RegionKey, RegionCollider>,
    /// Triangle labels and normals of each region collider, read by the material hook.
    surfaces: HashMap<ColliderHandle, Arc<Surface>>,
    balls: Vec<Ball>,
    steps: u64,
    unlabelled: bool,
}

impl ArScene {
    /// An empty scene (no room geometry yet).
    pub fn new(materials: MaterialTable, config: SceneConfig) -> Result<Self> {
        config.validate()?;
        let mut world = PhysicsWorld::new();
        let gravity = -config.up * GRAVITY;
        world.gravity = Vector::new(gravity.x, gravity.y, gravity.z);
        world.integration_parameters.dt = config.dt;
        // The material hook needs the triangle index of each manifold (see module docs).
        world.integration_parameters.contact_clustering = false;
        let mut surfaces = HashMap::new();
        if let Some(h) = config.floor_height {
            // A half-space (one sub-shape, index 0) labelled floor, its boundary through
            // `up * (h - drop)` with its normal along up (a unit vector: validated above).
            let normal = Vector::new(config.up.x, config.up.y, config.up.z);
            let origin = config.up * (h - FLOOR_PLANE_DROP);
            let plane = ColliderBuilder::halfspace(rapier3d::na::Unit::new_unchecked(normal))
                .translation(Vector::new(origin.x, origin.y, origin.z))
                .active_hooks(ActiveHooks::MODIFY_SOLVER_CONTACTS);
            let handle = world.insert_collider(plane, None);
            surfaces.insert(handle, Arc::new(Surface { labels: vec![SemanticClass::Floor.id()], origin }));
        }
        Ok(Self {
            world,
            config,
            materials,
            regions: BTreeMap::new(),
            surfaces,
            balls: Vec::new(),
            steps: 0,
            unlabelled: false,
        })
    }

    /// A scene holding `mesh` as its room.
    pub fn with_mesh(mesh: &LabeledMesh, materials: MaterialTable, config: SceneConfig) -> Result<Self> {
        let mut scene = Self::new(materials, config)?;
        scene.replace_mesh(mesh)?;
        Ok(scene)
    }

    /// Replaces the room by `mesh` (a new version of the live map): it is simplified and
    /// split into regions, and only regions whose content hash changed are rebuilt.
    pub fn replace_mesh(&mut self, mesh: &LabeledMesh) -> Result<RegionDiff> {
        let collision = CollisionMesh::build(mesh, &self.config.collision)?;
        self.replace_collision_mesh(collision)
    }

    /// As [`ArScene::replace_mesh`] for an already built collision mesh.
    pub fn replace_collision_mesh(&mut self, collision: CollisionMesh) -> Result<RegionDiff> {
        let mut diff = RegionDiff::default();
        let stale: Vec<RegionKey> =
            self.regions.keys().filter(|k| !collision.regions.contains_key(*k)).copied().collect();
        for key in stale {
            self.remove_region(key);
            diff.removed += 1;
        }
        for region in collision.regions.into_values() {
            match self.regions.get(&region.key).map(|r| r.hash == region.hash) {
                Some(true) => diff.unchanged += 1,
                Some(false) => {
                    self.update_region(region)?;
                    diff.replaced += 1;
                }
                None => {
                    self.update_region(region)?;
                    diff.added += 1;
                }
            }
        }
        self.unlabelled = collision.unlabelled;
        Ok(diff)
    }

    /// Sets the geometry of one region (an empty region removes it). Returns false when the
    /// region already had this content (same hash) and nothing was done. A region that rapier
    /// cannot turn into a triangle mesh is an error (and the region is left empty).
    pub fn update_region(&mut self, region: CollisionRegion) -> Result<bool> {
        if self.regions.get(&region.key).is_some_and(|r| r.hash == region.hash) {
            return Ok(false);
        }
        self.remove_region(region.key);
        if region.triangles.is_empty() {
            return Ok(true);
        }
        if region.labels.len() != region.triangles.len()
            || region.triangles.iter().flatten().any(|&i| i as usize >= region.vertices.len())
        {
            return Err(PhysicsError::Mesh(format!(
                "region {:?}: labels or indices do not match the vertices",
                region.key
            )));
        }
        let vertices: Vec<Vector> = region.vertices.iter().map(|v| Vector::new(v.x, v.y, v.z)).collect();
        // FIX_INTERNAL_EDGES: without it a ball hitting the edge between two triangles gets
        // that edge's normal; measured here, drops on a flat tessellated floor then rebound
        // anywhere between 0.95 and 1.06 of e^2 h instead of within 1 % (and on bumpy
        // scans balls gain energy, as TECH_NOTES records). Two-sided:
        // scanned meshes are not always consistently oriented, and a one-sided mesh drops
        // contacts from the back.
        let flags = TriMeshFlags::FIX_INTERNAL_EDGES_TWO_SIDED;
        let collider = match ColliderBuilder::trimesh_with_flags(vertices.clone(), region.triangles.clone(), flags) {
            Ok(builder) => builder,
            // The topology pass can reject odd meshes (e.g. an edge shared by more than two
            // triangles after clustering); a mesh without the edge fix still collides.
            Err(_) => ColliderBuilder::trimesh(vertices, region.triangles.clone())
                .map_err(|e| PhysicsError::Mesh(format!("region {:?}: {e}", region.key)))?,
        };
        let handle = self.world.insert_collider(collider.active_hooks(ActiveHooks::MODIFY_SOLVER_CONTACTS), None);
        self.surfaces.insert(handle, Arc::new(Surface { labels: region.labels, origin: Vec3::ZERO }));
        self.regions.insert(region.key, RegionCollider { handle, hash: region.hash });
        // Balls asleep on the old geometry must notice the change.
        self.world.wake_up_all(true);
        Ok(true)
    }

    fn remove_region(&mut self, key: RegionKey) {
        if let Some(old) = self.regions.remove(&key) {
            self.world.remove_collider(old.handle);
            self.surfaces.remove(&old.handle);
            self.world.wake_up_all(true);
        }
    }

    /// Number of region colliders.
    pub fn region_count(&self) -> usize {
        self.regions.len()
    }

    /// True when the current room mesh had no labels (all contacts use the unlabelled material).
    pub fn is_unlabelled(&self) -> bool {
        self.unlabelled
    }

    /// The material table in use.
    pub fn materials(&self) -> &MaterialTable {
        &self.materials
    }

    /// The simulation settings.
    pub fn config(&self) -> &SceneConfig {
        &self.config
    }

    /// Current scene time, seconds.
    pub fn time(&self) -> f32 {
        (self.steps as f64 * self.config.dt as f64) as f32
    }

    /// Throws a ball from `from` (its centre, world frame) along `dir` (any length > 0) at
    /// `speed` m/s. Arguments that are not finite or too large are errors.
    pub fn throw_ball(&mut self, from: Vec3, dir: Vec3, speed: f32) -> Result<BallId> {
        check_vector("position", from, MAX_COORDINATE)?;
        check_vector("direction", dir, f32::MAX)?;
        let len = dir.length();
        if !(len.is_finite() && len > 1e-9) {
            return Err(PhysicsError::InvalidArgument(format!("direction {dir} has no length")));
        }
        if !(speed.is_finite() && (0.0..=MAX_SPEED).contains(&speed)) {
            return Err(PhysicsError::InvalidArgument(format!("speed {speed} must be within 0..={MAX_SPEED} m/s")));
        }
        let v = dir / len * speed;
        let body = RigidBodyBuilder::dynamic()
            .translation(Vector::new(from.x, from.y, from.z))
            .linvel(Vector::new(v.x, v.y, v.z))
            .angular_damping(self.config.angular_damping)
            .ccd_enabled(true);
        // Ball-ball hits use rapier's own restitution (0.7: two rubber balls).
        let collider =
            ColliderBuilder::ball(self.config.ball_radius).density(self.config.ball_density).restitution(0.7);
        let (body, collider) = self.world.insert(body, collider);
        let mut record = Throw { radius: self.config.ball_radius, ..Default::default() };
        if self.unlabelled {
            record.warnings.push(UNLABELLED_WARNING.to_string());
        }
        record.times.push(self.time());
        record.positions.push(from.to_array());
        self.balls.push(Ball { body, collider, touching: false, velocity: v, record });
        Ok(BallId(self.balls.len() - 1))
    }

    /// Advances the scene by one fixed step and records contacts (and samples every
    /// `record_every` steps).
    pub fn step(&mut self) {
        for ball in &mut self.balls {
            if let Some(body) = self.world.bodies.get(ball.body) {
                let v = body.linvel();
                ball.velocity = Vec3::new(v.x, v.y, v.z);
            }
        }
        let hooks = MaterialHooks { surfaces: &self.surfaces, materials: &self.materials };
        self.world.step_with_events(&hooks, &());
        self.steps += 1;
        let time = self.time();
        let dt = self.config.dt;
        let sample = self.steps.is_multiple_of(self.config.record_every as u64);
        for ball in &mut self.balls {
            let hit = contact_impulses(&self.world, ball.collider, &self.surfaces);
            let Some(body) = self.world.bodies.get_mut(ball.body) else { continue };
            match hit {
                Some(hit) => {
                    // Velocity the ball hit with: before the step plus the step's gravity.
                    let approach = -(ball.velocity - self.config.up * (GRAVITY * dt)).dot(hit.normal);
                    let m = self.materials.label(hit.label);
                    let bounce = approach > BOUNCE_MIN_SPEED;
                    if bounce {
                        let v = body.linvel();
                        let v = Vec3::new(v.x, v.y, v.z);
                        let add = (m.restitution * approach - v.dot(hit.normal)).max(0.0);
                        let v = v + add * hit.normal;
                        body.set_linvel(Vector::new(v.x, v.y, v.z), true);
                    }
                    if bounce || !ball.touching {
                        ball.record.contacts.push(Contact {
                            time,
                            position: hit.point.to_array(),
                            class: self.materials.label_name(hit.label).to_string(),
                            restitution: m.restitution,
                            friction: m.friction,
                        });
                    }
                    ball.touching = true;
                }
                None => ball.touching = false,
            }
            if sample {
                let c = body.translation();
                ball.record.times.push(time);
                ball.record.positions.push([c.x, c.y, c.z]);
            }
        }
    }

    /// Runs the scene for `seconds` (rounded to whole steps) and returns each ball's
    /// trajectory recorded so far, in throw order.
    pub fn simulate(&mut self, seconds: f32) -> Result<Vec<Throw>> {
        if !(seconds.is_finite() && (0.0..=MAX_SECONDS).contains(&seconds)) {
            return Err(PhysicsError::InvalidArgument(format!(
                "duration {seconds} must be within 0..={MAX_SECONDS} s"
            )));
        }
        let steps = (seconds as f64 / self.config.dt as f64).round() as u64;
        for _ in 0..steps {
            self.step();
        }
        Ok(self.balls.iter().map(|b| b.record.clone()).collect())
    }

    /// Position and velocity of a ball's centre (world frame).
    pub fn ball_state(&self, ball: BallId) -> Option<(Vec3, Vec3)> {
        let body = self.world.bodies.get(self.balls.get(ball.0)?.body)?;
        let (p, v) = (body.translation(), body.linvel());
        Some((Vec3::new(p.x, p.y, p.z), Vec3::new(v.x, v.y, v.z)))
    }

    /// Mechanical energy of a ball, joules: kinetic (translation and rotation) plus
    /// potential `m g h` of its centre, `h` its height along [`SceneConfig::up`].
    pub fn ball_energy(&self, ball: BallId) -> Option<f32> {
        let body = self.world.bodies.get(self.balls.get(ball.0)?.body)?;
        let p = body.translation();
        let height = self.config.up.dot(Vec3::new(p.x, p.y, p.z));
        Some(body.kinetic_energy() + body.mass() * GRAVITY * height)
    }

    /// The trajectory recorded for a ball so far.
    pub fn ball_record(&self, ball: BallId) -> Option<&Throw> {
        self.balls.get(ball.0).map(|b| &b.record)
    }
}

/// Warning attached to throws on a mesh without labels.
pub const UNLABELLED_WARNING: &str = "the mesh has no semantic labels: every surface uses the unlabelled material";

fn check_vector(what: &str, v: Vec3, max: f32) -> Result<()> {
    if !v.is_finite() || v.abs().max_element() > max {
        return Err(PhysicsError::InvalidArgument(format!("{what} {v} must be finite with |coordinates| <= {max}")));
    }
    Ok(())
}

/// What the room did to a ball during a step.
struct Hit {
    /// Direction of the total contact impulse on the ball (unit).
    normal: Vec3,
    /// Contact point of the largest impulse, world frame.
    point: Vec3,
    /// Label of the triangle that took the largest impulse.
    label: u8,
}

/// Sums the impulses the room's colliders applied to `ball` during the last step; `None`
/// when there were none.
fn contact_impulses(
    world: &PhysicsWorld,
    ball: ColliderHandle,
    surfaces: &HashMap<ColliderHandle, Arc<Surface>>,
) -> Option<Hit> {
    let mut total = Vec3::ZERO;
    let mut best: Option<(f32, Vec3, u8)> = None;
    for pair in world.narrow_phase.contact_pairs_with(ball) {
        let (mesh, mesh_is_first) =
            if pair.collider1 == ball { (pair.collider2, false) } else { (pair.collider1, true) };
        let Some(surface) = surfaces.get(&mesh) else { continue };
        for manifold in pair.manifolds() {
            let tri = if mesh_is_first { manifold.subshape1 } else { manifold.subshape2 };
            let label = surface.labels.get(tri as usize).copied().unwrap_or(UNLABELED);
            // The manifold normal points from collider 1 to collider 2: make it point at the ball.
            let n = manifold.data.normal;
            let n = Vec3::new(n.x, n.y, n.z) * if mesh_is_first { 1.0 } else { -1.0 };
            for p in &manifold.points {
                if p.data.impulse <= 0.0 {
                    continue;
                }
                total += n * p.data.impulse;
                // Room colliders are only translated (by `origin`), never turned.
                let local = if mesh_is_first { p.local_p1 } else { p.local_p2 };
                if best.is_none_or(|(j, _, _)| p.data.impulse > j) {
                    best = Some((p.data.impulse, Vec3::new(local.x, local.y, local.z) + surface.origin, label));
                }
            }
        }
    }
    let (_, point, label) = best?;
    Some(Hit { normal: total.try_normalize()?, point, label })
}

/// Per-triangle data of one room collider.
struct Surface {
    labels: Vec<u8>,
    /// The collider's translation (zero for the regions, which sit at the identity pose;
    /// the ground plane's point on its boundary), which takes contact points from the
    /// collider's frame to the world's.
    origin: Vec3,
}

/// Sets each room manifold's friction from the class of its triangle, and its restitution
/// to 0: the scene applies restitution itself (see the module documentation).
struct MaterialHooks<'a> {
    surfaces: &'a HashMap<ColliderHandle, Arc<Surface>>,
    materials: &'a MaterialTable,
}

impl PhysicsHooks for MaterialHooks<'_> {
    fn modify_solver_contacts(&self, context: &mut ContactModificationContext) {
        let (c1, c2) = (context.collider1, context.collider2);
        let Some(rigid) = context.rigid_mut() else { return };
        let (surface, tri) = if let Some(s) = self.surfaces.get(&c1) {
            (s, rigid.manifold.subshape1)
        } else if let Some(s) = self.surfaces.get(&c2) {
            (s, rigid.manifold.subshape2)
        } else {
            return;
        };
        let m = self.materials.label(surface.labels.get(tri as usize).copied().unwrap_or(UNLABELED));
        *rigid.restitution = 0.0;
        *rigid.friction = m.friction;
    }
}
