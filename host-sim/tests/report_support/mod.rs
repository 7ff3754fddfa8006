//! Checks a report a test wrote against its committed JSON Schema (`host-sim/schemas/`), with
//! the `jsonschema` crate: every error is listed with the place in the report.

#![allow(dead_code)]

use std::path::Path;

use serde_json::Value;

/// The committed schema of report `name`.
pub fn committed_schema(name: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("schemas")
        .join(format!("{name}.schema.json"));
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Panics with every violation when `report` does not validate against schema `name`.
pub fn validate(name: &str, report: &Value) {
    let schema: Value = serde_json::from_str(&committed_schema(name)).unwrap();
    let validator = jsonschema::validator_for(&schema)
        .unwrap_or_else(|e| panic!("{name}.schema.json is not a valid schema: {e}"));
    let errors: Vec<String> = validator
        .iter_errors(report)
        .map(|e| format!("  at {}: {e}", e.instance_path()))
        .collect();
    assert!(
        errors.is_empty(),
        "the {name} report does not match its schema:\n{}",
        errors.join("\n")
    );
}

/// Reads the report at `path`, validates it against schema `name` and returns it.
pub fn validate_file(name: &str, path: &Path) -> Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let v: Value =
        serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    validate(name, &v);
    v
}
