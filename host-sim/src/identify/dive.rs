//! stub
use super::{files::Staged, IdentifyError, Json, Options, Outputs, Result};
use std::path::Path;
/// stub
#[derive(Debug, Clone)]
pub struct DiveResult {
    pub json: Json,
    pub rms_misfit_m: f64,
    pub taps: Vec<Tap>,
}
#[derive(Debug, Clone)]
pub struct Tap;
impl Tap {
    pub fn summary(&self) -> String {
        String::new()
    }
}
pub(crate) fn identify(
    path: &Path,
    _o: &Options,
    _out: &Outputs,
    _s: &mut Staged,
) -> Result<DiveResult> {
    Err(IdentifyError::new(path, "todo"))
}
