//! A progress reporter for long simulations: a bar redrawn in place on a terminal, plain
//! periodic lines in a log (CI, a pipe, a file), with simulated time, wall time, the speed
//! ratio and an ETA.
//!
//! ```text
//! DIVE  [███████████▌              ]  45%  sim 36.0/80.0 s  wall 1.3 s  27.6× real time  ETA 1.6 s
//! ```
//!
//! On a terminal the line is redrawn at most every 100 ms; otherwise a line is printed at
//! most every 5 s (and at 0 % and 100 %), so a CI log stays short. The writer is stderr by
//! default, or any `Write` for tests.

use std::io::{IsTerminal, Write};
use std::time::{Duration, Instant};

/// How the reporter draws.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProgressMode {
    /// Redraw one line in place (`\r`), for a terminal.
    Bar,
    /// Append plain lines now and then, for logs.
    Lines,
    /// Print nothing.
    Silent,
}

/// Reports the progress of one phase (e.g. "DIVE") measured in simulated seconds.
pub struct Progress {
    label: String,
    total_s: f64,
    mode: ProgressMode,
    out: Box<dyn Write + Send>,
    start: Instant,
    last_draw: Option<Instant>,
    interval: Duration,
    done: bool,
    width: usize,
}

impl Progress {
    /// A reporter on stderr: a bar when stderr is a terminal, plain lines otherwise.
    pub fn new(label: impl Into<String>, total_simulated_s: f64) -> Self {
        let mode = if std::io::stderr().is_terminal() {
            ProgressMode::Bar
        } else {
            ProgressMode::Lines
        };
        Self::with_writer(label, total_simulated_s, mode, Box::new(std::io::stderr()))
    }

    /// A reporter writing to `out` in `mode`.
    pub fn with_writer(
        label: impl Into<String>,
        total_simulated_s: f64,
        mode: ProgressMode,
        out: Box<dyn Write + Send>,
    ) -> Self {
        let interval = match mode {
            ProgressMode::Bar => Duration::from_millis(100),
            _ => Duration::from_secs(5),
        };
        Progress {
            label: label.into(),
            total_s: total_simulated_s.max(f64::MIN_POSITIVE),
            mode,
            out,
            start: Instant::now(),
            last_draw: None,
            interval,
            done: false,
            width: 26,
        }
    }

    /// Changes the minimum time between two draws (tests use zero).
    pub fn with_interval(mut self, interval: Duration) -> Self {
        self.interval = interval;
        self
    }

    /// The drawing mode.
    pub fn mode(&self) -> ProgressMode {
        self.mode
    }

    /// Reports that `simulated_s` seconds of the total are done. Cheap when nothing is due
    /// (one clock read), so it can be called every loop iteration.
    pub fn update(&mut self, simulated_s: f64) {
        if self.done || self.mode == ProgressMode::Silent {
            return;
        }
        let now = Instant::now();
        let due = match self.last_draw {
            None => true,
            Some(t) => now.duration_since(t) >= self.interval,
        };
        if due {
            self.last_draw = Some(now);
            self.draw(simulated_s, now.duration_since(self.start), false);
        }
    }

    /// Reports the end: draws the final state (100 % unless `simulated_s` says less) and, on
    /// a terminal, ends the line.
    pub fn finish(&mut self, simulated_s: f64) {
        if self.done || self.mode == ProgressMode::Silent {
            self.done = true;
            return;
        }
        self.draw(simulated_s, self.start.elapsed(), true);
        self.done = true;
    }

    /// The status text without the bar, e.g.
    /// `45%  sim 36.0/80.0 s  wall 1.3 s  27.6× real time  ETA 1.6 s`.
    pub fn status(&self, simulated_s: f64, wall: Duration) -> String {
        let frac = (simulated_s / self.total_s).clamp(0.0, 1.0);
        let wall_s = wall.as_secs_f64();
        let mut s = format!(
            "{:3.0}%  sim {:.1}/{:.1} s  wall {}",
            frac * 100.0,
            simulated_s.max(0.0),
            self.total_s,
            fmt_duration(wall_s)
        );
        if wall_s > 0.05 && simulated_s > 0.0 {
            let speed = simulated_s / wall_s;
            if speed >= 1.0 {
                s += &format!("  {speed:.1}× real time");
            } else {
                s += &format!("  1/{:.1} of real time", 1.0 / speed);
            }
            if frac < 1.0 {
                let eta = (self.total_s - simulated_s) / speed;
                s += &format!("  ETA {}", fmt_duration(eta));
            }
        }
        s
    }

    fn draw(&mut self, simulated_s: f64, wall: Duration, last: bool) {
        let frac = (simulated_s / self.total_s).clamp(0.0, 1.0);
        let status = self.status(simulated_s, wall);
        let _ = match self.mode {
            ProgressMode::Bar => {
                let bar = bar(frac, self.width);
                let end = if last { "\n" } else { "" };
                // \x1b[K clears what a longer previous line left behind.
                write!(self.out, "\r{} [{bar}] {status}\x1b[K{end}", self.label)
            }
            ProgressMode::Lines => writeln!(self.out, "{}: {status}", self.label),
            ProgressMode::Silent => Ok(()),
        };
        let _ = self.out.flush();
    }
}

/// A bar of `width` cells with eighth-cell resolution.
fn bar(frac: f64, width: usize) -> String {
    const PARTS: [char; 8] = [' ', '▏', '▎', '▍', '▌', '▋', '▊', '▉'];
    let eighths = (frac * width as f64 * 8.0).round() as usize;
    let (full, part) = (eighths / 8, eighths % 8);
    let mut s = "█".repeat(full.min(width));
    if full < width {
        s.push(PARTS[part]);
        s += &" ".repeat(width - full - 1);
    }
    s
}

/// `0.4 s`, `12.3 s`, `2 min 05 s`, `1 h 02 min`.
fn fmt_duration(s: f64) -> String {
    if !s.is_finite() || s < 0.0 {
        return "?".into();
    }
    if s < 60.0 {
        format!("{s:.1} s")
    } else if s < 3600.0 {
        format!("{} min {:02.0} s", (s / 60.0).floor(), s % 60.0)
    } else {
        format!(
            "{} h {:02.0} min",
            (s / 3600.0).floor(),
            (s % 3600.0) / 60.0
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bars_and_durations() {
        assert_eq!(bar(0.0, 4), "    ");
        assert_eq!(bar(1.0, 4), "████");
        assert_eq!(bar(0.5, 4), "██  ");
        assert_eq!(bar(0.5625, 4), "██▎ ");
        assert_eq!(fmt_duration(125.0), "2 min 05 s");
        assert_eq!(fmt_duration(0.42), "0.4 s");
    }
}
