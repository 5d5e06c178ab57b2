//! Every error type of the core is a `core::error::Error` with a message of its own, so the
//! host tools can put it behind `?` and `Box<dyn Error>` without wrapping.

use std::error::Error;

use kinematics_core::jerk_profile::ProfileError;
use kinematics_core::machine::{ImageRefusal, Implausible, MachineMismatch, RecordError};
use kinematics_core::{
    ConfigError, DynamicsError, EngageError, GridError, InvalidGain, KinematicsError, ModelError,
    ServoFault, SetpointRefusal, Singularity, StepError, TrajectoryError,
};

fn boxed(e: impl Error + 'static) -> Box<dyn Error> {
    Box::new(e)
}

#[test]
fn every_error_type_is_an_error_with_a_distinct_message() {
    let all: Vec<Box<dyn Error>> = vec![
        boxed(KinematicsError::NonFinite),
        boxed(KinematicsError::Unreachable),
        boxed(KinematicsError::NearSingularity(Singularity::Serial)),
        boxed(KinematicsError::NearSingularity(Singularity::Parallel)),
        boxed(KinematicsError::InvalidModel(ModelError::NonPositiveLink)),
        boxed(ModelError::NonFinite),
        boxed(ModelError::NonPositiveLink),
        boxed(GridError::Truncated),
        boxed(GridError::BadMagic),
        boxed(GridError::UnsupportedVersion(7)),
        boxed(GridError::BadHeader),
        boxed(GridError::BadCrc),
        boxed(GridError::NonFinite),
        boxed(GridError::BadModel),
        boxed(GridError::OutsideGrid),
        boxed(GridError::BadEncodeInput),
        boxed(GridError::BadDynamics),
        boxed(GridError::BadBacklash),
        boxed(GridError::BadWorkspace),
        boxed(GridError::BadMachineRecord),
        boxed(RecordError::Length),
        boxed(RecordError::Name),
        boxed(RecordError::Reserved),
        boxed(RecordError::EncoderSign),
        boxed(RecordError::Model(ModelError::NonFinite)),
        boxed(RecordError::Workspace),
        boxed(RecordError::Home),
        boxed(RecordError::Limit("dynamics_factor")),
        boxed(RecordError::Dynamics),
        boxed(MachineMismatch::Unreachable {
            at_mm: [200.0, 0.0],
            parameter: None,
        }),
        boxed(Implausible::HomeOutsideGrid {
            home_mm: [212.0, 0.0],
        }),
        boxed(ImageRefusal::Record(RecordError::Home)),
        boxed(DynamicsError::NonFinite),
        boxed(DynamicsError::OutOfRange),
        boxed(ProfileError::NonFinite),
        boxed(ProfileError::NonPositiveLimit),
        boxed(TrajectoryError::TooManyWaypoints),
        boxed(TrajectoryError::EmptyPath),
        boxed(TrajectoryError::JointLimits),
        boxed(TrajectoryError::Kinematics(KinematicsError::Unreachable)),
        boxed(ServoFault::NotEngaged),
        boxed(ServoFault::NonFiniteFeedback),
        boxed(ServoFault::FollowingError),
        boxed(SetpointRefusal::NotEngaged),
        boxed(SetpointRefusal::NonFinite),
        boxed(SetpointRefusal::Kinematics(KinematicsError::Unreachable)),
        boxed(SetpointRefusal::Grid(GridError::OutsideGrid)),
        boxed(SetpointRefusal::Jump),
        boxed(EngageError::NonFiniteFeedback),
        boxed(EngageError::Kinematics(KinematicsError::Unreachable)),
        boxed(EngageError::Grid(GridError::OutsideGrid)),
        boxed(ConfigError::SamplePeriod),
        boxed(ConfigError::MinTransmission),
        boxed(ConfigError::Limit("max_speed_mm_s")),
        boxed(ConfigError::Gain {
            axis: 0,
            gain: InvalidGain("kp_nm_per_rad"),
        }),
        boxed(InvalidGain("ki_nm_per_rad_s")),
    ];
    let messages: Vec<String> = all.iter().map(|e| e.to_string()).collect();
    for (k, m) in messages.iter().enumerate() {
        assert!(!m.is_empty());
        assert!(!messages[..k].contains(m), "two errors read {m:?}");
        // The cause is in the message, not in a `source` chain (printed once).
        assert!(all[k].source().is_none());
    }
    assert!(messages.iter().any(|m| m.contains("version 7")));
    assert!(messages
        .iter()
        .any(|m| m.contains("setpoint refused: pose out of reach")));
    assert!(messages.iter().any(|m| m.contains("axis 1: kp_nm_per_rad")));
    // `StepError` wraps the two without a message of its own: it reads as what it wraps.
    let step: Vec<Box<dyn Error>> = vec![
        boxed(StepError::Refused(SetpointRefusal::Jump)),
        boxed(StepError::Fault(ServoFault::FollowingError)),
    ];
    assert_eq!(step[0].to_string(), SetpointRefusal::Jump.to_string());
    assert_eq!(step[1].to_string(), ServoFault::FollowingError.to_string());
}
