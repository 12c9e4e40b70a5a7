//! Per-stage timing tables: the table the commands print, in the layout of the paper's
//! Table 5 (tracking, global optimisation, reconstruction, semantic segmentation), and the
//! `stages` object of `report.json`. The statistics themselves are
//! [`semrecon_pipeline::StageTimes`], recorded by the pipeline.

pub use semrecon_pipeline::StageTimes;

/// One row of the Table 5 layout: `(label, stage name in the timings)`.
const TABLE5: [(&str, &str); 6] = [
    ("frame tracking (per frame)", "tracking"),
    ("global pose optimisation (per keyframe, back end)", "global pose optimisation"),
    ("reconstruction: fusion (per frame)", "fusion"),
    ("reconstruction: meshing (per keyframe)", "meshing"),
    ("semantic snapshot (per keyframe, front end)", "semantic snapshot"),
    ("semantic segmentation (per pass, back end)", "semantic"),
];

/// Prints the per-component table in the layout of the paper's Table 5, then the other
/// recorded stages. The mean is there beside the median because some stages are bimodal:
/// fusion with far groups ([`semrecon_recon::GroupedFusion`]) fuses far chunks at one frame
/// of each group, so its median is a near-only frame's and its mean the cost per frame.
pub fn print_table(times: &StageTimes) {
    println!(
        "{:<46} {:>10} {:>10} {:>10} {:>10} {:>7}",
        "component", "median ms", "mean ms", "p95 ms", "max ms", "count"
    );
    let row = |label: &str, s: &semrecon_pipeline::StageSummary| {
        let mean = s.total_ms / s.count.max(1) as f64;
        println!("{label:<46} {:>10.2} {mean:>10.2} {:>10.2} {:>10.2} {:>7}", s.median_ms, s.p95_ms, s.max_ms, s.count)
    };
    for (label, stage) in TABLE5 {
        match times.summary(stage) {
            Some(s) => row(label, &s),
            None => println!("{label:<46} {:>10}", "n/a (did not run)"),
        }
    }
    for (name, s) in times.summaries() {
        if !TABLE5.iter().any(|(_, st)| *st == name) {
            row(name, &s);
        }
    }
}

/// `{stage: {median_ms, p95_ms, max_ms, count}}` with `tracking`, `fusion`, `meshing` and
/// `semantic` always present (zeros when a stage never ran), then the others.
pub fn stages_json(times: &StageTimes) -> serde_json::Value {
    const ALWAYS: [&str; 4] = ["tracking", "fusion", "meshing", "semantic"];
    let mut map = serde_json::Map::new();
    let mut names: Vec<&str> = ALWAYS.to_vec();
    let summaries = times.summaries();
    names.extend(summaries.iter().map(|(n, _)| *n).filter(|n| !ALWAYS.contains(n)));
    for name in names {
        let s = times.summary(name);
        map.insert(
            name.to_string(),
            serde_json::json!({
                "median_ms": s.map_or(0.0, |s| s.median_ms),
                "p95_ms": s.map_or(0.0, |s| s.p95_ms),
                "max_ms": s.map_or(0.0, |s| s.max_ms),
                "count": s.map_or(0, |s| s.count),
                "total_ms": s.map_or(0.0, |s| s.total_ms),
            }),
        );
    }
    serde_json::Value::Object(map)
}
