//! Progress of a long run: a live bar (steps, simulated time, rate, ETA) when stderr is a
//! terminal, otherwise a quiet log line to stderr every 10 % of the run or every `log_interval`.

use std::io::IsTerminal;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// How progress is shown.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ProgressMode {
    /// Bar on a terminal, log lines otherwise.
    Auto,
    Bar,
    Log,
    /// Nothing at all.
    Quiet,
}

/// Reports progress of a run of `total_steps` steps.
pub struct Progress {
    bar: Option<ProgressBar>,
    log: bool,
    total: u64,
    start_step: u64,
    started: Instant,
    last_log: Instant,
    last_decile: u64,
    log_interval: Duration,
    /// Simulated time unit shown after the time (e.g. `"s"`, `"ms"`).
    time_unit: String,
    time_scale: f64,
}

fn fmt_duration(d: Duration) -> String {
    let s = d.as_secs();
    if s >= 3600 {
        format!("{}h{:02}m", s / 3600, (s % 3600) / 60)
    } else if s >= 60 {
        format!("{}m{:02}s", s / 60, s % 60)
    } else {
        format!("{:.1}s", d.as_secs_f64())
    }
}

impl Progress {
    /// A reporter for a run from `start_step` (non-zero after a resume) to `total_steps`.
    /// Simulated times passed to [`update`](Self::update) are multiplied by `time_scale` and
    /// shown with `time_unit`.
    pub fn new(total_steps: u64, start_step: u64, mode: ProgressMode, time_scale: f64, time_unit: &str) -> Self {
        let tty = std::io::stderr().is_terminal();
        let (bar, log) = match mode {
            ProgressMode::Auto if tty => (true, false),
            ProgressMode::Auto | ProgressMode::Log => (false, true),
            ProgressMode::Bar => (true, false),
            ProgressMode::Quiet => (false, false),
        };
        let bar = bar.then(|| {
            let pb = ProgressBar::with_draw_target(Some(total_steps), ProgressDrawTarget::stderr());
            let style =
                ProgressStyle::with_template("{bar:30.cyan/blue} {pos}/{len} steps  {msg}  {per_sec}  ETA {eta}")
                    .unwrap_or_else(|_| ProgressStyle::default_bar());
            pb.set_style(style);
            pb.set_position(start_step);
            pb
        });
        let now = Instant::now();
        Progress {
            bar,
            log,
            total: total_steps,
            start_step,
            started: now,
            last_log: now,
            last_decile: (start_step * 10).checked_div(total_steps).unwrap_or(0),
            log_interval: Duration::from_secs(60),
            time_unit: time_unit.to_string(),
            time_scale,
        }
    }

    /// Log at least this often when not on a terminal (default 60 s).
    pub fn with_log_interval(mut self, interval: Duration) -> Self {
        self.log_interval = interval;
        self
    }

    /// The log line for `step` (exposed for tests and for callers with their own logger).
    pub fn status_line(&self, step: u64, sim_time: f64) -> String {
        let elapsed = self.started.elapsed();
        let done = step.saturating_sub(self.start_step);
        let rate = done as f64 / elapsed.as_secs_f64().max(1e-9);
        let left = self.total.saturating_sub(step);
        let eta = if rate > 0.0 {
            fmt_duration(Duration::from_secs_f64((left as f64 / rate).min(1e9)))
        } else {
            "?".to_string()
        };
        let pct = if self.total > 0 {
            100.0 * step as f64 / self.total as f64
        } else {
            100.0
        };
        format!(
            "step {step}/{} ({pct:.0}%), t = {:.6e} {}, {rate:.1} steps/s, elapsed {}, ETA {eta}",
            self.total,
            sim_time * self.time_scale,
            self.time_unit,
            fmt_duration(elapsed)
        )
    }

    /// Reports that `step` is done at simulated time `sim_time`. Cheap: call it every step.
    pub fn update(&mut self, step: u64, sim_time: f64) {
        if let Some(bar) = &self.bar {
            bar.set_position(step);
            bar.set_message(format!("t = {:.4e} {}", sim_time * self.time_scale, self.time_unit));
        } else if self.log {
            let decile = (step * 10).checked_div(self.total).unwrap_or(10);
            if decile > self.last_decile || self.last_log.elapsed() >= self.log_interval {
                self.last_decile = decile;
                self.last_log = Instant::now();
                eprintln!("{}", self.status_line(step, sim_time));
            }
        }
    }

    /// Prints a message without breaking the bar.
    pub fn println(&self, msg: &str) {
        match &self.bar {
            Some(bar) => bar.println(msg),
            None => {
                if self.log {
                    eprintln!("{msg}");
                }
            }
        }
    }

    /// Ends the report with a final line.
    pub fn finish(&mut self, step: u64, sim_time: f64) {
        let line = self.status_line(step, sim_time);
        if let Some(bar) = self.bar.take() {
            bar.finish_and_clear();
            eprintln!("{line}");
        } else if self.log {
            eprintln!("{line}");
        }
    }
}
