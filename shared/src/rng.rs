//! A small deterministic pseudo-random generator, for tests and synthetic data that
//! must repeat exactly from a seed.

/// Knuth's MMIX linear congruential generator; the tuple is its state (the seed).
#[derive(Debug, Clone)]
pub struct Lcg(pub u64);

impl Lcg {
    fn step(&mut self) -> u64 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        self.0
    }

    /// Uniform in [0, 1), from the 53 high bits of the next state.
    pub fn next_f64(&mut self) -> f64 {
        (self.step() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in [0, 1), from the 24 high bits of the next state.
    pub fn next_f32(&mut self) -> f32 {
        (self.step() >> 40) as f32 / (1u64 << 24) as f32
    }
}
