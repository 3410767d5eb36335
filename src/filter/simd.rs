//! Instruction-set tiers for the NL-means block kernel, chosen once at run
//! time.
//!
//! Every tier compiles the *same* Rust code (`nlmeans::filter_block_body`)
//! with a different set of target features, so every pixel gets the same
//! IEEE operations in the same order whichever tier or lane computes it: the
//! wider tiers only put more pixels in a register, and the AVX-512 tier walks
//! its rows in chunks of `kernels::CHUNK_AVX512` samples instead of
//! `kernels::CHUNK`, which changes which samples one loop iteration computes,
//! never their operations. Four kernels are written for the AVX-512 tier,
//! each computing the same bits from the same samples:
//! `kernels::taps_push_avx512` (the horizontal window sums for `f <= 4`,
//! pushed into a lane's box as they are formed) forms the shifted operands
//! in registers instead of loading them,
//! `kernels::feature_square_sum_half_avx512` reads a guide stored as
//! exact half floats, widened exactly (as the AVX2 tier's
//! `kernels::feature_square_sum_half_avx2` does, 8 at a time), and
//! `kernels::guide_pair_products_avx512` gives both lanes of a pair their
//! guides' weight argument in one pass (the square sums kept in registers,
//! masked loads and stores at the lanes' edges), and
//! `kernels::weights_avx512` computes a row's weights with three or four operations
//! fewer per sample than the portable form (`vscalefps` for the power of
//! two, whose single rounding is the multiply's; the box's scale folded
//! into the polynomial's coefficients, exact). The kernel's
//! fused multiply-adds are written as `f32::mul_add`, one correctly rounded
//! operation on every tier: the AVX2 and AVX-512 tiers are compiled with
//! `fma` (and require it), the portable tier calls the target's fused
//! instruction where its baseline has one (aarch64) and libm's `fmaf`
//! otherwise (x86-64 without FMA, much slower: it is a call per operation).
//! Rust never contracts a separate `a * b + c` on its own. Results are
//! therefore bit-identical across tiers (tested with each tier forced).
//!
//! The tier is the best the CPU supports, unless `NLDENOISE_SIMD=portable`,
//! `avx2` or `avx512` says otherwise (a tier the CPU lacks falls back to the
//! best available one), or [`force`] overrides it.

use std::sync::OnceLock;
use std::sync::atomic::{AtomicU8, Ordering};

/// A code path of the block kernel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Tier {
    /// The baseline target (SSE2 on x86-64).
    Portable,
    /// AVX2 with FMA and F16C (8 lanes; every AVX2 CPU has the other two).
    Avx2,
    /// AVX-512F (16 lanes).
    Avx512,
}

impl Tier {
    /// All tiers, slowest first.
    pub const ALL: [Tier; 3] = [Tier::Portable, Tier::Avx2, Tier::Avx512];

    /// Whether this CPU can run the tier.
    pub fn available(self) -> bool {
        match self {
            Tier::Portable => true,
            #[cfg(target_arch = "x86_64")]
            Tier::Avx2 => {
                std::arch::is_x86_feature_detected!("avx2")
                    && std::arch::is_x86_feature_detected!("fma")
                    && std::arch::is_x86_feature_detected!("f16c")
            }
            #[cfg(target_arch = "x86_64")]
            Tier::Avx512 => {
                std::arch::is_x86_feature_detected!("avx512f") && std::arch::is_x86_feature_detected!("fma")
            }
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }

    fn from_name(s: &str) -> Option<Tier> {
        match s.trim().to_ascii_lowercase().as_str() {
            "portable" | "scalar" => Some(Tier::Portable),
            "avx2" => Some(Tier::Avx2),
            "avx512" | "avx-512" => Some(Tier::Avx512),
            _ => None,
        }
    }
}

fn best_available(at_most: Tier) -> Tier {
    Tier::ALL.into_iter().rev().find(|t| t.available() && *t as u8 <= at_most as u8).unwrap_or(Tier::Portable)
}

static FORCED: AtomicU8 = AtomicU8::new(u8::MAX);

/// Force a tier for the whole process (`None`: back to automatic). A tier the
/// CPU lacks falls back to the best available one below it.
pub fn force(tier: Option<Tier>) {
    FORCED.store(tier.map_or(u8::MAX, |t| t as u8), Ordering::SeqCst);
}

/// The tier the kernel runs with now.
pub fn current() -> Tier {
    static AUTO: OnceLock<Tier> = OnceLock::new();
    let forced = FORCED.load(Ordering::SeqCst);
    if let Some(t) = Tier::ALL.into_iter().find(|t| *t as u8 == forced) {
        return best_available(t);
    }
    *AUTO.get_or_init(|| {
        let wanted = std::env::var("NLDENOISE_SIMD").ok().and_then(|s| Tier::from_name(&s)).unwrap_or(Tier::Avx512);
        best_available(wanted)
    })
}
