//! A byte budget on a simulated clock: the one rate limiter of the workspace.
//!
//! Bandwidth in swarm-explore is bytes per *simulated* second, so that what crosses a link per
//! step does not depend on how fast the machine runs the simulation. Two places meter bytes that
//! way: a robot paces what it offers each neighbour (robot-agent's `pacing`), and netem shapes
//! what a link carries (netem's `shaping::bandwidth`). Both use a [`ByteBudget`]: a GCRA rate
//! limiter (the `governor` crate) that reads a simulated clock ([`SimNow`]) instead of the wall
//! clock.
//!
//! One governor *cell* is one byte, or above [`MAX_CELLS_PER_S`] bytes per second a few bytes
//! ([`ByteRate`]): governor's cell period is a whole number of nanoseconds, and a period of at
//! least a microsecond keeps the rate exact to 0.1 %. How large a burst is, and what to do when
//! the budget is short, is each caller's policy.

use std::num::NonZeroU32;
use std::time::Duration;

use governor::clock::{Clock, Reference};
use governor::middleware::StateInformationMiddleware;
use governor::nanos::Nanos;
use governor::state::{InMemoryState, NotKeyed};
use governor::{Quota, RateLimiter};

/// How many steps of unused radio budget a link direction keeps, and may spend at once after
/// quiet steps (at least the largest message sent whole, [`crate::msg::largest_scan_delta_bytes`],
/// so that none waits forever): a robot's pacing per neighbour (robot-agent's `radio::station`)
/// and the airtime a direction saves on a shared channel (netem's `channel`).
pub const SAVE_STEPS: u32 = 4;

/// A simulated clock: nanoseconds since the start of the run.
pub trait SimNow: Clone {
    fn now_ns(&self) -> u64;
}

/// A [`SimNow`] as governor's clock.
#[derive(Clone, Debug)]
struct Sim<C>(C);

impl<C: SimNow> Clock for Sim<C> {
    type Instant = Nanos;

    fn now(&self) -> Nanos {
        Nanos::from(self.0.now_ns())
    }
}

/// Cell rates above this are metered in multi-byte cells.
pub const MAX_CELLS_PER_S: u64 = 1_000_000;

/// A rate in bytes per simulated second, as governor meters it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ByteRate {
    /// Bytes per simulated second (at least 1).
    pub bytes_per_s: u64,
    /// Bytes per governor cell: 1 up to [`MAX_CELLS_PER_S`] bytes per second.
    pub cell_bytes: u64,
    /// Simulated nanoseconds per cell, rounded to the nearest (at least 1).
    pub period_ns: u64,
}

impl ByteRate {
    /// The rate of `bytes_per_s` (0 reads as 1).
    pub fn new(bytes_per_s: u64) -> ByteRate {
        let rate = bytes_per_s.max(1);
        let cell_bytes = rate.div_ceil(MAX_CELLS_PER_S);
        // 1e9 · cell_bytes is exact in f64 and the quotient correctly rounded, so this is the
        // nearest integer to the exact period for every rate below 2^53 / 1e9 cells.
        let period_ns = ((1e9 * cell_bytes as f64 / rate as f64).round() as u64).max(1);
        ByteRate {
            bytes_per_s: rate,
            cell_bytes,
            period_ns,
        }
    }

    /// Whole cells that `bytes` fill, rounded up, saturating at `u32::MAX`.
    pub fn cells_up(&self, bytes: u64) -> u32 {
        u32::try_from(bytes.div_ceil(self.cell_bytes)).unwrap_or(u32::MAX)
    }

    /// Whole cells within `bytes`, rounded down, saturating at `u32::MAX`.
    pub fn cells_down(&self, bytes: u64) -> u32 {
        u32::try_from(bytes / self.cell_bytes).unwrap_or(u32::MAX)
    }
}

/// What [`ByteBudget::take`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Take {
    /// The cells were taken; `remaining` cells could be taken at once now.
    Taken { remaining: u32 },
    /// Nothing was taken: the cells are not all there before simulated time `at_ns`, which is
    /// `wait_ns` after the clock's time when asked.
    NotYet { at_ns: u64, wait_ns: u64 },
    /// Nothing was taken: more cells than the burst were asked for.
    OverBurst,
}

