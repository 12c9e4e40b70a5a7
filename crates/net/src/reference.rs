//! A plain forward of CBSCN, the oracle of the fused inference's tests (and, later, of the
//! trainer's): convolutions with the engine's naive [`semrecon_sparse::reference`] kernels,
//! batch norm written out as `gamma (x - mean) / sqrt(var + eps) + beta` followed by a
//! separate ReLU, linear layers as loops, level voxel sets and trilinear upsampling computed
//! from coordinates with `std` hash maps. It shares no geometry code with
//! [`crate::inference`]. Slow on purpose: small inputs only.

use std::collections::HashMap;

use semrecon_sparse::reference as conv;
use semrecon_sparse::{Coord, MapKind};

use crate::config::NetConfig;
use crate::error::{NetError, Result};
use crate::model::bn_names;
use crate::weights::Weights;

/// Class scores of every voxel.
///
/// # Shapes
/// `coords`: `[n]` distinct voxels; `features`: `[n, in_channels]`; result `[n, classes]`.
///
/// # Errors
/// Missing tensors, mismatched shapes.
pub fn forward(config: &NetConfig, weights: &Weights, coords: &[Coord], features: &[f32]) -> Result<Vec<f32>> {
    weights.check(config)?;
    let l = config.levels;
    let c = |i: usize| config.channels(i);
    let w = |name: String| weights.get(&name);
    let subm = MapKind::Submanifold { kernel_size: 3 };
    let mut levels = vec![coords.to_vec()];
    for i in 1..l {
        levels.push(parents(&levels[i - 1], 1));
    }
    let bn = |x: &[f32], prefix: String| batch_norm_relu(weights, &prefix, config.bn_eps, x);
    let block = |x: &[f32], prefix: String, lc: &[Coord], ch: usize| -> Result<Vec<f32>> {
        let h = bn(x, format!("{prefix}.bn1"))?;
        let h = conv::forward(subm, lc, lc, &h, ch, w(format!("{prefix}.conv1.weight"))?, ch)?;
        let h = bn(&h, format!("{prefix}.bn2"))?;
        let h = conv::forward(subm, lc, lc, &h, ch, w(format!("{prefix}.conv2.weight"))?, ch)?;
        Ok(x.iter().zip(&h).map(|(a, b)| a + b).collect())
    };

    let x0 = conv::forward(subm, coords, coords, features, config.in_channels, w("input.conv.weight".into())?, c(0))?;
    let mut enc = vec![block(&x0, "extract.0".into(), coords, c(0))?];
    for i in 1..l {
        let h = bn(&enc[i - 1], format!("down.{}.bn", i - 1))?;
        let h = conv::forward(
            MapKind::Down,
            &levels[i - 1],
            &levels[i],
            &h,
            c(i - 1),
            w(format!("down.{}.conv.weight", i - 1))?,
            c(i),
        )?;
        enc.push(block(&h, format!("extract.{i}"), &levels[i], c(i))?);
    }
    // dec[j] = D_j; D_(L-1) = E_(L-1).
    let mut dec: Vec<Vec<f32>> = vec![Vec::new(); l];
    dec[l - 1] = enc[l - 1].clone();
    for t in (0..l.saturating_sub(1)).rev() {
        let h = bn(&dec[t + 1], format!("up.{t}.bn"))?;
        let up = conv::forward(
            MapKind::Up,
            &levels[t + 1],
            &levels[t],
            &h,
            c(t + 1),
            w(format!("up.{t}.conv.weight"))?,
            c(t),
        )?;
        let skip = linear(&enc[t], c(t), w(format!("up.{t}.skip.weight"))?, c(t));
        let sum: Vec<f32> = up.iter().zip(&skip).map(|(a, b)| a + b).collect();
        let mut d = block(&sum, format!("up.{t}"), &levels[t], c(t))?;
        if l >= 2 {
            for j in t + 1..=l.saturating_sub(2) {
                let att = linear(&dec[j], c(j), w(format!("fuse.{t}.{j}.attention.weight"))?, 1);
                let mut val = linear(&dec[j], c(j), w(format!("fuse.{t}.{j}.value.weight"))?, c(t));
                for (r, &a) in att.iter().enumerate() {
                    let s = 1.0 / (1.0 + (-a).exp());
                    val[r * c(t)..(r + 1) * c(t)].iter_mut().for_each(|v| *v *= s);
                }
                let f = upsample_trilinear(&levels[j], &val, c(t), &levels[t], (j - t) as u32)?;
                d.iter_mut().zip(&f).for_each(|(a, b)| *a += b);
            }
        }
        dec[t] = d;
    }
    let h = bn(&dec[0], "head.bn".into())?;
    let mut logits = linear(&h, c(0), w("head.linear.weight".into())?, config.classes);
    let bias = w("head.linear.bias".into())?;
    for row in logits.chunks_exact_mut(config.classes) {
        row.iter_mut().zip(bias).for_each(|(v, b)| *v += b);
    }
    Ok(logits)
}

