//! Fitting the home head ([`crate::home_head`]) on rows of frozen features: softmax
//! cross-entropy with class weights, Adam, mini-batches in a seeded order.
//!
//! Written by hand rather than with burn (the `train` feature): the head is one hidden layer
//! over a few hundred thousand rows and fits in seconds, where burn's build alone takes about
//! ten minutes on two cores; the gradient is checked against finite differences in the tests.
//! Each batch's gradient is summed over fixed slices in a fixed order, so the fitted head is
//! the same bits for any thread count.

use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use rayon::prelude::*;

use crate::error::{NetError, Result};
use crate::home_head::{HomeHead, OBJECTS};

/// Rows per parallel slice of a batch (fixed, so that the sum's order never depends on the
/// thread count).
const GRADIENT_SLICE: usize = 64;

/// Settings of a fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitConfig {
    /// Hidden units.
    pub hidden: usize,
    /// Passes over the rows.
    pub epochs: usize,
    /// Rows per step.
    pub batch: usize,
    /// Adam's step size (halved for the last third of the epochs).
    pub learning_rate: f32,
    /// L2 penalty on the weight matrices.
    pub weight_decay: f32,
    /// Class weights are `(count / mean count)^-power` (0: none, 0.5: inverse square root).
    pub balance_power: f32,
    /// Seed of the initialisation and the row order.
    pub seed: u64,
}

impl Default for FitConfig {
    fn default() -> Self {
        Self {
            hidden: 64,
            epochs: 12,
            batch: 256,
            learning_rate: 2e-3,
            weight_decay: 1e-4,
            balance_power: 0.5,
            seed: 1,
        }
    }
}

/// Fits a head on `rows` (`[n, inputs]`) with targets `targets` (`[n]`, indices into
/// [`crate::home_head::OBJECTS`]).
///
/// # Errors
/// [`NetError::InvalidInput`] for mismatched lengths, a target out of range or no rows.
pub fn fit_home_head(rows: &[f32], targets: &[u8], inputs: usize, config: &FitConfig) -> Result<HomeHead> {
    let n = targets.len();
    if n == 0 || rows.len() != n * inputs || inputs == 0 {
        return Err(NetError::InvalidInput(format!("{} values for {n} rows of {inputs} inputs", rows.len())));
    }
    if let Some(t) = targets.iter().find(|&&t| t as usize >= OBJECTS) {
        return Err(NetError::InvalidInput(format!("target {t} out of the {OBJECTS} object classes")));
    }
    let h = config.hidden.max(1);
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    let he = |fan_in: usize| {
        Normal::new(0.0f32, (2.0 / fan_in as f32).sqrt()).map_err(|e| NetError::InvalidInput(e.to_string()))
    };
    let (n1, n2) = (he(inputs)?, he(h)?);
    let mut p = MlpParams {
        w1: (0..inputs * h).map(|_| n1.sample(&mut rng)).collect(),
        b1: vec![0.0; h],
        w2: (0..h * OBJECTS).map(|_| n2.sample(&mut rng) * 0.5).collect(),
        b2: vec![0.0; OBJECTS],
    };
    let weights = class_weights(targets, config.balance_power);
    let mut adam = Adam::new(&p);
    let mut order: Vec<usize> = (0..n).collect();
    let mut grad = p.zeros();
    for epoch in 0..config.epochs {
        order.shuffle(&mut rng);
        let lr = if epoch * 3 >= config.epochs * 2 { config.learning_rate * 0.5 } else { config.learning_rate };
        for batch in order.chunks(config.batch.max(1)) {
            // Fixed slices of the batch in parallel, summed in their order: the same bits for
            // any number of threads.
            let parts: Vec<(MlpParams, f32)> = batch
                .par_chunks(GRADIENT_SLICE)
                .map(|slice| {
                    let mut g = p.zeros();
                    let mut total = 0.0;
                    for &r in slice {
                        let w = weights[targets[r] as usize];
                        total += w;
                        p.accumulate_gradient(&rows[r * inputs..(r + 1) * inputs], targets[r] as usize, w, &mut g);
                    }
                    (g, total)
                })
                .collect();
            grad.clear();
            let mut total = 0.0;
            for (g, t) in &parts {
                grad.add(g);
                total += t;
            }
            grad.scale(1.0 / total.max(1e-6));
            grad.add_decay(&p, config.weight_decay);
            adam.step(&mut p, &grad, lr);
        }
    }
    HomeHead::new(inputs, h, p.w1, p.b1, p.w2, p.b2)
}

