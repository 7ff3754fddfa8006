//! Atomic file replacement, the one place every writer of the host tools goes through: a file
//! is written under a temporary name in its target directory (`tempfile`), synced, and renamed
//! over the target only when complete. Dropped before that, the temporary file is removed, so
//! a failure leaves the target as it was (absent, or the previous complete file).

use std::fs::File;
use std::io::{self, Write};
use std::path::{Path, PathBuf};

/// Why an atomic write failed, without the caller's error type: each layer maps it to its own
/// error (which names the file).
#[derive(Debug)]
pub enum AtomicError {
    /// The path ends in no file name.
    NoFileName,
    /// The target directory does not exist (creating it is the caller's decision: a typo in
    /// `--out` should fail, not silently create a tree).
    NoDirectory(PathBuf),
    /// An I/O step failed: what was being done and the operating system's words.
    Io(&'static str, io::Error),
}

impl std::fmt::Display for AtomicError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            AtomicError::NoFileName => write!(f, "the path names no file"),
            AtomicError::NoDirectory(d) => {
                write!(
                    f,
                    "cannot write: the directory {} does not exist",
                    d.display()
                )
            }
            AtomicError::Io(what, e) => write!(f, "{what}: {e}"),
        }
    }
}

/// A file being written or complete under its temporary name. [`PendingFile::commit`] renames
/// it into place; dropping it removes it. Lets a command write several files all-or-nothing.
#[derive(Debug)]
pub struct PendingFile {
    tmp: tempfile::TempPath,
    path: PathBuf,
}

impl PendingFile {
    /// Starts the file that will become `path`: the open temporary file and its pending rename.
    pub fn create(path: &Path) -> Result<(File, PendingFile), AtomicError> {
        path.file_name().ok_or(AtomicError::NoFileName)?;
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
            _ => PathBuf::from("."),
        };
        if !dir.is_dir() {
            return Err(AtomicError::NoDirectory(dir));
        }
        let file = tempfile::Builder::new()
            .prefix(".visco-")
            .suffix(".tmp")
            .tempfile_in(&dir)
            .map_err(|e| AtomicError::Io("cannot create the file", e))?;
        let (file, tmp) = file.into_parts();
        Ok((
            file,
            PendingFile {
                tmp,
                path: path.to_path_buf(),
            },
        ))
    }

    /// The final path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The temporary path (for a writer that writes the file by path, e.g. a figure).
    pub fn temp_path(&self) -> &Path {
        &self.tmp
    }

    /// Renames the temporary file to its final name (replacing an existing file).
    pub fn commit(self) -> Result<(), AtomicError> {
        self.tmp
            .persist(&self.path)
            .map_err(|e| AtomicError::Io("cannot move the finished file into place", e.error))
    }
}

/// Writes `bytes` to `path` atomically (see the module docs), synced to disk before the rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), AtomicError> {
    let (mut file, pending) = PendingFile::create(path)?;
    file.write_all(bytes)
        .map_err(|e| AtomicError::Io("cannot write the file", e))?;
    file.sync_all()
        .map_err(|e| AtomicError::Io("cannot flush the file", e))?;
    drop(file);
    pending.commit()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entries(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn a_commit_replaces_and_a_drop_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.txt");
        write_atomic(&p, b"one").unwrap();
        write_atomic(&p, b"two").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"two");
        let (mut f, pending) = PendingFile::create(&dir.path().join("b.txt")).unwrap();
        f.write_all(b"half").unwrap();
        assert_eq!(entries(dir.path()).len(), 2, "the temporary file is there");
        drop(pending);
        assert_eq!(entries(dir.path()), ["a.txt"]);
    }

    #[test]
    fn a_missing_directory_or_file_name_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("no/such/dir/x.txt");
        assert!(matches!(
            write_atomic(&missing, b"x"),
            Err(AtomicError::NoDirectory(_))
        ));
        assert!(matches!(
            write_atomic(Path::new("/"), b"x"),
            Err(AtomicError::NoFileName)
        ));
        assert!(entries(dir.path()).is_empty());
    }
}
