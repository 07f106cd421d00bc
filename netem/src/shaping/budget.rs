//! Bandwidth: bytes pass only as fast as a byte budget on the simulated clock allows (docs/design.md
//! §2, §5: "per-link rate (each direction) or shared medium (one budget for all links, the
//! thesis's pessimistic model §5.1) via governor on the simulated clock").
//!
//! A `Budget` is the workspace's byte budget on a simulated clock ([`proto::budget`], a governor
//! GCRA rate limiter; the robots pace their sending with the same one) read on netem's `SimClock`.
//! One governor *cell* is one byte (or, above 1 MB/s, a few bytes, so that governor's
//! whole-nanosecond cell period stays exact to 0.1 %). The burst
//! is one step's worth of bytes (`rate × step_seconds`): in lockstep, simulated time jumps by a
//! step at a time, so that is what lets a step's full budget through at the step boundary, and
//! an idle link never saves up more than one step.
//!
//! Governor decides *whether* bytes may pass and *when* they could; it cannot wait on a clock
//! that only advances from outside (its `until_ready` needs a wall clock). So waiting is ours:
//! the stage sleeps until governor's `earliest_possible()` instant on the simulated clock
//! (`SimClock::sleep_until`, a `watch` of the step time in lockstep, a tokio sleep in realtime).
//! While it waits it does not read: the buffer fills and the sender is pushed back by TCP.

use std::sync::{Arc, Mutex};

use proto::budget::{ByteBudget, ByteRate, Take};

use proto::clock::{SimClock, SimTime};

/// Smallest piece the stage waits for when it has more to send (bytes): keeps realtime links
/// from trickling out one byte per governor period.
const MIN_QUANTUM_BYTES: u64 = 256;

/// A byte budget: `rate` bytes per simulated second, bursts of one step.
#[derive(Debug)]
pub struct Budget {
    quantum_cells: u32,
    /// Largest grant in cells: a shared medium hands out a quantum at a time so that the links
    /// that share it take turns.
    max_grant_cells: u32,
    shared: bool,
    /// Locked for the whole of [`Budget::try_take`], whose checks belong together.
    budget: Mutex<ByteBudget<SimClock>>,
}

impl Budget {
    /// A budget of `rate_bytes_per_s` (> 0) with a burst of `burst_s` simulated seconds (one step).
    /// `shared`: several links draw from it (a shared medium).
    pub fn new(rate_bytes_per_s: u64, burst_s: f64, shared: bool, clock: SimClock) -> Arc<Budget> {
        let rate = ByteRate::new(rate_bytes_per_s);
        let burst_bytes = (rate.bytes_per_s as f64 * burst_s.max(0.0)).round() as u64;
        let burst_cells = rate.cells_down(burst_bytes).max(1);
        let quantum_bytes = MIN_QUANTUM_BYTES.max(rate.bytes_per_s / 50);
        let quantum_cells = rate.cells_up(quantum_bytes).clamp(1, burst_cells);
        Arc::new(Budget {
            quantum_cells,
            max_grant_cells: if shared { quantum_cells } else { burst_cells },
            shared,
            budget: Mutex::new(ByteBudget::new(rate, burst_cells, clock)),
        })
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, ByteBudget<SimClock>> {
        self.budget.lock().unwrap_or_else(|p| p.into_inner())
    }

    pub fn rate_bytes_per_s(&self) -> u64 {
        self.lock().rate().bytes_per_s
    }

    /// The most bytes one step can grant.
    pub fn burst_bytes(&self) -> u64 {
        let b = self.lock();
        u64::from(b.burst_cells()) * b.rate().cell_bytes
    }

    pub fn is_shared(&self) -> bool {
        self.shared
    }

    /// Takes up to `want` bytes of budget now: `Ok(granted)` with `1 ≤ granted ≤ want`, or
    /// `Err(t)`: nothing can be granted before simulated time `t`.
    pub fn try_take(&self, want: usize) -> Result<usize, SimTime> {
        let b = self.lock();
        let ByteRate {
            cell_bytes,
            period_ns,
            ..
        } = b.rate();
        let want = want.max(1) as u64;
        let want_cells = want
            .div_ceil(cell_bytes)
            .min(u64::from(self.max_grant_cells)) as u32;
        let q = want_cells.min(self.quantum_cells).max(1);
        let granted_cells = match b.take(q) {
            Take::Taken { remaining } => {
                let extra = (want_cells - q).min(remaining);
                if extra > 0 && matches!(b.take(extra), Take::Taken { .. }) {
                    q + extra
                } else {
                    q
                }
            }
            Take::NotYet { at_ns, wait_ns } => {
                // Fewer than `q` cells are there; take what is, so that a leftover smaller than a
                // quantum is not lost when a lockstep step refills the bucket to its burst.
                let avail = u64::from(q).saturating_sub(wait_ns.div_ceil(period_ns)) as u32;
                if avail > 0 && matches!(b.take(avail), Take::Taken { .. }) {
                    avail
                } else {
                    return Err(SimTime(at_ns));
                }
            }
            // `q` never exceeds the burst; if it somehow did, retry after one period.
            Take::OverBurst => return Err(b.clock().now().saturating_add_ns(period_ns)),
        };
        Ok((u64::from(granted_cells) * cell_bytes).min(want) as usize)
    }
}

/// Budget already taken from some budgets of a chain but not yet used, because another budget
/// of the chain refused: kept for the next attempt instead of being wasted.
#[derive(Debug, Default)]
pub struct Credits(Vec<(Arc<Budget>, usize)>);

/// Takes up to `want` bytes from *every* budget of `budgets` (a byte must be granted by each):
/// `Ok(n)` with `1 ≤ n ≤ want`, or `Err(t)`: retry at simulated time `t`.
pub fn take_all(
    budgets: &[Arc<Budget>],
    want: usize,
    credits: &mut Credits,
) -> Result<usize, SimTime> {
    credits
        .0
        .retain(|(c, _)| budgets.iter().any(|b| Arc::ptr_eq(b, c)));
    let mut n = want;
    for b in budgets {
        let idx = match credits.0.iter().position(|(c, _)| Arc::ptr_eq(b, c)) {
            Some(i) => i,
            None => {
                credits.0.push((Arc::clone(b), 0));
                credits.0.len() - 1
            }
        };
        if credits.0[idx].1 == 0 {
            credits.0[idx].1 = b.try_take(n)?;
        }
        n = n.min(credits.0[idx].1);
    }
    for c in &mut credits.0 {
        c.1 -= n.min(c.1);
    }
    Ok(n)
}