/// Distinct `floor(u / 2^shift)` of `fine`, in order of first appearance.
fn parents(fine: &[Coord], shift: u32) -> Vec<Coord> {
    let f = 1i32 << shift;
    let mut seen = HashMap::new();
    let mut out = Vec::new();
    for u in fine {
        let p = [u[0].div_euclid(f), u[1].div_euclid(f), u[2].div_euclid(f), u[3]];
        seen.entry(p).or_insert_with(|| {
            out.push(p);
        });
    }
    out
}

/// `max(0, gamma (x - mean) / sqrt(var + eps) + beta)` per channel.
fn batch_norm_relu(w: &Weights, prefix: &str, eps: f32, x: &[f32]) -> Result<Vec<f32>> {
    let [g, b, m, v] = bn_names(prefix);
    let (g, b, m, v) = (w.get(&g)?, w.get(&b)?, w.get(&m)?, w.get(&v)?);
    let ch = g.len();
    let mut y = x.to_vec();
    for row in y.chunks_exact_mut(ch) {
        for k in 0..ch {
            let n = g[k] * (row[k] - m[k]) / (v[k] + eps).sqrt() + b[k];
            row[k] = n.max(0.0);
        }
    }
    Ok(y)
}

/// `y = x W` row by row, `f64` accumulation.
fn linear(x: &[f32], c_in: usize, w: &[f32], c_out: usize) -> Vec<f32> {
    let mut y = Vec::with_capacity(x.len() / c_in.max(1) * c_out);
    for row in x.chunks_exact(c_in) {
        for o in 0..c_out {
            let s: f64 = row.iter().enumerate().map(|(i, &v)| f64::from(v) * f64::from(w[i * c_out + o])).sum();
            y.push(s as f32);
        }
    }
    y
}

/// Trilinear upsampling on sparse voxels by a factor `2^shift`: every fine voxel interpolates
/// from the coarse voxels whose centres bracket its centre, with the weights of absent coarse
/// voxels dropped and the rest renormalised.
///
/// # Shapes
/// `coarse`: `[m]`; `values`: `[m, channels]`; `fine`: `[n]`; result `[n, channels]`.
///
/// # Errors
/// [`NetError::InvalidInput`] when a fine voxel has no coarse voxel around it or the values
/// do not match.
pub fn upsample_trilinear(
    coarse: &[Coord],
    values: &[f32],
    channels: usize,
    fine: &[Coord],
    shift: u32,
) -> Result<Vec<f32>> {
    if values.len() != coarse.len() * channels {
        return Err(NetError::InvalidInput(format!(
            "{} values for {} coarse voxels of {channels} channels",
            values.len(),
            coarse.len()
        )));
    }
    let index: HashMap<Coord, usize> = coarse.iter().enumerate().map(|(i, &c)| (c, i)).collect();
    let f = f64::from(1u32 << shift);
    let mut out = vec![0f32; fine.len() * channels];
    for (u, fc) in fine.iter().enumerate() {
        // Centre of the fine voxel in coarse units, shifted so that coarse centres are integers.
        let p: Vec<f64> = (0..3).map(|a| (f64::from(fc[a]) + 0.5) / f - 0.5).collect();
        let base: Vec<f64> = p.iter().map(|v| v.floor()).collect();
        let mut acc = vec![0f64; channels];
        let mut total = 0f64;
        for corner in 0..8 {
            let mut key = [0i32; 4];
            let mut weight = 1.0;
            for a in 0..3 {
                let hi = (corner >> a) & 1 == 1;
                let frac = p[a] - base[a];
                key[a] = base[a] as i32 + i32::from(hi);
                weight *= if hi { frac } else { 1.0 - frac };
            }
            key[3] = fc[3];
            if let Some(&r) = index.get(&key) {
                total += weight;
                for (k, a) in acc.iter_mut().enumerate() {
                    *a += weight * f64::from(values[r * channels + k]);
                }
            }
        }
        if total <= 0.0 {
            return Err(NetError::InvalidInput(format!("fine voxel {fc:?} has no coarse voxel around it")));
        }
        for (k, a) in acc.iter().enumerate() {
            out[u * channels + k] = (a / total) as f32;
        }
    }
    Ok(out)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn trilinear_interpolates_linearly_between_two_voxels() {
        let coarse = [[0, 0, 0, 0], [1, 0, 0, 0]];
        let fine: Vec<Coord> = (0..4).map(|x| [x, 0, 1, 0]).collect();
        let y = upsample_trilinear(&coarse, &[1.0, 3.0], 1, &fine, 1).unwrap();
        assert_eq!(y, vec![1.0, 1.5, 2.5, 3.0]);
        assert!(upsample_trilinear(&coarse, &[1.0, 3.0], 1, &[[9, 9, 9, 0]], 1).is_err());
    }
}
