//! Writing output files so that a failed run never leaves a half-written, clobbered or partial
//! set of files behind.
//!
//! Every file the tools produce goes through here:
//! * **Only onto regular files or new paths.** A destination that exists and is anything else
//!   (a symbolic link, a FIFO, a device such as `/dev/full`, a directory) is refused before
//!   anything is written: a rename would replace it with a regular file (as root, a device
//!   node), and a symbolic link would be replaced rather than followed.
//! * **Each file atomically:** the bytes go to a temporary file in the destination's
//!   directory, which is renamed over the destination only once complete.
//! * **Never onto an input, never two outputs in one file:** the set made by
//!   [`CommandFiles::check`](super::policy::CommandFiles::check) knows the command's inputs
//!   and checks every staged file against them and the files staged before, by identity
//!   (`super::policy`).
//! * **A command's files together:** [`Outputs`] stages every file of a command (each
//!   destination checked, each temporary written and synced) and renames them only in
//!   [`Outputs::commit`], once all are ready; dropping an uncommitted set removes its
//!   temporaries. So `grid --out BAD --csv x.csv` fails without writing `x.csv`.
//!
//! What remains: a rename that fails after the destinations were checked (a disk removed
//! between two renames) leaves the earlier files renamed; the error says which.

use super::declared::{identify, input_clash, output_clash, Declared, DeclaredDir, FileId};
use super::IoError;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

/// Distinguishes the temporaries of one process.
static COUNTER: AtomicUsize = AtomicUsize::new(0);

/// Refuses a destination that exists and is not a regular file (see the module doc).
pub fn check_destination(path: &Path) -> Result<(), IoError> {
    let refuse = |what: &str| IoError::Write {
        path: path.to_path_buf(),
        message: format!("it is {what}; outputs are written only onto regular files or new paths"),
    };
    match std::fs::symlink_metadata(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(IoError::Write {
            path: path.to_path_buf(),
            message: e.to_string(),
        }),
        Ok(m) => {
            let t = m.file_type();
            if t.is_file() {
                Ok(())
            } else if t.is_symlink() {
                Err(refuse("a symbolic link"))
            } else if t.is_dir() {
                Err(refuse("a directory"))
            } else {
                Err(refuse(&describe_special(&t)))
            }
        }
    }
}

#[cfg(unix)]
fn describe_special(t: &std::fs::FileType) -> String {
    use std::os::unix::fs::FileTypeExt;
    if t.is_fifo() {
        "a FIFO".into()
    } else if t.is_char_device() || t.is_block_device() {
        "a device".into()
    } else if t.is_socket() {
        "a socket".into()
    } else {
        "not a regular file".into()
    }
}

#[cfg(not(unix))]
fn describe_special(_: &std::fs::FileType) -> String {
    "not a regular file".into()
}

/// The directory of `path` (created) and its file name, the destination checked.
fn prepare(path: &Path) -> Result<(&Path, String), IoError> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let file_name = path.file_name().ok_or_else(|| IoError::NoFileName {
        path: path.to_path_buf(),
    })?;
    check_destination(path)?;
    std::fs::create_dir_all(dir).map_err(|e| IoError::CreateDir {
        dir: dir.to_path_buf(),
        message: e.to_string(),
    })?;
    Ok((dir, file_name.to_string_lossy().into_owned()))
}

/// A staged file: its destination (as declared) and its complete temporary.
#[derive(Debug)]
struct Staged {
    declared: Declared,
    tmp: PathBuf,
}

/// The files of one command, renamed into place together (see the module doc). Made by
/// [`CommandFiles::check`](super::policy::CommandFiles::check), which knows the command's
/// inputs and outputs by flag; [`Outputs::new`] is a set with no inputs (a library writing
/// its own files).
#[derive(Debug, Default)]
pub struct Outputs {
    staged: Vec<Staged>,
    /// The command's input files: never an output.
    inputs: Vec<Declared>,
    /// The outputs the command declared (their flags name a staged file in messages).
    declared: Vec<Declared>,
    /// The directories the command declared.
    dirs: Vec<DeclaredDir>,
}

