//! Every command that reads a calibration image judges it as the controller does
//! (`host_sim::calib::image`): another machine's image and absurd content are refused through
//! the binary, naming what differs with both values, with nothing written; `grid --nominal`
//! writes the commissioning image of a machine file.

use kinematics_core::grid::{append_workspace, encode, WorkspaceLimits, WORKSPACE_LEN};
use kinematics_core::{paper, ConvexWorkspace, CorrectionGrid, FiveBar};
use std::path::{Path, PathBuf};
use std::process::Command;

fn run(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into(),
        String::from_utf8_lossy(&out.stderr).into(),
    )
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn second() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("machines/second.toml")
}

/// Expects failure with every one of `want` in stderr, no panic, and `absent` not written.
fn refused(args: &[&str], want: &[&str], absent: &Path) {
    let (ok, _, stderr) = run(args);
    assert!(!ok, "{args:?} succeeded");
    for w in want {
        assert!(stderr.contains(w), "{args:?}: '{stderr}' lacks '{w}'");
    }
    assert!(!stderr.contains("panicked"), "{args:?} panicked: {stderr}");
    assert!(!absent.exists(), "{args:?} wrote {}", absent.display());
}

/// A CRC-valid image of the paper machine (nominal model, its workspace block) whose node
/// corrections are `field(i, j)`: what an adversary or a broken tool can write.
fn paper_image(dir: &Path, name: &str, field: impl Fn(u16, u16) -> [f32; 2]) -> PathBuf {
    let g = paper::grid_geometry();
    let nodes: Vec<[f32; 2]> = (0..g.ny)
        .flat_map(|j| (0..g.nx).map(move |i| (i, j)))
        .map(|(i, j)| field(i, j))
        .collect();
    let mut img = vec![0u8; g.image_len() + WORKSPACE_LEN];
    let n = encode(&mut img, &g, &FiveBar::paper_nominal(), &nodes).unwrap();
    let limits = WorkspaceLimits {
        region: ConvexWorkspace::rectangle(
            paper::WORKSPACE_X_MM.map(|v| v as f32),
            paper::WORKSPACE_Y_MM.map(|v| v as f32),
        )
        .unwrap(),
        stop_margin_mm: 0.1,
    };
    append_workspace(&mut img, n, n, &limits).unwrap();
    let path = dir.join(name);
    std::fs::write(&path, img).unwrap();
    path
}

fn targets(dir: &Path) -> PathBuf {
    let path = dir.join("targets.csv");
    std::fs::write(&path, "x_mm,y_mm\n212.132,0\n200,10\n").unwrap();
    path
}

#[test]
fn grid_nominal_writes_each_machines_commissioning_image() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (machine, name) in [(None, "paper"), (Some(second()), "second")] {
        let out = d.join(format!("{name}.bin"));
        let mut args = vec!["grid", "--nominal", "--out", s(&out)];
        if let Some(m) = &machine {
            args.extend(["--machine", s(m)]);
        }
        let (ok, stdout, stderr) = run(&args);
        assert!(ok, "{stderr}");
        let v: serde_json::Value = serde_json::from_str(&stdout).unwrap();
        assert_eq!(v["commissioning"], true);
        assert_eq!(v["judgement"]["machine"], name);
        let bytes = std::fs::read(&out).unwrap();
        let g = CorrectionGrid::parse(&bytes).unwrap();
        let record = g.machine().unwrap();
        assert_eq!(record.name.as_str(), name);
        assert_eq!(
            v["judgement"]["digest"],
            format!("{:08x}", record.digest()).as_str()
        );
        assert!(g.workspace().is_some() && g.dynamics().is_none());
        assert_eq!(g.correction_rad(record.home_mm), Ok([0.0; 2]));
        // Commanding with it is commanding with the nominal.
        let t = targets(d);
        let angles = d.join(format!("{name}_angles.csv"));
        let mut args = vec![
            "command",
            "--grid",
            s(&out),
            "--targets",
            s(&t),
            "--out",
            s(&angles),
        ];
        if let Some(m) = &machine {
            args.extend(["--machine", s(m)]);
        }
        let (ok, _, stderr) = run(&args);
        assert!(ok, "{stderr}");
    }
    // --nominal takes no measurements.
    let (ok, _, stderr) = run(&[
        "grid",
        "--nominal",
        "--model",
        "m.json",
        "--out",
        s(&d.join("x.bin")),
    ]);
    assert!(!ok && stderr.contains("cannot be used with"), "{stderr}");
    // Without --nominal, --model and --data are required.
    let (ok, _, stderr) = run(&["grid", "--out", s(&d.join("x.bin"))]);
    assert!(!ok && stderr.contains("--model"), "{stderr}");
}

