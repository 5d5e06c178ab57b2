//! Other builds of a design, for the journey's sweeps (`tests/commission.rs`,
//! `benches/commission_builds.rs`): a plant file's design (its nominal geometry, parallelograms,
//! stiffnesses, drives) with part errors, encoder zeros and an instrument set-up drawn afresh,
//! reproducibly from a seed. What is drawn, and why these magnitudes:
//! * each driven lever's and distal bar's length off by N(0, 1 mm) (the paper plant's are
//!   0.9-2.3 mm), its follower off the same plus N(0, 30 µm) (a pair machined together: the
//!   paper plant's partners differ by 30-80 µm; much more and the overconstrained loop jams),
//! * every pin off by N(0, 25 µm) per axis (the paper plant's: 10-60 µm),
//! * the encoder zeros N(0, 0.02°) off the machine file's,
//! * the instrument anywhere: its frame up to 2 m off along each axis and turned up to 20°.

use host_sim::plant::PlantConfig;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Another build of `base`'s design (module doc); `zero_offset_deg`: the machine file's
/// encoder zeros.
pub fn another_build(base: &PlantConfig, zero_offset_deg: [f64; 2], seed: u64) -> PlantConfig {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let length = Normal::new(0.0, 1.0).expect("finite");
    let partner = Normal::new(0.0, 0.03).expect("finite");
    let pin = Normal::new(0.0, 0.025).expect("finite");
    let zero = Normal::new(0.0, 0.02).expect("finite");
    let mut p = base.clone();
    let e = &mut p.sixbar.errors;
    for i in 0..2 {
        e.lever_length_mm[i] = length.sample(&mut rng);
        e.bar_f_length_mm[i] = e.lever_length_mm[i] + partner.sample(&mut rng);
        e.bar_q_length_mm[i] = length.sample(&mut rng);
        e.bar_g_length_mm[i] = e.bar_q_length_mm[i] + partner.sample(&mut rng);
    }
    for v in e.pins_mut() {
        *v = [pin.sample(&mut rng), pin.sample(&mut rng)];
    }
    p.drive_1.encoder_offset_deg = zero_offset_deg[0] + zero.sample(&mut rng);
    p.drive_2.encoder_offset_deg = zero_offset_deg[1] + zero.sample(&mut rng);
    p.instrument.frame_offset_mm = [
        rng.random_range(-2000.0..2000.0),
        rng.random_range(-2000.0..2000.0),
    ];
    p.instrument.frame_rotation_deg = rng.random_range(-20.0..20.0);
    p.description = format!("{}: another build (seed {seed})", base.description);
    p
}
