//! Which machine a file belongs to: its name and a digest of its geometry, carried by every file
//! the tools write (`model.json` and `dynamics.json`: a `machine` object; a measurement CSV: a
//! `# machine=NAME digest=HEX8` line before its header), and the check every command makes of
//! the files it is given against the machine it works on (`--machine`).
//!
//! Why: a model, grid or measurement of another machine reads like one of this machine and
//! produces plausible-looking nonsense (angles 17° off; a grid image with corrections of
//! 298,099 µrad, which a firmware then committed). Two machines are the same when their
//! digests are equal; the name is for messages (two files of machines named alike but built
//! differently are told apart by the digest).
//!
//! The digest is the machine record's (`kinematics_core::machine::MachineRecord::digest`,
//! see [`MachineSpec::identity`]): CRC-32C over the geometry's canonical encoding (working
//! mode, encoder convention, nominal five-bar, workspace polygon), the one the calibration
//! image's `HRMC` block carries and the firmware holds. Files written before they carried an identity are read with a note; their models are
//! still checked against the machine's geometry ([`check_model_geometry`]).

use crate::machine_spec::MachineSpec;
use kinematics_core::machine::MachineRecord;
use kinematics_core::FiveBar;
use serde::{Deserialize, Serialize};

/// A machine's identity: its name and the digest of its geometry.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MachineIdentity {
    pub name: String,
    /// CRC-32C of the geometry's canonical encoding, as 8 lower-case hex digits.
    pub digest: String,
}

impl std::fmt::Display for MachineIdentity {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "machine '{}' (digest {})", self.name, self.digest)
    }
}

impl MachineSpec {
    /// This machine's identity: its name and its machine record's digest
    /// (`kinematics_core::machine::MachineRecord::digest`, the CRC-32C of the geometry's
    /// canonical encoding: working mode, encoder convention, nominal model, workspace polygon),
    /// the same digest the calibration image's `HRMC` block carries.
    pub fn identity(&self) -> MachineIdentity {
        let digest = match self.record() {
            Ok(r) => r.digest(),
            // A description never validated (built in code, a name the controller cannot
            // store): the digest covers only the geometry, so a record with this geometry
            // under another name has the same one.
            Err(_) => {
                let mut r = MachineRecord::paper();
                r.nominal = self.nominal.cast::<f32>();
                if let Ok(w) = self.workspace.limits() {
                    r.workspace = w;
                }
                r.digest()
            }
        };
        MachineIdentity {
            name: self.name.clone(),
            digest: format!("{digest:08x}"),
        }
    }
}

/// A measurement CSV's identity line: `# machine=NAME digest=HEX8`.
pub fn csv_line(id: &MachineIdentity) -> String {
    format!("# machine={} digest={}", id.name, id.digest)
}

/// The identity of a `# machine=NAME digest=HEX8` line, if it is one.
pub fn parse_csv_line(line: &str) -> Option<MachineIdentity> {
    let rest = line.trim().strip_prefix('#')?.trim_start();
    let rest = rest.strip_prefix("machine=")?;
    let (name, tail) = rest.rsplit_once(" digest=")?;
    let digest = tail.split_whitespace().next()?;
    (digest.len() == 8 && digest.bytes().all(|b| b.is_ascii_hexdigit())).then(|| MachineIdentity {
        name: name.trim().to_string(),
        digest: digest.to_ascii_lowercase(),
    })
}

/// A file a command was given and the machine it says it belongs to.
#[derive(Clone, Debug)]
pub struct FileMachine {
    /// `--flag path`, for messages.
    pub what: String,
    pub identity: Option<MachineIdentity>,
}

/// Checks every file against the machine the command works on (`machine`, described as
/// `machine_what`, e.g. `--machine second.toml`): a file of another machine is refused naming
/// both; a file without an identity gives a note (returned).
pub fn check_files(
    machine: &MachineIdentity,
    machine_what: &str,
    files: &[FileMachine],
) -> Result<Vec<String>, String> {
    let mut notes = Vec::new();
    for f in files {
        match &f.identity {
            Some(id) if id.digest == machine.digest => {}
            Some(id) => {
                let how = if id.name == machine.name {
                    "a machine of the same name but another geometry"
                } else {
                    "another machine"
                };
                return Err(format!(
                    "{} is of {id}, but {machine_what} is {machine}: {how}; use the files of one machine (or give --machine for the files' machine)",
                    f.what
                ));
            }
            None => notes.push(format!(
                "{} names no machine (written before files carried one): taken as {machine}",
                f.what
            )),
        }
    }
    Ok(notes)
}

