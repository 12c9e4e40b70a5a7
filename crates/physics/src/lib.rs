//! AR physics for semrecon, the paper's application: virtual balls thrown into the
//! reconstructed room bounce off its surfaces with a restitution and friction chosen by
//! each surface's semantic class (soft on a sofa, hard on a floor or table).
//!
//! - [`materials`]: per-class materials from an editable TOML file (defaults shipped).
//! - [`collision_mesh`]: the labelled mesh simplified and split into regions, so a live
//!   map update rebuilds only what changed.
//! - [`scene`]: the rapier scene, balls with continuous collision detection, trajectories.
//! - [`throw_from_ply`]: one throw into a PLY mesh, what `semrecon throw` runs.
#![warn(missing_docs)]

pub mod collision_mesh;
pub mod error;
pub mod materials;
pub mod scene;
mod throw;

pub use collision_mesh::{CollisionMesh, CollisionMeshConfig, CollisionRegion, RegionKey};
pub use error::{PhysicsError, Result};
pub use materials::{Material, MaterialTable, DEFAULT_MATERIALS_TOML};
pub use scene::{ArScene, BallId, Contact, RegionDiff, SceneConfig, Throw, FLOOR_PLANE_DROP};
pub use throw::{throw_from_ply, throw_into_mesh};
