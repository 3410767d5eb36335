//! The NL-means math of SPEC §1–5, evaluated on any rectangle of a frame.
//!
//! [`denoise_region`] filters the output rectangle `out` of a frame whose data
//! window is `frame`, reading inputs that cover `(out ⊕ halo) ∩ frame`, where
//! the halo is derived by [`Pipeline`] from the configured stages. Whole-frame
//! filtering is the case `out == frame`; a tile is any other rectangle, and the
//! result is the same bit for bit because every stage is defined on frame
//! coordinates (see `docs/algorithm.md`).

mod column_sums;
pub mod features;
pub mod kernels;
pub mod nlmeans;
pub mod reference;
pub mod repair;
pub mod simd;
pub mod variance;

pub use features::Feature;
pub use variance::VarianceSource;

use std::borrow::Cow;
use std::sync::Arc;

use rayon::prelude::*;

use crate::error::Error;
use crate::geom::Rect;
use crate::image::Plane;
use features::GuideSettings;
use nlmeans::{GuideFeature, Job, NlmSettings};

/// Settings of the feature prefilter (NL-means of each feature with its own variance).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FeaturePrefilter {
    /// Search radius (0 turns the prefilter off).
    pub search_radius: usize,
    /// Patch radius.
    pub patch_radius: usize,
    /// Strength `k` of the prefilter.
    pub strength: f32,
}

/// Every parameter of the filter. `Default` gives the documented defaults.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Params {
    /// Search radius `r` (slides: 10).
    pub search_radius: usize,
    /// Patch radius `f` (slides: 3).
    pub patch_radius: usize,
    /// Colour strength `k` (slides: 0.45).
    pub strength: f32,
    /// Variance cancellation factor `alpha` (1).
    pub alpha: f32,
    /// Denominator guard `eps` (1e-10).
    pub eps: f32,
    /// Feature strength `kf` (slides: 0.6).
    pub feature_strength: f32,
    /// Gradient floor `tau` (slides: 1e-3).
    pub tau: f32,
    /// Radius `rho` of the variance prefilter `max(v, box_rho(v))`; 0 = off.
    pub variance_prefilter_radius: usize,
    /// Radius of the same prefilter applied to feature variances; 0 = off.
    pub feature_variance_prefilter_radius: usize,
    /// Use feature variances in the feature distance when present (Rousselle 2013).
    pub feature_variance: bool,
    /// NL-means prefilter of features that carry a variance.
    pub feature_prefilter: FeaturePrefilter,
}

impl Default for Params {
    fn default() -> Self {
        Params {
            search_radius: 10,
            patch_radius: 3,
            strength: 0.45,
            alpha: 1.0,
            eps: 1e-10,
            feature_strength: 0.6,
            tau: 1e-3,
            variance_prefilter_radius: 1,
            feature_variance_prefilter_radius: 1,
            feature_variance: true,
            feature_prefilter: FeaturePrefilter { search_radius: 3, patch_radius: 2, strength: 0.45 },
        }
    }
}

