//! Per-stage timing statistics (median, p95, max): the pipeline records every stage of every
//! frame and keyframe here, and the command-line tools print and export the summaries.

use std::time::Duration;

/// Durations recorded per named stage, in the order stages first appear.
#[derive(Debug, Clone, Default)]
pub struct StageTimes {
    stages: Vec<(String, Vec<f64>)>,
}

/// Summary of one stage in milliseconds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StageSummary {
    /// Median (nearest rank).
    pub median_ms: f64,
    /// 95th percentile (nearest rank).
    pub p95_ms: f64,
    /// Largest measurement.
    pub max_ms: f64,
    /// Number of measurements.
    pub count: usize,
    /// Sum of the measurements.
    pub total_ms: f64,
}

impl StageTimes {
    /// Adds one measurement of `stage`.
    pub fn record(&mut self, stage: &str, elapsed: Duration) {
        self.record_ms(stage, elapsed.as_secs_f64() * 1e3);
    }

    /// Adds one measurement of `stage` in milliseconds.
    pub fn record_ms(&mut self, stage: &str, ms: f64) {
        match self.stages.iter_mut().find(|(name, _)| name == stage) {
            Some((_, v)) => v.push(ms),
            None => self.stages.push((stage.to_string(), vec![ms])),
        }
    }

    /// Every measurement of `stage` in milliseconds, in recording order (empty when none).
    pub fn samples(&self, stage: &str) -> &[f64] {
        self.stages.iter().find(|(n, _)| n == stage).map_or(&[], |(_, v)| v.as_slice())
    }

    /// The summary of one stage, `None` when it never ran.
    pub fn summary(&self, stage: &str) -> Option<StageSummary> {
        let v = self.samples(stage);
        (!v.is_empty()).then(|| summarize(v))
    }

    /// Median, p95 (nearest rank) and max of every stage, in first-appearance order.
    pub fn summaries(&self) -> Vec<(&str, StageSummary)> {
        self.stages.iter().map(|(name, v)| (name.as_str(), summarize(v))).collect()
    }

    /// Adds every measurement of `other`.
    pub fn merge(&mut self, other: &StageTimes) {
        for (name, v) in &other.stages {
            for &ms in v {
                self.record_ms(name, ms);
            }
        }
    }
}

fn summarize(v: &[f64]) -> StageSummary {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let rank = |q: f64| s[((q * s.len() as f64).ceil() as usize).clamp(1, s.len()) - 1];
    StageSummary {
        median_ms: rank(0.5),
        p95_ms: rank(0.95),
        max_ms: s[s.len() - 1],
        count: s.len(),
        total_ms: s.iter().sum(),
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
        let s = t.summary("fusion").expect("recorded");
        assert_eq!((s.median_ms.round(), s.p95_ms.round(), s.max_ms.round(), s.count), (50.0, 95.0, 100.0, 100));
        assert!(t.summary("tracking").is_none());
    }
}
