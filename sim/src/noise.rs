//! Seeded random streams, one per noise source.
//!
//! Every source (each wheel encoder, each laser) draws from its own ChaCha8 stream, keyed by
//! the run's seed and the source's name. Adding a sensor therefore never changes the noise
//! another sensor sees, and the same seed gives the same bytes on every run.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// FNV-1a, a fixed hash (std's hasher may change between releases).
fn fnv1a(s: &str) -> u64 {
    s.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    })
}

/// SplitMix64 finaliser, to spread nearby seeds.
fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The random stream of the source `name` in a run seeded with `seed`.
pub fn stream(seed: u64, name: &str) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(mix(seed ^ mix(fnv1a(name))))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::Rng;

    #[test]
    fn streams_differ_by_name_and_seed_and_repeat() {
        let a: u64 = stream(1, "lidar.front").random();
        assert_eq!(a, stream(1, "lidar.front").random::<u64>());
        assert_ne!(a, stream(1, "lidar.rear").random::<u64>());
        assert_ne!(a, stream(2, "lidar.front").random::<u64>());
    }
}