impl Params {
    /// Check every parameter; the error names the parameter and the value.
    pub fn validate(&self) -> Result<(), Error> {
        let finite_pos = |name: &str, v: f32, allow_zero: bool| {
            if !v.is_finite() || v < 0.0 || (!allow_zero && v == 0.0) {
                Err(Error::InvalidParameter(format!(
                    "{name} must be a finite number {} 0, got {v}",
                    if allow_zero { ">=" } else { ">" }
                )))
            } else {
                Ok(())
            }
        };
        // Bounds that keep every intermediate of the distance finite and
        // normal (see `nlmeans::distance_rows` and `repair`).
        if self.strength > 1000.0 || self.feature_prefilter.strength > 1000.0 {
            return Err(Error::InvalidParameter(format!(
                "strength must be at most 1000, got {}",
                self.strength.max(self.feature_prefilter.strength)
            )));
        }
        if !(1e-30..=1.0).contains(&self.eps) {
            return Err(Error::InvalidParameter(format!("eps must be within [1e-30, 1], got {}", self.eps)));
        }
        finite_pos("strength", self.strength, true)?;
        finite_pos("alpha", self.alpha, true)?;
        finite_pos("eps", self.eps, false)?;
        finite_pos("feature strength", self.feature_strength, false)?;
        finite_pos("tau", self.tau, false)?;
        finite_pos("feature prefilter strength", self.feature_prefilter.strength, true)?;
        for (name, v) in [
            ("search radius", self.search_radius),
            ("patch radius", self.patch_radius),
            ("variance prefilter radius", self.variance_prefilter_radius),
            ("feature variance prefilter radius", self.feature_variance_prefilter_radius),
            ("feature prefilter search radius", self.feature_prefilter.search_radius),
            ("feature prefilter patch radius", self.feature_prefilter.patch_radius),
        ] {
            if v > 1000 {
                return Err(Error::InvalidParameter(format!("{name} must be at most 1000, got {v}")));
            }
        }
        Ok(())
    }

    fn main_settings(&self) -> NlmSettings {
        NlmSettings {
            search_radius: self.search_radius,
            patch_radius: self.patch_radius,
            strength: self.strength,
            alpha: self.alpha,
            eps: self.eps,
        }
    }

    fn guide_settings(&self) -> GuideSettings {
        let fp = self.feature_prefilter;
        GuideSettings {
            feature_strength: self.feature_strength,
            tau: self.tau,
            use_variance: self.feature_variance,
            variance_prefilter_radius: self.feature_variance_prefilter_radius,
            prefilter: (fp.search_radius > 0).then_some(NlmSettings {
                search_radius: fp.search_radius,
                patch_radius: fp.patch_radius,
                strength: fp.strength,
                alpha: self.alpha,
                eps: self.eps,
            }),
        }
    }
}

/// A buffer to denoise (the beauty or one light layer) with its variance.
#[derive(Clone, Debug)]
pub struct Buffer {
    /// Name shown in logs (`beauty`, `direct`, ...).
    pub name: String,
    /// One plane per channel.
    pub values: Vec<Plane>,
    /// Where its variance of the mean comes from.
    pub variance: VarianceSource,
}

/// Everything the filter reads, as planes in frame coordinates.
#[derive(Clone, Debug)]
pub struct FrameInputs {
    /// The beauty (colour) buffer.
    pub colour: Buffer,
    /// Guide features (may be empty: colour-only filtering).
    pub features: Vec<Feature>,
    /// Light layers filtered separately and summed into the beauty (may be empty).
    pub layers: Vec<Buffer>,
}

impl FrameInputs {
    /// Every plane cropped to `rect ∩ plane` (the window a tile reads).
    pub fn crop(&self, rect: Rect) -> FrameInputs {
        self.map_planes(&|p: &Plane| p.crop(rect.intersect(&p.rect())))
    }

    /// Apply `f` to every plane.
    pub fn map_planes(&self, f: &dyn Fn(&Plane) -> Plane) -> FrameInputs {
        let planes = |v: &[Plane]| v.iter().map(f).collect::<Vec<_>>();
        let var = |v: &VarianceSource| match v {
            VarianceSource::Sample(s) => VarianceSource::Sample(planes(s)),
            VarianceSource::Halves { a, b } => VarianceSource::Halves { a: planes(a), b: planes(b) },
        };
        let buf = |b: &Buffer| Buffer { name: b.name.clone(), values: planes(&b.values), variance: var(&b.variance) };
        FrameInputs {
            colour: buf(&self.colour),
            features: self
                .features
                .iter()
                .map(|ft| Feature {
                    name: ft.name.clone(),
                    values: planes(&ft.values),
                    variance: ft.variance.as_deref().map(planes),
                })
                .collect(),
            layers: self.layers.iter().map(buf).collect(),
        }
    }
}

