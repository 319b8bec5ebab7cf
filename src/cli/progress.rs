//! Progress for the terminal, with an ETA: a bar when stderr is a terminal, drawn only
//! once a task has run for a second (short tasks stay quiet); otherwise (a log file, a
//! CI job) one plain line every `LINE_EVERY`, which a bar's carriage returns would
//! garble.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;
use std::time::{Duration, Instant};

/// How often a progress line is written when stderr is not a terminal.
const LINE_EVERY: Duration = Duration::from_secs(30);

pub struct Progress {
    bar: ProgressBar,
    what: String,
    message: String,
    start: Instant,
    shown: bool,
    terminal: bool,
    last_line: Instant,
}

impl Progress {
    pub fn new(what: &str) -> Self {
        let bar = ProgressBar::with_draw_target(Some(0), ProgressDrawTarget::hidden());
        let style =
            ProgressStyle::with_template("{msg:>10} [{bar:30}] {pos}/{len} ({percent}%) ETA {eta}")
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> ");
        bar.set_style(style);
        bar.set_message(what.to_string());
        let start = Instant::now();
        Self {
            bar,
            what: what.to_string(),
            message: String::new(),
            start,
            shown: false,
            terminal: std::io::stderr().is_terminal(),
            last_line: start,
        }
    }

    pub fn update(&mut self, done: usize, total: usize) {
        self.bar.set_length(total as u64);
        self.bar.set_position(done as u64);
        let elapsed = self.start.elapsed();
        if self.terminal {
            if !self.shown && elapsed > Duration::from_secs(1) {
                self.shown = true;
                self.bar.set_draw_target(ProgressDrawTarget::stderr());
            }
        } else if self.last_line.elapsed() >= LINE_EVERY {
            self.last_line = Instant::now();
            eprintln!("{}", line(&self.what, &self.message, done, total, elapsed));
        }
    }

    pub fn set_message(&mut self, what: &str) {
        self.bar.set_message(what.to_string());
        self.message = what.to_string();
    }

    pub fn finish(self) {
        self.bar.finish_and_clear();
    }
}

/// "optimise: 120/1440 (8 %), 2m10s elapsed, ETA 23m50s, loss 0.0412".
fn line(what: &str, message: &str, done: usize, total: usize, elapsed: Duration) -> String {
    let pct = 100 * done / total.max(1);
    let eta = if done > 0 && done <= total {
        let left = elapsed.as_secs_f64() * (total - done) as f64 / done as f64;
        clock(Duration::from_secs_f64(left))
    } else {
        "unknown".into()
    };
    let mut s = format!(
        "{what}: {done}/{total} ({pct} %), {} elapsed, ETA {eta}",
        clock(elapsed)
    );
    if !message.is_empty() {
        s.push_str(", ");
        s.push_str(message);
    }
    s
}

fn clock(d: Duration) -> String {
    let s = d.as_secs();
    match s {
        0..60 => format!("{s}s"),
        60..3600 => format!("{}m{:02}s", s / 60, s % 60),
        _ => format!("{}h{:02}m", s / 3600, s % 3600 / 60),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_progress_line_gives_the_count_the_time_and_the_eta() {
        let l = line("optimise", "loss 0.5", 120, 1440, Duration::from_secs(130));
        assert_eq!(
            l,
            "optimise: 120/1440 (8 %), 2m10s elapsed, ETA 23m50s, loss 0.5"
        );
        let l = line("BEV", "", 0, 9, Duration::from_secs(4000));
        assert_eq!(l, "BEV: 0/9 (0 %), 1h06m elapsed, ETA unknown");
    }
}
