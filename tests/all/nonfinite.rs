//! NaN, infinities, negative variances and absurd fireflies in any input never
//! spread: the output is finite, a bad pixel does not blank its neighbours,
//! pixels beyond the halo are untouched, tiling stays bit-exact, and the
//! repaired pixels are counted.

use nldenoise::filter::{self, InputShape, Params, Pipeline};
use nldenoise::geom::Rect;

use crate::common::{ALL_KINDS, bits, frame_inputs, small_params, with_bad_samples};

const BAD: [(i64, i64); 5] = [(10, 10), (11, 10), (30, 5), (0, 0), (45, 33)];

#[test]
fn bad_samples_are_repaired_and_do_not_spread() {
    let frame = Rect::from_origin_size(0, 0, 48, 36);
    for kinds in ALL_KINDS {
        for params in [small_params(3, 2), Params::default()] {
            let clean_in = frame_inputs(frame, 17, kinds);
            let bad_in = with_bad_samples(&clean_in, &BAD);
            let clean = filter::denoise_region(&clean_in, frame, frame, &params).unwrap();
            let bad = filter::denoise_region(&bad_in, frame, frame, &params).unwrap();
            assert_eq!(bad.repaired, BAD.len(), "{kinds:?}: every bad pixel counted once");
            assert_eq!(clean.repaired, 0);
            let halo = Pipeline::new(params, InputShape::of(&clean_in)).halo() as i64;
            let near = |x: i64, y: i64| BAD.iter().any(|&(bx, by)| (bx - x).abs() <= halo && (by - y).abs() <= halo);
            for (pc, pb) in clean.colour.iter().zip(&bad.colour) {
                let mut diff = 0.0f64;
                let mut n = 0;
                for y in frame.y0..frame.y1 {
                    for x in frame.x0..frame.x1 {
                        let (c, b) = (pc.get(x, y), pb.get(x, y));
                        assert!(b.is_finite(), "{kinds:?}: output at ({x},{y}) is {b}");
                        if near(x, y) {
                            diff += (c - b).abs() as f64;
                            n += 1;
                        } else {
                            assert_eq!(c.to_bits(), b.to_bits(), "{kinds:?}: ({x},{y}) beyond the halo changed");
                        }
                    }
                }
                // Near the bad pixels the output stays close to the clean one
                // (values are around 0.2-1.2): no blanking, no poisoning.
                let mean = diff / n as f64;
                assert!(mean < 0.05, "{kinds:?}: mean change {mean} near the bad pixels");
            }
        }
    }
}

#[test]
fn a_frame_with_whole_regions_of_nan_stays_finite() {
    let frame = Rect::from_origin_size(0, 0, 40, 30);
    let clean = frame_inputs(frame, 3, ALL_KINDS[2]);
    let region: Vec<(i64, i64)> = (5..15).flat_map(|y| (8..20).map(move |x| (x, y))).collect();
    let nan = clean.map_planes(&|p| {
        let mut q = p.clone();
        for &(x, y) in &region {
            q.set(x, y, f32::NAN);
        }
        q
    });
    let out = filter::denoise_region(&nan, frame, frame, &small_params(3, 2)).unwrap();
    assert_eq!(out.repaired, region.len());
    assert!(out.colour.iter().chain(out.layers.iter().flatten()).all(|p| p.data().iter().all(|v| v.is_finite())));
}

#[test]
fn tiles_equal_whole_frame_with_bad_samples() {
    let frame = Rect::from_origin_size(-3, 2, 40, 31);
    let bad: Vec<(i64, i64)> = vec![(-3, 2), (5, 9), (6, 9), (20, 20), (36, 32), (15, 2)];
    for kinds in ALL_KINDS {
        let inputs = with_bad_samples(&frame_inputs(frame, 23, kinds), &bad);
        let params = small_params(3, 2);
        let whole = filter::denoise_region(&inputs, frame, frame, &params).unwrap();
        let halo = Pipeline::new(params, InputShape::of(&inputs)).halo();
        for (tw, th) in [(1, 1), (7, 5), (16, 16)] {
            let mut repaired = 0;
            let mut planes: Vec<nldenoise::image::Plane> =
                whole.colour.iter().map(|_| nldenoise::image::Plane::filled(frame, f32::NAN)).collect();
            for tile in frame.tiles(tw, th) {
                let window = inputs.crop(tile.expand(halo).intersect(&frame));
                let out = filter::denoise_region(&window, frame, tile, &params).unwrap();
                repaired += out.repaired;
                for (dst, src) in planes.iter_mut().zip(&out.colour) {
                    dst.paste(src);
                }
            }
            assert_eq!(repaired, whole.repaired, "{kinds:?} {tw}x{th}: counts differ");
            let t = filter::Denoised { colour: planes, layers: Vec::new(), repaired };
            let w = filter::Denoised { colour: whole.colour.clone(), layers: Vec::new(), repaired };
            assert!(bits(&t) == bits(&w), "{kinds:?}: tiles {tw}x{th} differ from whole frame");
        }
    }
}