/// The filter's output on the output rectangle.
#[derive(Clone, Debug, PartialEq)]
pub struct Denoised {
    /// Denoised beauty, one plane per colour channel (the sum of the layers when layers are used).
    pub colour: Vec<Plane>,
    /// Denoised layers, in input order.
    pub layers: Vec<Vec<Plane>>,
    /// Pixels of the output rectangle that had an unusable input sample
    /// (NaN, infinite, out of range) repaired before filtering ([`repair`]).
    pub repaired: usize,
}

/// What kinds of input the pipeline has: enough to derive every stage's reach.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct InputShape {
    /// For each feature: whether it carries a variance.
    pub feature_has_variance: Vec<bool>,
    /// Number of light layers.
    pub layers: usize,
}

impl InputShape {
    /// The shape of a set of inputs.
    pub fn of(inputs: &FrameInputs) -> InputShape {
        InputShape {
            feature_has_variance: inputs.features.iter().map(|f| f.variance.is_some()).collect(),
            layers: inputs.layers.len(),
        }
    }
}

/// The configured pipeline, and how far each of its stages reads.
///
/// This is the one place the halo is derived (SPEC §6):
///
/// * the main NL-means reads colour, variance and layers within `r + 2f`
///   (the patch box of the distance, then the box of the weights), so raw
///   variance is read within `r + 2f + rho` (variance prefilter);
/// * feature guides are read at `p + n` for patch centres within `f` of the
///   output pixel, and their gradient at the centres: `g = max(r + f, f + 1)`;
/// * a prefiltered feature adds its own NL-means reach `r_fp + 2 f_fp`, and its
///   variance a further `rho`.
///
/// The halo is the largest of these reaches over the inputs present, plus
/// [`repair::REPAIR_RADIUS`] for the repair of unusable samples, which reads
/// a 3×3 neighbourhood of every input sample a stage reads.
#[derive(Clone, Debug)]
pub struct Pipeline {
    params: Params,
    shape: InputShape,
}

impl Pipeline {
    /// A pipeline for these parameters and inputs.
    pub fn new(params: Params, shape: InputShape) -> Pipeline {
        Pipeline { params, shape }
    }

    /// The parameters.
    pub fn params(&self) -> &Params {
        &self.params
    }

    /// Reach of the main NL-means: `r + 2f`.
    pub fn main_radius(&self) -> usize {
        self.params.main_settings().radius()
    }

    /// Reach of the raw colour (and layer) variance: `r + 2f + rho`.
    pub fn variance_radius(&self) -> usize {
        self.main_radius() + self.params.variance_prefilter_radius
    }

    /// Where guide features are needed around the output: `max(r + f, f + 1)`.
    pub fn guide_radius(&self) -> usize {
        (self.params.search_radius + self.params.patch_radius).max(self.params.patch_radius + 1)
    }

    /// Reach of feature `j`'s raw values and raw variance.
    pub fn feature_radii(&self, j: usize) -> (usize, usize) {
        let gs = self.params.guide_settings();
        let has_var = self.shape.feature_has_variance[j];
        let g = self.guide_radius();
        (g + gs.values_radius(has_var), if gs.reads_variance(has_var) { g + gs.variance_radius(has_var) } else { 0 })
    }

    /// The halo: how far around an output pixel any input is read.
    pub fn halo(&self) -> usize {
        let mut h = self.variance_radius();
        for j in 0..self.shape.feature_has_variance.len() {
            let (v, var) = self.feature_radii(j);
            h = h.max(v).max(var);
        }
        h + repair::REPAIR_RADIUS
    }

