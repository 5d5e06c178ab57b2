//! The machine file: one TOML file per machine, what `--machine FILE` reads
//! (`host-sim/machines/paper.toml` is the documented example and the default; every key is
//! described in `host-sim/MACHINE.md`).
//!
//! A contract like the other formats: versioned (`format_version = 1`; another version is
//! refused with the one this tool reads), every key with its unit in its name, unknown keys
//! refused (`deny_unknown_fields`: a misspelt key must not silently fall back to a default),
//! every error naming the file and the key. The file is read into a
//! [`MachineSpec`](crate::machine_spec::MachineSpec) and checked with
//! [`MachineSpec::validate`] (numbers in range, the grid covering the workspace, every point
//! reachable with the singularity margin).

use super::{read_text, IoError};
use crate::machine_spec::{
    Approach, BranchKey, ControllerSpec, GantrySpec, GridLattice, MachineSpec, Workspace,
};
use kinematics_core::{FiveBar, FiveBarDynamics, WorkingMode};
use serde::Deserialize;
use std::path::Path;

/// The one version this tool reads.
pub const FORMAT_VERSION: u32 = 1;

/// The paper machine's file as shipped (the default; a test checks it equals
/// `MachineSpec::paper()`).
pub const PAPER_TOML: &str = include_str!("../../machines/paper.toml");

/// The file, as TOML has it.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct MachineFile {
    format_version: u32,
    name: String,
    #[serde(default)]
    #[allow(dead_code)] // read so that the key is allowed; reports use `name`
    description: String,
    nominal: Nominal,
    encoders: Encoders,
    workspace: WorkspaceKeys,
    grid: Grid,
    instrument: Instrument,
    approach: ApproachKeys,
    servo: Servo,
    /// Optional: the paper's gantry when absent (`GantrySpec::paper`).
    #[serde(default)]
    gantry: GantryKeys,
    /// Optional: home and the limits an image is judged against (defaults in MACHINE.md).
    #[serde(default)]
    controller: ControllerKeys,
    /// Optional: the design's dynamics (default: the paper machine's).
    nominal_dynamics: Option<NominalDynamics>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct ControllerKeys {
    home_mm: Option<[f64; 2]>,
    same_machine_tolerance_mm: Option<f64>,
    max_node_correction_mm: Option<f64>,
    max_correction_slope: Option<f64>,
    max_backlash_urad: Option<f64>,
    dynamics_factor: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct NominalDynamics {
    motor_inertia_kg_m2: [f64; 2],
    tool_mass_kg: f64,
    distal_inertia_kg_m2: [f64; 2],
    viscous_nm_s_per_rad: [f64; 2],
    coulomb_nm: [f64; 2],
    coulomb_speed_rad_s: f64,
}

/// `[gantry]`: every key optional, the paper gantry's value when absent.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct GantryKeys {
    travel_x_mm: Option<[f64; 2]>,
    travel_y_mm: Option<[f64; 2]>,
    home_mm: Option<[f64; 2]>,
    speed_mm_s: Option<f64>,
    accel_g: Option<f64>,
    jerk_mm_s3: Option<f64>,
    bandwidth_hz: Option<f64>,
    moving_mass_kg: Option<[f64; 2]>,
    friction_n: Option<[f64; 2]>,
    feedforward_mass_error_pct: Option<f64>,
    scale_resolution_um: Option<f64>,
    micro_margin_mm: Option<f64>,
    micro_joint_speed_rad_s: Option<f64>,
}