/// Weight of each object class: `(count / mean count)^-power` over the classes present
/// (absent classes weigh 0).
fn class_weights(targets: &[u8], power: f32) -> [f32; OBJECTS] {
    let mut count = [0usize; OBJECTS];
    for &t in targets {
        count[t as usize] += 1;
    }
    let present = count.iter().filter(|&&c| c > 0).count().max(1);
    let mean = targets.len() as f32 / present as f32;
    count.map(|c| if c == 0 { 0.0 } else { (c as f32 / mean).powf(-power) })
}

/// The MLP's parameters (or their gradients, or Adam's moments: the same shapes).
#[derive(Debug, Clone)]
struct MlpParams {
    w1: Vec<f32>,
    b1: Vec<f32>,
    w2: Vec<f32>,
    b2: Vec<f32>,
}

impl MlpParams {
    fn zeros(&self) -> Self {
        Self {
            w1: vec![0.0; self.w1.len()],
            b1: vec![0.0; self.b1.len()],
            w2: vec![0.0; self.w2.len()],
            b2: vec![0.0; self.b2.len()],
        }
    }

    fn parts_mut(&mut self) -> [&mut Vec<f32>; 4] {
        [&mut self.w1, &mut self.b1, &mut self.w2, &mut self.b2]
    }

    fn clear(&mut self) {
        for part in self.parts_mut() {
            part.fill(0.0);
        }
    }

    fn add(&mut self, other: &MlpParams) {
        let theirs = [&other.w1, &other.b1, &other.w2, &other.b2];
        for (mine, theirs) in self.parts_mut().into_iter().zip(theirs) {
            for (a, b) in mine.iter_mut().zip(theirs) {
                *a += b;
            }
        }
    }

    fn scale(&mut self, s: f32) {
        for part in self.parts_mut() {
            part.iter_mut().for_each(|g| *g *= s);
        }
    }

    fn add_decay(&mut self, p: &MlpParams, decay: f32) {
        for (g, w) in self.w1.iter_mut().zip(&p.w1) {
            *g += decay * w;
        }
        for (g, w) in self.w2.iter_mut().zip(&p.w2) {
            *g += decay * w;
        }
    }

    /// Adds `weight x d(cross-entropy)/d(params)` of one row to `grad`; returns the loss.
    fn accumulate_gradient(&self, x: &[f32], target: usize, weight: f32, grad: &mut MlpParams) -> f32 {
        let h = self.b1.len();
        let mut pre = self.b1.clone();
        for (i, &xi) in x.iter().enumerate() {
            if xi != 0.0 {
                for (a, w) in pre.iter_mut().zip(&self.w1[i * h..(i + 1) * h]) {
                    *a += xi * w;
                }
            }
        }
        let act: Vec<f32> = pre.iter().map(|&a| a.max(0.0)).collect();
        let mut logits = [0f32; OBJECTS];
        logits.copy_from_slice(&self.b2);
        for (j, &aj) in act.iter().enumerate() {
            if aj > 0.0 {
                for (o, w) in logits.iter_mut().zip(&self.w2[j * OBJECTS..(j + 1) * OBJECTS]) {
                    *o += aj * w;
                }
            }
        }
        let max = logits.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        let mut prob = logits.map(|l| (l - max).exp());
        let sum: f32 = prob.iter().sum();
        prob.iter_mut().for_each(|q| *q /= sum);
        let loss = -prob[target].max(1e-12).ln() * weight;
        // d loss / d logits = weight (p - onehot).
        let mut dl = prob;
        dl[target] -= 1.0;
        dl.iter_mut().for_each(|d| *d *= weight);
        let mut dact = vec![0f32; h];
        for j in 0..h {
            let row = &self.w2[j * OBJECTS..(j + 1) * OBJECTS];
            let g = &mut grad.w2[j * OBJECTS..(j + 1) * OBJECTS];
            for k in 0..OBJECTS {
                g[k] += act[j] * dl[k];
                dact[j] += row[k] * dl[k];
            }
        }
        for (g, d) in grad.b2.iter_mut().zip(&dl) {
            *g += d;
        }
        for j in 0..h {
            if pre[j] <= 0.0 {
                dact[j] = 0.0;
            }
            grad.b1[j] += dact[j];
        }
        for (i, &xi) in x.iter().enumerate() {
            if xi != 0.0 {
                for (g, d) in grad.w1[i * h..(i + 1) * h].iter_mut().zip(&dact) {
                    *g += xi * d;
                }
            }
        }
        loss
    }
}

