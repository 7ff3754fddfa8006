//! `visco schema`: the JSON Schema of each report the tools write, derived from the structs
//! that write them (`visco::report`). `visco schema --write host-sim/schemas` regenerates the
//! committed files; a test fails when they differ from the generated ones.

use std::path::PathBuf;

use super::CliResult;
use visco::report::{schema, REPORTS};

/// Print a report's JSON Schema, or write every report's schema into a directory.
#[derive(Debug, clap::Args)]
pub struct SchemaArgs {
    /// The report (identify, diagnose, concealed, demo, sweep, faults); all of them with
    /// --write.
    #[arg(value_parser = clap::builder::PossibleValuesParser::new(REPORTS.iter().map(|r| r.0)))]
    report: Option<String>,
    /// Write `<report>.schema.json` for every report (or the one named) into this directory.
    #[arg(long, value_name = "DIR")]
    write: Option<PathBuf>,
}

pub fn run(args: SchemaArgs) -> CliResult {
    let names: Vec<&str> = match &args.report {
        Some(r) => vec![r.as_str()],
        None if args.write.is_some() => REPORTS.iter().map(|r| r.0).collect(),
        None => return Err("name a report, or give --write DIR for all of them".into()),
    };
    for name in names {
        // The names come from REPORTS (clap checks them), each of which has a schema.
        let text = schema(name).ok_or_else(|| format!("no report `{name}`"))?;
        match &args.write {
            Some(dir) => {
                let path = dir.join(format!("{name}.schema.json"));
                visco::output::write_atomic(&path, text.as_bytes())?;
                println!("{}", path.display());
            }
            None => print!("{text}"),
        }
    }
    Ok(())
}
