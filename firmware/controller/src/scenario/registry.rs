//! The scenarios of `cargo qemu-test`, one entry each: the one list the parser, the board's
//! hooks, the checks, `qemu/test.sh` (through the `list` command line) and the table of
//! docs/dev/testing.md follow (see the module doc of [`super`]). The order is `qemu/test.sh`'s.
use kinematics_core::{GridError, SetpointRefusal};

use super::{
    Check, Console, Expected, FaultInjection, HomingSim, Image, InjectAt, InjectedFault,
    OnWatchdog, Run, SelfTest, Spec, Upload, Window, FROZEN_AT_REST_LEAD,
    FROZEN_AT_REST_MAX_TRAVEL_MM, FROZEN_AT_REST_WITHIN, FROZEN_MOVING_WITHIN, HOMING_MAX_TICKS,
    HOMING_POWER_ON_MM, LARGE_GLITCH_RAD, MAX_TICKS, OUT_OF_REACH_TOUR_MM, SMALL_GLITCH_RAD,
    UPLOAD_AT_TICKS,
};
use crate::encoder_check::{EncoderFault, EncoderFaultKind};
use crate::fault::Fault;
use crate::waypoint_moves::Profile;

/// A test scenario's defaults: nothing injected, the production tour and trajectory, absolute
/// encoders, no upload, [`MAX_TICKS`], a watchdog interrupt fails it.
const TEST: Spec = Spec {
    name: "",
    runs: &[],
    fault: None,
    tour_mm: None,
    trajectory: None,
    link_motion: false,
    homing: None,
    home_at_boot: false,
    upload: None,
    time_limit_ticks: Some(MAX_TICKS),
    check: Check::Nothing,
    watchdog: OnWatchdog::Fail,
    after_watchdog_reset: None,
};

/// A run of the valid image loaded, passing.
const fn valid(test: &'static str) -> Run {
    Run {
        test,
        image: Image::Valid,
        expect: Console::Pass,
    }
}

/// A fault at the tour's top speed.
const fn at_top_speed(fault: InjectedFault) -> Option<FaultInjection> {
    Some(FaultInjection {
        at: InjectAt::TopSpeed,
        fault,
    })
}

/// The fault expected in the injection's own sample.
const fn in_its_sample(fault: fn(Fault) -> bool) -> Expected {
    Expected {
        window: Some(Window::AfterInjection(0)),
        fault,
        max_travel_mm: None,
    }
}

/// The machine of the homing scenarios and `link`: incremental encoders, powered up off home.
const HOMING_SIM: HomingSim = HomingSim {
    power_on_mm: HOMING_POWER_ON_MM,
    index: [true, true],
};

