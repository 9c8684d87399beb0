//! Hot loops compiled for the widest vector unit the processor has.
//!
//! The build targets baseline x86-64 (SSE2), so one binary runs on any x86-64 processor. A loop
//! over whole images or pixel runs goes through [`widest!`], which also compiles it into a
//! function with AVX2 enabled and calls that one when the processor has AVX2 (std checks once
//! and caches the answer). Only AVX2 is enabled, not FMA, and Rust never fuses a multiply and
//! an add on its own: both copies do the same arithmetic in the same order, so results are
//! bit-identical whichever runs.

/// Evaluates the expression, compiled with AVX2 when the processor has it.
///
/// The expression is written twice: once as it stands (the baseline copy), once in a closure
/// that an AVX2 function calls and must inline (the compiler may otherwise keep a large one
/// apart, compiled for baseline x86-64). Functions the expression calls must be
/// `#[inline(always)]` for their loops to be compiled for AVX2 too.
macro_rules! widest {
    ($body:expr) => {{
        #[cfg(target_arch = "x86_64")]
        {
            #[target_feature(enable = "avx2")]
            fn avx2<R>(f: impl FnOnce() -> R) -> R {
                f()
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: the processor has AVX2.
                unsafe {
                    avx2(
                        #[inline(always)]
                        || $body,
                    )
                }
            } else {
                $body
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            $body
        }
    }};
}

pub(crate) use widest;
