//! host-sim's integration tests: one binary, each file of this directory one module, so that
//! the harness spreads every test over the cores (the long co-simulated journeys beside the
//! short ones) and the crate links once. `link_qemu.rs` and `moving_machine.rs` are binaries of
//! their own (host-sim/Cargo.toml says why). Run one file's tests by its module's name,
//! `cargo test -p host-sim --test integration commission::`: a filter is a part of
//! `module::test`, so `diagnose::` runs diagnose.rs and `diagnose` also diagnose_plant.rs and
//! diagnose_shape.rs.
//!
//! Every module's doc says what it checks. By the machine builder's journey:
//! * calibration: [`table1`], [`full_fit`], [`lm`], [`pipeline`], [`grid_command`],
//!   [`grid_noise`], [`workflow`], [`verify`], [`demo`], [`import`];
//! * the diagnosis: [`diagnose`], [`diagnose_plant`], [`diagnose_shape`];
//! * the controller in the loop: [`link_serial`], [`link_flags`], [`cosim`], [`session`],
//!   [`commission`], [`backlash_servo`], [`cut`] (and the binaries `link_qemu`,
//!   `moving_machine`);
//! * every command's inputs and outputs: [`cli`], [`cli_plant`], [`input_checks`],
//!   [`refusals`], [`image_judgement`], [`output_policy`].
//!
//! Tests here share one process: one that needs an environment variable sets it on the child
//! process it starts, never with `std::env::set_var` (the tests beside it would see it).

mod backlash_servo;
mod cli;
mod cli_plant;
mod commission;
mod cosim;
mod cut;
mod demo;
mod diagnose;
mod diagnose_plant;
mod diagnose_shape;
mod full_fit;
mod grid_command;
mod grid_noise;
mod image_judgement;
mod import;
mod input_checks;
mod link_flags;
mod link_serial;
mod lm;
mod output_policy;
mod pipeline;
mod refusals;
mod session;
mod table1;
mod verify;
mod workflow;

/// With `autotests = false` a file added to tests/ runs only once it is declared: every `.rs`
/// file of the directory is a module of this binary or a `[[test]]` of its own in Cargo.toml.
#[test]
fn every_test_file_is_a_module_of_this_binary_or_a_binary() {
    let crate_dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = crate_dir.join("tests");
    let root = std::fs::read_to_string(dir.join("integration.rs")).unwrap();
    let manifest = std::fs::read_to_string(crate_dir.join("Cargo.toml")).unwrap();
    let mut missing = Vec::new();
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        let Some(name) = path.file_stem().and_then(|s| s.to_str()) else {
            continue;
        };
        let is_rs = path.extension().is_some_and(|e| e == "rs");
        let declared = root.contains(&format!("\nmod {name};\n"))
            || manifest.contains(&format!("path = \"tests/{name}.rs\""));
        if is_rs && !declared {
            missing.push(name.to_owned());
        }
    }
    assert!(
        missing.is_empty(),
        "tests/{{{}}}.rs: declare each with `mod NAME;` in tests/integration.rs (or as a \
         `[[test]]` of its own in Cargo.toml)",
        missing.join(",")
    );
}
