//! Segmentation metrics: a confusion matrix over the classes and what the paper reports from
//! it (per-class IoU, mean IoU, overall accuracy). Ground truth labelled [`UNLABELED`] is not
//! counted, and a class that occurs neither in the ground truth nor in the prediction is left
//! out of the mean (its IoU is 0/0, which means nothing).

use semrecon_data::class::UNLABELED;

/// Counts of (true class, predicted class) pairs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ConfusionMatrix {
    classes: usize,
    /// Row-major `[classes (truth), classes + 1 (prediction)]`; the last column counts
    /// predictions outside the class range (always wrong).
    counts: Vec<u64>,
}

impl ConfusionMatrix {
    /// An empty matrix over `classes` classes.
    pub fn new(classes: usize) -> Self {
        Self { classes, counts: vec![0; classes * (classes + 1)] }
    }

    /// Number of classes.
    pub fn classes(&self) -> usize {
        self.classes
    }

    /// Adds pairs; truths of [`UNLABELED`] (or out of range) are skipped.
    ///
    /// # Shapes
    /// `truth` and `prediction`: `[n]`; extra entries of the longer one are ignored.
    pub fn add(&mut self, truth: &[u8], prediction: &[u8]) {
        let k = self.classes;
        for (&t, &p) in truth.iter().zip(prediction) {
            let (t, p) = (t as usize, (p as usize).min(k));
            if t == UNLABELED as usize || t >= k {
                continue;
            }
            self.counts[t * (k + 1) + p] += 1;
        }
    }

    /// Adds every count of `other` (same number of classes).
    pub fn merge(&mut self, other: &Self) {
        debug_assert_eq!(self.classes, other.classes);
        for (a, b) in self.counts.iter_mut().zip(&other.counts) {
            *a += b;
        }
    }

    /// Number of pairs with this truth and prediction.
    pub fn count(&self, truth: usize, prediction: usize) -> u64 {
        self.counts[truth * (self.classes + 1) + prediction]
    }

    /// All counted pairs.
    pub fn total(&self) -> u64 {
        self.counts.iter().sum()
    }

    /// Intersection over union of every class; `None` for a class absent from both the truth
    /// and the prediction.
    pub fn iou(&self) -> Vec<Option<f64>> {
        let k = self.classes;
        (0..k)
            .map(|c| {
                let tp = self.count(c, c);
                let truth: u64 = (0..=k).map(|p| self.count(c, p)).sum();
                let predicted: u64 = (0..k).map(|t| self.count(t, c)).sum();
                let union = truth + predicted - tp;
                (union > 0).then(|| tp as f64 / union as f64)
            })
            .collect()
    }

    /// Mean of the defined per-class IoUs (0 when none is defined).
    pub fn miou(&self) -> f64 {
        let defined: Vec<f64> = self.iou().into_iter().flatten().collect();
        if defined.is_empty() {
            0.0
        } else {
            defined.iter().sum::<f64>() / defined.len() as f64
        }
    }

    /// Mean IoU over the classes present in the truth (0 when none is). On one scene, a
    /// class the scene lacks scores 0 in [`ConfusionMatrix::miou`] as soon as a single vertex
    /// is predicted as it; this mean leaves such classes out (their false positives still
    /// lower the IoU of the true classes they were taken from).
    pub fn miou_present(&self) -> f64 {
        let k = self.classes;
        let present: Vec<f64> = self
            .iou()
            .into_iter()
            .enumerate()
            .filter(|&(c, _)| (0..=k).any(|p| self.count(c, p) > 0))
            .filter_map(|(_, iou)| iou)
            .collect();
        if present.is_empty() {
            0.0
        } else {
            present.iter().sum::<f64>() / present.len() as f64
        }
    }

    /// Share of counted pairs predicted right (0 when nothing was counted).
    pub fn accuracy(&self) -> f64 {
        let total = self.total();
        if total == 0 {
            return 0.0;
        }
        (0..self.classes).map(|c| self.count(c, c)).sum::<u64>() as f64 / total as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn iou_matches_hand_count() {
        let mut m = ConfusionMatrix::new(3);
        // truth 0: 0,0,1  truth 1: 1  truth 2: never; prediction 2 once (for truth 1).
        m.add(&[0, 0, 0, 1, 1, UNLABELED], &[0, 0, 1, 1, 2, 0]);
        let iou = m.iou();
        assert_eq!(iou[0], Some(2.0 / 3.0));
        assert_eq!(iou[1], Some(1.0 / 3.0));
        assert_eq!(iou[2], Some(0.0));
        assert!((m.miou() - (2.0 / 3.0 + 1.0 / 3.0) / 3.0).abs() < 1e-12);
        assert!((m.accuracy() - 3.0 / 5.0).abs() < 1e-12);
        // Class 2 is predicted but absent from the truth: left out of the present mean.
        assert!((m.miou_present() - (2.0 / 3.0 + 1.0 / 3.0) / 2.0).abs() < 1e-12);
    }

    #[test]
    fn absent_classes_are_left_out_and_out_of_range_predictions_are_wrong() {
        let mut m = ConfusionMatrix::new(13);
        m.add(&[5, 5], &[5, 200]);
        assert_eq!(m.iou().iter().filter(|v| v.is_some()).count(), 1);
        assert_eq!(m.miou(), 0.5);
        assert_eq!(m.accuracy(), 0.5);
        let mut other = ConfusionMatrix::new(13);
        other.add(&[5], &[5]);
        m.merge(&other);
        assert_eq!(m.total(), 3);
    }
}