impl Outputs {
    /// An empty set that knows no inputs.
    pub fn new() -> Self {
        Outputs::default()
    }

    /// A set for a command whose files `super::policy` checked.
    pub(crate) fn checked(
        inputs: Vec<Declared>,
        declared: Vec<Declared>,
        dirs: Vec<DeclaredDir>,
    ) -> Self {
        Outputs {
            staged: Vec::new(),
            inputs,
            declared,
            dirs,
        }
    }

    /// The destinations staged so far.
    pub fn paths(&self) -> Vec<PathBuf> {
        self.staged
            .iter()
            .map(|s| s.declared.path.clone())
            .collect()
    }

    /// `path` as the flag that declared it (or the directory it is in) names it.
    fn describe(&self, path: &Path, id: &FileId) -> Declared {
        let flag = match self.declared.iter().find(|d| d.id == *id) {
            Some(d) => d.flag.clone(),
            None => match self.dirs.iter().find(|d| d.holds(path)) {
                Some(d) => format!(
                    "{} (its {})",
                    d.flag,
                    path.file_name().unwrap_or_default().to_string_lossy()
                ),
                None => "the output".into(),
            },
        };
        Declared {
            flag,
            path: path.to_path_buf(),
            id: id.clone(),
        }
    }

    /// Stages `bytes` for `path`.
    pub fn bytes(&mut self, path: &Path, bytes: &[u8]) -> Result<(), IoError> {
        self.with(path, |tmp| {
            let mut f = std::fs::File::create(tmp).map_err(|e| IoError::Write {
                path: tmp.to_path_buf(),
                message: e.to_string(),
            })?;
            f.write_all(bytes)
                .and_then(|()| f.sync_all())
                .map_err(|e| IoError::Write {
                    path: tmp.to_path_buf(),
                    message: e.to_string(),
                })
        })
    }

    /// Stages a file that `write` produces at a temporary path (for writers that insist on a
    /// path); the temporary keeps the destination's extension last.
    pub fn with(
        &mut self,
        path: &Path,
        write: impl FnOnce(&Path) -> Result<(), IoError>,
    ) -> Result<(), IoError> {
        let id = identify(path);
        let me = self.describe(path, &id);
        if let Some(i) = self.inputs.iter().find(|i| i.id == id) {
            return Err(IoError::Clash(input_clash(&me, i)));
        }
        if let Some(s) = self.staged.iter().find(|s| s.declared.id == id) {
            return Err(IoError::Clash(output_clash(&me, &s.declared)));
        }
        let (dir, file_name) = prepare(path)?;
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let tmp = dir.join(format!(".tmp{}-{n}-{file_name}", std::process::id()));
        if let Err(e) = write(&tmp) {
            let _ = std::fs::remove_file(&tmp);
            return Err(IoError::Write {
                path: path.to_path_buf(),
                message: e.to_string(),
            });
        }
        self.staged.push(Staged { declared: me, tmp });
        Ok(())
    }

    /// Renames every staged file into place (destinations checked again first); returns the
    /// destinations in staging order.
    pub fn commit(mut self) -> Result<Vec<PathBuf>, IoError> {
        for s in &self.staged {
            check_destination(&s.declared.path)?;
        }
        let staged = std::mem::take(&mut self.staged);
        let mut done = Vec::with_capacity(staged.len());
        for (k, s) in staged.iter().enumerate() {
            if let Err(e) = std::fs::rename(&s.tmp, &s.declared.path) {
                for rest in &staged[k..] {
                    let _ = std::fs::remove_file(&rest.tmp);
                }
                let written = if done.is_empty() {
                    String::new()
                } else {
                    format!(
                        " (already written: {})",
                        done.iter()
                            .map(|p: &PathBuf| p.display().to_string())
                            .collect::<Vec<_>>()
                            .join(", ")
                    )
                };
                return Err(IoError::Write {
                    path: s.declared.path.clone(),
                    message: format!("{e}{written}"),
                });
            }
            done.push(s.declared.path.clone());
        }
        Ok(done)
    }
}

