//! The importers read files: each input is written to a file of this process (with the
//! extension the importer expects) and imported with every option given, so that the parser
//! goes as deep as the bytes allow.
use std::path::PathBuf;
use visco::recording::import::ImportOptions;

pub fn file_with(ext: &str, data: &[u8]) -> PathBuf {
    let p = std::env::temp_dir().join(format!("visco-fuzz-{}.{ext}", std::process::id()));
    std::fs::write(&p, data).expect("temp file");
    p
}

pub fn options() -> ImportOptions {
    ImportOptions {
        spring_constant_n_per_m: Some(0.1),
        sensitivity_m_per_unit: Some(5e-8),
        tip_radius_m: Some(5e-6),
        sample_rate_hz: Some(2000.0),
    }
}