    /// One line per stage, for `nldenoise info --plan` and logs.
    pub fn describe(&self) -> Vec<String> {
        let p = &self.params;
        let mut lines = vec![
            format!(
                "main NL-means: r={} f={} k={} reads colour/layers within r+2f = {}",
                p.search_radius,
                p.patch_radius,
                p.strength,
                self.main_radius()
            ),
            format!(
                "variance prefilter: rho={} (raw variance read within {})",
                p.variance_prefilter_radius,
                self.variance_radius()
            ),
        ];
        for j in 0..self.shape.feature_has_variance.len() {
            let (v, var) = self.feature_radii(j);
            let gs = p.guide_settings();
            let has_var = self.shape.feature_has_variance[j];
            lines.push(format!(
                "feature {j}: guide within max(r+f, f+1) = {}, prefilter {}, values read within {v}{}",
                self.guide_radius(),
                if gs.prefilters(has_var) {
                    format!("r={} f={}", p.feature_prefilter.search_radius, p.feature_prefilter.patch_radius)
                } else {
                    "off".to_string()
                },
                if var > 0 { format!(", variance within {var}") } else { String::new() }
            ));
        }
        lines.push(format!(
            "repair of NaN/Inf/out-of-range samples: mean of the 3x3 neighbourhood, +{}",
            repair::REPAIR_RADIUS
        ));
        lines.push(format!("halo = {}", self.halo()));
        lines
    }
}

fn check_cover(what: &str, plane: &Plane, need: Rect) -> Result<(), Error> {
    if plane.rect().contains_rect(&need) {
        Ok(())
    } else {
        Err(Error::InvalidInput(format!("{what} covers {:?} but the filter needs {:?}", plane.rect(), need)))
    }
}

fn check_buffer(b: &Buffer, need_values: Rect, need_var: Rect) -> Result<(), Error> {
    if b.values.is_empty() {
        return Err(Error::InvalidInput(format!("buffer {} has no channels", b.name)));
    }
    for p in &b.values {
        check_cover(&b.name, p, need_values)?;
    }
    let var_planes = b.variance.planes();
    let expected = match &b.variance {
        VarianceSource::Sample(_) => b.values.len(),
        VarianceSource::Halves { .. } => 2 * b.values.len(),
    };
    if var_planes.len() != expected {
        return Err(Error::InvalidInput(format!(
            "buffer {} has {} channels but its variance source has {} planes (expected {expected})",
            b.name,
            b.values.len(),
            var_planes.len()
        )));
    }
    for p in var_planes {
        check_cover(&format!("variance of {}", b.name), p, need_var)?;
    }
    Ok(())
}

/// Denoise the rectangle `out` of the frame whose data window is `frame`.
///
/// Inputs must cover `(out ⊕ halo) ∩ frame` with the halo of
/// [`Pipeline::halo`]; the result equals the same rectangle of whole-frame
/// filtering bit for bit. The kernel's blocks run in parallel (rayon); to
/// schedule them yourself, use [`PreparedRegion`].
pub fn denoise_region(inputs: &FrameInputs, frame: Rect, out: Rect, params: &Params) -> Result<Denoised, Error> {
    let region = PreparedRegion::new(Cow::Borrowed(inputs), frame, out, params)?;
    let blocks: Vec<_> = region.blocks().par_iter().map(|b| region.filter_block(*b)).collect();
    Ok(region.finish(blocks))
}

/// The inputs a [`PreparedRegion`] reads: borrowed, its own (a copy, or
/// repaired), or shared with other regions.
enum RegionInputs<'a> {
    Borrowed(&'a FrameInputs),
    Owned(FrameInputs),
    Shared(Arc<FrameInputs>),
}

impl std::ops::Deref for RegionInputs<'_> {
    type Target = FrameInputs;

    fn deref(&self) -> &FrameInputs {
        match self {
            RegionInputs::Borrowed(i) => i,
            RegionInputs::Owned(i) => i,
            RegionInputs::Shared(i) => i,
        }
    }
}

