//! Progress on stderr, for `swarm run` and `swarm sweep`: the current state as one line updated
//! in place on a terminal, or as a line of its own elsewhere (logs, CI), at most as often as the
//! caller asks; events as lines that stay.

use std::io::IsTerminal;
use std::time::{Duration, Instant};

pub struct Progress {
    tty: bool,
    quiet: bool,
    /// Least time between two shown states: on a terminal, and elsewhere.
    every: (Duration, Duration),
    last: Instant,
}

impl Progress {
    /// A run's progress: updated at most every 200 ms on a terminal, every 5 s elsewhere;
    /// `quiet` shows events only.
    pub fn new(quiet: bool) -> Progress {
        Progress {
            tty: std::io::stderr().is_terminal(),
            quiet,
            every: (Duration::from_millis(200), Duration::from_secs(5)),
            last: Instant::now(),
        }
    }

    /// Progress that shows every state (a sweep's: one per finished run).
    pub fn every_state() -> Progress {
        Progress {
            every: (Duration::ZERO, Duration::ZERO),
            ..Progress::new(false)
        }
    }

    /// Shows the current state, unless the last one was shown too recently.
    pub fn show(&mut self, line: &str) {
        if self.quiet {
            return;
        }
        let every = if self.tty { self.every.0 } else { self.every.1 };
        if self.last.elapsed() >= every {
            self.last = Instant::now();
            if self.tty {
                eprint!("\r\x1b[2K{line}");
            } else {
                eprintln!("{line}");
            }
        }
    }

    /// A line that stays (shown also when quiet).
    pub fn event(&mut self, line: &str) {
        if self.tty && !self.quiet {
            eprint!("\r\x1b[2K");
        }
        eprintln!("{line}");
    }

    /// Ends the line updated in place (on a terminal), so that what follows starts anew.
    pub fn finish(&mut self) {
        if self.tty && !self.quiet {
            eprintln!();
        }
    }
}
