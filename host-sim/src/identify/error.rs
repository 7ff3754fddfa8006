//! The one error type of `identify`: where (file, line), why, and what to do.

use std::fmt;
use std::path::{Path, PathBuf};

use crate::recording::RecordingError;

/// A refusal: the recording cannot be identified, or an output cannot be written.
///
/// Displayed on one line as `FILE[:LINE]: reason (fix: ...)`, the format of
/// [`RecordingError`], which converts into it unchanged.
#[derive(Debug, Clone, PartialEq)]
pub struct IdentifyError {
    /// The file at fault (the recording, or an output).
    pub file: PathBuf,
    /// The member of an archive, if any (from the recording layer).
    pub entry: Option<String>,
    /// The 1-based line of the recording where the problem sits, if it sits on one.
    pub line: Option<u64>,
    /// What is wrong.
    pub reason: String,
    /// What to do about it.
    pub fix: Option<String>,
}

impl IdentifyError {
    /// An error about `file`.
    pub fn new(file: &Path, reason: impl Into<String>) -> Self {
        IdentifyError {
            file: file.to_path_buf(),
            entry: None,
            line: None,
            reason: reason.into(),
            fix: None,
        }
    }

    /// Sets the line.
    pub fn at_line(mut self, line: u64) -> Self {
        self.line = Some(line);
        self
    }

    /// Sets the fix.
    pub fn with_fix(mut self, fix: impl Into<String>) -> Self {
        self.fix = Some(fix.into());
        self
    }

    /// An I/O failure on an output.
    pub fn io(file: &Path, what: &str, err: &std::io::Error) -> Self {
        Self::new(file, format!("{what}: {err}"))
    }
}

impl From<RecordingError> for IdentifyError {
    fn from(e: RecordingError) -> Self {
        IdentifyError {
            file: e.file,
            entry: e.entry,
            line: e.line,
            reason: e.reason,
            fix: e.fix,
        }
    }
}

impl fmt::Display for IdentifyError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.display())?;
        if let Some(entry) = &self.entry {
            write!(f, ":{entry}")?;
        }
        if let Some(line) = self.line {
            write!(f, ":{line}")?;
        }
        write!(f, ": {}", self.reason)?;
        if let Some(fix) = &self.fix {
            write!(f, " (fix: {fix})")?;
        }
        Ok(())
    }
}

impl std::error::Error for IdentifyError {}

/// Short for results of `identify`.
pub type Result<T> = std::result::Result<T, IdentifyError>;
