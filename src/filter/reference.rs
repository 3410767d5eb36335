//! A naive, independent implementation of the same math in `f64`, used by the
//! tests as the oracle for the fast filter.
//!
//! It follows the slides' "naive implementation": for every patch centre `s`
//! and neighbour `s + n`, the patch distance is averaged over the patch, the
//! weight is scattered to every pixel of the patch (normalised by how many
//! patches of that offset cover the pixel, which is what the fast filter's
//! box mean of the weights computes). O(r^2 f^2) per pixel, whole frames only.

use super::{Buffer, FrameInputs, Params, VarianceSource};
use crate::geom::Rect;
use crate::image::Plane;

type Grid = Vec<Vec<f64>>; // [channel][pixel]

struct Frame {
    rect: Rect,
}

impl Frame {
    fn idx(&self, x: i64, y: i64) -> usize {
        ((y - self.rect.y0) * self.rect.width() as i64 + (x - self.rect.x0)) as usize
    }
}

fn to_grid(planes: &[Plane], rect: Rect) -> Grid {
    planes.iter().map(|p| p.crop(rect).data().iter().map(|&v| v as f64).collect()).collect()
}

fn raw_variance(src: &VarianceSource, rect: Rect) -> Grid {
    match src {
        VarianceSource::Sample(v) => to_grid(v, rect),
        VarianceSource::Halves { a, b } => {
            let (a, b) = (to_grid(a, rect), to_grid(b, rect));
            a.iter().zip(&b).map(|(a, b)| a.iter().zip(b).map(|(x, y)| (x - y) * (x - y) / 4.0).collect()).collect()
        }
    }
}

fn prefilter_variance(fr: &Frame, v: &Grid, rho: usize) -> Grid {
    let r = rho as i64;
    v.iter()
        .map(|ch| {
            let mut out = ch.clone();
            for y in fr.rect.y0..fr.rect.y1 {
                for x in fr.rect.x0..fr.rect.x1 {
                    let (mut sum, mut n) = (0.0, 0.0);
                    for yy in y - r..=y + r {
                        for xx in x - r..=x + r {
                            if fr.rect.contains(xx, yy) {
                                sum += ch[fr.idx(xx, yy)];
                                n += 1.0;
                            }
                        }
                    }
                    out[fr.idx(x, y)] = ch[fr.idx(x, y)].max(sum / n);
                }
            }
            out
        })
        .collect()
}

struct Guide {
    values: Grid,
    variance: Option<Grid>,
    den: Grid, // kf^2 max(tau, V_c, G)
}

#[allow(clippy::too_many_arguments)]
fn naive_nlmeans(
    fr: &Frame,
    jobs: &[(Grid, Grid)],
    guides: &[Guide],
    r: usize,
    f: usize,
    k: f64,
    alpha: f64,
    eps: f64,
) -> Vec<Grid> {
    let (r, f) = (r as i64, f as i64);
    let rect = fr.rect;
    let n_px = rect.area();
    jobs.iter()
        .map(|(u, v)| {
            let mut flt = vec![vec![0.0f64; n_px]; u.len()];
            let mut wsum = vec![0.0f64; n_px];
            for dy in -r..=r {
                for dx in -r..=r {
                    let valid = rect.valid_for_offset(dx, dy);
                    if valid.is_empty() {
                        continue;
                    }
                    let count = |x: i64, y: i64| {
                        let b = Rect { x0: x - f, y0: y - f, x1: x + f + 1, y1: y + f + 1 }.intersect(&valid);
                        b.area() as f64
                    };
                    for sy in valid.y0..valid.y1 {
                        for sx in valid.x0..valid.x1 {
                            let (mut d, mut nd) = (0.0, 0.0);
                            for iy in -f..=f {
                                for ix in -f..=f {
                                    let (px, py) = (sx + ix, sy + iy);
                                    if !valid.contains(px, py) {
                                        continue;
                                    }
                                    let (p, q) = (fr.idx(px, py), fr.idx(px + dx, py + dy));
                                    let mut dc = 0.0;
                                    for c in 0..u.len() {
                                        let diff = u[c][p] - u[c][q];
                                        let num = diff * diff - alpha * (v[c][p] + v[c][p].min(v[c][q]));
                                        dc += num / (eps + k * k * (v[c][p] + v[c][q]));
                                    }
                                    d += dc / u.len() as f64;
                                    nd += 1.0;
                                }
                            }
                            let wc = (-(d / nd).max(0.0)).exp();
                            let (p, q) = (fr.idx(sx, sy), fr.idx(sx + dx, sy + dy));
                            let mut df = 0.0f64;
                            for g in guides {
                                let mut phi = 0.0;
                                for c in 0..g.values.len() {
                                    let diff = g.values[c][p] - g.values[c][q];
                                    let mut num = diff * diff;
                                    if let Some(gv) = &g.variance {
                                        num -= gv[c][p] + gv[c][p].min(gv[c][q]);
                                    }
                                    phi += num / g.den[c][p];
                                }
                                df = df.max(phi / g.values.len() as f64);
                            }
                            let w = wc.min((-df).exp());
                            for iy in -f..=f {
                                for ix in -f..=f {
                                    let (px, py) = (sx + ix, sy + iy);
                                    if !valid.contains(px, py) {
                                        continue;
                                    }
                                    let wp = w / count(px, py);
                                    let (pi, qi) = (fr.idx(px, py), fr.idx(px + dx, py + dy));
                                    wsum[pi] += wp;
                                    for c in 0..u.len() {
                                        flt[c][pi] += wp * u[c][qi];
                                    }
                                }
                            }
                        }
                    }
                }
            }
            flt.into_iter().map(|ch| ch.iter().zip(&wsum).map(|(a, b)| a / b).collect()).collect()
        })
        .collect()
}