/// A region of [`denoise_region`] ready for the NL-means kernel: inputs
/// checked and repaired, variances prefiltered, guides prepared. Its
/// [`blocks`](Self::blocks) can be filtered in any order, on any thread
/// (each a function of frame coordinates only), and [`finish`](Self::finish)
/// assembles them: the same bits as [`denoise_region`].
pub struct PreparedRegion<'a> {
    inputs: RegionInputs<'a>,
    variances: Vec<Vec<Plane>>,
    guides: Vec<GuideFeature>,
    frame: Rect,
    out: Rect,
    settings: NlmSettings,
    repaired: usize,
}

impl<'a> PreparedRegion<'a> {
    /// Check `inputs` (as [`denoise_region`]) and run every stage before the
    /// kernel: the repair, the variance prefilter, the guides.
    pub fn new(inputs: Cow<'a, FrameInputs>, frame: Rect, out: Rect, params: &Params) -> Result<Self, Error> {
        let inputs = match inputs {
            Cow::Borrowed(i) => RegionInputs::Borrowed(i),
            Cow::Owned(i) => RegionInputs::Owned(i),
        };
        Self::prepare(inputs, frame, out, params)
    }

    /// [`new`](Self::new) on inputs shared with other regions (the
    /// engine's band, which each of its tiles reads in place instead of a
    /// copy of its window): the same bits.
    pub fn shared(inputs: Arc<FrameInputs>, frame: Rect, out: Rect, params: &Params) -> Result<Self, Error> {
        Self::prepare(RegionInputs::Shared(inputs), frame, out, params)
    }

    fn prepare(inputs: RegionInputs<'a>, frame: Rect, out: Rect, params: &Params) -> Result<Self, Error> {
        let region = |inputs, variances, guides, repaired| PreparedRegion {
            inputs,
            variances,
            guides,
            frame,
            out,
            settings: params.main_settings(),
            repaired,
        };
        params.validate()?;
        if !frame.contains_rect(&out) {
            return Err(Error::InvalidInput(format!("output rectangle {out:?} is not inside the frame {frame:?}")));
        }
        let pipeline = Pipeline::new(*params, InputShape::of(&inputs));
        check_inputs(&inputs, &pipeline, frame, out)?;
        if out.is_empty() {
            return Ok(region(inputs, Vec::new(), Vec::new(), 0));
        }
        let main_rect = out.expand(pipeline.main_radius()).intersect(&frame);
        let rho = params.variance_prefilter_radius;
        let window = out.expand(pipeline.halo()).intersect(&frame);
        let (fixed, repaired) = match repair::repair_inputs(&inputs, frame, window, out) {
            (Cow::Owned(fixed), n) => (Some(fixed), n),
            (Cow::Borrowed(_), n) => (None, n),
        };
        let inputs = fixed.map_or(inputs, RegionInputs::Owned);
        let variances: Vec<Vec<Plane>> = buffers(&inputs)
            .iter()
            .map(|b| variance::prefiltered(&b.variance, b.values.len(), frame, rho, main_rect))
            .collect();
        let gs = params.guide_settings();
        let guide_rect = out.expand(pipeline.guide_radius()).intersect(&frame);
        let den_rect = out.expand(params.patch_radius).intersect(&frame);
        let guides: Vec<_> =
            inputs.features.iter().map(|f| features::prepare(f, &gs, frame, guide_rect, den_rect)).collect();
        Ok(region(inputs, variances, guides, repaired))
    }

    /// The kernel's blocks (none for an empty output rectangle), as tall as
    /// [`nlmeans::block_rows`] chooses for rayon's current pool.
    pub fn blocks(&self) -> Vec<Rect> {
        self.blocks_of(nlmeans::block_rows(rayon::current_num_threads(), false))
    }

    /// The kernel's blocks, at most `rows` tall, for a caller that runs them
    /// on a pool of its own ([`nlmeans::block_rows`] of its threads). Any
    /// height gives the same bits.
    pub fn blocks_of(&self, rows: usize) -> Vec<Rect> {
        if self.out.is_empty() { Vec::new() } else { nlmeans::blocks(self.out, rows) }
    }

