//! Every instruction-set tier computes the same bits (SPEC §6): the tiers
//! compile the same code with wider registers, and every fused multiply-add
//! is one correctly rounded operation on each of them.

use nldenoise::filter::{self, simd};
use nldenoise::geom::Rect;

use crate::common::{ALL_KINDS, bits, frame_inputs, small_params};

#[test]
fn every_tier_gives_the_same_bits() {
    let frame = Rect::from_origin_size(-3, 5, 67, 41);
    let available: Vec<simd::Tier> = simd::Tier::ALL.into_iter().filter(|t| t.available()).collect();
    eprintln!("tiers available here: {available:?}");
    // r = 4 gives groups of 5 and 4 offsets, r = 10 whole groups of 7 (the
    // accumulation's register-shifted path on the AVX-512 tier takes both).
    for (kinds, params) in ALL_KINDS.into_iter().flat_map(|k| [(k, small_params(4, 2)), (k, small_params(10, 3))]) {
        let inputs = frame_inputs(frame, 21, kinds);
        let run = |tier: simd::Tier, out: Rect| {
            simd::force(Some(tier));
            assert_eq!(simd::current(), tier);
            let window = inputs.crop(
                out.expand(filter::Pipeline::new(params, filter::InputShape::of(&inputs)).halo()).intersect(&frame),
            );
            bits(&filter::denoise_region(&window, frame, out, &params).unwrap())
        };
        let portable = run(simd::Tier::Portable, frame);
        for &tier in &available {
            assert!(run(tier, frame) == portable, "{tier:?} differs from portable on {kinds:?}");
            // A tile computed on this tier equals the same pixels of the portable whole frame.
            let tile = Rect::from_origin_size(10, 12, 13, 9);
            simd::force(Some(simd::Tier::Portable));
            let full = filter::denoise_region(&inputs, frame, frame, &params).unwrap();
            let tile_bits = run(tier, tile);
            let want: Vec<Vec<u32>> = full
                .colour
                .iter()
                .chain(full.layers.iter().flatten())
                .map(|p| p.crop(tile).data().iter().map(|v| v.to_bits()).collect())
                .collect();
            assert!(tile_bits == want, "{tier:?} tile differs from the portable whole frame on {kinds:?}");
        }
    }
    simd::force(None);
}
