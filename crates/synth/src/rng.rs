//! Derived seeds: every random stream (a site's layout draws, one row of one image's noise) gets
//! its own seed from the master seed, so results do not depend on the order or the number of
//! threads that draw them. The generator is `rand::rngs::StdRng` (ChaCha12 in rand 0.10):
//! scenes are reproducible for a given seed and a given version of `rand`/`rand_distr` (their
//! algorithms are not promised stable across major versions).

use rand::SeedableRng;
use rand::rngs::StdRng;

/// Stream of an image's noise: the reference image.
pub(crate) const STREAM_REFERENCE: u64 = 1;
/// The gradient image.
pub(crate) const STREAM_GRADIENT: u64 = 2;
/// Stack image `k` uses `STREAM_STACK + k`.
pub(crate) const STREAM_STACK: u64 = 1 << 32;
/// Per-site layout draws (domain separator).
const DOMAIN_LAYOUT: u64 = 0x4c41_594f_5554; // "LAYOUT"
const DOMAIN_IMAGE: u64 = 0x0049_4d41_4745; // "IMAGE"
const DOMAIN_ROW: u64 = 0x0052_4f57; // "ROW"

/// The SplitMix64 finaliser (Steele, Lea & Flood 2014): a bijective 64-bit mixer.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// A seed derived from `seed` and a list of words (order matters).
pub(crate) fn derive(seed: u64, words: &[u64]) -> u64 {
    words.iter().fold(mix(seed), |h, &w| mix(h ^ mix(w)))
}

/// Noise seed of one image of a scene (passed to [`crate::render`]).
pub fn image_seed(master: u64, stream: u64) -> u64 {
    derive(master, &[DOMAIN_IMAGE, stream])
}

/// Noise seed of gradient frame `n` of a campaign ([`crate::Scene::frame`], `bostrack synth`):
/// SplitMix64 of the master seed and the frame number, so frames are independent of each other
/// and of the reference and stack noise streams. (Kept bit for bit from the first `bostrack
/// synth`, so campaigns written before stay reproducible.)
pub(crate) fn frame_seed(master: u64, n: usize) -> u64 {
    let mut z = master
        ^ 0x4752_4144_4945_4e54u64.wrapping_add((n as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15));
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// RNG of the layout draws of lattice site `(i, j)`.
pub(crate) fn site_rng(master: u64, i: i32, j: i32) -> StdRng {
    StdRng::seed_from_u64(derive(
        master,
        &[DOMAIN_LAYOUT, i as i64 as u64, j as i64 as u64],
    ))
}

/// RNG of the noise of row `row` of the image with noise seed `seed`.
pub(crate) fn row_rng(seed: u64, row: usize) -> StdRng {
    StdRng::seed_from_u64(derive(seed, &[DOMAIN_ROW, row as u64]))
}
