//! Image quality metrics (SPEC §8): relMSE, MSE, PSNR, max absolute difference.

/// Metrics of `x` against the reference `r` over the same samples.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Metrics {
    /// `mean (x - r)^2 / (r^2 + 0.01)`.
    pub rel_mse: f64,
    /// `mean (x - r)^2`.
    pub mse: f64,
    /// `10 log10(1 / MSE)` (peak value 1, linear radiance); infinite when equal.
    pub psnr: f64,
    /// Largest `|x - r|`.
    pub max_abs_diff: f64,
    /// Every sample has the same bit pattern.
    pub bitwise_identical: bool,
    /// Samples where `x` or `r` is not finite (excluded from the means).
    pub non_finite: usize,
}

/// Compare channel slices pairwise (`xs[i]` against `refs[i]`).
pub fn compare(xs: &[&[f32]], refs: &[&[f32]]) -> Metrics {
    assert_eq!(xs.len(), refs.len());
    let (mut rel, mut se, mut max_abs, mut n, mut bad) = (0.0f64, 0.0f64, 0.0f64, 0usize, 0usize);
    let mut identical = true;
    for (x, r) in xs.iter().zip(refs) {
        assert_eq!(x.len(), r.len());
        for (&a, &b) in x.iter().zip(r.iter()) {
            identical &= a.to_bits() == b.to_bits();
            if !a.is_finite() || !b.is_finite() {
                bad += 1;
                continue;
            }
            let (a, b) = (a as f64, b as f64);
            let d2 = (a - b) * (a - b);
            rel += d2 / (b * b + 0.01);
            se += d2;
            max_abs = max_abs.max((a - b).abs());
            n += 1;
        }
    }
    let n_f = n.max(1) as f64;
    let mse = se / n_f;
    Metrics {
        rel_mse: rel / n_f,
        mse,
        psnr: if mse > 0.0 { 10.0 * (1.0 / mse).log10() } else { f64::INFINITY },
        max_abs_diff: max_abs,
        bitwise_identical: identical,
        non_finite: bad,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relmse_matches_definition() {
        let x = [1.0f32, 0.0, 2.0];
        let r = [0.5f32, 0.25, 2.0];
        let m = compare(&[&x], &[&r]);
        let want = (0.25 / 0.26 + 0.0625 / 0.0725 + 0.0) / 3.0;
        assert!((m.rel_mse - want).abs() < 1e-12);
        assert!(!m.bitwise_identical);
        assert!(compare(&[&x], &[&x]).bitwise_identical);
        assert_eq!(compare(&[&x], &[&x]).psnr, f64::INFINITY);
    }
}
