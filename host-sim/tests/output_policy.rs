//! The output policy (`host_sim::io::policy`) through the binary: no command writes onto one of
//! its inputs or puts two outputs in one file, however the paths are spelt (`./x`, an absolute
//! path, `sub/../x`, a hard link, a path through a linked directory); one file twice among
//! pooled inputs is refused; a command that fails leaves no output behind. The property test
//! runs every subcommand with every aliasing of its paths and checks that no input changes by
//! a byte, that the refusal names both flags, and that nothing is written.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

/// Runs the binary in `cwd`; returns (success, stdout, stderr).
fn run_in(cwd: &Path, args: &[String]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .current_dir(cwd)
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into(),
        String::from_utf8_lossy(&out.stderr).into(),
    )
}

fn strings(args: &[&str]) -> Vec<String> {
    args.iter().map(|a| a.to_string()).collect()
}

fn ok_in(cwd: &Path, args: &[&str]) {
    let (ok, _, stderr) = run_in(cwd, &strings(args));
    assert!(ok, "{args:?}: {stderr}");
}

/// Every regular file under `dir` (links not followed) with its bytes.
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let e = e.unwrap();
            let t = e.file_type().unwrap();
            if t.is_dir() {
                stack.push(e.path());
            } else if t.is_file() {
                out.insert(
                    e.path().strip_prefix(dir).unwrap().to_path_buf(),
                    std::fs::read(e.path()).unwrap(),
                );
            }
        }
    }
    out
}

/// The session's files, made with the binary in `dir`: a plan, measurements of its lists on
/// the simulated paper machine, a fitted model, a grid image, a commanded list and a tracker
/// export of the identification session, and the machine file.
fn fixture(dir: &Path) {
    let machine = Path::new(env!("CARGO_MANIFEST_DIR")).join("machines/paper.toml");
    std::fs::copy(machine, dir.join("machine.toml")).unwrap();
    let m = ["--plant", "paper", "--noise-um", "1"];
    let measure = |list: &str, seed: &str, out: &str, extra: &[&str]| {
        let mut a = vec!["measure"];
        a.extend(m);
        a.extend(["--targets", list, "--seed", seed, "--out", out]);
        a.extend(extra);
        ok_in(dir, &a);
    };
    ok_in(dir, &["plan", "--seed", "1", "--out", "pl"]);
    measure("pl/identify.csv", "11", "id.csv", &[]);
    ok_in(
        dir,
        &[
            "fit", "--data", "id.csv", "--method", "full", "--no-loo", "--out", "m.json",
        ],
    );
    measure("pl/grid.csv", "15", "nodes.csv", &["--model", "m.json"]);
    ok_in(
        dir,
        &[
            "grid",
            "--model",
            "m.json",
            "--data",
            "nodes.csv",
            "--out",
            "g.bin",
        ],
    );
    measure("pl/verify.csv", "12", "ver.csv", &[]);
    measure("pl/repeat.csv", "21", "rep.csv", &[]);
    measure("pl/verify.csv", "18", "verb.csv", &["--grid", "g.bin"]);
    measure("pl/repeat.csv", "22", "repb.csv", &["--grid", "g.bin"]);
    ok_in(
        dir,
        &[
            "command",
            "--targets",
            "pl/identify.csv",
            "--out",
            "ang.csv",
        ],
    );
    // The identification session as a tracker exports it.
    let rows = host_sim::io::measurement_csv::read_measurements(&dir.join("id.csv")).unwrap();
    let mut export = String::from("Point;X [mm];Y [mm]\n");
    for (k, r) in rows.iter().enumerate() {
        export.push_str(&format!(
            "P{:03};{:.6};{:.6}\n",
            k + 1,
            r.measured_mm[0],
            r.measured_mm[1]
        ));
    }
    std::fs::write(dir.join("exp.csv"), export).unwrap();
}

/// A path flag of a command: an input (a fixture file), an output (its file name), or an
/// output directory (its name and a file the command always writes there).
#[derive(Clone, Copy, Debug)]
enum Slot {
    In(&'static str, &'static str),
    Out(&'static str, &'static str),
    Dir(&'static str, &'static str, &'static str),
}

impl Slot {
    fn flag(&self) -> &'static str {
        match self {
            Slot::In(f, _) | Slot::Out(f, _) | Slot::Dir(f, _, _) => f,
        }
    }
}