    /// Filter one of [`blocks`](Self::blocks): per job (the beauty, or each
    /// light layer), one plane per channel over `block`.
    pub fn filter_block(&self, block: Rect) -> Vec<Vec<Plane>> {
        nlmeans::filter_block(&self.jobs(), &self.guides, self.frame, block, &self.settings)
    }

    /// The output from every block's result (in any order).
    pub fn finish(&self, blocks: Vec<Vec<Vec<Plane>>>) -> Denoised {
        if self.out.is_empty() {
            return Denoised { colour: Vec::new(), layers: Vec::new(), repaired: 0 };
        }
        let mut results = nlmeans::assemble(&self.jobs(), self.out, blocks);
        let repaired = self.repaired;
        if self.inputs.layers.is_empty() {
            Denoised { colour: results.pop().expect("one job"), layers: Vec::new(), repaired }
        } else {
            // The first two layers' sum formed as it is written (one pass
            // instead of a copy of the first then an add), the others added.
            let mut colour: Vec<Plane> = match &results[..] {
                [a, b, ..] => a
                    .iter()
                    .zip(b)
                    .map(|(a, b)| {
                        let sum = a.data().iter().zip(b.data()).map(|(x, y)| x + y).collect();
                        Plane::from_vec(a.rect(), sum).expect("layers over the same rect")
                    })
                    .collect(),
                _ => results[0].clone(),
            };
            for layer in results.iter().skip(2) {
                for (acc, p) in colour.iter_mut().zip(layer) {
                    for (a, v) in acc.data_mut().iter_mut().zip(p.data()) {
                        *a += *v;
                    }
                }
            }
            Denoised { colour, layers: results, repaired }
        }
    }

    fn jobs(&self) -> Vec<Job<'_>> {
        buffers(&self.inputs)
            .into_iter()
            .zip(&self.variances)
            .map(|(b, v)| Job { values: b.values.iter().collect(), variance: v.iter().collect() })
            .collect()
    }
}

/// Check that every input covers what its stages read of it.
fn check_inputs(inputs: &FrameInputs, pipeline: &Pipeline, frame: Rect, out: Rect) -> Result<(), Error> {
    // Inputs are read one pixel further than each stage's reach, for the repair.
    let reach = |radius: usize| out.expand(radius + repair::REPAIR_RADIUS).intersect(&frame);
    let (main_in, var_in) = (reach(pipeline.main_radius()), reach(pipeline.variance_radius()));

    check_buffer(&inputs.colour, main_in, var_in)?;
    for layer in &inputs.layers {
        check_buffer(layer, main_in, var_in)?;
        if layer.values.len() != inputs.colour.values.len() {
            return Err(Error::InvalidInput(format!(
                "layer {} has {} channels but the beauty has {}",
                layer.name,
                layer.values.len(),
                inputs.colour.values.len()
            )));
        }
    }
    for (j, feat) in inputs.features.iter().enumerate() {
        let (vr, varr) = pipeline.feature_radii(j);
        if feat.values.is_empty() {
            return Err(Error::InvalidInput(format!("feature {} has no channels", feat.name)));
        }
        for p in &feat.values {
            check_cover(&feat.name, p, reach(vr))?;
        }
        if let Some(v) = &feat.variance {
            if v.len() != feat.values.len() {
                return Err(Error::InvalidInput(format!(
                    "feature {} variance has {} channels, expected {}",
                    feat.name,
                    v.len(),
                    feat.values.len()
                )));
            }
            if varr > 0 {
                for p in v {
                    check_cover(&format!("variance of {}", feat.name), p, reach(varr))?;
                }
            }
        }
    }
    Ok(())
}

/// The buffers filtered as jobs: the light layers, or else the beauty.
fn buffers(inputs: &FrameInputs) -> Vec<&Buffer> {
    if inputs.layers.is_empty() { vec![&inputs.colour] } else { inputs.layers.iter().collect() }
}