impl GantryKeys {
    fn into_spec(self) -> GantrySpec {
        let d = GantrySpec::paper();
        GantrySpec {
            travel_x_mm: self.travel_x_mm.unwrap_or(d.travel_x_mm),
            travel_y_mm: self.travel_y_mm.unwrap_or(d.travel_y_mm),
            home_mm: self.home_mm.unwrap_or(d.home_mm),
            speed_mm_s: self.speed_mm_s.unwrap_or(d.speed_mm_s),
            accel_g: self.accel_g.unwrap_or(d.accel_g),
            jerk_mm_s3: self.jerk_mm_s3.unwrap_or(d.jerk_mm_s3),
            bandwidth_hz: self.bandwidth_hz.unwrap_or(d.bandwidth_hz),
            moving_mass_kg: self.moving_mass_kg.unwrap_or(d.moving_mass_kg),
            friction_n: self.friction_n.unwrap_or(d.friction_n),
            feedforward_mass_error_pct: self
                .feedforward_mass_error_pct
                .unwrap_or(d.feedforward_mass_error_pct),
            scale_resolution_um: self.scale_resolution_um.unwrap_or(d.scale_resolution_um),
            micro_margin_mm: self.micro_margin_mm.unwrap_or(d.micro_margin_mm),
            micro_joint_speed_rad_s: self
                .micro_joint_speed_rad_s
                .unwrap_or(d.micro_joint_speed_rad_s),
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Nominal {
    a_mm: f64,
    b_mm: f64,
    c_mm: f64,
    d_mm: f64,
    a0_mm: [f64; 2],
    b0_mm: [f64; 2],
    elbow_1: BranchKey,
    elbow_2: BranchKey,
    assembly: BranchKey,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Encoders {
    sign: [i8; 2],
    zero_offset_deg: [f64; 2],
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct WorkspaceKeys {
    x_mm: Option<[f64; 2]>,
    y_mm: Option<[f64; 2]>,
    vertices_mm: Option<Vec<[f64; 2]>>,
    stop_margin_mm: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Grid {
    x_mm: [f64; 2],
    y_mm: [f64; 2],
    step_mm: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Instrument {
    sigma_um: f64,
}

#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(rename_all = "lowercase")]
enum PolicyKey {
    Positive,
    Random,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ApproachKeys {
    policy: PolicyKey,
    distance_mm: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Servo {
    sample_period_s: f64,
    min_transmission: f64,
    max_acceleration_g: f64,
}

/// Nodes along one axis of the grid's extent: `(hi − lo)/step + 1`, a whole number.
fn nodes(key: &str, span: [f64; 2], step: f64) -> Result<usize, String> {
    if !(step > 0.0 && step.is_finite()) {
        return Err(format!("'grid.step_mm' must be positive, not {step}"));
    }
    if !(span[0].is_finite() && span[1].is_finite() && span[1] > span[0]) {
        return Err(format!(
            "'grid.{key}' must be [low, high] with low < high, not {span:?}"
        ));
    }
    let cells = (span[1] - span[0]) / step;
    let whole = cells.round();
    if (cells - whole).abs() > 1e-9 * whole.max(1.0) || whole > 1e6 {
        return Err(format!(
            "'grid.{key}' = {span:?} is not a whole number of {step} mm steps ({cells} steps)"
        ));
    }
    Ok(whole as usize + 1)
}

impl MachineFile {
    fn into_spec(self) -> Result<MachineSpec, String> {
        if self.format_version != FORMAT_VERSION {
            return Err(format!(
                "'format_version' = {}: this host-sim reads version {FORMAT_VERSION}",
                self.format_version
            ));
        }
        if self.name.trim().is_empty() {
            return Err("'name' is empty".into());
        }
        let n = &self.nominal;
        for (i, &s) in self.encoders.sign.iter().enumerate() {
            match s {
                1 => {}
                -1 => {
                    return Err(format!(
                        "'encoders.sign' [{i}] = -1: only +1 is supported (the encoder angle grows counter-clockwise with the \
                         link); set the counter's direction in the drive or the encoder interface so that it does"
                    ))
                }
                _ => return Err(format!("'encoders.sign' [{i}] = {s}: must be +1 (or -1, not supported yet)")),
            }
        }
        let nominal = FiveBar {
            a_mm: n.a_mm,
            b_mm: n.b_mm,
            c_mm: n.c_mm,
            d_mm: n.d_mm,
            base_a0_mm: n.a0_mm,
            base_b0_mm: [n.b0_mm[0] - n.a0_mm[0], n.b0_mm[1] - n.a0_mm[1]],
            encoder_offset_rad: self.encoders.zero_offset_deg.map(f64::to_radians),
            mode: WorkingMode {
                elbow_1: n.elbow_1.into(),
                elbow_2: n.elbow_2.into(),
                assembly: n.assembly.into(),
            },
        };
        let links = [
            ("a_mm", n.a_mm),
            ("b_mm", n.b_mm),
            ("c_mm", n.c_mm),
            ("d_mm", n.d_mm),
        ];
        for (key, v) in links {
            if !(v > 0.0 && v.is_finite()) {
                return Err(format!(
                    "'nominal.{key}' must be a positive length, not {v}"
                ));
            }
        }
        for (key, v) in [
            ("nominal.a0_mm", n.a0_mm),
            ("nominal.b0_mm", n.b0_mm),
            ("encoders.zero_offset_deg", self.encoders.zero_offset_deg),
        ] {
            if !v.iter().all(|x| x.is_finite()) {
                return Err(format!("'{key}' is not finite: {v:?}"));
            }
        }
        let w = &self.workspace;
        let workspace = match (w.x_mm, w.y_mm, &w.vertices_mm) {
            (Some(x), Some(y), None) => Workspace::rectangle(x, y, w.stop_margin_mm),
            (None, None, Some(v)) => Workspace::polygon(v, w.stop_margin_mm),
            _ => Err("give either 'workspace.x_mm' and 'workspace.y_mm' (a rectangle) or 'workspace.vertices_mm' (a convex polygon, counter-clockwise)".into()),
        }
        .map_err(|e| format!("[workspace]: {e}"))?;
        let g = &self.grid;
        let grid = GridLattice {
            x0_mm: g.x_mm[0],
            y0_mm: g.y_mm[0],
            step_mm: g.step_mm,
            nx: nodes("x_mm", g.x_mm, g.step_mm)?,
            ny: nodes("y_mm", g.y_mm, g.step_mm)?,
        };
        let nominal_dynamics = match &self.nominal_dynamics {
            None => kinematics_core::paper::nominal_dynamics(),
            Some(d) => FiveBarDynamics {
                motor_inertia_kg_m2: d.motor_inertia_kg_m2,
                tool_mass_kg: d.tool_mass_kg,
                distal_inertia_kg_m2: d.distal_inertia_kg_m2,
                viscous_nm_s_per_rad: d.viscous_nm_s_per_rad,
                coulomb_nm: d.coulomb_nm,
                coulomb_speed_rad_s: d.coulomb_speed_rad_s,
            },
        };
        let k = &self.controller;
        let defaults = ControllerSpec::defaults(workspace.centre_mm(), nominal_dynamics);
        let controller = ControllerSpec {
            home_mm: k.home_mm.unwrap_or(defaults.home_mm),
            same_machine_tolerance_mm: k
                .same_machine_tolerance_mm
                .unwrap_or(defaults.same_machine_tolerance_mm),
            max_node_correction_mm: k
                .max_node_correction_mm
                .unwrap_or(defaults.max_node_correction_mm),
            max_correction_slope: k
                .max_correction_slope
                .unwrap_or(defaults.max_correction_slope),
            max_backlash_urad: k.max_backlash_urad.unwrap_or(defaults.max_backlash_urad),
            dynamics_factor: k.dynamics_factor.unwrap_or(defaults.dynamics_factor),
            nominal_dynamics,
        };
        let spec = MachineSpec {
            name: self.name,
            nominal,
            workspace,
            grid,
            instrument_sigma_um: self.instrument.sigma_um,
            sample_period_s: self.servo.sample_period_s,
            min_transmission: self.servo.min_transmission,
            approach: match self.approach.policy {
                PolicyKey::Positive => Approach::Positive,
                PolicyKey::Random => Approach::FromVisit,
            },
            approach_mm: self.approach.distance_mm,
            max_acceleration_g: self.servo.max_acceleration_g,
            controller,
            gantry: self.gantry.into_spec(),
        };
        spec.validate()?;
        Ok(spec)
    }
}

/// Parses and checks a machine file's text.
pub fn parse_machine(text: &str) -> Result<MachineSpec, IoError> {
    let file: MachineFile =
        toml::from_str(text).map_err(|e| IoError::Parse(e.to_string().trim_end().to_string()))?;
    file.into_spec().map_err(IoError::Parse)
}

/// Reads a machine file.
pub fn read_machine(path: &Path) -> Result<MachineSpec, IoError> {
    parse_machine(&read_text(path)?).map_err(|e| IoError::NotA {
        path: path.to_path_buf(),
        what: "machine file",
        message: e.to_string(),
    })
}

/// The paper machine, from the shipped file (the default of every tool).
pub fn paper() -> MachineSpec {
    parse_machine(PAPER_TOML).expect("the shipped paper machine file is valid (tested)")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shipped_paper_file_is_the_builtin_paper_machine() {
        assert_eq!(parse_machine(PAPER_TOML).unwrap(), MachineSpec::paper());
    }

    /// The paper file with one edit.
    fn edited(from: &str, to: &str) -> Result<MachineSpec, IoError> {
        assert!(PAPER_TOML.contains(from), "{from}");
        parse_machine(&PAPER_TOML.replacen(from, to, 1))
    }

    fn refused(from: &str, to: &str, want: &str) {
        let e = edited(from, to).unwrap_err().to_string();
        assert!(e.contains(want), "{from} -> {to}: '{e}' lacks '{want}'");
    }

    #[test]
    fn bad_files_are_refused_naming_the_key() {
        refused(
            "format_version = 1",
            "format_version = 2",
            "this host-sim reads version 1",
        );
        refused("step_mm = 5.0", "step_mn = 5.0", "step_mn");
        refused("sigma_um = 1.0", "sigma_um = 1.0\ncolour = 3", "colour");
        refused("a_mm = 150.0", "a_mm = -150.0", "nominal.a_mm");
        refused("a_mm = 150.0", "a_mm = nan", "nominal.a_mm");
        refused("sign = [1, 1]", "sign = [1, -1]", "only +1 is supported");
        refused(
            "step_mm = 5.0",
            "step_mm = 3.0",
            "not a whole number of 3 mm steps",
        );
        refused("policy = \"positive\"", "policy = \"sideways\"", "sideways");
        refused("elbow_1 = \"positive\"", "elbow_1 = \"up\"", "up");
        refused("y_mm = [-75.0, 75.0]\nstop_margin_mm", "vertices_mm = [[162.132, -75.0], [262.132, -75.0], [212.0, 75.0]]\ny_mm = [-75.0, 75.0]\nstop_margin_mm", "either");
        refused(
            "stop_margin_mm = 0.1",
            "stop_margin_mm = -0.1",
            "workspace.stop_margin_mm",
        );
        refused(
            "distance_mm = 5.0",
            "distance_mm = 0.0",
            "approach.distance_mm",
        );
        refused("accel_g = 1.0", "accel_g = -1.0", "gantry.accel_g");
        refused("accel_g = 1.0", "acel_g = 1.0", "acel_g");
        // The grid must cover the workspace, every node be reachable.
        refused(
            "[grid]\nx_mm = [162.132, 262.132]",
            "[grid]\nx_mm = [167.132, 262.132]",
            "outside the grid's rectangle",
        );
        refused(
            "[grid]\nx_mm = [162.132, 262.132]",
            "[grid]\nx_mm = [162.132, 312.132]",
            "not reachable",
        );
    }

    /// Every key of the shipped files (between them, every key the reader knows: the paper's
    /// rectangle, the second's polygon), dotted.
    fn keys(text: &str) -> Vec<String> {
        let table: toml::Table = toml::from_str(text).unwrap();
        let mut out = Vec::new();
        for (k, v) in &table {
            match v.as_table() {
                Some(t) => out.extend(t.keys().map(|sub| format!("{k}.{sub}"))),
                None => out.push(k.clone()),
            }
        }
        out
    }

    #[test]
    fn every_key_is_documented_with_its_unit_in_machine_md() {
        let doc = include_str!("../../MACHINE.md");
        let mut all = keys(PAPER_TOML);
        all.extend(keys(include_str!("../../machines/second.toml")));
        assert!(all.len() >= 52, "{all:?}");
        for key in &all {
            // A row of the key table: "| `key` | unit | ..." (x_mm and y_mm share a row).
            let row = doc
                .lines()
                .find(|l| l.starts_with('|') && l.contains(&format!("`{key}`")));
            let row = row.unwrap_or_else(|| panic!("MACHINE.md does not document '{key}'"));
            let unit = row.split('|').nth(2).unwrap().trim();
            // Longest suffixes first: `_rad_s` is not `_s`, `_kg_m2` not `_m2`, `_mm_s` not `_s`.
            let units = [
                ("_nm_s_per_rad", "N·m·s/rad"),
                ("_mm_s3", "mm/s³"),
                ("_mm_s", "mm/s"),
                ("_rad_s", "rad/s"),
                ("_kg_m2", "kg·m²"),
                ("_kg", "kg"),
                ("_nm", "N·m"),
                ("_urad", "µrad"),
                ("_mm", "mm"),
                ("_um", "µm"),
                ("_deg", "°"),
                ("_s", "s"),
                ("_hz", "Hz"),
                ("_n", "N"),
                ("_pct", "%"),
            ];
            let want = units.iter().find(|(u, _)| key.ends_with(*u));
            let said = match want {
                Some((_, u)) => unit == *u,
                None if key.ends_with("_g") => unit.starts_with('g'),
                None => unit == "—",
            };
            assert!(said, "MACHINE.md gives '{key}' the unit '{unit}'");
        }
    }

    /// `[gantry]` is optional, and so is each of its keys: the paper gantry's value stands in.
    #[test]
    fn the_gantry_section_is_optional_key_by_key() {
        let start = PAPER_TOML.find("[gantry]").unwrap();
        let without = &PAPER_TOML[..start];
        assert_eq!(parse_machine(without).unwrap().gantry, GantrySpec::paper());
        let one = format!("{without}[gantry]\naccel_g = 2.0\n");
        let g = parse_machine(&one).unwrap().gantry;
        assert_eq!(
            (g.accel_g, g.speed_mm_s),
            (2.0, GantrySpec::paper().speed_mm_s)
        );
    }

    #[test]
    fn the_controller_keys_default_and_are_range_checked() {
        // The paper file has neither section: the defaults, the paper's dynamics, home at the
        // centre; its record is the firmware's built-in one.
        let paper = parse_machine(PAPER_TOML).unwrap();
        assert_eq!(
            paper.record().unwrap(),
            kinematics_core::MachineRecord::paper()
        );
        let with = |keys: &str| {
            parse_machine(&format!("{PAPER_TOML}\n[controller]\n{keys}\n"))
                .map_err(|e| e.to_string())
        };
        let s = with("home_mm = [200.0, 10.0]\ndynamics_factor = 2.5").unwrap();
        assert_eq!(
            (s.controller.home_mm, s.controller.dynamics_factor),
            ([200.0, 10.0], 2.5)
        );
        assert_eq!(
            s.record().unwrap().digest(),
            paper.record().unwrap().digest()
        );
        for (keys, want) in [
            ("home_mm = [100.0, 0.0]", "'controller.home_mm'"),
            (
                "same_machine_tolerance_mm = 0.0",
                "'controller.same_machine_tolerance_mm'",
            ),
            ("same_machine_tolerance_mm = 20.5", "(0, 20]"),
            (
                "max_node_correction_mm = -1.0",
                "'controller.max_node_correction_mm'",
            ),
            (
                "max_correction_slope = 0.6",
                "'controller.max_correction_slope'",
            ),
            (
                "max_backlash_urad = 20000.0",
                "'controller.max_backlash_urad'",
            ),
            ("dynamics_factor = 1.0", "'controller.dynamics_factor'"),
            ("dynamics_factor = nan", "'controller.dynamics_factor'"),
            ("max_sleep_s = 1.0", "max_sleep_s"),
        ] {
            let e = with(keys).unwrap_err();
            assert!(e.contains(want), "{keys}: '{e}' lacks '{want}'");
        }
        // Limits at their ceilings are accepted.
        with("same_machine_tolerance_mm = 20.0\nmax_correction_slope = 0.5\nmax_backlash_urad = 10000.0\ndynamics_factor = 20.0").unwrap();
        let dynamics = "[nominal_dynamics]\nmotor_inertia_kg_m2 = [0.004, 0.004]\ntool_mass_kg = 0.2\ndistal_inertia_kg_m2 = [0.0, 0.0]\nviscous_nm_s_per_rad = [0.02, 0.02]\ncoulomb_nm = [0.05, 0.05]\ncoulomb_speed_rad_s = 0.01";
        let s = parse_machine(&format!("{PAPER_TOML}\n{dynamics}\n")).unwrap();
        assert_eq!(s.controller.nominal_dynamics.tool_mass_kg, 0.2);
        let e = parse_machine(&format!(
            "{PAPER_TOML}\n{}\n",
            dynamics.replace("coulomb_nm = [0.05, 0.05]", "coulomb_nm = [0.0, 0.05]")
        ))
        .unwrap_err()
        .to_string();
        assert!(e.contains("'nominal_dynamics'"), "{e}");
        let e = parse_machine(
            &PAPER_TOML.replace("name = \"paper\"", "name = \"a name far too long for it\""),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("'name'") && e.contains("16"), "{e}");
    }

    #[test]
    fn the_shipped_second_machine_reads() {
        let s = parse_machine(include_str!("../../machines/second.toml")).unwrap();
        assert_eq!((s.grid.nx, s.grid.ny, s.grid.step_mm), (22, 32, 4.0));
        assert_eq!(s.nominal.base_b0_mm, [15.0, -65.0]);
        assert!(s.nominal.base_b0_mm[0].hypot(s.nominal.base_b0_mm[1]) >= 50.0);
        assert!(!s.workspace.is_rectangle && s.workspace.region.vertices_mm().len() == 8);
        // Its shipped plant is built around exactly this five-bar, with ideal_for's
        // parallelogram offsets (rounded to 1 µm in the file).
        let plant = crate::plant::PlantConfig::by_name(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/plants/second.toml"
        ))
        .unwrap();
        let ideal = crate::plant::PlantConfig::ideal_for(&s.nominal, &s.grid_nodes_mm()).unwrap();
        let mut want = ideal.sixbar.nominal_five_bar();
        want.encoder_offset_rad = [0.0; 2];
        assert_eq!(plant.sixbar.nominal_five_bar(), want);
        for (p, i) in plant
            .sixbar
            .parallelogram_offsets_mm()
            .iter()
            .flatten()
            .zip(ideal.sixbar.parallelogram_offsets_mm().iter().flatten())
        {
            assert!(
                (p[0] - i[0]).abs() < 1e-3 && (p[1] - i[1]).abs() < 1e-3,
                "{p:?} vs {i:?}"
            );
        }
        crate::calib::machine::check_plant_fits(&plant, &s).unwrap();
    }

    #[test]
    fn a_polygon_workspace_and_a_second_geometry_read() {
        let cut = "vertices_mm = [[162.132, -75.0], [262.132, -75.0], [262.132, 35.0], [222.132, 75.0], [162.132, 75.0]]";
        let s = edited(
            "x_mm = [162.132, 262.132]\ny_mm = [-75.0, 75.0]\nstop_margin_mm",
            &format!("{cut}\nstop_margin_mm"),
        )
        .unwrap();
        assert!(!s.workspace.is_rectangle);
        assert!(
            s.workspace.contains([212.132, 0.0], 0.0) && !s.workspace.contains([260.0, 70.0], 0.0)
        );
        let s = edited("b0_mm = [0.0, 0.0]", "b0_mm = [0.0, -2.0]").unwrap();
        assert_eq!(s.nominal.base_b0_mm, [0.0, -2.0]);
        let s = edited(
            "zero_offset_deg = [0.0, 0.0]",
            "zero_offset_deg = [0.5, -0.25]",
        )
        .unwrap();
        assert_eq!(
            s.nominal.encoder_offset_rad,
            [0.5f64.to_radians(), -0.25f64.to_radians()]
        );
    }
}