/// Every subcommand that reads or writes files, with valid files for each path flag (so that
/// without the policy it would run and write).
fn commands() -> Vec<(&'static str, Vec<&'static str>, Vec<Slot>)> {
    use Slot::*;
    let machine = In("--machine", "machine.toml");
    vec![
        (
            "plan",
            vec!["--seed", "1"],
            vec![machine, Dir("--out", "pl2", "identify.csv")],
        ),
        (
            "measure",
            vec!["--plant", "paper", "--seed", "3"],
            vec![
                machine,
                In("--targets", "pl/verify.csv"),
                In("--model", "m.json"),
                In("--grid", "g.bin"),
                Out("--out", "out.csv"),
            ],
        ),
        (
            "fit",
            vec!["--method", "full", "--no-loo"],
            vec![
                machine,
                In("--data", "id.csv"),
                Out("--out", "fm.json"),
                Out("--plot", "fm.png"),
            ],
        ),
        (
            "grid",
            vec![],
            vec![
                machine,
                In("--model", "m.json"),
                In("--data", "nodes.csv"),
                Out("--out", "g1.bin"),
                Out("--csv", "g1.csv"),
                Out("--plot", "g1.png"),
            ],
        ),
        (
            "command",
            vec![],
            vec![
                machine,
                In("--model", "m.json"),
                In("--grid", "g.bin"),
                In("--targets", "pl/verify.csv"),
                Out("--out", "angles.csv"),
            ],
        ),
        (
            "accuracy",
            vec![],
            vec![machine, In("--data", "rep.csv"), Out("--plot", "acc.png")],
        ),
        (
            "verify",
            vec![],
            vec![
                machine,
                In("--after-verify", "ver.csv"),
                In("--after-repeat", "rep.csv"),
                In("--before-verify", "verb.csv"),
                In("--before-repeat", "repb.csv"),
                Out("--out", "r.html"),
                Out("--json", "r.json"),
            ],
        ),
        (
            "diagnose",
            vec![],
            vec![
                machine,
                In("--data", "id.csv"),
                In("--model", "m.json"),
                Out("--out", "d1.json"),
                Out("--out-model", "d1m.json"),
                Dir("--plots", "plots", "residual_start.png"),
            ],
        ),
        (
            "import",
            vec!["--map", "id=Point,x=X [mm],y=Y [mm]"],
            vec![
                In("--export", "exp.csv"),
                In("--commanded", "ang.csv"),
                In("--plan", "pl/identify.csv"),
                Out("--out", "r1.csv"),
                Out("--report", "r1.json"),
            ],
        ),
        (
            "simulate",
            vec!["--seconds", "0.05"],
            vec![
                machine,
                In("--model", "m.json"),
                In("--grid", "g.bin"),
                Out("--log", "log.csv"),
                Out("--plot", "sim.png"),
            ],
        ),
        (
            "demo",
            vec![],
            vec![machine, Dir("--out", "demo", "model.json")],
        ),
    ]
}

/// Ways of spelling the path `name` (relative to the working directory) differently. `exists`:
/// the file exists (a hard link to it can be made). Returns the spelling and what to create
/// first.
fn spellings(cwd: &Path, name: &str, exists: bool) -> Vec<String> {
    let mut v = vec![
        format!("./{name}"),
        cwd.join(name).to_str().unwrap().to_string(),
        format!("sub/../{name}"),
        format!("missing/../{name}"),
        format!("up/{name}"),
    ];
    if exists && !name.contains('/') {
        let link = format!("hard-{name}");
        if !cwd.join(&link).exists() {
            std::fs::hard_link(cwd.join(name), cwd.join(&link)).unwrap();
        }
        v.push(link);
    }
    v
}

/// The arguments of `cmd` with `slots`, `replace` giving some slots another path.
fn arguments(
    cmd: &str,
    extra: &[&str],
    slots: &[Slot],
    replace: &BTreeMap<usize, String>,
) -> Vec<String> {
    let mut a = vec![cmd.to_string()];
    a.extend(extra.iter().map(|s| s.to_string()));
    for (k, slot) in slots.iter().enumerate() {
        let path = match slot {
            Slot::In(_, p) | Slot::Out(_, p) | Slot::Dir(_, p, _) => p.to_string(),
        };
        a.push(slot.flag().to_string());
        a.push(replace.get(&k).cloned().unwrap_or(path));
    }
    a
}

/// One aliasing: runs it and checks the policy held.
fn expect_refused(cwd: &Path, args: &[String], flags: [&str; 2]) {
    let before = snapshot(cwd);
    let (ok, _, stderr) = run_in(cwd, args);
    assert!(!ok, "{args:?} succeeded");
    assert!(!stderr.contains("panicked"), "{args:?} panicked: {stderr}");
    for f in flags {
        assert!(
            stderr.contains(f),
            "{args:?}: the refusal does not name {f}: {stderr}"
        );
    }
    let after = snapshot(cwd);
    assert_eq!(
        before.keys().collect::<Vec<_>>(),
        after.keys().collect::<Vec<_>>(),
        "{args:?} wrote or removed files"
    );
    for (p, bytes) in &before {
        assert!(after[p] == *bytes, "{args:?} changed {}", p.display());
    }
}