#[test]
fn absurd_images_are_refused_by_every_reader_naming_the_node() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let t = targets(d);
    let out = d.join("angles.csv");
    let checker = paper_image(d, "checker.bin", |i, j| {
        [if (i + j) % 2 == 0 { 0.05 } else { -0.05 }; 2]
    });
    let half_rad = paper_image(d, "half.bin", |_, _| [0.5; 2]);
    let steps = paper_image(d, "steps.bin", |i, j| {
        [if (i + j) % 2 == 0 { 2e-3 } else { -2e-3 }; 2]
    });
    for (img, want) in [
        (
            &checker,
            "the correction of grid node (0, 0) moves the tool by",
        ),
        (
            &half_rad,
            "the correction of grid node (0, 0) moves the tool by",
        ),
        (&steps, "would command a step"),
    ] {
        refused(
            &[
                "command",
                "--grid",
                s(img),
                "--targets",
                s(&t),
                "--out",
                s(&out),
            ],
            &[
                want,
                "the limit is",
                "refused: no calibration of machine 'paper'",
            ],
            &out,
        );
        refused(
            &[
                "measure",
                "--plant",
                "paper",
                "--grid",
                s(img),
                "--targets",
                s(&t),
                "--out",
                s(&out),
            ],
            &[want],
            &out,
        );
    }
    // The same image with small, smooth corrections is accepted.
    let fine = paper_image(d, "fine.bin", |i, j| {
        [1e-5 * f32::from(i), -1e-5 * f32::from(j)]
    });
    let (ok, _, stderr) = run(&[
        "command",
        "--grid",
        s(&fine),
        "--targets",
        s(&t),
        "--out",
        s(&out),
    ]);
    assert!(ok, "{stderr}");
}

#[test]
fn another_machines_image_is_refused_naming_both_machines() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let t = targets(d);
    let out = d.join("angles.csv");
    let second_img = d.join("second.bin");
    let (ok, _, stderr) = run(&[
        "grid",
        "--nominal",
        "--machine",
        s(&second()),
        "--out",
        s(&second_img),
    ]);
    assert!(ok, "{stderr}");
    let record = CorrectionGrid::parse(&std::fs::read(&second_img).unwrap())
        .unwrap()
        .machine()
        .unwrap();
    let paper_digest = format!("{:08x}", kinematics_core::MachineRecord::paper().digest());
    let second_digest = format!("{:08x}", record.digest());
    refused(
        &[
            "command",
            "--grid",
            s(&second_img),
            "--targets",
            s(&t),
            "--out",
            s(&out),
        ],
        &[
            &format!("built for machine 'second' (digest {second_digest})"),
            &format!("this is machine 'paper' (digest {paper_digest})"),
        ],
        &out,
    );
    // An image without a record, of the paper's five-bar, read for the second machine: its
    // model is judged, centimetres off.
    let fine = paper_image(d, "fine.bin", |_, _| [0.0; 2]);
    refused(
        &[
            "command",
            "--machine",
            s(&second()),
            "--grid",
            s(&fine),
            "--targets",
            s(&t),
            "--out",
            s(&out),
        ],
        &["the image's model is another machine", "tolerance 3 mm"],
        &out,
    );
    // link upload judges before it connects: refused without a controller on the port.
    let (ok, _, stderr) = run(&[
        "link",
        "--tcp",
        "127.0.0.1:9",
        "--timeout-s",
        "0.5",
        "upload",
        "--grid",
        s(&second_img),
        "--machine",
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("machines/paper.toml")
            .to_str()
            .unwrap(),
    ]);
    assert!(
        !ok && stderr.contains("built for machine 'second'"),
        "{stderr}"
    );
    assert!(!stderr.contains("connecting"), "{stderr}");
    for img in [&checker_free(d), &second_img] {
        // Without --machine: judged against its own record (the second machine's image
        // passes the judgement and fails to connect), or the built-in paper machine.
        let (ok, _, stderr) = run(&[
            "link",
            "--tcp",
            "127.0.0.1:9",
            "--timeout-s",
            "0.5",
            "upload",
            "--grid",
            s(img),
        ]);
        assert!(!ok && stderr.contains("connecting"), "{stderr}");
    }
    let absurd = paper_image(d, "absurd.bin", |_, _| [0.5; 2]);
    let (ok, _, stderr) = run(&[
        "link",
        "--tcp",
        "127.0.0.1:9",
        "upload",
        "--grid",
        s(&absurd),
    ]);
    assert!(!ok && stderr.contains("moves the tool by"), "{stderr}");
}

/// A plausible paper image without a record.
fn checker_free(d: &Path) -> PathBuf {
    paper_image(d, "plain.bin", |_, _| [1e-5, 0.0])
}

// The QEMU board's bundled images (the firmware's build script and its upload scenario use
// this generator): plausible calibrations of the paper machine, as the firmware will judge them.
#[allow(dead_code)]
mod machine {
    include!("../../firmware/src/board/qemu/machine.rs");
}
mod synthetic {
    include!("../../firmware/src/board/qemu/synthetic_image.rs");
}

#[test]
fn the_qemu_boards_bundled_images_are_accepted() {
    let paper = kinematics_core::MachineRecord::paper();
    for sign in [1.0, -1.0] {
        let img = synthetic::synthetic_image(sign);
        let v = host_sim::calib::image::judge_bytes(&img, &paper).unwrap();
        assert!(!v.carried && v.same.worst_mm < 1e-3, "{v:?}");
        let [lo, hi] = v.margins.inertia_ratio.unwrap();
        assert!(lo > 0.5 && hi < 1.5, "{lo} {hi}");
    }
}
