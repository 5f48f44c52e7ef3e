//! Progress reporting of long runs: a progress bar on a terminal (`indicatif`), a plain
//! line every ~30 s otherwise (logs, CI, batch jobs); the iteration rate over a moving
//! window (for the ETA) and durations for people.

use std::io::IsTerminal as _;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// Seconds between the plain progress lines written when stderr is not a terminal
/// (`SVRASTER_PROGRESS_EVERY` overrides: seconds > 0).
const PLAIN_EVERY_S: f64 = 30.0;

/// The plain lines' period: `SVRASTER_PROGRESS_EVERY` seconds, else [`PLAIN_EVERY_S`].
fn plain_every_s() -> f64 {
    std::env::var("SVRASTER_PROGRESS_EVERY")
        .ok()
        .and_then(|v| v.parse::<f64>().ok())
        .filter(|v| v.is_finite() && *v > 0.0)
        .unwrap_or(PLAIN_EVERY_S)
}

/// Progress of `total` steps of one job on stderr: an `indicatif` bar when stderr is a
/// terminal; otherwise a plain line for the first step, then at most one every ~30 s,
/// and one for the last step.
pub(super) struct Progress {
    bar: Option<ProgressBar>,
    label: String,
    total: u64,
    last_line: Option<Instant>,
    quiet: bool,
    every_s: f64,
    /// Set by [`Progress::line_due`]: the step whose plain line was promised (the
    /// caller measured its values for it); once used, lines come only at promised steps.
    promised: Option<Option<u64>>,
}

impl Progress {
    pub(super) fn new(label: &str, total: u64) -> Self {
        let bar = std::io::stderr().is_terminal().then(|| {
            let b = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr());
            let style =
                ProgressStyle::with_template("{prefix} {bar:24.cyan/blue} {pos}/{len} {msg}")
                    .expect("a valid progress template")
                    .progress_chars("=> ");
            b.set_style(style);
            b.set_prefix(label.to_string());
            b
        });
        Progress {
            bar,
            label: label.into(),
            total,
            last_line: None,
            quiet: false,
            every_s: plain_every_s(),
            promised: None,
        }
    }

    /// A progress that prints nothing.
    pub(super) fn hidden() -> Self {
        Progress {
            bar: None,
            label: String::new(),
            total: 0,
            last_line: None,
            quiet: true,
            every_s: PLAIN_EVERY_S,
            promised: None,
        }
    }

    /// Step `pos` of `total` is done; `msg` says how it went (rate, loss, ETA …).
    pub(super) fn update(&mut self, pos: u64, msg: impl FnOnce() -> String) {
        if self.quiet {
            return;
        }
        if let Some(b) = &self.bar {
            b.set_position(pos);
            b.set_message(msg());
            return;
        }
        let now = Instant::now();
        let due = match self.promised {
            Some(p) => p == Some(pos) || self.last_line.is_none() || pos >= self.total,
            None => plain_line_due(
                self.last_line.map(|t| now - t),
                pos,
                self.total,
                self.every_s,
            ),
        };
        if due {
            eprintln!("{} {pos}/{} {}", self.label, self.total, msg());
            self.last_line = Some(now);
        }
    }

    /// Whether [`Progress::update`] at step `pos` is to write a plain line (never for a
    /// bar, which redraws as it likes), decided now and kept: the caller then measures
    /// the values that line shows. Once called, plain lines come only at the steps it
    /// promised (and the first and last).
    pub(super) fn line_due(&mut self, pos: u64) -> bool {
        let due = !self.quiet
            && self.bar.is_none()
            && plain_line_due(
                self.last_line.map(|t| t.elapsed()),
                pos,
                self.total,
                self.every_s,
            );
        self.promised = Some(due.then_some(pos));
        due
    }

    /// Whether a terminal bar is shown.
    pub(super) fn is_bar(&self) -> bool {
        self.bar.is_some()
    }

    /// A line of its own (an event: an adaptive step, a saved checkpoint), above the bar.
    pub(super) fn line(&self, msg: &str) {
        if self.quiet {
            return;
        }
        match &self.bar {
            Some(b) => b.println(msg),
            None => eprintln!("{msg}"),
        }
    }

    /// Replaces the bar by a plain line with its last state.
    pub(super) fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
            eprintln!(
                "{} {}/{} {}",
                self.label,
                b.position(),
                self.total,
                b.message()
            );
        }
    }
}