/// A budget of `rate` with bursts of `burst_cells` cells on the simulated clock `C`. A new budget
/// is full (one whole burst).
#[derive(Debug)]
pub struct ByteBudget<C: SimNow> {
    rate: ByteRate,
    burst_cells: u32,
    clock: C,
    limiter: RateLimiter<NotKeyed, InMemoryState, Sim<C>, StateInformationMiddleware>,
}

impl<C: SimNow> ByteBudget<C> {
    /// A full budget; a burst of 0 cells reads as 1.
    pub fn new(rate: ByteRate, burst_cells: u32, clock: C) -> ByteBudget<C> {
        let burst_cells = burst_cells.max(1);
        let quota = Quota::with_period(Duration::from_nanos(rate.period_ns))
            .unwrap_or_else(|| Quota::per_second(NonZeroU32::MIN))
            .allow_burst(NonZeroU32::new(burst_cells).unwrap_or(NonZeroU32::MIN));
        let limiter = RateLimiter::direct_with_clock(quota, Sim(clock.clone()))
            .with_middleware::<StateInformationMiddleware>();
        ByteBudget {
            rate,
            burst_cells,
            clock,
            limiter,
        }
    }

    pub fn rate(&self) -> ByteRate {
        self.rate
    }

    pub fn burst_cells(&self) -> u32 {
        self.burst_cells
    }

    pub fn clock(&self) -> &C {
        &self.clock
    }

    /// Takes `cells` cells (0 reads as 1) if they are all there now, else nothing.
    pub fn take(&self, cells: u32) -> Take {
        match self
            .limiter
            .check_n(NonZeroU32::new(cells).unwrap_or(NonZeroU32::MIN))
        {
            Ok(Ok(snapshot)) => Take::Taken {
                remaining: snapshot.remaining_burst_capacity(),
            },
            Ok(Err(not_until)) => {
                let wait = not_until.wait_time_from(Sim(self.clock.clone()).now());
                Take::NotYet {
                    at_ns: not_until
                        .earliest_possible()
                        .duration_since(Nanos::from(0))
                        .as_u64(),
                    wait_ns: u64::try_from(wait.as_nanos()).unwrap_or(u64::MAX),
                }
            }
            Err(_) => Take::OverBurst,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::cell::Cell;
    use std::rc::Rc;

    #[derive(Clone, Default)]
    struct Manual(Rc<Cell<u64>>);

    impl SimNow for Manual {
        fn now_ns(&self) -> u64 {
            self.0.get()
        }
    }

    #[test]
    fn rates_are_metered_in_cells_of_at_least_a_microsecond() {
        assert_eq!(
            ByteRate::new(1000),
            ByteRate {
                bytes_per_s: 1000,
                cell_bytes: 1,
                period_ns: 1_000_000
            }
        );
        assert_eq!(ByteRate::new(0), ByteRate::new(1));
        let fast = ByteRate::new(3_000_001);
        assert_eq!((fast.cell_bytes, fast.period_ns), (4, 1333));
        assert_eq!((fast.cells_up(9), fast.cells_down(9)), (3, 2));
        assert_eq!(ByteRate::new(3).period_ns, 333_333_333);
        assert_eq!(ByteRate::new(2_000_000_000).period_ns, 1000);
    }

    #[test]
    fn a_budget_refills_at_its_rate_on_the_simulated_clock_only() {
        let clock = Manual::default();
        let b = ByteBudget::new(ByteRate::new(1000), 500, clock.clone());
        assert_eq!(b.take(400), Take::Taken { remaining: 100 });
        assert_eq!(
            b.take(101),
            Take::NotYet {
                at_ns: 1_000_000,
                wait_ns: 1_000_000
            }
        );
        assert_eq!(b.take(501), Take::OverBurst);
        // Wall time does not refill it; simulated time does, up to the burst.
        std::thread::sleep(Duration::from_millis(5));
        assert_eq!(
            b.take(101),
            Take::NotYet {
                at_ns: 1_000_000,
                wait_ns: 1_000_000
            }
        );
        clock.0.set(300_000_000);
        assert_eq!(b.take(400), Take::Taken { remaining: 0 });
        clock.0.set(10_000_000_000);
        assert_eq!(b.take(1), Take::Taken { remaining: 499 });
    }
}