/// The largest relative difference of a model's link lengths and base distance from the
/// machine's nominal ones for "the same machine" when a file carries no identity (or a grid
/// image none): a fit moves a link by well under 1 %; another machine's differ by more.
pub const MAX_GEOMETRY_DIFFERENCE: f64 = 0.02;

/// A model against the machine's nominal five-bar: the same working mode, and link lengths and
/// base distance within [`MAX_GEOMETRY_DIFFERENCE`]; the message names the parameter and both
/// values.
pub fn check_model_geometry(
    model: &FiveBar<f64>,
    nominal: &FiveBar<f64>,
    what: &str,
    machine: &str,
) -> Result<(), String> {
    if model.mode != nominal.mode {
        return Err(format!(
            "{what} has another working mode than machine '{machine}' ({:?} against {:?}): it is a model of another machine",
            model.mode, nominal.mode
        ));
    }
    let base = |m: &FiveBar<f64>| m.base_b0_mm[0].hypot(m.base_b0_mm[1]);
    for (name, a, b) in [
        ("a_mm", model.a_mm, nominal.a_mm),
        ("b_mm", model.b_mm, nominal.b_mm),
        ("c_mm", model.c_mm, nominal.c_mm),
        ("d_mm", model.d_mm, nominal.d_mm),
        ("|B0 - A0| (mm)", base(model), base(nominal)),
    ] {
        let scale = b.abs().max(model.a_mm.min(nominal.a_mm));
        if (a - b).abs() > MAX_GEOMETRY_DIFFERENCE * scale {
            return Err(format!(
                "{what} has {name} = {a:.3} where machine '{machine}' has {b:.3} (more than {:.0} % apart): it is a model of another machine; use this machine's model (or give --machine for the model's machine)",
                MAX_GEOMETRY_DIFFERENCE * 100.0
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn digests_tell_machines_apart_and_lines_round_trip() {
        let paper = MachineSpec::paper().identity();
        let second =
            crate::io::machine_file::parse_machine(include_str!("../machines/second.toml"))
                .unwrap()
                .identity();
        assert_eq!(paper, MachineSpec::paper().identity(), "deterministic");
        assert_ne!(paper.digest, second.digest);
        let mut moved = MachineSpec::paper();
        moved.nominal.a_mm += 0.5;
        assert_ne!(moved.identity().digest, paper.digest);
        assert_eq!(moved.identity().name, "paper");
        // The image's record and the files carry one digest.
        assert_eq!(
            paper.digest,
            format!("{:08x}", MachineSpec::paper().record().unwrap().digest())
        );
        let mut unnamed = MachineSpec::paper();
        unnamed.name = "a name longer than sixteen characters".into();
        assert_eq!(unnamed.identity().digest, paper.digest);
        assert_eq!(parse_csv_line(&csv_line(&paper)), Some(paper.clone()));
        let spaced = MachineIdentity {
            name: "cell 3 left".into(),
            digest: "0a1b2c3d".into(),
        };
        assert_eq!(parse_csv_line(&csv_line(&spaced)), Some(spaced));
        assert_eq!(parse_csv_line("# just a comment"), None);
        let files = [FileMachine {
            what: "--model m.json".into(),
            identity: Some(second.clone()),
        }];
        let e = check_files(&paper, "--machine (default: paper)", &files).unwrap_err();
        assert!(e.contains("--model m.json is of machine 'second'"), "{e}");
        let e = check_files(
            &moved.identity(),
            "--machine m.toml",
            &[FileMachine {
                what: "--data d.csv".into(),
                identity: Some(paper.clone()),
            }],
        )
        .unwrap_err();
        assert!(e.contains("the same name but another geometry"), "{e}");
        let notes = check_files(
            &paper,
            "--machine",
            &[FileMachine {
                what: "--data t.csv".into(),
                identity: None,
            }],
        )
        .unwrap();
        assert!(notes[0].contains("names no machine"), "{notes:?}");
    }

    #[test]
    fn another_machines_model_is_told_by_its_geometry() {
        let paper = MachineSpec::paper().nominal;
        let second =
            crate::io::machine_file::parse_machine(include_str!("../machines/second.toml"))
                .unwrap()
                .nominal;
        let mut fitted = paper;
        fitted.a_mm += 0.3;
        fitted.base_a0_mm = [2.0, -1.0];
        check_model_geometry(&fitted, &paper, "--model m.json", "paper").unwrap();
        let e = check_model_geometry(&second, &paper, "--model m.json", "paper").unwrap_err();
        assert!(
            e.contains("a_mm = 120.000 where machine 'paper' has 150.000"),
            "{e}"
        );
    }
}