/// Adam's moments.
struct Adam {
    m: MlpParams,
    v: MlpParams,
    t: i32,
}

impl Adam {
    fn new(p: &MlpParams) -> Self {
        Self { m: p.zeros(), v: p.zeros(), t: 0 }
    }

    fn step(&mut self, p: &mut MlpParams, g: &MlpParams, lr: f32) {
        const B1: f32 = 0.9;
        const B2: f32 = 0.999;
        const EPS: f32 = 1e-8;
        self.t += 1;
        let (c1, c2) = (1.0 - B1.powi(self.t), 1.0 - B2.powi(self.t));
        let gs = [&g.w1, &g.b1, &g.w2, &g.b2];
        let ms = self.m.parts_mut();
        let vs = self.v.parts_mut();
        for (((pp, gg), mm), vv) in p.parts_mut().into_iter().zip(gs).zip(ms).zip(vs) {
            for i in 0..pp.len() {
                mm[i] = B1 * mm[i] + (1.0 - B1) * gg[i];
                vv[i] = B2 * vv[i] + (1.0 - B2) * gg[i] * gg[i];
                pp[i] -= lr * (mm[i] / c1) / ((vv[i] / c2).sqrt() + EPS);
            }
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn the_gradient_matches_finite_differences() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let normal = Normal::new(0.0f32, 0.7).unwrap();
        let (inputs, h) = (5, 4);
        let mut v = |n: usize| (0..n).map(|_| normal.sample(&mut rng)).collect::<Vec<f32>>();
        let p = MlpParams { w1: v(inputs * h), b1: v(h), w2: v(h * OBJECTS), b2: v(OBJECTS) };
        let x = v(inputs);
        let mut g = p.zeros();
        p.accumulate_gradient(&x, 3, 1.5, &mut g);
        let loss = |q: &MlpParams| q.accumulate_gradient(&x, 3, 1.5, &mut q.zeros()) as f64;
        let eps = 1e-2f32;
        for part in 0..4 {
            for i in 0..[p.w1.len(), p.b1.len(), p.w2.len(), p.b2.len()][part] {
                let (mut a, mut b) = (p.clone(), p.clone());
                a.parts_mut()[part][i] += eps;
                b.parts_mut()[part][i] -= eps;
                let numeric = (loss(&a) - loss(&b)) / (2.0 * eps as f64);
                let analytic = [&g.w1, &g.b1, &g.w2, &g.b2][part][i] as f64;
                assert!(
                    (numeric - analytic).abs() < 2e-2 * (1.0 + analytic.abs()),
                    "part {part} [{i}]: {numeric} vs {analytic}"
                );
            }
        }
    }

    #[test]
    fn a_separable_problem_is_learned_and_the_fit_is_deterministic() {
        // Class = which of three inputs is largest, plus a height threshold for a fourth.
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let u = rand_distr::Uniform::new(0.0f32, 1.0).unwrap();
        let mut rows = Vec::new();
        let mut targets = Vec::new();
        for _ in 0..3000 {
            let r: Vec<f32> = (0..4).map(|_| u.sample(&mut rng)).collect();
            let t = if r[3] > 0.8 { 3 } else { (0..3).fold(0, |b, k| if r[k] > r[b] { k } else { b }) };
            rows.extend_from_slice(&r);
            targets.push(t as u8);
        }
        let config = FitConfig { hidden: 16, epochs: 30, batch: 64, learning_rate: 1e-2, ..FitConfig::default() };
        let head = fit_home_head(&rows, &targets, 4, &config).unwrap();
        let right = (0..targets.len())
            .filter(|&r| {
                let s = head.scores(&rows[r * 4..(r + 1) * 4]);
                (0..OBJECTS).fold(0, |b, k| if s[k] > s[b] { k } else { b }) == targets[r] as usize
            })
            .count();
        assert!(right as f32 > 0.93 * targets.len() as f32, "{right} of {}", targets.len());
        assert_eq!(head, fit_home_head(&rows, &targets, 4, &config).unwrap());
        assert!(fit_home_head(&rows, &targets[1..], 4, &config).is_err());
        assert!(fit_home_head(&rows[..4], &[OBJECTS as u8], 4, &config).is_err());
    }
}
