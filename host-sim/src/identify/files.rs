//! Output files, all or nothing: every file is written under a temporary name in its target
//! directory and renamed into place only when all of them are complete ([`Staged::commit`]);
//! dropped uncommitted (an error anywhere), the temporary files are removed.
//!
//! Also the CSV writers of the outputs: map grids and fit series.

use std::fs::{self, File};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use super::error::{IdentifyError, Result};
use crate::recording::format_f64;

static COUNTER: AtomicU64 = AtomicU64::new(0);

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

/// Files written under temporary names, renamed together.
#[derive(Debug, Default)]
pub struct Staged {
    files: Vec<(PathBuf, PathBuf)>,
    committed: bool,
}

/// A text file being written, under its temporary name.
pub struct StagedWriter {
    out: Option<BufWriter<File>>,
    tmp: PathBuf,
    path: PathBuf,
    finished: bool,
}

impl StagedWriter {
    /// The final path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Appends text.
    pub fn write_str(&mut self, s: &str) -> Result<()> {
        match self.out.as_mut() {
            Some(out) => out
                .write_all(s.as_bytes())
                .map_err(|e| IdentifyError::io(&self.path, "cannot write", &e)),
            None => Err(IdentifyError::new(
                &self.path,
                "written after it was finished",
            )),
        }
    }
}

impl Staged {
    /// Nothing staged yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Starts a file that will become `path`.
    pub fn create(&mut self, path: &Path) -> Result<StagedWriter> {
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
            _ => PathBuf::from("."),
        };
        if !dir.is_dir() {
            return Err(
                IdentifyError::new(path, "the output directory does not exist")
                    .with_fix(format!("create {} first", dir.display())),
            );
        }
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .ok_or_else(|| IdentifyError::new(path, "not a file name"))?;
        let tmp = dir.join(format!(
            ".{name}.tmp-{}-{}",
            std::process::id(),
            COUNTER.fetch_add(1, Ordering::Relaxed)
        ));
        let file = File::create(&tmp).map_err(|e| IdentifyError::io(path, "cannot create", &e))?;
        Ok(StagedWriter {
            out: Some(BufWriter::with_capacity(1 << 16, file)),
            tmp,
            path: path.to_path_buf(),
            finished: false,
        })
    }

    /// Finishes a file started with [`Staged::create`]; it is renamed at [`Staged::commit`].
    pub fn finish(&mut self, mut w: StagedWriter) -> Result<()> {
        let out = w
            .out
            .take()
            .ok_or_else(|| IdentifyError::new(&w.path, "finished twice"))?;
        let file = out
            .into_inner()
            .map_err(|e| IdentifyError::io(&w.path, "cannot write", e.error()))?;
        file.sync_all()
            .map_err(|e| IdentifyError::io(&w.path, "cannot write", &e))?;
        w.finished = true;
        self.files.push((w.tmp.clone(), w.path.clone()));
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
        let w = self.create(path)?;
        let tmp = w.tmp.clone();
        render(&tmp).map_err(|e| IdentifyError::new(path, e.reason))?;
        let mut w = w;
        w.out.take();
        w.finished = true;
        self.files.push((tmp, path.to_path_buf()));
        Ok(())
    }

    /// The final paths staged so far.
    pub fn paths(&self) -> Vec<PathBuf> {
        self.files.iter().map(|(_, p)| p.clone()).collect()
    }

    /// Renames every staged file into place, in the order staged.
    pub fn commit(mut self) -> Result<Vec<PathBuf>> {
        for (tmp, path) in &self.files {
            fs::rename(tmp, path).map_err(|e| {
                IdentifyError::io(path, "cannot move the finished file into place", &e)
            })?;
        }
        self.committed = true;
        Ok(self.paths())
    }
}

impl Drop for StagedWriter {
    fn drop(&mut self) {
        // A writer dropped unfinished was abandoned: its file goes.
        if !self.finished {
            self.out.take();
            let _ = fs::remove_file(&self.tmp);
        }
    }
}

impl Drop for Staged {
    fn drop(&mut self) {
        if !self.committed {
            for (tmp, _) in &self.files {
                let _ = fs::remove_file(tmp);
            }
        }
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
