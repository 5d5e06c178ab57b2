//! The output policy: what a command may write, decided before it reads heavily or writes
//! anything. Every subcommand declares its files here, by flag:
//!
//! ```no_run
//! # use host_sim::io::policy::CommandFiles;
//! # use std::path::PathBuf;
//! # fn f(model: PathBuf, data: Vec<PathBuf>, out: PathBuf, csv: Option<PathBuf>) -> Result<(), host_sim::io::IoError> {
//! let mut outputs = CommandFiles::new()
//!     .input("--model", &model)
//!     .repeats("--data", &data) // pooled readings: one file twice would count as repeats
//!     .output("--out", &out)
//!     .output("--csv", &csv) // an Option: nothing when absent
//!     .check()?; // every clash refused here, naming both flags
//! // ... the work ...
//! outputs.bytes(&out, b"image")?; // staged: a temporary beside the destination
//! outputs.commit()?; // every output renamed into place together, or none
//! # Ok(()) }
//! ```
//!
//! What [`CommandFiles::check`] refuses, each message naming both flags and both spellings:
//! * an output that is an input (`fit --data fm.csv --out ./fm.csv`);
//! * two outputs that are one file (`grid --out g1.bin --csv ./g1.bin`);
//! * one file given twice to a flag whose files pool as repeats (`grid --data a.csv ./a.csv`).
//!
//! "The same file" is decided by [`FileId`] (`super::declared`): device and inode after following links for a path
//! that exists (so `./x`, `d/../x`, an absolute path, a hard link and a path through a linked
//! directory are all `x`), else the nearest existing ancestor resolved and the rest of the path
//! normalised (two outputs not written yet, spelt differently). The returned
//! [`Outputs`](super::atomic::Outputs) keeps the inputs: a file staged later (a default name
//! derived from another, a plot in a directory) is checked again, and every file is written
//! only when all are ready (`super::atomic`).
//!
//! Why here and not in each command: the literal comparisons each command had did not see
//! `./x`, and a command that forgot one lost the user's measurements. A new command gets the
//! whole policy by declaring its flags; `tests/output_policy.rs` checks every subcommand's
//! source does.

use super::atomic::Outputs;
pub use super::declared::{identify, Declared, DeclaredDir, FileId};
use super::declared::{input_clash, output_clash};
use super::IoError;
use std::path::{Path, PathBuf};

/// Paths as a flag holds them: one, an optional one, or several (`--data a.csv b.csv`).
pub trait FlagPaths {
    /// The paths, in the order given.
    fn paths(&self) -> Vec<PathBuf>;
}

impl FlagPaths for Path {
    fn paths(&self) -> Vec<PathBuf> {
        vec![self.to_path_buf()]
    }
}

impl FlagPaths for PathBuf {
    fn paths(&self) -> Vec<PathBuf> {
        vec![self.clone()]
    }
}

impl<T: FlagPaths + ?Sized> FlagPaths for &T {
    fn paths(&self) -> Vec<PathBuf> {
        (**self).paths()
    }
}

impl<T: FlagPaths> FlagPaths for Option<T> {
    fn paths(&self) -> Vec<PathBuf> {
        self.as_ref().map(FlagPaths::paths).unwrap_or_default()
    }
}

impl<T: FlagPaths> FlagPaths for [T] {
    fn paths(&self) -> Vec<PathBuf> {
        self.iter().flat_map(FlagPaths::paths).collect()
    }
}

impl<T: FlagPaths> FlagPaths for Vec<T> {
    fn paths(&self) -> Vec<PathBuf> {
        self.as_slice().paths()
    }
}

/// The files of one command, by flag (module doc).
#[derive(Clone, Debug, Default)]
pub struct CommandFiles {
    inputs: Vec<Declared>,
    /// Inputs whose files pool as repeats: the same file twice in one flag is refused.
    repeats: Vec<String>,
    outputs: Vec<Declared>,
    dirs: Vec<DeclaredDir>,
}

impl CommandFiles {
    /// No files yet.
    pub fn new() -> Self {
        CommandFiles::default()
    }

    /// Files the command reads (never written; an absent `Option` declares nothing).
    pub fn input(mut self, flag: &str, paths: impl FlagPaths) -> Self {
        for p in paths.paths() {
            self.inputs.push(Declared::new(flag, p));
        }
        self
    }

    /// Files the command reads and pools (`grid --data round1.csv round2.csv`): the same file
    /// twice would count its readings as repeats, so it is refused.
    pub fn repeats(mut self, flag: &str, paths: impl FlagPaths) -> Self {
        self.repeats.push(flag.to_string());
        self.input(flag, paths)
    }

