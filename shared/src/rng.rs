//! Counter-based random numbers: a path's stream is seeded by hashing (pixel, sample, seed)
//! with the PCG hash of Jarzynski & Olano (JCGT 2020, "Hash Functions for GPU Rendering"), then
//! stepped with PCG32's RXS-M-XS output. Integer-only, so CPU and GPU draw identical numbers,
//! and no two pixels or samples share a stream (the thesis seeded per pixel only).

/// PCG hash: a 32-bit permutation with good avalanche (one LCG step, then PCG's output).
pub fn pcg_hash(x: u32) -> u32 {
    output(lcg(x))
}

fn lcg(state: u32) -> u32 {
    state.wrapping_mul(747_796_405).wrapping_add(2_891_336_453)
}

/// PCG's RXS-M-XS output permutation.
fn output(state: u32) -> u32 {
    let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(277_803_737);
    (word >> 22) ^ word
}

/// A random stream.
#[derive(Copy, Clone, Debug)]
pub struct Rng {
    state: u32,
}

impl Rng {
    /// The stream of sample `sample` of pixel `pixel` under `seed`.
    pub fn new(pixel: u32, sample: u32, seed: u32) -> Rng {
        Rng {
            state: pcg_hash(pixel ^ pcg_hash(sample ^ pcg_hash(seed))),
        }
    }

    pub fn next_u32(&mut self) -> u32 {
        self.state = lcg(self.state);
        output(self.state)
    }

    /// Uniform in `[0, 1)`: the top 24 bits, exactly representable.
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u32() >> 8) as f32 * (1.0 / 16_777_216.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uniform_in_unit_interval_with_the_right_mean() {
        let mut r = Rng::new(17, 3, 0);
        let n = 100_000;
        let mut sum = 0.0f64;
        for _ in 0..n {
            let x = r.next_f32();
            assert!((0.0..1.0).contains(&x));
            sum += x as f64;
        }
        assert!((sum / n as f64 - 0.5).abs() < 0.005, "mean {}", sum / n as f64);
    }

    #[test]
    fn neighbouring_pixels_and_samples_get_different_streams() {
        let first = |p, s| Rng::new(p, s, 0).next_u32();
        let mut seen = std::collections::HashSet::new();
        for p in 0..256 {
            for s in 0..64 {
                seen.insert(first(p, s));
            }
        }
        assert!(seen.len() > 256 * 64 - 8, "{} distinct of {}", seen.len(), 256 * 64);
    }
}
