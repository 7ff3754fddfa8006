//! Output files, all or nothing: every file is written under a temporary name in its target
//! directory and renamed into place only when all of them are complete ([`Staged::commit`]);
//! dropped uncommitted (an error anywhere), the temporary files are removed.
//!
//! Also the CSV writers of the outputs: map grids and fit series.

use std::fs::{self, File};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use super::error::{IdentifyError, Result};
use crate::output::atomic::{AtomicError, PendingFile};
use crate::recording::format_f64;

/// Where a report and its companion files go: `--out DIR`, else the report's directory; and
/// the stem the companions are named after. Refuses a report without a file name, an output
/// that would overwrite the input, and a report whose directory does not exist (a typo should
/// fail, not grow a tree).
pub fn plan_outputs(
    json: &Path,
    out_dir: Option<&Path>,
    input: &Path,
) -> Result<(PathBuf, String)> {
    let dir = match out_dir {
        Some(d) => d.to_path_buf(),
        None => match json.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        },
    };
    let stem = json
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .filter(|s| !s.is_empty())
        .ok_or_else(|| IdentifyError::new(json, "the report needs a file name"))?;
    for out in [json, dir.as_path()] {
        if same_file(out, input) {
            return Err(IdentifyError::new(
                out,
                "the output would overwrite the recording",
            ));
        }
    }
    if let Some(parent) = json.parent().filter(|p| !p.as_os_str().is_empty()) {
        if !parent.is_dir() {
            return Err(
                IdentifyError::new(json, "the report's directory does not exist")
                    .with_fix(format!("create {} first", parent.display())),
            );
        }
    }
    Ok((dir, stem))
}

/// Creates `dir` when missing; whether it did (so that a failure can remove it again).
pub fn create_missing_dir(dir: &Path) -> Result<bool> {
    if dir.exists() {
        return Ok(false);
    }
    fs::create_dir(dir)
        .map_err(|e| IdentifyError::io(dir, "cannot create the output directory", &e))?;
    Ok(true)
}

fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(x), Ok(y)) => x == y,
        _ => false,
    }
}

/// Files written under temporary names ([`crate::output::atomic`]), renamed together.
#[derive(Debug, Default)]
pub struct Staged {
    files: Vec<PendingFile>,
}

/// A text file being written, under its temporary name.
pub struct StagedWriter {
    out: Option<BufWriter<File>>,
    pending: PendingFile,
}

impl StagedWriter {
    /// The final path.
    pub fn path(&self) -> &Path {
        self.pending.path()
    }

    /// Appends text.
    pub fn write_str(&mut self, s: &str) -> Result<()> {
        match self.out.as_mut() {
            Some(out) => out
                .write_all(s.as_bytes())
                .map_err(|e| IdentifyError::io(self.pending.path(), "cannot write", &e)),
            None => Err(IdentifyError::new(
                self.pending.path(),
                "written after it was finished",
            )),
        }
    }
}

fn atomic_error(path: &Path, e: AtomicError) -> IdentifyError {
    match e {
        AtomicError::NoFileName => IdentifyError::new(path, "not a file name"),
        AtomicError::NoDirectory(dir) => {
            IdentifyError::new(path, "the output directory does not exist")
                .with_fix(format!("create {} first", dir.display()))
        }
        AtomicError::Io(what, err) => IdentifyError::io(path, what, &err),
    }
}

impl Staged {
    /// Nothing staged yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Starts a file that will become `path`.
    pub fn create(&mut self, path: &Path) -> Result<StagedWriter> {
        let (file, pending) = PendingFile::create(path).map_err(|e| atomic_error(path, e))?;
        Ok(StagedWriter {
            out: Some(BufWriter::with_capacity(1 << 16, file)),
            pending,
        })
    }

    /// Finishes a file started with [`Staged::create`]; it is renamed at [`Staged::commit`].
    /// (A writer dropped unfinished was abandoned: its temporary file goes with it.)
    pub fn finish(&mut self, mut w: StagedWriter) -> Result<()> {
        let path = w.pending.path().to_path_buf();
        let out = w
            .out
            .take()
            .ok_or_else(|| IdentifyError::new(&path, "finished twice"))?;
        let file = out
            .into_inner()
            .map_err(|e| IdentifyError::io(&path, "cannot write", e.error()))?;
        file.sync_all()
            .map_err(|e| IdentifyError::io(&path, "cannot write", &e))?;
        self.files.push(w.pending);
        Ok(())
    }

    /// Writes a whole file.
    pub fn write(&mut self, path: &Path, text: &str) -> Result<()> {
        self.write_bytes(path, text.as_bytes())
    }

    /// Writes a whole file of bytes.
    pub fn write_bytes(&mut self, path: &Path, bytes: &[u8]) -> Result<()> {
        let mut w = self.create(path)?;
        match w.out.as_mut() {
            Some(out) => out
                .write_all(bytes)
                .map_err(|e| IdentifyError::io(path, "cannot write", &e))?,
            None => return Err(IdentifyError::new(path, "written after it was finished")),
        }
        self.finish(w)
    }

    /// Stages a file that another writer produces: `render` writes it to the temporary path
    /// given (e.g. a figure of [`crate::output::figure`], which writes atomically itself).
    pub fn render(
        &mut self,
        path: &Path,
        render: impl FnOnce(&Path) -> crate::output::Result<()>,
    ) -> Result<()> {
        let (file, pending) = PendingFile::create(path).map_err(|e| atomic_error(path, e))?;
        drop(file);
        render(pending.temp_path()).map_err(|e| IdentifyError::new(path, e.reason))?;
        self.files.push(pending);
        Ok(())
    }

    /// The final paths staged so far.
    pub fn paths(&self) -> Vec<PathBuf> {
        self.files.iter().map(|p| p.path().to_path_buf()).collect()
    }

    /// Renames every staged file into place, in the order staged; dropped uncommitted, the
    /// temporary files are removed.
    pub fn commit(self) -> Result<Vec<PathBuf>> {
        let paths = self.paths();
        for p in self.files {
            let path = p.path().to_path_buf();
            p.commit().map_err(|e| atomic_error(&path, e))?;
        }
        Ok(paths)
    }
}

/// Appends a number in the shortest round-trip notation (`nan` for a missing value).
pub fn push_num(s: &mut String, v: f64) {
    if v.is_finite() {
        format_f64(v, s);
    } else {
        s.push_str("nan");
    }
}
