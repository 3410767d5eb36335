//! Region (tile) evaluation equals whole-frame filtering bit for bit, and the
//! derived halo is exactly what the pipeline reads.

use std::borrow::Cow;

use nldenoise::filter::{self, FrameInputs, InputShape, Params, Pipeline};
use nldenoise::geom::Rect;
use nldenoise::image::Plane;
use proptest::prelude::*;

use crate::common::{ALL_KINDS, Kinds, bits, frame_inputs, small_params};

/// Filter `frame` tile by tile, each tile reading only `(tile ⊕ halo) ∩ frame`.
fn tiled(inputs: &FrameInputs, frame: Rect, params: &Params, tw: usize, th: usize) -> filter::Denoised {
    let halo = Pipeline::new(*params, InputShape::of(inputs)).halo();
    let mut colour: Vec<Plane> = inputs.colour.values.iter().map(|_| Plane::filled(frame, f32::NAN)).collect();
    let mut layers: Vec<Vec<Plane>> =
        inputs.layers.iter().map(|l| l.values.iter().map(|_| Plane::filled(frame, f32::NAN)).collect()).collect();
    for tile in frame.tiles(tw, th) {
        let window = inputs.crop(tile.expand(halo).intersect(&frame));
        let out = filter::denoise_region(&window, frame, tile, params).unwrap();
        for (dst, src) in colour.iter_mut().zip(&out.colour) {
            dst.paste(src);
        }
        for (dl, sl) in layers.iter_mut().zip(&out.layers) {
            for (dst, src) in dl.iter_mut().zip(sl) {
                dst.paste(src);
            }
        }
    }
    filter::Denoised { colour, layers, repaired: 0 }
}

fn assert_tiled_equals_whole(frame: Rect, seed: u64, kinds: Kinds, params: &Params, tiles: &[(usize, usize)]) {
    let inputs = frame_inputs(frame, seed, kinds);
    let whole = filter::denoise_region(&inputs, frame, frame, params).unwrap();
    let whole_bits = bits(&whole);
    for &(tw, th) in tiles {
        let t = tiled(&inputs, frame, params, tw, th);
        assert!(bits(&t) == whole_bits, "tiles {tw}x{th} differ from whole frame ({kinds:?}, {frame:?}, {params:?})");
    }
}

#[test]
fn tiles_equal_whole_frame_for_every_input_kind() {
    let frame = Rect::from_origin_size(-7, 11, 37, 29);
    for kinds in ALL_KINDS {
        assert_tiled_equals_whole(
            frame,
            42,
            kinds,
            &small_params(3, 2),
            &[(1, 1), (7, 7), (16, 16), (5, 29), (64, 64)],
        );
    }
}

#[test]
fn tiles_equal_whole_frame_with_blocks_wider_than_512() {
    // Whole-frame blocks of 515 columns (the kernel's blocks reach 1024
    // columns since session 39), against tiles of narrower blocks.
    let frame = Rect::from_origin_size(-2, 1, 1030, 12);
    for kinds in ALL_KINDS {
        assert_tiled_equals_whole(frame, 11, kinds, &small_params(3, 2), &[(480, 12), (1030, 5)]);
    }
}

#[test]
fn tiles_equal_whole_frame_on_thin_frames() {
    for frame in
        [Rect::from_origin_size(0, 0, 1, 40), Rect::from_origin_size(0, 0, 40, 1), Rect::from_origin_size(3, 3, 2, 2)]
    {
        for kinds in ALL_KINDS {
            assert_tiled_equals_whole(frame, 7, kinds, &small_params(4, 2), &[(1, 1), (7, 3), (3, 7)]);
        }
    }
}

#[test]
fn thread_count_does_not_change_bits() {
    let frame = Rect::from_origin_size(0, 0, 150, 70);
    let inputs = frame_inputs(frame, 5, ALL_KINDS[2]);
    let params = small_params(3, 2);
    let run = |n: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
        bits(&pool.install(|| filter::denoise_region(&inputs, frame, frame, &params).unwrap()))
    };
    let one = run(1);
    for n in [2, 3, 4] {
        assert!(run(n) == one, "{n} threads differ from 1");
    }
}

#[test]
fn block_height_does_not_change_bits() {
    // Tall enough for several blocks of every height tried, for every kind
    // of input (light layers, features with and without variance).
    let frame = Rect::from_origin_size(-3, 5, 90, 140);
    let params = small_params(3, 2);
    for kinds in ALL_KINDS {
        let inputs = frame_inputs(frame, 9, kinds);
        let region = filter::PreparedRegion::new(Cow::Borrowed(&inputs), frame, frame, &params).unwrap();
        let run = |rows: usize| {
            let blocks = region.blocks_of(rows);
            bits(&region.finish(blocks.iter().map(|b| region.filter_block(*b)).collect()))
        };
        let want = bits(&filter::denoise_region(&inputs, frame, frame, &params).unwrap());
        for rows in [1, 5, 33, 128, 384] {
            assert!(run(rows) == want, "blocks of {rows} rows differ ({kinds:?})");
        }
    }
}