fn gradient(fr: &Frame, values: &Grid) -> Vec<f64> {
    let rect = fr.rect;
    let mut g = vec![0.0; rect.area()];
    for ch in values {
        for y in rect.y0..rect.y1 {
            for x in rect.x0..rect.x1 {
                let c = ch[fr.idx(x, y)];
                let side = |xx: i64, yy: i64| rect.contains(xx, yy).then(|| ((c - ch[fr.idx(xx, yy)]) / 2.0).powi(2));
                let pair = |a: Option<f64>, b: Option<f64>| match (a, b) {
                    (Some(a), Some(b)) => a.min(b),
                    (Some(a), None) | (None, Some(a)) => a,
                    (None, None) => 0.0,
                };
                g[fr.idx(x, y)] += pair(side(x - 1, y), side(x + 1, y)) + pair(side(x, y - 1), side(x, y + 1));
            }
        }
    }
    g
}

/// Naive whole-frame denoise; returns the beauty channels (the sum of the
/// layers when layers are present) in `f64`, one vector per channel.
pub fn denoise_frame(inputs: &FrameInputs, frame: Rect, params: &Params) -> Vec<Vec<f64>> {
    let fr = Frame { rect: frame };
    let rho = params.variance_prefilter_radius;
    let (alpha, eps) = (params.alpha as f64, params.eps as f64);
    let buffers: Vec<&Buffer> =
        if inputs.layers.is_empty() { vec![&inputs.colour] } else { inputs.layers.iter().collect() };
    let jobs: Vec<(Grid, Grid)> = buffers
        .iter()
        .map(|b| (to_grid(&b.values, frame), prefilter_variance(&fr, &raw_variance(&b.variance, frame), rho)))
        .collect();
    let fp = params.feature_prefilter;
    let guides: Vec<Guide> = inputs
        .features
        .iter()
        .map(|feat| {
            let var = feat
                .variance
                .as_ref()
                .map(|v| prefilter_variance(&fr, &to_grid(v, frame), params.feature_variance_prefilter_radius));
            let mut values = to_grid(&feat.values, frame);
            if let (Some(v), true) = (&var, fp.search_radius > 0) {
                values = naive_nlmeans(
                    &fr,
                    &[(values, v.clone())],
                    &[],
                    fp.search_radius,
                    fp.patch_radius,
                    fp.strength as f64,
                    alpha,
                    eps,
                )
                .pop()
                .unwrap();
            }
            let g = gradient(&fr, &values);
            let variance = if params.feature_variance { var } else { None };
            let kf2 = (params.feature_strength as f64).powi(2);
            let tau = params.tau as f64;
            let den = (0..values.len())
                .map(|c| {
                    (0..frame.area())
                        .map(|i| {
                            let mut m = tau.max(g[i]);
                            if let Some(v) = &variance {
                                m = m.max(v[c][i]);
                            }
                            kf2 * m
                        })
                        .collect()
                })
                .collect();
            Guide { values, variance, den }
        })
        .collect();
    let outs = naive_nlmeans(
        &fr,
        &jobs,
        &guides,
        params.search_radius,
        params.patch_radius,
        params.strength as f64,
        alpha,
        eps,
    );
    let mut beauty = outs[0].clone();
    for o in &outs[1..] {
        for (b, ch) in beauty.iter_mut().zip(o) {
            for (x, y) in b.iter_mut().zip(ch) {
                *x += y;
            }
        }
    }
    beauty
}
