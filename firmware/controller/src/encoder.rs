//! Quadrature encoders: counts to joint angle.
//!
//! embedded-hal 1.0 has no encoder trait, hence [`QuadratureEncoder`]. Encoder plausibility
//! (a reading that jumps further than the machine can move in one sample, a counter that
//! stopped) is [`crate::encoder_check`].

/// A quadrature encoder read through a hardware counter.
pub trait QuadratureEncoder {
    /// Position in counts, extended to 32 bits (no wrap within the machine's travel).
    fn position_counts(&mut self) -> i32;
}

/// Encoder angle (rad) of a count, for `counts_per_rev` counts per motor revolution.
#[inline]
pub fn counts_to_rad(counts: i32, counts_per_rev: u32) -> f32 {
    counts as f32 * (2.0 * core::f32::consts::PI / counts_per_rev as f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_revolution_is_two_pi_and_the_sign_is_kept() {
        let cpr = 1u32 << 22;
        assert!((counts_to_rad(cpr as i32, cpr) - 2.0 * core::f32::consts::PI).abs() < 1e-6);
        assert_eq!(counts_to_rad(-(cpr as i32) / 4, cpr), -core::f32::consts::FRAC_PI_2);
        assert_eq!(counts_to_rad(0, cpr), 0.0);
        // One count is 1.5 µrad at 2^22 counts per revolution.
        assert!((counts_to_rad(1, cpr) - 1.498e-6).abs() < 1e-9);
    }
}
