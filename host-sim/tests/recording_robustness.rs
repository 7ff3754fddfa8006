//! No input makes the readers panic: real files with random bytes changed, cut short, or
//! lines scrambled must give `Ok` or an error, never a crash. (A deterministic stand-in for
//! the fuzzing these parsers will get later.)

mod recording_support;

use std::path::Path;

use recording_support::*;
use visco::recording::import::import_all;
use visco::recording::Recording;

/// xorshift64*: deterministic, no dependency.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// Overwrites a few random bytes; sometimes with digits, separators or line ends, which
/// reach deeper into the text parsers than arbitrary bytes.
fn mutate(rng: &mut Rng, bytes: &mut [u8]) {
    const INTERESTING: &[u8] = b"0123456789.,-+eE\t\n\r=:#\\ NaInf\x00\xff";
    for _ in 0..1 + rng.below(4) {
        let i = rng.below(bytes.len());
        if let Some(b) = bytes.get_mut(i) {
            *b = if rng.below(2) == 0 {
                INTERESTING[rng.below(INTERESTING.len())]
            } else {
                rng.next() as u8
            };
        }
    }
}

fn survive(path: &Path, name: &str, bytes: &[u8]) {
    std::fs::write(path, bytes).unwrap();
    let result = std::panic::catch_unwind(|| {
        let _ = import_all(path, &everything());
        let _ = Recording::read(path);
    });
    assert!(result.is_ok(), "{name}: panicked on {}", path.display());
}

#[test]
fn mutated_and_truncated_vendor_files_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    // Stored (uncompressed) copies, so mutations reach properties and data, not just CRCs.
    let mut sources: Vec<(String, Vec<u8>)> = Vec::new();
    for name in [SPOT3, SR] {
        let p = dir.path().join(format!("stored-{name}"));
        rezip(&real(name), &p, |_, b| Some(b));
        sources.push((name.to_string(), std::fs::read(&p).unwrap()));
    }
    for name in [WORKSHOP, NTMDT] {
        sources.push((name.to_string(), std::fs::read(real(name)).unwrap()));
    }
    for (name, original) in &sources {
        let ext = Path::new(name)
            .extension()
            .unwrap()
            .to_string_lossy()
            .into_owned();
        let target = dir.path().join(format!("m.{ext}"));
        for _ in 0..150 {
            let mut b = original.clone();
            mutate(&mut rng, &mut b);
            survive(&target, name, &b);
        }
        for _ in 0..30 {
            let cut = rng.below(original.len());
            survive(&target, name, &original[..cut]);
        }
    }
}

#[test]
fn mutated_recordings_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.csv");
    let rec = import_one(SPOT3, &tip_only());
    rec.write(&good).unwrap();
    let original = std::fs::read(&good).unwrap();
    // Mutations concentrated on the header and first rows, where the structure is.
    let head = original.len().min(4000);
    let mut rng = Rng(42);
    let target = dir.path().join("m.csv");
    for _ in 0..300 {
        let mut b = original[..head].to_vec();
        mutate(&mut rng, &mut b);
        survive(&target, "recording", &b);
    }
}
