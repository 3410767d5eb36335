//! The fast filter against the naive O(r^2 f^2) reference, on random inputs
//! with features, variance (sample and halves), prefilters and layers.

use nldenoise::filter::{self, reference};
use nldenoise::geom::Rect;

use crate::common::{ALL_KINDS, frame_inputs, small_params};

fn check(frame: Rect, seed: u64, r: usize, f: usize) {
    check_with(frame, seed, r, f, true);
}

/// `feature_variance` false: every guide without variance, so the kernel
/// shares each guide's square sums between offsets `n` and `-n`.
fn check_with(frame: Rect, seed: u64, r: usize, f: usize, feature_variance: bool) {
    for kinds in ALL_KINDS {
        let inputs = frame_inputs(frame, seed, kinds);
        let mut params = small_params(r, f);
        params.feature_variance = feature_variance;
        let fast = filter::denoise_region(&inputs, frame, frame, &params).unwrap();
        let naive = reference::denoise_frame(&inputs, frame, &params);
        let mut worst = 0.0f64;
        for (fc, nc) in fast.colour.iter().zip(&naive) {
            for (a, b) in fc.data().iter().zip(nc) {
                assert!(a.is_finite(), "{kinds:?}: non-finite output");
                worst = worst.max((*a as f64 - b).abs() / (b.abs() + 1e-2));
            }
        }
        assert!(worst < 2e-5, "{kinds:?} {frame:?} r={r} f={f}: worst relative difference {worst}");
    }
}

#[test]
fn fast_matches_naive_reference() {
    check(Rect::from_origin_size(0, 0, 23, 17), 1, 3, 1);
    check(Rect::from_origin_size(-5, 7, 19, 13), 2, 2, 2);
}

#[test]
fn fast_matches_naive_reference_without_feature_variances() {
    check_with(Rect::from_origin_size(0, 0, 23, 17), 6, 3, 1, false);
    check_with(Rect::from_origin_size(2, -3, 17, 12), 7, 4, 2, false);
}

#[test]
fn fast_matches_naive_reference_on_degenerate_shapes() {
    check(Rect::from_origin_size(3, 0, 1, 11), 3, 2, 1);
    check(Rect::from_origin_size(0, -2, 12, 1), 4, 3, 1);
    check(Rect::from_origin_size(0, 0, 5, 4), 5, 4, 3);
}

#[test]
fn radius_zero_returns_the_input() {
    let frame = Rect::from_origin_size(0, 0, 9, 7);
    let inputs = frame_inputs(frame, 9, ALL_KINDS[1]);
    let mut params = small_params(0, 0);
    params.feature_prefilter.search_radius = 0;
    let out = filter::denoise_region(&inputs, frame, frame, &params).unwrap();
    for (o, i) in out.colour.iter().zip(&inputs.colour.values) {
        assert_eq!(o.data(), i.data());
    }
}