impl Drop for Outputs {
    fn drop(&mut self) {
        for s in &self.staged {
            let _ = std::fs::remove_file(&s.tmp);
        }
    }
}

/// Writes `bytes` to `path` atomically (temporary file + rename), creating parent directories.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    let mut o = Outputs::new();
    o.bytes(path, bytes)?;
    o.commit().map(|_| ())
}

/// Lets `write` produce a file at a temporary path, then renames it over `path`; on error the
/// temporary is removed. For writers that insist on a path.
pub fn write_atomic_with(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), IoError>,
) -> Result<(), IoError> {
    let mut o = Outputs::new();
    o.with(path, write)?;
    o.commit().map(|_| ())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn writes_whole_file_and_leaves_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("sub/out.txt");
        write_atomic(&p, b"hello").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"hello");
        let names: Vec<_> = std::fs::read_dir(p.parent().unwrap())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names.len(), 1, "{names:?}");
    }

    #[test]
    fn failure_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        // A directory where the file should go: rename fails.
        let p = dir.path().join("taken");
        std::fs::create_dir(&p).unwrap();
        std::fs::write(p.join("x"), b"x").unwrap();
        assert!(write_atomic(&p, b"data").is_err());
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("taken")]);
    }

    #[test]
    fn an_input_is_never_an_output() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("grid1.csv");
        std::fs::write(&input, b"measurements").unwrap();
        let mut out = crate::io::policy::CommandFiles::new()
            .input("--data", &input)
            .check()
            .unwrap();
        out.bytes(&dir.path().join("grid1.bin"), b"image").unwrap();
        // The same file by another spelling.
        let e = out
            .bytes(&dir.path().join("./grid1.csv"), b"table")
            .unwrap_err()
            .to_string();
        assert!(e.contains("the input --data"), "{e}");
        drop(out);
        assert_eq!(std::fs::read(&input).unwrap(), b"measurements");
        assert_eq!(names(dir.path()), vec!["grid1.csv".to_string()]);
    }

    #[cfg(unix)]
    #[test]
    fn refuses_symlinks_fifos_and_devices() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("target.txt");
        std::fs::write(&target, b"keep").unwrap();
        let link = dir.path().join("link.txt");
        std::os::unix::fs::symlink(&target, &link).unwrap();
        let e = write_atomic(&link, b"new").unwrap_err().to_string();
        assert!(e.contains("symbolic link"), "{e}");
        assert!(std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink());
        assert_eq!(std::fs::read(&target).unwrap(), b"keep");
        let fifo = dir.path().join("fifo");
        assert!(std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success());
        let e = write_atomic(&fifo, b"x").unwrap_err().to_string();
        assert!(e.contains("a FIFO"), "{e}");
        use std::os::unix::fs::FileTypeExt;
        assert!(std::fs::symlink_metadata(&fifo)
            .unwrap()
            .file_type()
            .is_fifo());
        // A device is refused before anything is written (checked, never written to).
        let e = check_destination(Path::new("/dev/null"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("a device"), "{e}");
        assert_eq!(names(dir.path()), vec!["fifo", "link.txt", "target.txt"]);
    }

    #[test]
    fn a_set_is_written_only_when_every_file_is_ready() {
        let dir = tempfile::tempdir().unwrap();
        let good = dir.path().join("good.csv");
        let bad = dir.path().join("taken");
        std::fs::create_dir(&bad).unwrap();
        let mut o = Outputs::new();
        o.bytes(&good, b"table").unwrap();
        assert!(o.bytes(&bad, b"image").is_err());
        drop(o);
        assert_eq!(
            names(dir.path()),
            vec!["taken"],
            "nothing written, no temporary left"
        );
        let mut o = Outputs::new();
        o.bytes(&good, b"a").unwrap();
        assert!(o
            .bytes(&good, b"b")
            .unwrap_err()
            .to_string()
            .contains("same file"));
        assert_eq!(o.commit().unwrap(), vec![good.clone()]);
        assert_eq!(std::fs::read(&good).unwrap(), b"a");
    }
}