/// A working directory with the fixture, a subdirectory and a link to itself.
fn workdir(fixture: &Path) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    for (p, bytes) in snapshot(fixture) {
        let to = dir.path().join(&p);
        std::fs::create_dir_all(to.parent().unwrap()).unwrap();
        std::fs::write(to, bytes).unwrap();
    }
    std::fs::create_dir(dir.path().join("sub")).unwrap();
    #[cfg(unix)]
    std::os::unix::fs::symlink(dir.path(), dir.path().join("up")).unwrap();
    dir
}

/// Every aliasing of `cmd`'s paths: each output (or a file in an output directory) spelt as
/// each input and as each other output.
fn aliasings_of(cmd: &str, fixture: &Path) -> usize {
    let (name, extra, slots) = commands().into_iter().find(|c| c.0 == cmd).unwrap();
    let mut runs = 0;
    for (o, out) in slots.iter().enumerate() {
        for (t, target) in slots.iter().enumerate() {
            if o == t {
                continue;
            }
            let target_file = match target {
                Slot::In(_, p) | Slot::Out(_, p) => *p,
                Slot::Dir(..) => continue,
            };
            let is_input = matches!(target, Slot::In(..));
            let dir = workdir(fixture);
            let cwd = dir.path();
            match out {
                Slot::In(..) => continue,
                Slot::Out(..) => {
                    for spelt in spellings(cwd, target_file, is_input) {
                        let replace = BTreeMap::from([(o, spelt)]);
                        let args = arguments(name, &extra, &slots, &replace);
                        expect_refused(cwd, &args, [out.flag(), target.flag()]);
                        runs += 1;
                    }
                }
                Slot::Dir(_, _, inside) => {
                    if !is_input {
                        continue;
                    }
                    // The input put where the command writes a file of the directory.
                    std::fs::create_dir_all(cwd.join("alias")).unwrap();
                    let moved = format!("alias/{inside}");
                    std::fs::copy(cwd.join(target_file), cwd.join(&moved)).unwrap();
                    for spelt in ["./alias", "sub/../alias", "up/alias"] {
                        let replace = BTreeMap::from([(o, spelt.to_string()), (t, moved.clone())]);
                        let args = arguments(name, &extra, &slots, &replace);
                        expect_refused(cwd, &args, [out.flag(), target.flag()]);
                        runs += 1;
                    }
                }
            }
        }
    }
    runs
}

fn fixture_dir() -> &'static Path {
    static FIXTURE: std::sync::OnceLock<tempfile::TempDir> = std::sync::OnceLock::new();
    FIXTURE
        .get_or_init(|| {
            let dir = tempfile::tempdir().unwrap();
            fixture(dir.path());
            dir
        })
        .path()
}

#[test]
fn no_aliasing_of_any_commands_paths_changes_an_input() {
    let fx = fixture_dir();
    let mut total = 0;
    for (cmd, _, _) in commands() {
        let n = aliasings_of(cmd, fx);
        assert!(n > 0, "{cmd}: no aliasing tried");
        total += n;
    }
    eprintln!("output policy: {total} aliasings refused, no input changed");
}

