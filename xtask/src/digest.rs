//! The core's expected digests, committed: `xtask/core-digests.txt` holds the lines of
//! [`firmware::core_digest_lines`] (CRC-32 of every per-sample output and every record of the
//! host core's closed-loop runs), and `cargo xtask test` compares them. A change of the core
//! that is meant to change its results re-blesses the file in the same commit
//! (`cargo xtask core-digest --bless`) and says why in the commit message; any other change of
//! a digest fails the test with a line-by-line diff.

use crate::firmware::{self, Result};
use std::path::PathBuf;

/// The committed file of expected digests.
pub fn expected_path() -> PathBuf {
    firmware::root().join("xtask/core-digests.txt")
}

const HEADER: &str = "\
# Expected output of `cargo xtask core-digest`: CRC-32 of every per-sample output (U code, U,
# X, Y, status, estimates) and of every record of closed-loop runs of the host core
# (xtask/src/firmware.rs, core_digest_lines). `cargo xtask test` fails when a line differs.
# A change meant to change the core's results re-blesses this file in the same commit
# (`cargo xtask core-digest --bless`) and gives the reason in the commit message.
";

/// The digest lines of `text`, comments and blank lines left out.
fn digest_lines(text: &str) -> Vec<String> {
    text.lines()
        .map(str::trim_end)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .map(str::to_string)
        .collect()
}

/// The run a line belongs to: its first two fields (scenario and number type).
fn run_key(line: &str) -> String {
    line.split_whitespace()
        .take(2)
        .collect::<Vec<_>>()
        .join(" ")
}

/// A readable diff of expected against measured lines, or `None` when they are equal.
pub fn diff(expected: &[String], got: &[String]) -> Option<String> {
    if expected == got {
        return None;
    }
    let mut out = String::new();
    for e in expected {
        match got.iter().find(|g| run_key(g) == run_key(e)) {
            Some(g) if g == e => {}
            Some(g) => out.push_str(&format!("  expected {e}\n  measured {g}\n")),
            None => out.push_str(&format!("  expected {e}\n  measured (no such run)\n")),
        }
    }
    for g in got {
        if !expected.iter().any(|e| run_key(e) == run_key(g)) {
            out.push_str(&format!("  expected (no such run)\n  measured {g}\n"));
        }
    }
    if out.is_empty() {
        out.push_str("  the same runs in a different order\n");
    }
    Some(out)
}

/// `cargo xtask core-digest [--bless]`: prints the digests and compares them with the
/// committed file, or (`--bless`) rewrites the file with them.
pub fn run(bless: bool) -> Result<()> {
    let got = firmware::core_digest_lines()?;
    for l in &got {
        println!("{l}");
    }
    let path = expected_path();
    if bless {
        let text = format!("{HEADER}{}\n", got.join("\n"));
        std::fs::write(&path, text).map_err(|e| format!("{}: {e}", path.display()))?;
        println!("wrote {}", path.display());
        return Ok(());
    }
    check(&got)
}

/// Compares measured digest lines with the committed file.
pub fn check(got: &[String]) -> Result<()> {
    let path = expected_path();
    let text = std::fs::read_to_string(&path).map_err(|e| {
        format!(
            "{}: {e} (write it with `cargo xtask core-digest --bless`)",
            path.display()
        )
    })?;
    match diff(&digest_lines(&text), got) {
        None => {
            println!("core digests equal to {}", path.display());
            Ok(())
        }
        Some(d) => Err(format!(
            "{}: the core's closed-loop results changed (not bit-identical):\n{d}\
             If the change is intended, run `cargo xtask core-digest --bless` and commit the \
             file with the change, giving the reason.",
            path.display()
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lines(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn equal_lines_pass_and_any_change_is_shown() {
        let e = lines(&["dive-tap f32 10 samples steps 0000abcd", "sve-line f32 5 x"]);
        assert_eq!(diff(&e, &e), None);
        let g = lines(&["dive-tap f32 10 samples steps 0000abce", "sve-line f32 5 x"]);
        let d = diff(&e, &g).unwrap();
        assert!(d.contains("expected dive-tap f32 10 samples steps 0000abcd"));
        assert!(d.contains("measured dive-tap f32 10 samples steps 0000abce"));
        assert!(!d.contains("sve-line"));
        let missing = diff(&e, &e[..1]).unwrap();
        assert!(missing.contains("(no such run)"));
    }

    #[test]
    fn comments_and_blank_lines_are_not_digests() {
        assert_eq!(
            digest_lines("# header\n\na b c  \n# x\nd e\n"),
            lines(&["a b c", "d e"])
        );
    }
}
