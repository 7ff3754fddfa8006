//! The one error type of the output layer, and the atomic file write every writer goes through.

use std::fmt;
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// A failure to write or read an output file. It always names the file; `Display` prints
/// `PATH: reason`, one line, like the rest of the `visco` command's errors.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OutputError {
    /// The file being written or read.
    pub path: PathBuf,
    /// What went wrong, in words.
    pub reason: String,
}

impl OutputError {
    /// An error about `path`.
    pub fn new(path: &Path, reason: impl Into<String>) -> Self {
        OutputError {
            path: path.to_path_buf(),
            reason: reason.into(),
        }
    }

    /// An I/O failure, with the operating system's words.
    pub fn io(path: &Path, what: &str, err: &std::io::Error) -> Self {
        Self::new(path, format!("{what}: {err}"))
    }
}

impl fmt::Display for OutputError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.path.display(), self.reason)
    }
}

impl std::error::Error for OutputError {}

/// Short for results of the output layer.
pub type Result<T> = std::result::Result<T, OutputError>;

static TMP_COUNTER: AtomicU64 = AtomicU64::new(0);

/// Writes `bytes` to `path` atomically: into a hidden temporary file in the same directory,
/// flushed to disk, then renamed over `path`. A failure at any step removes the temporary
/// file and leaves `path` as it was (absent, or the previous complete file).
///
/// The directory must exist: creating it is the caller's decision (a typo in `--out` should
/// fail, not silently create a tree).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .ok_or_else(|| OutputError::new(path, "the path names no file"))?;
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    if !dir.is_dir() {
        return Err(OutputError::new(
            path,
            format!(
                "cannot write: the directory {} does not exist",
                dir.display()
            ),
        ));
    }
    let n = TMP_COUNTER.fetch_add(1, Ordering::Relaxed);
    let tmp = dir.join(format!(".{name}.{}.{n}.tmp", std::process::id()));
    let result = (|| {
        let mut f = fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)
            .map_err(|e| OutputError::io(path, "cannot create the file", &e))?;
        f.write_all(bytes)
            .map_err(|e| OutputError::io(path, "cannot write the file", &e))?;
        f.sync_all()
            .map_err(|e| OutputError::io(path, "cannot flush the file", &e))?;
        drop(f);
        fs::rename(&tmp, path)
            .map_err(|e| OutputError::io(path, "cannot move the finished file into place", &e))
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result
}

/// Reads a whole file, naming it in the error.
pub(crate) fn read_all(path: &Path) -> Result<Vec<u8>> {
    fs::read(path).map_err(|e| OutputError::io(path, "cannot read the file", &e))
}
