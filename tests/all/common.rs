//! Synthetic frames for the tests: deterministic, generic (edges, noise,
//! non-uniform variance), with every optional input kind.

use nldenoise::filter::{Buffer, Feature, FrameInputs, Params, VarianceSource};
use nldenoise::geom::Rect;
use nldenoise::image::Plane;

/// Small deterministic generator (SplitMix64).
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(seed ^ 0x9E37_79B9_7F4A_7C15)
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }
    /// Approximately normal (sum of uniforms), mean 0, variance 1.
    pub fn normal(&mut self) -> f32 {
        (0..12).map(|_| self.uniform()).sum::<f32>() - 6.0
    }
}

/// Which optional inputs a synthetic frame carries.
#[derive(Clone, Copy, Debug)]
pub struct Kinds {
    pub features: bool,
    pub layers: bool,
    pub halves: bool,
}

pub const ALL_KINDS: [Kinds; 4] = [
    Kinds { features: false, layers: false, halves: false },
    Kinds { features: true, layers: false, halves: false },
    Kinds { features: true, layers: true, halves: false },
    Kinds { features: false, layers: false, halves: true },
];

fn noisy_plane(rect: Rect, rng: &mut Rng, base: impl Fn(i64, i64) -> f32, sigma: &Plane) -> Plane {
    Plane::from_fn(rect, |x, y| base(x, y) + sigma.get(x, y).sqrt() * rng.normal())
}

/// A generic noisy frame over `frame`.
pub fn frame_inputs(frame: Rect, seed: u64, kinds: Kinds) -> FrameInputs {
    let mut rng = Rng::new(seed);
    let edge_x = frame.x0 + (frame.width() as i64) / 3;
    let edge_y = frame.y0 + (frame.height() as i64) / 2;
    let base = move |c: usize| {
        move |x: i64, y: i64| {
            let a = if x < edge_x { 0.2 } else { 0.7 };
            let b = if y < edge_y { 0.0 } else { 0.3 };
            a + b + 0.05 * c as f32 + 0.02 * ((x + 2 * y) % 5) as f32
        }
    };
    let var_plane = |rng: &mut Rng, scale: f32| Plane::from_fn(frame, |_, _| scale * (0.2 + rng.uniform()));
    let make_buffer = |rng: &mut Rng, name: &str, scale: f32, halves: bool| {
        let vars: Vec<Plane> = (0..3).map(|_| var_plane(rng, scale)).collect();
        if halves {
            let a: Vec<Plane> = (0..3).map(|c| noisy_plane(frame, rng, base(c), &vars[c].map(|v| 2.0 * v))).collect();
            let b: Vec<Plane> = (0..3).map(|c| noisy_plane(frame, rng, base(c), &vars[c].map(|v| 2.0 * v))).collect();
            let values =
                (0..3).map(|c| Plane::from_fn(frame, |x, y| (a[c].get(x, y) + b[c].get(x, y)) * 0.5)).collect();
            Buffer { name: name.into(), values, variance: VarianceSource::Halves { a, b } }
        } else {
            let values = (0..3).map(|c| noisy_plane(frame, rng, base(c), &vars[c])).collect();
            Buffer { name: name.into(), values, variance: VarianceSource::Sample(vars) }
        }
    };
    let mut colour = make_buffer(&mut rng, "beauty", 0.01, kinds.halves);
    let mut layers = Vec::new();
    if kinds.layers {
        let direct = make_buffer(&mut rng, "direct", 0.004, false);
        let indirect = make_buffer(&mut rng, "indirect", 0.008, false);
        colour.values = (0..3)
            .map(|c| Plane::from_fn(frame, |x, y| direct.values[c].get(x, y) + indirect.values[c].get(x, y)))
            .collect();
        layers = vec![direct, indirect];
    }
    let mut features = Vec::new();
    if kinds.features {
        let albedo_base = move |c: usize| {
            move |x: i64, y: i64| {
                if (x / 3 + y / 4) % 2 == 0 { 0.2 + 0.1 * c as f32 } else { 0.8 }
            }
        };
        let avar: Vec<Plane> = (0..3).map(|_| var_plane(&mut rng, 1e-4)).collect();
        let albedo = (0..3).map(|c| noisy_plane(frame, &mut rng, albedo_base(c), &avar[c])).collect();
        features.push(Feature { name: "albedo".into(), values: albedo, variance: Some(avar) });
        // Exact half floats, as a renderer storing normals as half writes
        // them (the AVX-512 tier then reads them as halves).
        let normal = (0..3)
            .map(|c| {
                Plane::from_fn(frame, |x, y| {
                    let v = if x < edge_x { [0.0, 1.0, 0.0][c] } else { [0.7, 0.0, 0.7][c] } + 0.01 * (y % 3) as f32;
                    half::f16::from_f32(v).to_f32()
                })
            })
            .collect();
        features.push(Feature { name: "N".into(), values: normal, variance: None });
        let zvar = vec![var_plane(&mut rng, 1e-3)];
        let depth = vec![noisy_plane(frame, &mut rng, |x, y| 2.0 + 0.05 * x as f32 + 0.03 * y as f32, &zvar[0])];
        features.push(Feature { name: "Z".into(), values: depth, variance: Some(zvar) });
    }
    FrameInputs { colour, features, layers }
}

/// Parameters with every prefilter on and small radii (fast tests).
pub fn small_params(r: usize, f: usize) -> Params {
    let mut p = Params {
        search_radius: r,
        patch_radius: f,
        variance_prefilter_radius: 1,
        feature_variance_prefilter_radius: 2,
        feature_variance: true,
        ..Params::default()
    };
    p.feature_prefilter.search_radius = 2;
    p.feature_prefilter.patch_radius = 1;
    p
}

/// Bit patterns of every output plane, in order.
pub fn bits(d: &nldenoise::filter::Denoised) -> Vec<Vec<u32>> {
    d.colour.iter().chain(d.layers.iter().flatten()).map(|p| p.data().iter().map(|v| v.to_bits()).collect()).collect()
}

/// Unusable samples a renderer can emit.
pub const BAD_VALUES: [f32; 6] = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 1e30, -1e30, f32::MIN];

/// `inputs` with bad samples written into every plane (values and variances,
/// a negative variance too) at `pixels`, cycling through [`BAD_VALUES`].
pub fn with_bad_samples(inputs: &FrameInputs, pixels: &[(i64, i64)]) -> FrameInputs {
    let counter = std::cell::Cell::new(0usize);
    inputs.map_planes(&|p: &Plane| {
        let mut q = p.clone();
        for &(x, y) in pixels {
            if q.rect().contains(x, y) {
                let i = counter.get();
                counter.set(i + 1);
                q.set(x, y, if i % 7 == 6 { -0.5 } else { BAD_VALUES[i % BAD_VALUES.len()] });
            }
        }
        q
    })
}
