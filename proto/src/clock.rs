//! The simulated clock that every byte budget is metered on (docs/design.md §2, §5): netem's
//! shaping and each robot's pacing read the same kind of clock.
//!
//! Bandwidth is specified in bytes per *simulated* second, latency in simulated milliseconds, so
//! that the bytes that can cross a link per step do not depend on how fast the machine runs the
//! simulation. Two modes, as in the world-server:
//!
//! * **lockstep**: simulated time is `step × step_seconds` and moves only when the owner calls
//!   [`SimClock::advance_to`] (netem in `Netem::on_step`, a robot's pacer at each step). Between
//!   two steps time stands still, however long the step takes on the wall clock; a waiter for a
//!   later instant sleeps on a `tokio::sync::watch` of the time until a step reaches it.
//! * **realtime**: simulated time is the wall time since the clock was made, times `speedup`; a
//!   waiter sleeps the corresponding wall duration (tokio's clock, so paused-time tests work).
//!
//! The byte budgets ([`crate::budget`]) read this clock through [`crate::budget::SimNow`].

use std::sync::Arc;
use std::time::Duration;

use tokio::sync::watch;

/// An instant of simulated time: nanoseconds since the start of the run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct SimTime(pub u64);

impl SimTime {
    pub const ZERO: SimTime = SimTime(0);

    /// Seconds to a `SimTime`; negative and NaN give zero, huge values saturate.
    pub fn from_secs_f64(s: f64) -> SimTime {
        if s.is_nan() || s <= 0.0 {
            SimTime(0)
        } else {
            // `as` saturates on overflow.
            SimTime((s * 1e9).round() as u64)
        }
    }

    pub fn as_secs_f64(self) -> f64 {
        self.0 as f64 / 1e9
    }

    pub fn saturating_add_ns(self, ns: u64) -> SimTime {
        SimTime(self.0.saturating_add(ns))
    }
}

/// A cheaply clonable handle on one simulated clock (netem's, or a robot's pacer's).
#[derive(Clone, Debug)]
pub struct SimClock {
    inner: Arc<Inner>,
}

#[derive(Debug)]
struct Inner {
    mode: Mode,
    /// Lockstep: the current time. Realtime: unused except as a wake-up channel.
    now_ns: watch::Sender<u64>,
}

#[derive(Debug)]
enum Mode {
    Lockstep,
    Realtime {
        start: tokio::time::Instant,
        speedup: f64,
    },
}

impl crate::budget::SimNow for SimClock {
    fn now_ns(&self) -> u64 {
        self.now().0
    }
}

impl SimClock {
    /// A clock at time zero that only moves through [`SimClock::advance_to`].
    pub fn lockstep() -> SimClock {
        SimClock {
            inner: Arc::new(Inner {
                mode: Mode::Lockstep,
                now_ns: watch::Sender::new(0),
            }),
        }
    }

    /// A clock that runs `speedup` times faster than the wall clock from now on. A speed-up that is
    /// not a positive finite number is taken as 1.
    pub fn realtime(speedup: f64) -> SimClock {
        let speedup = if speedup.is_finite() && speedup > 0.0 {
            speedup
        } else {
            1.0
        };
        SimClock {
            inner: Arc::new(Inner {
                mode: Mode::Realtime {
                    start: tokio::time::Instant::now(),
                    speedup,
                },
                now_ns: watch::Sender::new(0),
            }),
        }
    }

    pub fn is_lockstep(&self) -> bool {
        matches!(self.inner.mode, Mode::Lockstep)
    }

    /// The current simulated time.
    pub fn now(&self) -> SimTime {
        match &self.inner.mode {
            Mode::Lockstep => SimTime(*self.inner.now_ns.borrow()),
            Mode::Realtime { start, speedup } => {
                SimTime::from_secs_f64(start.elapsed().as_secs_f64() * speedup)
            }
        }
    }

    /// Lockstep: moves the time forward to `t` and wakes every waiter whose instant has come.
    /// Time never goes back (an older `t` is ignored). Realtime: does nothing.
    pub fn advance_to(&self, t: SimTime) {
        if self.is_lockstep() {
            self.inner.now_ns.send_if_modified(|now| {
                if t.0 > *now {
                    *now = t.0;
                    true
                } else {
                    false
                }
            });
        }
    }

    /// Completes once the simulated time is at least `t`.
    pub async fn sleep_until(&self, t: SimTime) {
        match &self.inner.mode {
            Mode::Lockstep => {
                let mut rx = self.inner.now_ns.subscribe();
                // The sender lives as long as `self`, so this cannot fail.
                let _ = rx.wait_for(|&now| now >= t.0).await;
            }
            Mode::Realtime { speedup, .. } => loop {
                let now = self.now();
                if now >= t {
                    return;
                }
                let wall_s = (t.0 - now.0) as f64 / 1e9 / speedup;
                // Round up to the next microsecond so that we do not wake a hair too early and spin.
                let wall = Duration::from_secs_f64(wall_s.min(1e9)) + Duration::from_micros(1);
                tokio::time::sleep(wall).await;
            },
        }
    }

    /// Completes after `ns` simulated nanoseconds.
    pub async fn sleep_ns(&self, ns: u64) {
        let t = self.now().saturating_add_ns(ns);
        self.sleep_until(t).await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn lockstep_time_moves_only_forward_and_only_when_told() {
        let c = SimClock::lockstep();
        assert_eq!(c.now(), SimTime::ZERO);
        c.advance_to(SimTime(5));
        c.advance_to(SimTime(3));
        assert_eq!(c.now(), SimTime(5));
        tokio::time::sleep(Duration::from_millis(5)).await;
        assert_eq!(
            c.now(),
            SimTime(5),
            "wall time does not move a lockstep clock"
        );
    }

    #[tokio::test]
    async fn lockstep_sleeper_wakes_when_a_step_reaches_its_instant() {
        let c = SimClock::lockstep();
        let c2 = c.clone();
        let waiter = tokio::spawn(async move { c2.sleep_until(SimTime(2_000)).await });
        tokio::task::yield_now().await;
        c.advance_to(SimTime(1_000));
        tokio::time::sleep(Duration::from_millis(10)).await;
        assert!(!waiter.is_finished());
        c.advance_to(SimTime(2_500));
        tokio::time::timeout(Duration::from_secs(2), waiter)
            .await
            .expect("woken")
            .expect("no panic");
    }

    #[tokio::test(start_paused = true)]
    async fn realtime_runs_speedup_times_the_wall_clock() {
        let c = SimClock::realtime(10.0);
        tokio::time::advance(Duration::from_millis(100)).await;
        let now = c.now().as_secs_f64();
        assert!((now - 1.0).abs() < 1e-3, "{now}");
        let before = tokio::time::Instant::now();
        c.sleep_until(SimTime::from_secs_f64(3.0)).await;
        let waited = before.elapsed().as_secs_f64();
        // tokio's timer has millisecond resolution.
        assert!((waited - 0.2).abs() < 2.5e-3, "{waited}");
    }

    #[test]
    fn conversions_saturate() {
        assert_eq!(SimTime::from_secs_f64(-1.0), SimTime(0));
        assert_eq!(SimTime::from_secs_f64(f64::NAN), SimTime(0));
        assert_eq!(SimTime::from_secs_f64(1.5), SimTime(1_500_000_000));
        assert_eq!(SimTime::from_secs_f64(1e300), SimTime(u64::MAX));
    }
}
