//! The one error type of the output layer, and its atomic file write.

use std::fmt;
use std::fs;
use std::path::{Path, PathBuf};

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

/// Writes `bytes` to `path` atomically ([`super::atomic`]), naming the file in the error.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    super::atomic::write_atomic(path, bytes).map_err(|e| OutputError::new(path, e.to_string()))
}

/// Reads a whole file, naming it in the error.
pub(crate) fn read_all(path: &Path) -> Result<Vec<u8>> {
    fs::read(path).map_err(|e| OutputError::io(path, "cannot read the file", &e))
}
