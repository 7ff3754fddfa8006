//! stub
use super::{files::Staged, IdentifyError, Json, Options, Outputs, Result};
use std::path::Path;
/// stub
#[derive(Debug, Clone)]
pub struct SveResult {
    pub json: Json,
    pub rms_misfit_m: f64,
}
impl SveResult {
    pub fn summary(&self) -> String {
        String::new()
    }
}
pub(crate) fn identify(
    path: &Path,
    _o: &Options,
    _out: &Outputs,
    _s: &mut Staged,
) -> Result<SveResult> {
    Err(IdentifyError::new(path, "todo"))
}
