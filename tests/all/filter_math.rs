//! Properties of the filter's math on synthetic data with known answers.

use nldenoise::filter::{self, Buffer, Feature, FrameInputs, Params, VarianceSource, variance};
use nldenoise::geom::Rect;
use nldenoise::image::Plane;

use crate::common::{ALL_KINDS, Rng, frame_inputs};

/// Mean of the per-pixel estimates over a frame whose true variance of the mean is known.
#[test]
fn variance_estimators_are_unbiased() {
    let frame = Rect::from_origin_size(0, 0, 200, 150);
    let (sigma2, n) = (0.04f32, 16usize); // per-sample variance, samples per pixel
    let mut rng = Rng::new(3);
    let mut a = Plane::filled(frame, 0.0);
    let mut b = Plane::filled(frame, 0.0);
    let mut svar = Plane::filled(frame, 0.0);
    for y in frame.y0..frame.y1 {
        for x in frame.x0..frame.x1 {
            let s: Vec<f32> = (0..n).map(|_| 0.5 + sigma2.sqrt() * rng.normal()).collect();
            let mean = s.iter().sum::<f32>() / n as f32;
            let var = s.iter().map(|v| (v - mean) * (v - mean)).sum::<f32>() / (n - 1) as f32;
            svar.set(x, y, var / n as f32);
            a.set(x, y, s[..n / 2].iter().sum::<f32>() / (n / 2) as f32);
            b.set(x, y, s[n / 2..].iter().sum::<f32>() / (n / 2) as f32);
        }
    }
    let truth = (sigma2 / n as f32) as f64;
    let mean_of = |p: &Plane| p.data().iter().map(|&v| v as f64).sum::<f64>() / p.data().len() as f64;
    let halves = VarianceSource::Halves { a: vec![a], b: vec![b] }.raw(0, frame);
    let sample = VarianceSource::Sample(vec![svar]).raw(0, frame);
    for (name, est) in [("halves", &halves), ("sample", &sample)] {
        let m = mean_of(est);
        assert!((m - truth).abs() < 0.05 * truth, "{name}: mean estimate {m} vs true {truth}");
    }
    // The prefilter is max(v, box(v)): never below v, and equal to the local mean where that is larger.
    let pre = variance::prefilter(&halves, frame, 2, frame);
    let mut raised = 0;
    for (p, v) in pre.data().iter().zip(halves.data()) {
        assert!(p >= v);
        raised += (p > v) as usize;
    }
    assert!(raised > frame.area() / 3, "prefilter should raise many of the noisy estimates ({raised})");
    // Its mean error against the truth is smaller than the raw estimate's.
    let rmse =
        |p: &Plane| (p.data().iter().map(|&v| (v as f64 - truth).powi(2)).sum::<f64>() / p.data().len() as f64).sqrt();
    let boxed = variance::prefilter(&halves, frame, 2, frame);
    assert!(rmse(&boxed) < rmse(&halves), "prefiltered variance should be closer to the truth");
}

/// A colour edge hidden in noise but present in the albedo: the joint filter keeps it.
#[test]
fn albedo_feature_keeps_an_edge_that_colour_only_blurs() {
    // Contrast 0.06 against noise sigma 0.1: the colour patch distance barely sees it.
    let frame = Rect::from_origin_size(0, 0, 48, 128);
    let edge = 24;
    let truth = |x: i64| if x < edge { 0.40 } else { 0.46 };
    let mut rng = Rng::new(17);
    let var = 0.01f32;
    let values: Vec<Plane> =
        (0..3).map(|_| Plane::from_fn(frame, |x, _| truth(x) + var.sqrt() * rng.normal())).collect();
    let albedo: Vec<Plane> = (0..3).map(|_| Plane::from_fn(frame, |x, _| if x < edge { 0.2 } else { 0.8 })).collect();
    let colour = Buffer {
        name: "beauty".into(),
        values,
        variance: VarianceSource::Sample((0..3).map(|_| Plane::filled(frame, var)).collect()),
    };
    // The patchwise aggregation (SPEC §4) evaluates the feature weight at patch
    // centres, so pixels within f of the edge still receive the other side
    // through patches centred there; beyond f the guide must stop the blur,
    // which colour-only spreads over the search radius.
    let params = Params { variance_prefilter_radius: 0, ..Params::default() };
    let f = params.patch_radius as i64;
    let columns: Vec<i64> = (edge - f - 5..edge - f).chain(edge + f..edge + f + 5).collect();
    let err_near_edge = |features: Vec<Feature>| {
        let inputs = FrameInputs { colour: colour.clone(), features, layers: vec![] };
        let out = filter::denoise_region(&inputs, frame, frame, &params).unwrap();
        // Blurring an edge is a bias: average the signed error over the rows
        // (which averages the residual noise away) for each column next to the edge.
        let mut bias = 0.0f64;
        for &x in &columns {
            for c in &out.colour {
                let mean: f64 = (frame.y0..frame.y1).map(|y| c.get(x, y) as f64 - truth(x) as f64).sum::<f64>()
                    / frame.height() as f64;
                bias += mean.abs();
            }
        }
        bias
    };
    let colour_only = err_near_edge(vec![]);
    let joint = err_near_edge(vec![Feature { name: "albedo".into(), values: albedo, variance: None }]);
    assert!(
        joint < 0.25 * colour_only,
        "edge bias with the albedo guide {joint} should be well below colour-only {colour_only}"
    );
    eprintln!("edge bias: joint {joint}, colour-only {colour_only}");
}

#[test]
fn layers_are_filtered_separately_and_sum_to_the_beauty() {
    let frame = Rect::from_origin_size(0, 0, 30, 20);
    let inputs = frame_inputs(frame, 8, ALL_KINDS[2]);
    let params = crate::common::small_params(3, 1);
    let out = filter::denoise_region(&inputs, frame, frame, &params).unwrap();
    assert_eq!(out.layers.len(), 2);
    for c in 0..3 {
        for i in 0..frame.area() {
            let sum = out.layers[0][c].data()[i] + out.layers[1][c].data()[i];
            assert_eq!(out.colour[c].data()[i].to_bits(), sum.to_bits());
        }
    }
    // Each layer is filtered with its own weights: filtering a layer alone gives the same result.
    let alone = FrameInputs { colour: inputs.layers[0].clone(), features: inputs.features.clone(), layers: vec![] };
    let direct = filter::denoise_region(&alone, frame, frame, &params).unwrap();
    assert_eq!(direct.colour, out.layers[0]);
    // And the filter does denoise: the output is closer to the noise-free layer sum than the input.
    assert_ne!(out.colour[0].data(), inputs.colour.values[0].data());
}

#[test]
fn invalid_parameters_are_errors() {
    let frame = Rect::from_origin_size(0, 0, 8, 8);
    let inputs = frame_inputs(frame, 1, ALL_KINDS[0]);
    for p in [
        Params { tau: 0.0, ..Params::default() },
        Params { strength: f32::NAN, ..Params::default() },
        Params { search_radius: 5000, ..Params::default() },
    ] {
        let e = filter::denoise_region(&inputs, frame, frame, &p).unwrap_err();
        assert!(e.to_string().contains("invalid parameter"), "{e}");
    }
    // Inputs that do not cover the halo are refused, not read out of bounds.
    let small = inputs.crop(Rect::from_origin_size(2, 2, 3, 3));
    assert!(filter::denoise_region(&small, frame, Rect::from_origin_size(2, 2, 3, 3), &Params::default()).is_err());
}
