//! Per-stage timing statistics (median, p95, max) for the tables the commands print and the
//! `stages` object of `report.json`.

use std::time::Duration;

/// Durations recorded per named stage, in the order stages first appear.
#[derive(Default)]
pub struct StageTimes {
    stages: Vec<(String, Vec<f64>)>,
}

/// Summary of one stage in milliseconds.
pub struct StageSummary {
    pub median_ms: f64,
    pub p95_ms: f64,
    pub max_ms: f64,
    pub count: usize,
}

impl StageTimes {
    /// Adds one measurement of `stage`.
    pub fn record(&mut self, stage: &str, elapsed: Duration) {
        let ms = elapsed.as_secs_f64() * 1e3;
        match self.stages.iter_mut().find(|(name, _)| name == stage) {
            Some((_, v)) => v.push(ms),
            None => self.stages.push((stage.to_string(), vec![ms])),
        }
    }

    /// Median, p95 (nearest rank) and max of every stage.
    pub fn summaries(&self) -> Vec<(&str, StageSummary)> {
        self.stages
            .iter()
            .map(|(name, v)| {
                let mut s = v.clone();
                s.sort_by(f64::total_cmp);
                let rank = |q: f64| s[((q * s.len() as f64).ceil() as usize).clamp(1, s.len()) - 1];
                (
                    name.as_str(),
                    StageSummary { median_ms: rank(0.5), p95_ms: rank(0.95), max_ms: s[s.len() - 1], count: s.len() },
                )
            })
            .collect()
    }

    /// `{stage: {median_ms, p95_ms, max_ms, count}}`.
    pub fn to_json(&self) -> serde_json::Value {
        let mut map = serde_json::Map::new();
        for (name, s) in self.summaries() {
            map.insert(
                name.to_string(),
                serde_json::json!({"median_ms": s.median_ms, "p95_ms": s.p95_ms, "max_ms": s.max_ms, "count": s.count}),
            );
        }
        serde_json::Value::Object(map)
    }

    /// The table the commands print.
    pub fn print_table(&self) {
        println!("{:<20} {:>10} {:>10} {:>10} {:>7}", "stage", "median ms", "p95 ms", "max ms", "count");
        for (name, s) in self.summaries() {
            println!("{:<20} {:>10.2} {:>10.2} {:>10.2} {:>7}", name, s.median_ms, s.p95_ms, s.max_ms, s.count);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn summaries_use_nearest_rank() {
        let mut t = StageTimes::default();
        for ms in 1..=100 {
            t.record("fusion", Duration::from_millis(ms));
        }
        let s = &t.summaries()[0].1;
        assert_eq!((s.median_ms.round(), s.p95_ms.round(), s.max_ms.round(), s.count), (50.0, 95.0, 100.0, 100));
    }
}
