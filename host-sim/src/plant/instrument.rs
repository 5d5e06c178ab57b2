//! The measuring instrument: its own frame, a scale error and Gaussian noise.
//!
//! `reading = offset + R(rotation)·(1 + scale)·tool + N(0, σ²)` per axis, like the paper's
//! FARO (±20 µm class) and Renishaw (±1 µm class) interferometers. The noise comes from a
//! ChaCha8 stream seeded by the caller, so a measurement run is reproducible.

use crate::plant::config::InstrumentConfig;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

#[derive(Clone, Debug)]
pub struct Instrument {
    offset_mm: [f64; 2],
    rot_sin_cos: (f64, f64),
    scale: f64,
    pub noise_sigma_mm: f64,
    rng: ChaCha8Rng,
}

impl Instrument {
    pub fn new(cfg: &InstrumentConfig, seed: u64) -> Self {
        Instrument {
            offset_mm: cfg.frame_offset_mm,
            rot_sin_cos: cfg.frame_rotation_deg.to_radians().sin_cos(),
            scale: 1.0 + cfg.scale_error_ppm * 1e-6,
            noise_sigma_mm: cfg.noise_sigma_um * 1e-3,
            rng: ChaCha8Rng::seed_from_u64(seed),
        }
    }

    /// Restarts the noise stream as [`Instrument::new`] with `seed` starts it.
    pub fn reseed(&mut self, seed: u64) {
        self.rng = ChaCha8Rng::seed_from_u64(seed);
    }

    /// The noiseless reading of a tool point (machine frame).
    pub fn frame_mm(&self, tool_mm: [f64; 2]) -> [f64; 2] {
        let (s, c) = self.rot_sin_cos;
        let p = [tool_mm[0] * self.scale, tool_mm[1] * self.scale];
        [
            self.offset_mm[0] + c * p[0] - s * p[1],
            self.offset_mm[1] + s * p[0] + c * p[1],
        ]
    }

    /// One reading, with noise.
    pub fn read_mm(&mut self, tool_mm: [f64; 2]) -> [f64; 2] {
        let mut r = self.frame_mm(tool_mm);
        if self.noise_sigma_mm > 0.0 {
            for v in &mut r {
                let n: f64 = StandardNormal.sample(&mut self.rng);
                *v += self.noise_sigma_mm * n;
            }
        }
        r
    }
}
