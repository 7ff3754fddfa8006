//! The one error type of the recording layer.
//!
//! Every refusal names *where* (the file, the member inside an archive when there is one, the
//! 1-based line when the input is text), *why*, and, where one exists, *what to do about it*.
//! The command line prints it as a single line, `error: FILE:LINE: reason (fix: ...)`, so a
//! person can jump to the spot and a script can parse it.

use std::fmt;
use std::path::{Path, PathBuf};

/// What went wrong, coarsely, so callers can react without parsing the text.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorKind {
    /// Reading or writing the file failed at the operating-system level.
    Io,
    /// A recording CSV breaks the contract of `recording.md`.
    Contract,
    /// A vendor file is malformed, truncated or of an unsupported variant.
    Vendor,
    /// A value the contract needs is neither in the file nor given on the command line.
    MissingValue,
    /// The caller asked for something impossible (bad flag value, unknown curve index, ...).
    Usage,
}

/// A refusal with its location, reason and fix.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordingError {
    /// The file being read or written.
    pub file: PathBuf,
    /// The member of an archive (e.g. `segments/0/segment-header.properties`), if any.
    pub entry: Option<String>,
    /// 1-based line number in the text being read, if the problem sits on one line.
    pub line: Option<u64>,
    /// Coarse classification.
    pub kind: ErrorKind,
    /// What is wrong, in words.
    pub reason: String,
    /// What to do about it, when there is something to do.
    pub fix: Option<String>,
}

impl RecordingError {
    /// A new error about `file` with no line and no fix yet.
    pub fn new(file: &Path, kind: ErrorKind, reason: impl Into<String>) -> Self {
        RecordingError {
            file: file.to_path_buf(),
            entry: None,
            line: None,
            kind,
            reason: reason.into(),
            fix: None,
        }
    }

    /// A contract violation on a given 1-based line.
    pub fn contract(file: &Path, line: u64, reason: impl Into<String>) -> Self {
        Self::new(file, ErrorKind::Contract, reason).at_line(line)
    }

    /// An I/O failure, with the operating system's words.
    pub fn io(file: &Path, what: &str, err: &std::io::Error) -> Self {
        Self::new(file, ErrorKind::Io, format!("{what}: {err}"))
    }

    /// Sets the line.
    pub fn at_line(mut self, line: u64) -> Self {
        self.line = Some(line);
        self
    }

    /// Sets the archive member.
    pub fn in_entry(mut self, entry: impl Into<String>) -> Self {
        self.entry = Some(entry.into());
        self
    }

    /// Sets the fix.
    pub fn with_fix(mut self, fix: impl Into<String>) -> Self {
        self.fix = Some(fix.into());
        self
    }
}

impl fmt::Display for RecordingError {
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

impl std::error::Error for RecordingError {}

/// Short for results of this layer.
pub type Result<T> = std::result::Result<T, RecordingError>;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn display_has_file_entry_line_reason_fix() {
        let e = RecordingError::contract(Path::new("a.csv"), 7, "bad cell").with_fix("do this");
        assert_eq!(e.to_string(), "a.csv:7: bad cell (fix: do this)");
        let e = RecordingError::new(Path::new("m.jpk-force"), ErrorKind::Vendor, "short")
            .in_entry("segments/0/channels/height.dat");
        assert_eq!(
            e.to_string(),
            "m.jpk-force:segments/0/channels/height.dat: short"
        );
    }
}
