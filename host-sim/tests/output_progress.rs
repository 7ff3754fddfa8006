//! The progress reporter: a bar redrawn in place on a terminal, plain lines in a log.

use std::io::Write;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use visco::output::progress::{Progress, ProgressMode};

/// A `Write` whose bytes the test can read afterwards.
#[derive(Clone, Default)]
struct Shared(Arc<Mutex<Vec<u8>>>);

impl Write for Shared {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(b);
        Ok(b.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Shared {
    fn text(&self) -> String {
        String::from_utf8(self.0.lock().unwrap().clone()).unwrap()
    }
}

#[test]
fn lines_mode_prints_plain_lines_with_times() {
    let out = Shared::default();
    let mut p = Progress::with_writer("DIVE", 80.0, ProgressMode::Lines, Box::new(out.clone()))
        .with_interval(Duration::ZERO);
    p.update(0.0);
    std::thread::sleep(Duration::from_millis(60));
    p.update(20.0);
    p.finish(80.0);
    p.update(90.0); // after finish: ignored
    let text = out.text();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 3, "{text}");
    assert!(
        lines[0].starts_with("DIVE:   0%  sim 0.0/80.0 s  wall "),
        "{}",
        lines[0]
    );
    assert!(lines[1].contains(" 25%  sim 20.0/80.0 s"), "{}", lines[1]);
    assert!(
        lines[1].contains("real time") && lines[1].contains("ETA"),
        "{}",
        lines[1]
    );
    assert!(lines[2].contains("100%  sim 80.0/80.0 s") && !lines[2].contains("ETA"));
    assert!(!text.contains('\r') && !text.contains('\x1b'));
}

#[test]
fn bar_mode_redraws_one_line_and_is_rate_limited() {
    let out = Shared::default();
    let mut p = Progress::with_writer("SVE", 40.0, ProgressMode::Bar, Box::new(out.clone()));
    for k in 0..1000 {
        p.update(k as f64 * 0.04); // far faster than the 100 ms redraw interval
    }
    p.finish(40.0);
    let text = out.text();
    assert!(text.matches('\r').count() <= 3, "rate-limited: {text:?}");
    assert!(text.ends_with('\n'));
    assert!(text.contains("SVE [") && text.contains("█"));
    assert!(text.contains("100%  sim 40.0/40.0 s"));
}

#[test]
fn silent_mode_prints_nothing() {
    let out = Shared::default();
    let mut p = Progress::with_writer("x", 1.0, ProgressMode::Silent, Box::new(out.clone()));
    p.update(0.5);
    p.finish(1.0);
    assert!(out.text().is_empty());
}
