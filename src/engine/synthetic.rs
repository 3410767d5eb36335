//! A procedural [`RowSource`]: a noisy "render" generated on demand, row by
//! row, in the channel layout of production files. It stands in for a
//! renderer feeding the engine, and makes frames of any size (larger than
//! memory) for tests and benchmarks without reading a file.

use super::RowSource;
use crate::error::Error;
use crate::geom::Rect;
use crate::image::{ChannelRows, Samples};

/// What a synthetic frame carries.
#[derive(Clone, Copy, Debug)]
pub struct Synthetic {
    /// The data window.
    pub frame: Rect,
    /// Add `albedo.*`, `N.*` and `Z` features.
    pub features: bool,
    /// Add light layers `direct.*` and `indirect.*` (summing to the beauty)
    /// with their variances `var.direct.*`, `var.indirect.*`.
    pub layers: bool,
    /// Noise standard deviation of one half buffer.
    pub sigma: f32,
}

fn hash_noise(x: i64, y: i64, c: u64) -> f32 {
    let mut z = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ c.wrapping_mul(0x1656_67B1_9E37_79F9);
    z = (z ^ (z >> 31)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z ^= z >> 29;
    // Sum of two uniforms: mean 0, variance 1/6 -> scale to variance 1.
    let u1 = (z >> 40) as f32 / (1u64 << 24) as f32;
    let u2 = ((z >> 16) & 0xFF_FFFF) as f32 / (1u64 << 24) as f32;
    (u1 + u2 - 1.0) * 6f32.sqrt()
}

/// A channel of the synthetic frame: name, stored as f16?
const BASE: &[(&str, bool)] = &[
    ("A.B", true),
    ("A.G", true),
    ("A.R", true),
    ("B", true),
    ("B.B", true),
    ("B.G", true),
    ("B.R", true),
    ("G", true),
    ("R", true),
    ("var.B", false),
    ("var.G", false),
    ("var.R", false),
];
const FEATURES: &[(&str, bool)] = &[
    ("N.X", true),
    ("N.Y", true),
    ("N.Z", true),
    ("Z", false),
    ("albedo.B", true),
    ("albedo.G", true),
    ("albedo.R", true),
];

impl Synthetic {
    /// Channels with their storage (true = f16), sorted by name.
    pub fn channels(&self) -> Vec<(String, bool)> {
        let mut v: Vec<(String, bool)> = BASE.iter().map(|(n, h)| (n.to_string(), *h)).collect();
        if self.features {
            v.extend(FEATURES.iter().map(|(n, h)| (n.to_string(), *h)));
        }
        if self.layers {
            for layer in ["direct", "indirect"] {
                for c in ["B", "G", "R"] {
                    v.push((format!("{layer}.{c}"), true));
                    v.push((format!("var.{layer}.{c}"), false));
                }
            }
        }
        v.sort();
        v
    }

    /// The whole frame in memory, every channel in its storage type.
    pub fn to_frame(&self) -> crate::exrio::Frame {
        let mut src = SyntheticSource::new(*self);
        let names = src.channel_names();
        let all: Vec<usize> = (0..names.len()).collect();
        let rows = src.read_rows(&all, self.frame).expect("synthetic rows");
        let channels = names.iter().zip(rows).map(|(n, r)| crate::exrio::Channel::new(n.clone(), r.samples)).collect();
        crate::exrio::Frame::new(self.frame, channels)
    }

    /// The noise-free value of colour channel `c` at a pixel.
    pub fn clean(&self, x: i64, y: i64, c: usize) -> f32 {
        let albedo = self.albedo(x, y, c);
        let shade = 0.5 + 0.5 * ((x - self.frame.x0) as f32 / self.frame.width().max(1) as f32);
        albedo * shade
    }

    fn albedo(&self, x: i64, y: i64, c: usize) -> f32 {
        if (x.div_euclid(32) + y.div_euclid(32)) % 2 == 0 { 0.25 + 0.1 * c as f32 } else { 0.7 }
    }

    /// The sample of channel `name` at a pixel.
    pub fn sample(&self, name: &str, x: i64, y: i64) -> f32 {
        let leaf = name.rsplit('.').next().unwrap_or(name);
        let c = match leaf {
            "R" | "X" => 0,
            "G" | "Y" => 1,
            _ => 2,
        };
        let s = self.sigma;
        let half_a = |c: usize| self.clean(x, y, c) + s * hash_noise(x, y, 2 * c as u64);
        let half_b = |c: usize| self.clean(x, y, c) + s * hash_noise(x, y, 2 * c as u64 + 1);
        // Direct light is 60 % of the clean value, with 60 % of the noise.
        let direct = |c: usize| 0.6 * (half_a(c) + half_b(c)) * 0.5;
        match name {
            n if n.starts_with("direct.") => direct(c),
            n if n.starts_with("indirect.") => (half_a(c) + half_b(c)) * 0.5 - direct(c),
            n if n.starts_with("var.direct.") => 0.36 * s * s / 2.0,
            n if n.starts_with("var.indirect.") => 0.16 * s * s / 2.0,
            n if n.starts_with("A.") => half_a(c),
            n if n.starts_with("B.") => half_b(c),
            n if n.starts_with("var.") => s * s / 2.0,
            n if n.starts_with("albedo.") => self.albedo(x, y, c),
            n if n.starts_with("N.") => [0.0, 0.0, 1.0][c],
            "Z" => 5.0 + (y - self.frame.y0) as f32 * 1e-3,
            _ => (half_a(c) + half_b(c)) * 0.5,
        }
    }
}

/// [`Synthetic`] as a row source.
pub struct SyntheticSource {
    /// The frame description.
    pub spec: Synthetic,
    channels: Vec<(String, bool)>,
}

impl SyntheticSource {
    /// A source for `spec`.
    pub fn new(spec: Synthetic) -> SyntheticSource {
        SyntheticSource { channels: spec.channels(), spec }
    }

    /// Storage type of each channel (true = f16).
    pub fn is_half(&self) -> Vec<bool> {
        self.channels.iter().map(|c| c.1).collect()
    }
}

impl RowSource for SyntheticSource {
    fn data_window(&self) -> Rect {
        self.spec.frame
    }

    fn channel_names(&self) -> Vec<String> {
        self.channels.iter().map(|c| c.0.clone()).collect()
    }

    fn sample_bytes(&self) -> Vec<usize> {
        self.channels.iter().map(|c| if c.1 { 2 } else { 4 }).collect()
    }

    fn read_rows(&mut self, channels: &[usize], rows: Rect) -> Result<Vec<ChannelRows>, Error> {
        let rows = Rect { x0: self.spec.frame.x0, x1: self.spec.frame.x1, ..rows }.intersect(&self.spec.frame);
        Ok(channels
            .iter()
            .map(|&i| {
                let (name, half) = &self.channels[i];
                let mut v = Vec::with_capacity(rows.area());
                for y in rows.y0..rows.y1 {
                    for x in rows.x0..rows.x1 {
                        v.push(self.spec.sample(name, x, y));
                    }
                }
                let samples = if *half {
                    Samples::F16(v.iter().map(|&s| half::f16::from_f32(s)).collect())
                } else {
                    Samples::F32(v)
                };
                ChannelRows { rect: rows, samples }
            })
            .collect())
    }
}
