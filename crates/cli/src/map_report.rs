//! The map's memory in `report.json` and in the summary: where its bytes are (plain chunks,
//! packed chunks, the spill file), the surface it covers and bytes per square metre, and the
//! memory budget with whether it had to be raised.
//!
//! Surface area is the final mesh's (the sum of its triangles' areas): the surface the map
//! was built to hold, so that maps at other voxel sizes or from other scans compare per
//! square metre, while the chunk count depends on how the band crosses the chunk grid.

use semrecon_data::LabeledMesh;
use semrecon_recon::{MapMemory, TsdfMap};
use serde::Serialize;

/// The `map_memory` object of `report.json`.
#[derive(Debug, Clone, Serialize)]
pub struct MapMemoryReport {
    /// Allocated chunks (8x8x8 voxels).
    pub chunks: usize,
    /// Chunks plain (4 KiB of voxels each: being fused), packed in memory, spilled to disk.
    pub hot_chunks: usize,
    pub packed_chunks: usize,
    pub spilled_chunks: usize,
    /// Bytes in memory, in all and by kind (records: every chunk's key, frame runs and flags,
    /// and the hash index; cache: packed chunks unpacked by readers since the last compaction).
    pub bytes_in_memory: usize,
    pub hot_bytes: usize,
    pub packed_bytes: usize,
    pub record_bytes: usize,
    pub cache_bytes: usize,
    /// Bytes of spilled chunks in the spill file.
    pub spilled_bytes: usize,
    /// Bytes in memory once the scan's end had spilled every packed chunk (with a budget:
    /// nothing reads the map while the final mesh is assembled); `null` without a budget.
    pub bytes_in_memory_after_finish: Option<usize>,
    /// Area of the final mesh, square metres.
    pub surface_m2: f64,
    /// `bytes_in_memory / surface_m2`.
    pub bytes_per_m2: Option<f64>,
    /// `--max-memory` in bytes (`null`: none).
    pub budget_bytes: Option<usize>,
    /// What the budget was raised to because the chunks near the camera needed more
    /// (`null`: not raised).
    pub budget_raised_to: Option<usize>,
}

/// Sum of the triangle areas of `mesh`, square metres.
pub fn mesh_area_m2(mesh: &LabeledMesh) -> f64 {
    mesh.triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
            0.5 * f64::from((b - a).cross(c - a).length())
        })
        .sum()
}

impl MapMemoryReport {
    /// The report of `map`, whose memory at the end of the scan was `m` (the pipeline's
    /// [`semrecon_pipeline::Pipeline::map_memory`]) and whose final mesh is `mesh`.
    pub fn new(map: &TsdfMap, m: MapMemory, mesh: &LabeledMesh) -> Self {
        let surface_m2 = mesh_area_m2(mesh);
        let budget = map.memory_budget();
        Self {
            chunks: m.chunks,
            hot_chunks: m.hot_chunks,
            packed_chunks: m.packed_chunks,
            spilled_chunks: m.spilled_chunks,
            bytes_in_memory: m.in_memory(),
            hot_bytes: m.hot_bytes,
            packed_bytes: m.packed_bytes,
            record_bytes: m.record_bytes,
            cache_bytes: m.cache_bytes,
            spilled_bytes: m.spilled_bytes,
            bytes_in_memory_after_finish: budget.map(|_| map.memory().in_memory()),
            surface_m2,
            bytes_per_m2: (surface_m2 > 0.0).then(|| m.in_memory() as f64 / surface_m2),
            budget_bytes: budget.map(|b| b.0),
            budget_raised_to: budget.and_then(|b| b.1),
        }
    }

    /// One line for the summary.
    pub fn summary(&self) -> String {
        let mb = |b: usize| b as f64 / 1e6;
        let mut line = format!(
            "map: {} chunks ({} plain, {} packed, {} spilled), {:.0} MB in memory ({:.0} plain, {:.0} packed, {:.0} records){}; \
             {:.2} m2 of surface, {}",
            self.chunks,
            self.hot_chunks,
            self.packed_chunks,
            self.spilled_chunks,
            mb(self.bytes_in_memory),
            mb(self.hot_bytes),
            mb(self.packed_bytes + self.cache_bytes),
            mb(self.record_bytes),
            if self.spilled_chunks > 0 { format!(", {:.0} MB spilled to disk", mb(self.spilled_bytes)) } else { String::new() },
            self.surface_m2,
            self.bytes_per_m2.map_or("n/a".to_string(), |b| format!("{:.2} MB/m2", b / 1e6)),
        );
        if let Some(b) = self.budget_bytes {
            line += &format!("; budget {:.0} MB", mb(b));
            if let Some(r) = self.budget_raised_to {
                line += &format!(", raised to {:.0} MB", mb(r));
            }
            if let Some(after) = self.bytes_in_memory_after_finish {
                line += &format!(", {:.0} MB in memory once spilled for the final mesh", mb(after));
            }
        }
        line
    }
}