/// Whether a plain (non-terminal) progress line is due for step `pos` of `total`, `since`
/// the last one (None: none written yet).
fn plain_line_due(since: Option<Duration>, pos: u64, total: u64, every_s: f64) -> bool {
    match since {
        None => true,
        Some(d) => pos >= total || d.as_secs_f64() >= every_s,
    }
}

/// Iteration rate over a moving window (the last ~30 s, and never fewer than 200
/// iterations, so that one adaptive step — tens of seconds for one iteration — is
/// amortised rather than read as the rate), so the ETA follows the run's current speed
/// (the first iterations carry warm-up and a larger model) instead of its mean since the
/// start.
/// Fewest iterations the rate window spans (once the run has them).
const MIN_ITERS: u32 = 200;

pub(super) struct RateWindow {
    samples: std::collections::VecDeque<(u32, f64)>,
    window_s: f64,
}

impl RateWindow {
    pub(super) fn new(window_s: f64) -> Self {
        RateWindow {
            samples: std::collections::VecDeque::new(),
            window_s,
        }
    }

    /// Records that iteration `iter` finished at time `t` (seconds).
    pub(super) fn push(&mut self, iter: u32, t: f64) {
        self.samples.push_back((iter, t));
        while self.samples.len() > 2
            && t - self.samples[1].1 >= self.window_s
            && iter - self.samples[1].0 >= MIN_ITERS
        {
            self.samples.pop_front();
        }
    }

    /// Iterations per second over the window (NaN before two samples).
    pub(super) fn rate(&self) -> f64 {
        match (self.samples.front(), self.samples.back()) {
            (Some(a), Some(b)) if b.1 > a.1 => f64::from(b.0 - a.0) / (b.1 - a.1),
            _ => f64::NAN,
        }
    }
}

pub(super) fn fmt_duration(s: f64) -> String {
    if !s.is_finite() {
        return "?".into();
    }
    let s = s.round() as u64;
    if s >= 3600 {
        format!("{}h{:02}m", s / 3600, (s % 3600) / 60)
    } else if s >= 60 {
        format!("{}m{:02}s", s / 60, s % 60)
    } else {
        format!("{s}s")
    }
}

#[cfg(test)]
mod tests {
    use super::{plain_line_due, RateWindow, PLAIN_EVERY_S};
    use std::time::Duration;

    #[test]
    fn plain_lines_first_last_and_every_30_s() {
        let s = Duration::from_secs_f64;
        assert!(plain_line_due(None, 1, 100, PLAIN_EVERY_S));
        assert!(!plain_line_due(Some(s(29.0)), 50, 100, PLAIN_EVERY_S));
        assert!(plain_line_due(Some(s(30.0)), 50, 100, PLAIN_EVERY_S));
        assert!(plain_line_due(Some(s(0.1)), 100, 100, PLAIN_EVERY_S));
    }

    #[test]
    fn eta_follows_the_current_rate() {
        // 10 slow iterations (1 s each), then 200 fast ones (0.1 s each).
        let mut w = RateWindow::new(5.0);
        let mut t = 0.0;
        w.push(0, t);
        assert!(w.rate().is_nan());
        for i in 1..=210u32 {
            t += if i <= 10 { 1.0 } else { 0.1 };
            w.push(i, t);
        }
        // The mean since the start would say 210 / 30 s = 7 it/s; the last 200
        // iterations took 20 s.
        assert!((w.rate() - 10.0).abs() < 1e-6, "{}", w.rate());
        // One 35 s pause (an adaptive step) is amortised over the last 200 iterations,
        // not read as a rate of 1/35 it/s.
        t += 35.0;
        w.push(211, t);
        let r = w.rate();
        assert!(r > 3.0 && r < 10.0, "{r}");
        // A run that slows down for good is seen within the window.
        for i in 212..=600u32 {
            t += 1.0;
            w.push(i, t);
        }
        assert!((w.rate() - 1.0).abs() < 1e-6, "{}", w.rate());
    }
}
