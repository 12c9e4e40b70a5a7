//! The process's memory beside the map's, for `report.json` and the summary: the live mesh's
//! chunk store and the resident peak. A whole home's budget (`--max-memory`) bounds the map;
//! these say what the rest of the process costs, so that a user can size a device from a run.

use semrecon_recon::MeshStoreMemory;
use serde::Serialize;

/// The `process_memory` object of `report.json`.
#[derive(Debug, Clone, Serialize)]
pub struct ProcessMemoryReport {
    /// Heap bytes of the live mesh's chunk store at the end: meshes at their allocated
    /// capacity, and entries and index.
    pub mesh_store_bytes: usize,
    /// The chunk meshes at their lengths (what they need).
    pub mesh_store_used_bytes: usize,
    /// Heap bytes of the semantic map at the end (surface cells, their per-chunk sums and the
    /// labels' evidence; `null` with semantics off).
    pub semantic_map_bytes: Option<usize>,
    /// The most memory the process held resident (Linux `VmHWM`; `null` elsewhere), taken
    /// after the outputs were written.
    pub peak_resident_bytes: Option<usize>,
}

impl ProcessMemoryReport {
    /// The report for a mesh store's `memory` and the semantic map's bytes, with the
    /// process's peak read now.
    pub fn new(memory: MeshStoreMemory, semantic_map_bytes: Option<usize>) -> Self {
        Self {
            mesh_store_bytes: memory.total(),
            mesh_store_used_bytes: memory.mesh_used_bytes,
            semantic_map_bytes,
            peak_resident_bytes: peak_resident_bytes(),
        }
    }

    /// One line for the summary.
    pub fn summary(&self) -> String {
        let mb = |b: usize| b as f64 / 1e6;
        format!(
            "process memory: live mesh {:.0} MB ({:.0} MB of packed chunk meshes),{} peak resident {}",
            mb(self.mesh_store_bytes),
            mb(self.mesh_store_used_bytes),
            self.semantic_map_bytes.map_or(String::new(), |b| format!(" semantic map {:.0} MB,", mb(b))),
            self.peak_resident_bytes.map_or("n/a".to_string(), |b| format!("{:.0} MB", mb(b)))
        )
    }
}

/// The process's resident peak from `/proc/self/status` (`VmHWM`, kB), `None` where there is
/// no such file (not Linux) or it has no such line.
pub fn peak_resident_bytes() -> Option<usize> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    parse_vm_hwm(&status)
}

fn parse_vm_hwm(status: &str) -> Option<usize> {
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: usize = line.trim_start_matches("VmHWM:").trim().trim_end_matches("kB").trim().parse().ok()?;
    Some(kb * 1024)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_the_resident_peak_line() {
        let status = "Name:\tsemrecon\nVmPeak:\t  100 kB\nVmHWM:\t    2048 kB\nVmRSS:\t 1024 kB\n";
        assert_eq!(parse_vm_hwm(status), Some(2048 * 1024));
        assert_eq!(parse_vm_hwm("Name: x\n"), None);
        assert_eq!(parse_vm_hwm("VmHWM: lots kB\n"), None);
    }

    #[test]
    fn the_peak_is_known_on_linux() {
        if cfg!(target_os = "linux") {
            assert!(peak_resident_bytes().is_some_and(|b| b > 0));
        }
    }
}
