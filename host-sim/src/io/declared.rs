//! A file named on the command line: its identity ([`FileId`], what makes two spellings one
//! file), the flag that named it ([`Declared`], [`DeclaredDir`]) and the messages of a clash
//! between two of them. [`super::policy`] declares a command's files with these and
//! [`super::atomic`] checks what it stages later against them.
use std::path::{Component, Path, PathBuf};

/// What makes two paths the same file (module doc).
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub enum FileId {
    /// An existing file: its device and inode (links followed).
    Inode { dev: u64, ino: u64 },
    /// A path that does not exist yet: absolute, its existing part resolved, the rest
    /// normalised.
    New(PathBuf),
}

/// The identity of `path` (module doc). A path that cannot be examined (no permission) is
/// identified by its normalised spelling.
pub fn identify(path: &Path) -> FileId {
    if let Ok(m) = std::fs::metadata(path) {
        if let Some(id) = inode(&m) {
            return id;
        }
        if let Ok(c) = std::fs::canonicalize(path) {
            return FileId::New(c);
        }
    }
    // `d/new/../x` is `d/x` once `new` is made (outputs' directories are created): the
    // normalised path may be an existing file.
    let resolved = resolve_new(path);
    match std::fs::metadata(&resolved).ok().and_then(|m| inode(&m)) {
        Some(id) => id,
        None => FileId::New(resolved),
    }
}

#[cfg(unix)]
fn inode(m: &std::fs::Metadata) -> Option<FileId> {
    use std::os::unix::fs::MetadataExt;
    Some(FileId::Inode {
        dev: m.dev(),
        ino: m.ino(),
    })
}

#[cfg(not(unix))]
fn inode(_: &std::fs::Metadata) -> Option<FileId> {
    None
}

/// An absolute path for `path` whose existing ancestors are resolved (links, `..`) and whose
/// remaining components are normalised lexically (`.` dropped, `..` removing the previous).
fn resolve_new(path: &Path) -> PathBuf {
    let absolute = if path.is_absolute() {
        path.to_path_buf()
    } else {
        std::env::current_dir()
            .unwrap_or_else(|_| PathBuf::from("/"))
            .join(path)
    };
    // Walk up to the nearest ancestor that exists, remembering the rest.
    let mut rest: Vec<std::ffi::OsString> = Vec::new();
    let mut base = absolute.as_path();
    let resolved = loop {
        if let Ok(c) = std::fs::canonicalize(base) {
            break c;
        }
        match (base.parent(), base.file_name()) {
            (Some(parent), Some(name)) => {
                rest.push(name.to_os_string());
                base = parent;
            }
            // `..` or `.` at the end of a missing path, or the root: normalise what is left.
            (Some(parent), None) => {
                rest.push(
                    base.components()
                        .next_back()
                        .map(|c| c.as_os_str().to_os_string())
                        .unwrap_or_default(),
                );
                base = parent;
            }
            (None, _) => break base.to_path_buf(),
        }
    };
    let mut out = resolved;
    for part in rest.iter().rev() {
        match Path::new(part).components().next() {
            Some(Component::ParentDir) => {
                out.pop();
            }
            Some(Component::CurDir) | None => {}
            _ => out.push(part),
        }
    }
    out
}

/// A declared path: the flag that named it and the path as given.
#[derive(Clone, Debug)]
pub struct Declared {
    pub flag: String,
    pub path: PathBuf,
    pub id: FileId,
}

impl Declared {
    pub(crate) fn new(flag: &str, path: PathBuf) -> Self {
        Declared {
            id: identify(&path),
            flag: flag.to_string(),
            path,
        }
    }

    /// `--flag path`, for messages.
    pub fn describe(&self) -> String {
        format!("{} {}", self.flag, self.path.display())
    }
}

/// A directory a command writes files into (`plan --out DIR`, `diagnose --plots DIR`).
#[derive(Clone, Debug)]
pub struct DeclaredDir {
    pub flag: String,
    pub dir: PathBuf,
    pub(crate) id: FileId,
}

/// The message of an output that is an input.
pub(crate) fn input_clash(output: &Declared, input: &Declared) -> String {
    format!(
        "{} is the file of the input {}: an output never replaces an input; give the output another path",
        output.describe(),
        input.describe()
    )
}

/// The message of two outputs that are one file.
pub(crate) fn output_clash(output: &Declared, earlier: &Declared) -> String {
    format!(
        "{} and {} are the same file: give each output its own path",
        earlier.describe(),
        output.describe()
    )
}

impl DeclaredDir {
    /// The directory `dir`, named by `flag`.
    pub(crate) fn new(flag: &str, dir: PathBuf) -> Self {
        DeclaredDir {
            flag: flag.to_string(),
            id: identify(&dir),
            dir,
        }
    }

    /// Whether `path` is inside this directory (its flag then names a file staged there).
    pub(crate) fn holds(&self, path: &Path) -> bool {
        let parent = match path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p,
            _ => Path::new("."),
        };
        identify(parent) == self.id
    }
}