/// Every scenario (module doc of [`super`]).
pub static SCENARIOS: [Spec; 25] = [
    // The bundled image alone (no loader) is the same valid image: the ELF runs standalone.
    Spec {
        name: "track",
        runs: &[
            valid("track"),
            Run {
                test: "bundled-image",
                image: Image::Bundled,
                expect: Console::Pass,
            },
        ],
        check: Check::Track,
        ..TEST
    },
    Spec {
        name: "track-5g",
        runs: &[valid("track-5g")],
        trajectory: Some((
            Profile::JerkLimited,
            5.0 * kinematics_core::servo::STANDARD_GRAVITY_MM_S2,
        )),
        check: Check::Track5g,
        ..TEST
    },
    // Faults of a moving machine, injected at the tour's top speed (1.38 m/s): categories 1
    // and 2 (a controlled stop, then torque off / hold) ...
    Spec {
        name: "nan-setpoint",
        runs: &[valid("nan-setpoint")],
        fault: at_top_speed(InjectedFault::NanSetpoint),
        check: Check::Fault(in_its_sample(|f| {
            f == Fault::Setpoint(SetpointRefusal::NonFinite)
        })),
        ..TEST
    },
    Spec {
        name: "out-of-reach",
        runs: &[valid("out-of-reach")],
        tour_mm: Some(&OUT_OF_REACH_TOUR_MM),
        check: Check::FaultInsideGrid(Expected {
            window: None,
            fault: |f| f == Fault::StopOutsideWorkspace,
            max_travel_mm: None,
        }),
        ..TEST
    },
    Spec {
        name: "jump",
        runs: &[valid("jump")],
        fault: at_top_speed(InjectedFault::SetpointStep(1.0)),
        check: Check::Fault(in_its_sample(|f| {
            f == Fault::Setpoint(SetpointRefusal::Jump)
        })),
        ..TEST
    },
    Spec {
        name: "underrun",
        runs: &[valid("underrun")],
        fault: at_top_speed(InjectedFault::DryStream),
        check: Check::Fault(in_its_sample(|f| f == Fault::Underrun)),
        ..TEST
    },
    // ... and category 0 (torque off at once; the drives' dynamic braking must stop the
    // machine inside the workspace): the controller and the encoders.
    Spec {
        name: "overrun",
        runs: &[valid("overrun")],
        fault: at_top_speed(InjectedFault::Overruns(3)),
        check: Check::FaultWithOverruns(Expected {
            window: Some(Window::EndOfOverrunStreak),
            fault: |f| f == Fault::DeadlineMissed,
            max_travel_mm: None,
        }),
        ..TEST
    },
    Spec {
        name: "encoder-frozen-at-rest",
        runs: &[valid("encoder-frozen-at-rest")],
        fault: Some(FaultInjection {
            at: InjectAt::BeforeTopSpeedMove(FROZEN_AT_REST_LEAD),
            fault: InjectedFault::EncoderFreeze,
        }),
        check: Check::Fault(Expected {
            window: Some(Window::AfterMoveStart(FROZEN_AT_REST_WITHIN)),
            fault: |f| {
                matches!(
                    f,
                    Fault::Encoder(EncoderFault {
                        axis: 0,
                        kind: EncoderFaultKind::Stuck
                    })
                )
            },
            max_travel_mm: Some(FROZEN_AT_REST_MAX_TRAVEL_MM),
        }),
        ..TEST
    },
    Spec {
        name: "encoder-frozen-moving",
        runs: &[valid("encoder-frozen-moving")],
        fault: at_top_speed(InjectedFault::EncoderFreeze),
        check: Check::Fault(Expected {
            window: Some(Window::AfterInjection(FROZEN_MOVING_WITHIN)),
            fault: |f| matches!(f, Fault::Encoder(EncoderFault { axis: 0, .. })),
            max_travel_mm: None,
        }),
        ..TEST
    },
    Spec {
        name: "glitch-small",
        runs: &[valid("glitch-small")],
        fault: at_top_speed(InjectedFault::EncoderOffset(SMALL_GLITCH_RAD)),
        check: Check::Fault(in_its_sample(|f| {
            f == Fault::Encoder(EncoderFault {
                axis: 0,
                kind: EncoderFaultKind::Acceleration,
            })
        })),
        ..TEST
    },
    Spec {
        name: "glitch-large",
        runs: &[valid("glitch-large")],
        fault: at_top_speed(InjectedFault::EncoderOffset(LARGE_GLITCH_RAD)),
        check: Check::Fault(in_its_sample(|f| {
            f == Fault::Encoder(EncoderFault {
                axis: 0,
                kind: EncoderFaultKind::Speed,
            })
        })),
        ..TEST
    },
    // The servo task stalls (interrupts disabled) while the tool moves at speed: the watchdog
    // removes torque within its timeout, then resets the machine; the boot after it keeps the
    // drives off while the machine, which moves on through the reset, coasts within category
    // 0's bounds.
    Spec {
        name: "stalled-task",
        runs: &[Run {
            test: "stalled-task",
            image: Image::Valid,
            expect: Console::Watchdog,
        }],
        fault: at_top_speed(InjectedFault::Stall),
        check: Check::UntilStall,
        watchdog: OnWatchdog::Expected,
        after_watchdog_reset: Some("watchdog-restart"),
        ..TEST
    },
    Spec {
        name: "watchdog-restart",
        check: Check::WatchdogRestart,
        ..TEST
    },
    // Incremental encoders: the machine powers up at an unknown pose, homes on its index marks
    // (speed and torque limited), then runs the tour with the grid applied; without joint 1's
    // index mark the search ends at rest and the drives go off.
    Spec {
        name: "homing",
        runs: &[valid("homing")],
        homing: Some(HOMING_SIM),
        home_at_boot: true,
        time_limit_ticks: Some(HOMING_MAX_TICKS),
        check: Check::HomingThenTrack,
        ..TEST
    },
    Spec {
        name: "homing-no-index",
        runs: &[valid("homing-no-index")],
        homing: Some(HomingSim {
            index: [false, true],
            ..HOMING_SIM
        }),
        home_at_boot: true,
        check: Check::HomingNoIndex,
        ..TEST
    },
    // A calibration uploaded at run time into the inactive slot (the firmware's bundled second
    // image), committed and switched to at rest; the same upload corrupted on the way is
    // refused and the old image stays in force.
    Spec {
        name: "calibration-upload",
        runs: &[valid("calibration-upload")],
        upload: Some(Upload {
            at_ticks: UPLOAD_AT_TICKS,
            corrupt: false,
        }),
        time_limit_ticks: Some(MAX_TICKS + 1_000),
        check: Check::Upload,
        ..TEST
    },
    Spec {
        name: "calibration-upload-corrupt",
        runs: &[valid("calibration-upload-corrupt")],
        upload: Some(Upload {
            at_ticks: UPLOAD_AT_TICKS,
            corrupt: true,
        }),
        time_limit_ticks: Some(MAX_TICKS + 1_000),
        check: Check::Upload,
        ..TEST
    },
    // Bad images, flashed by the test: refused, drives never enabled.
    Spec {
        name: "bad-image-crc",
        runs: &[Run {
            test: "corrupt-image",
            image: Image::Corrupt,
            expect: Console::Pass,
        }],
        check: Check::BadImage(GridError::BadCrc),
        ..TEST
    },
    Spec {
        name: "bad-image-magic",
        runs: &[
            Run {
                test: "erased-image",
                image: Image::Erased,
                expect: Console::Pass,
            },
            Run {
                test: "no-image",
                image: Image::None,
                expect: Console::Pass,
            },
        ],
        check: Check::BadImage(GridError::BadMagic),
        ..TEST
    },
    // The production path (what the real board runs) past the old 6 s scenario limit.
    Spec {
        name: "long-run",
        runs: &[valid("long-run")],
        time_limit_ticks: None,
        check: Check::LongRun,
        ..TEST
    },
    // The failure paths themselves: a panic and a HardFault must end QEMU with exit 1 and
    // their own line, not hang and not fail some other way.
    Spec {
        name: "panic",
        runs: &[Run {
            test: "panic-exits",
            image: Image::Valid,
            expect: Console::Panic,
        }],
        check: Check::SelfTest(SelfTest::Panic),
        ..TEST
    },
    Spec {
        name: "hard-fault",
        runs: &[Run {
            test: "hardfault-exits",
            image: Image::Valid,
            expect: Console::HardFault,
        }],
        check: Check::SelfTest(SelfTest::HardFault),
        ..TEST
    },
    // Not run by `qemu/test.sh`: the host link's test drives the machine over the link
    // (host-sim/tests/link_qemu.rs); setpoints from the link, incremental encoders (the host
    // homes it), no time limit (the host ends QEMU), only the deadline checked.
    Spec {
        name: "link",
        link_motion: true,
        homing: Some(HOMING_SIM),
        time_limit_ticks: None,
        check: Check::Link,
        ..TEST
    },
    // Co-simulation (`firmware/src/board/qemu/cosim.rs`, `host_sim::cosim`): host-sim's plant
    // in lockstep instead of the in-firmware one; the production path otherwise (the host
    // checks the machine), not run by `qemu/test.sh` (host-sim/tests/cosim.rs runs it).
    Spec {
        name: "cosim",
        time_limit_ticks: None,
        check: Check::Nothing,
        watchdog: OnWatchdog::Production,
        ..TEST
    },
    // The production path on the QEMU board: nothing injected or checked, no time limit.
    Spec {
        name: "run",
        time_limit_ticks: None,
        check: Check::Nothing,
        watchdog: OnWatchdog::Production,
        ..TEST
    },
];
