// The QEMU machine's true dynamics and the calibration image's: one file, a module of the
// board (`plant.rs` uses it) and included by `build.rs` (which writes the image), so the two
// cannot drift.
//
// The truth: the paper machine's bars, elbow pieces and platform lumped into the hidden
// robot's parameters (host-sim's `paper` plant computes the same numbers from geometry and
// material: levers and distal bars 120 mm², followers 40 mm² of aluminium, 30 g elbow pieces,
// 100 g platform with tool), on rotors of 2.2e-3 and 1.8e-3 kg·m² (joint side). Friction and
// the drives' dynamic braking are the plant's own (`plant.rs`).
//
// The image: what the servo feeds forward, the whole machine (rotors and linkage), every
// inertia and the tool mass 20 % off the truth with alternating signs (the feed-forward
// robustness case), friction under-estimated.

/// The rotors' inertia at the joints (kg·m²).
pub const ROTOR_INERTIA_KG_M2: [f32; 2] = [2.2e-3, 1.8e-3];

/// The linkage's bodies lumped into the hidden robot (rotors and friction not included).
pub const LINKAGE: kinematics_core::FiveBarDynamics<f32> = kinematics_core::FiveBarDynamics {
    motor_inertia_kg_m2: [1.89e-3, 1.89e-3],
    tool_mass_kg: 0.165,
    distal_inertia_kg_m2: [-2.43e-4, -2.43e-4],
    viscous_nm_s_per_rad: [0.0; 2],
    coulomb_nm: [0.0; 2],
    coulomb_speed_rad_s: 1.0e-3,
};

/// The dynamics the calibration image carries.
pub const IMAGE_DYNAMICS: kinematics_core::FiveBarDynamics<f32> =
    kinematics_core::FiveBarDynamics {
        motor_inertia_kg_m2: [
            (ROTOR_INERTIA_KG_M2[0] + LINKAGE.motor_inertia_kg_m2[0]) * 1.2,
            (ROTOR_INERTIA_KG_M2[1] + LINKAGE.motor_inertia_kg_m2[1]) * 0.8,
        ],
        tool_mass_kg: LINKAGE.tool_mass_kg * 1.2,
        distal_inertia_kg_m2: [
            LINKAGE.distal_inertia_kg_m2[0] * 0.8,
            LINKAGE.distal_inertia_kg_m2[1] * 1.2,
        ],
        viscous_nm_s_per_rad: [0.008, 0.008],
        coulomb_nm: [0.025, 0.025],
        coulomb_speed_rad_s: 0.01,
    };