/// Replace every sample of `inputs` at Chebyshev distance `>= from` of `tile` by `value`.
fn poison_from(inputs: &FrameInputs, tile: Rect, from: usize, value: f32) -> FrameInputs {
    let keep = tile.expand(from - 1);
    inputs.map_planes(&|p: &Plane| {
        let mut q = p.clone();
        let r = p.rect();
        for y in r.y0..r.y1 {
            for x in r.x0..r.x1 {
                if !keep.contains(x, y) {
                    q.set(x, y, value);
                }
            }
        }
        q
    })
}

#[test]
fn halo_is_sufficient_and_tight() {
    let frame = Rect::from_origin_size(0, 0, 60, 50);
    let tile = Rect::from_origin_size(25, 20, 6, 5);
    let configs: Vec<(Kinds, Params)> = vec![
        (ALL_KINDS[0], small_params(3, 2)),
        (ALL_KINDS[3], small_params(2, 1)),
        (ALL_KINDS[1], small_params(3, 1)),
        (ALL_KINDS[2], Params { variance_prefilter_radius: 3, ..small_params(2, 2) }),
        (
            ALL_KINDS[1],
            Params {
                feature_prefilter: filter::FeaturePrefilter { search_radius: 4, patch_radius: 2, strength: 0.45 },
                ..small_params(2, 1)
            },
        ),
    ];
    for (kinds, params) in configs {
        let inputs = frame_inputs(frame, 11, kinds);
        let halo = Pipeline::new(params, InputShape::of(&inputs)).halo();
        assert!(
            tile.expand(halo + 1).x0 >= 0 && frame.contains_rect(&tile.expand(halo + 1)),
            "test tile must not touch the border"
        );
        // The ring at distance halo - 1 holds NaN, so the repair reads the ring at the halo.
        let with_ring = |outside_from: usize, value: f32| -> FrameInputs {
            inputs.map_planes(&|p: &Plane| {
                Plane::from_fn(p.rect(), |x, y| {
                    let d =
                        (tile.x0 - x).max(x - (tile.x1 - 1)).max(tile.y0 - y).max(y - (tile.y1 - 1)).max(0) as usize;
                    if d == halo - 1 {
                        f32::NAN
                    } else if d >= outside_from {
                        value
                    } else {
                        p.get(x, y)
                    }
                })
            })
        };
        let base = with_ring(usize::MAX, 0.0);
        let want = bits(&filter::denoise_region(&base, frame, tile, &params).unwrap());
        assert!(want.iter().flatten().all(|b| f32::from_bits(*b).is_finite()), "{kinds:?}: NaN ring leaked");
        // Anything beyond the halo may change without effect...
        let far = with_ring(halo + 1, 123.0);
        assert!(
            bits(&filter::denoise_region(&far, frame, tile, &params).unwrap()) == want,
            "{kinds:?}: data beyond the halo {halo} changed the output"
        );
        // ...but the ring at exactly the halo distance matters: one pixel less is not enough.
        let near = with_ring(halo, 123.0);
        assert!(
            bits(&filter::denoise_region(&near, frame, tile, &params).unwrap()) != want,
            "{kinds:?}: halo {halo} is not tight"
        );
        // Without unusable samples, the stages themselves read exactly halo - 1.
        let clean = bits(&filter::denoise_region(&inputs, frame, tile, &params).unwrap());
        assert!(
            bits(&filter::denoise_region(&poison_from(&inputs, tile, halo, 123.0), frame, tile, &params).unwrap())
                == clean
        );
        assert!(
            bits(&filter::denoise_region(&poison_from(&inputs, tile, halo - 1, 123.0), frame, tile, &params).unwrap())
                != clean
        );
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, .. ProptestConfig::default() })]
    #[test]
    fn random_frames_tiles_and_options_are_bit_exact(
        w in 1usize..40, h in 1usize..30, x0 in -20i64..20, y0 in -20i64..20,
        tw in 1usize..20, th in 1usize..20, r in 0usize..5, f in 0usize..3, rho in 0usize..3,
        fp in 0usize..3, kind in 0usize..4, seed in 0u64..1000, fv in any::<bool>(),
    ) {
        let frame = Rect::from_origin_size(x0, y0, w, h);
        let mut params = small_params(r, f);
        params.variance_prefilter_radius = rho;
        params.feature_variance_prefilter_radius = (rho + 1) % 3;
        params.feature_prefilter.search_radius = fp;
        params.feature_variance = fv;
        assert_tiled_equals_whole(frame, seed, ALL_KINDS[kind], &params, &[(tw, th)]);
    }
}