    /// A file the command writes.
    pub fn output(mut self, flag: &str, paths: impl FlagPaths) -> Self {
        for p in paths.paths() {
            self.outputs.push(Declared::new(flag, p));
        }
        self
    }

    /// Files the command writes into `dir` under the given names (more may be staged there
    /// later; each is checked when staged).
    pub fn output_dir<S: AsRef<str>>(
        mut self,
        flag: &str,
        dir: impl FlagPaths,
        names: &[S],
    ) -> Self {
        for d in dir.paths() {
            for n in names {
                self.outputs.push(Declared::new(
                    &format!("{flag} (its {})", n.as_ref()),
                    d.join(n.as_ref()),
                ));
            }
            self.dirs.push(DeclaredDir::new(flag, d));
        }
        self
    }

    /// Every clash refused (module doc); the staged set that writes the outputs.
    pub fn check(self) -> Result<Outputs, IoError> {
        let clash = |message: String| Err(IoError::Clash(message));
        for (k, a) in self.inputs.iter().enumerate() {
            if !self.repeats.contains(&a.flag) {
                continue;
            }
            if let Some(b) = self.inputs[..k]
                .iter()
                .find(|b| b.flag == a.flag && b.id == a.id)
            {
                return clash(format!(
                    "{} names one file twice ({} and {}): its readings would count as repeats; give each file once",
                    a.flag,
                    b.path.display(),
                    a.path.display()
                ));
            }
        }
        for (k, o) in self.outputs.iter().enumerate() {
            if let Some(i) = self.inputs.iter().find(|i| i.id == o.id) {
                return clash(input_clash(o, i));
            }
            if let Some(p) = self.outputs[..k].iter().find(|p| p.id == o.id) {
                return clash(output_clash(o, p));
            }
            if let Some(d) = self.dirs.iter().find(|d| d.id == o.id) {
                return clash(format!(
                    "{} is the directory of {} {}: give the file another path",
                    o.describe(),
                    d.flag,
                    d.dir.display()
                ));
            }
        }
        Ok(Outputs::checked(self.inputs, self.outputs, self.dirs))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spellings_of_one_file_are_one_identity() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::create_dir(d.join("sub")).unwrap();
        std::fs::write(d.join("a.csv"), b"x").unwrap();
        let a = identify(&d.join("a.csv"));
        assert_eq!(identify(&d.join("sub/../a.csv")), a);
        assert_eq!(identify(&d.join("./a.csv")), a);
        std::fs::hard_link(d.join("a.csv"), d.join("hard.csv")).unwrap();
        assert_eq!(identify(&d.join("hard.csv")), a);
        #[cfg(unix)]
        {
            std::os::unix::fs::symlink(d, d.join("sub/up")).unwrap();
            assert_eq!(identify(&d.join("sub/up/a.csv")), a);
            // Not yet existing: resolved through the link, normalised.
            assert_eq!(
                identify(&d.join("sub/up/new/../b.bin")),
                identify(&d.join("b.bin"))
            );
        }
        assert_ne!(identify(&d.join("b.bin")), identify(&d.join("c.bin")));
        assert_eq!(
            identify(&d.join("x/y/./z.csv")),
            identify(&d.join("x/w/../y/z.csv"))
        );
    }

    #[test]
    fn clashes_name_both_flags() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::write(d.join("v.csv"), b"m").unwrap();
        let e = CommandFiles::new()
            .input("--after-verify", d.join("v.csv"))
            .output("--out", d.join("sub/../v.csv"))
            .check()
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("--out") && e.contains("--after-verify") && e.contains("never replaces"),
            "{e}"
        );
        let e = CommandFiles::new()
            .output("--out", d.join("g1.bin"))
            .output("--csv", d.join("./g1.bin"))
            .check()
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("--out") && e.contains("--csv") && e.contains("same file"),
            "{e}"
        );
        let e = CommandFiles::new()
            .repeats("--data", vec![d.join("v.csv"), d.join("./v.csv")])
            .check()
            .unwrap_err()
            .to_string();
        assert!(e.contains("count as repeats"), "{e}");
        // Not a repeat flag: one file for two roles is fine.
        CommandFiles::new()
            .input("--before-verify", d.join("v.csv"))
            .input("--after-verify", d.join("v.csv"))
            .output("--out", d.join("r.html"))
            .check()
            .unwrap();
        let e = CommandFiles::new()
            .input("--machine", d.join("v.csv"))
            .output_dir("--out", d, &["v.csv", "plan.json"])
            .check()
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("--out (its v.csv)") && e.contains("--machine"),
            "{e}"
        );
        assert_eq!(std::fs::read(d.join("v.csv")).unwrap(), b"m");
    }
}
