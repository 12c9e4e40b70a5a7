//! Per-stage timing tables: the table the commands print, in the layout of the paper's
//! Table 5 (tracking, global optimisation, reconstruction, semantic segmentation), and the
//! `stages` object of `report.json`. The statistics themselves are
//! [`semrecon_pipeline::StageTimes`], recorded by the pipeline.

pub use semrecon_pipeline::StageTimes;

/// One row of the Table 5 layout: `(label, stage name in the timings)`.
const TABLE5: [(&str, &str); 6] = [
    ("frame tracking (per frame)", "tracking"),
    ("global pose optimisation (per keyframe)", "global pose optimisation"),
    ("reconstruction: fusion (per frame)", "fusion"),
    ("reconstruction: meshing (per keyframe)", "meshing"),
    ("semantic snapshot (per keyframe, front end)", "semantic snapshot"),
    ("semantic segmentation (per pass, back end)", "semantic"),
];

/// Prints the per-component table in the layout of the paper's Table 5, then the other
/// recorded stages.
pub fn print_table(times: &StageTimes) {
    println!("{:<46} {:>10} {:>10} {:>10} {:>7}", "component", "median ms", "p95 ms", "max ms", "count");
    for (label, stage) in TABLE5 {
        match times.summary(stage) {
            Some(s) => {
                println!("{label:<46} {:>10.2} {:>10.2} {:>10.2} {:>7}", s.median_ms, s.p95_ms, s.max_ms, s.count)
            }
            None => println!("{label:<46} {:>10}", "n/a (did not run)"),
        }
    }
    for (name, s) in times.summaries() {
        if !TABLE5.iter().any(|(_, st)| *st == name) {
            println!("{name:<46} {:>10.2} {:>10.2} {:>10.2} {:>7}", s.median_ms, s.p95_ms, s.max_ms, s.count);
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
