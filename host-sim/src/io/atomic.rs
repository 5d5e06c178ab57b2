//! Writing output files so that a failed run never leaves a half-written one behind.
//!
//! Every file the tools produce goes through [`write_atomic`]: the bytes go to a temporary file
//! in the same directory, which is renamed over the target only once it is complete.

use super::IoError;
use std::io::Write;
use std::path::Path;

/// The directory of `path` (created) and its file name.
fn prepare(path: &Path) -> Result<(&Path, String), IoError> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    std::fs::create_dir_all(dir).map_err(|e| IoError::CreateDir { dir: dir.to_path_buf(), message: e.to_string() })?;
    let file_name = path.file_name().ok_or_else(|| IoError::NoFileName { path: path.to_path_buf() })?;
    Ok((dir, file_name.to_string_lossy().into_owned()))
}

/// Writes `bytes` to `path` atomically (temporary file + rename), creating parent directories.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    let (dir, file_name) = prepare(path)?;
    let tmp = dir.join(format!(".{file_name}.tmp{}", std::process::id()));
    let result = (|| -> std::io::Result<()> {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.map_err(|e| IoError::Write { path: path.to_path_buf(), message: e.to_string() })
}

/// Lets `write` produce a file at a temporary path, then renames it over `path`; on error the
/// temporary is removed. For writers that insist on a path (the PNG encoder).
pub fn write_atomic_with(path: &Path, write: impl FnOnce(&Path) -> Result<(), IoError>) -> Result<(), IoError> {
    let (dir, file_name) = prepare(path)?;
    // Keep the extension last: encoders pick the format from it.
    let tmp = dir.join(format!(".tmp{}-{file_name}", std::process::id()));
    let result = write(&tmp).map_err(|e| e.to_string()).and_then(|()| std::fs::rename(&tmp, path).map_err(|e| e.to_string()));
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.map_err(|message| IoError::Write { path: path.to_path_buf(), message })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_whole_file_and_leaves_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("sub/out.txt");
        write_atomic(&p, b"hello").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"hello");
        let names: Vec<_> = std::fs::read_dir(p.parent().unwrap()).unwrap().map(|e| e.unwrap().file_name()).collect();
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
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(names, vec![std::ffi::OsString::from("taken")]);
    }
}