/// The reported reproductions one by one, as a user types them.
#[test]
fn outputs_onto_inputs_or_each_other_are_refused_naming_both_flags() {
    let dir = workdir(fixture_dir());
    let cwd = dir.path();
    std::fs::copy(cwd.join("ver.csv"), cwd.join("v.csv")).unwrap();
    std::fs::copy(cwd.join("id.csv"), cwd.join("fm.csv")).unwrap();
    std::fs::copy(cwd.join("pl/verify.csv"), cwd.join("t.csv")).unwrap();
    std::fs::copy(cwd.join("nodes.csv"), cwd.join("a.csv")).unwrap();
    let cases: Vec<(Vec<&str>, [&str; 2])> = vec![
        (
            vec![
                "verify",
                "--after-verify",
                "v.csv",
                "--after-repeat",
                "rep.csv",
                "--out",
                "./v.csv",
            ],
            ["--out", "--after-verify"],
        ),
        (
            vec![
                "verify",
                "--after-verify",
                "ver.csv",
                "--after-repeat",
                "rep.csv",
                "--json",
                "./r.html",
                "--out",
                "r.html",
            ],
            ["--out", "--json"],
        ),
        (
            vec![
                "fit", "--data", "fm.csv", "--method", "full", "--out", "fm.csv",
            ],
            ["--out", "--data"],
        ),
        (
            vec![
                "fit", "--data", "fm.csv", "--method", "full", "--out", "x.json", "--plot",
                "fm.csv",
            ],
            ["--plot", "--data"],
        ),
        (
            vec![
                "command",
                "--model",
                "m.json",
                "--targets",
                "t.csv",
                "--out",
                "m.json",
            ],
            ["--out", "--model"],
        ),
        (
            vec!["command", "--targets", "t.csv", "--out", "t.csv"],
            ["--out", "--targets"],
        ),
        (
            vec![
                "measure",
                "--plant",
                "paper",
                "--targets",
                "t.csv",
                "--grid",
                "g.bin",
                "--out",
                "g.bin",
            ],
            ["--out", "--grid"],
        ),
        (
            vec![
                "grid",
                "--model",
                "m.json",
                "--data",
                "nodes.csv",
                "--out",
                "g1.bin",
                "--csv",
                "./g1.bin",
            ],
            ["--out", "--csv"],
        ),
        (
            vec![
                "import",
                "--export",
                "exp.csv",
                "--map",
                "id=Point,x=X [mm],y=Y [mm]",
                "--commanded",
                "ang.csv",
                "--out",
                "r1.csv",
                "--report",
                "./r1.csv",
            ],
            ["--out", "--report"],
        ),
        (
            vec![
                "diagnose",
                "--data",
                "id.csv",
                "--out",
                "d1.json",
                "--out-model",
                "./d1.json",
            ],
            ["--out", "--out-model"],
        ),
        (
            vec![
                "grid", "--model", "m.json", "--data", "a.csv", "./a.csv", "--out", "g2.bin",
            ],
            ["--data", "count as repeats"],
        ),
    ];
    for (args, flags) in cases {
        expect_refused(cwd, &strings(&args), flags);
    }
}

/// A command that fails leaves no output at all, whichever output fails.
#[test]
fn a_failing_output_leaves_no_other_output() {
    let dir = workdir(fixture_dir());
    let cwd = dir.path();
    // verify --json DIR: the page is not written either.
    std::fs::create_dir(cwd.join("jdir")).unwrap();
    let before = snapshot(cwd);
    let (ok, _, stderr) = run_in(
        cwd,
        &strings(&[
            "verify",
            "--after-verify",
            "ver.csv",
            "--after-repeat",
            "rep.csv",
            "--json",
            "jdir",
            "--out",
            "page.html",
        ]),
    );
    assert!(!ok && stderr.contains("directory"), "{stderr}");
    assert_eq!(snapshot(cwd), before, "verify left a file");
    assert!(!cwd.join("page.html").exists());
    // plan --out pl3 with pl3/verify.csv a directory: no list is written.
    std::fs::create_dir_all(cwd.join("pl3/verify.csv")).unwrap();
    let (ok, _, stderr) = run_in(cwd, &strings(&["plan", "--out", "pl3"]));
    assert!(!ok && stderr.contains("verify.csv"), "{stderr}");
    let left: Vec<_> = std::fs::read_dir(cwd.join("pl3"))
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(left, vec![std::ffi::OsString::from("verify.csv")]);
    // diagnose --plots FILE: neither the report nor the model is left.
    std::fs::write(cwd.join("plotfile"), b"keep").unwrap();
    let (ok, _, stderr) = run_in(
        cwd,
        &strings(&[
            "diagnose",
            "--data",
            "id.csv",
            "--out",
            "d.json",
            "--out-model",
            "dm.json",
            "--plots",
            "plotfile",
        ]),
    );
    assert!(!ok, "{stderr}");
    assert!(!cwd.join("d.json").exists() && !cwd.join("dm.json").exists());
    assert_eq!(std::fs::read(cwd.join("plotfile")).unwrap(), b"keep");
}

/// Every subcommand's source declares its files to the policy and writes through it (a new
/// command that writes directly would not be checked).
#[test]
fn every_subcommand_writes_through_the_policy() {
    let cli = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/cli");
    for e in std::fs::read_dir(&cli).unwrap() {
        let path = e.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        if name == "mod.rs" {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        // The link flags' only path is a serial device (opened, never read as a file nor
        // written); the commands that flatten them declare their own files.
        let device_only = name == "link_args.rs";
        for direct in [
            "write_atomic",
            "Outputs::new",
            "std::fs::write",
            "File::create",
            "write_measurements(",
            "write_model_file(",
            "vector_plot(",
            "xy_plot(",
        ] {
            assert!(
                !text.contains(direct),
                "src/cli/{name} writes with {direct}, not through io::policy"
            );
        }
        let writes = text.contains("outputs.bytes")
            || text.contains("out.bytes")
            || (text.contains("PathBuf") && !device_only);
        if writes {
            assert!(
                text.contains("CommandFiles::new()"),
                "src/cli/{name} takes paths but does not declare them to io::policy::CommandFiles"
            );
        }
    }
}
