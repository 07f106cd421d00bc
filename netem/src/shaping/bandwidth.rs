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
use tokio::sync::{mpsc, watch};

use super::{Chunk, DirShape};
use crate::clock::{SimClock, SimTime};

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

/// The bandwidth effect: splits each chunk into the pieces its budgets grant, stamping each
/// piece with the simulated time it was granted.
pub async fn bandwidth(
    mut input: mpsc::Receiver<Chunk>,
    output: mpsc::Sender<Chunk>,
    mut shape: watch::Receiver<DirShape>,
    clock: SimClock,
) {
    let mut credits = Credits::default();
    while let Some(mut chunk) = input.recv().await {
        while !chunk.is_empty() {
            let (budgets, stalled) = {
                let s = shape.borrow_and_update();
                (s.budgets.clone(), s.stalled)
            };
            // A stalled (blackholed) direction spends no budget: bytes granted now would only
            // pile up behind the stall and leave in a burst when it ends.
            if stalled {
                if shape.wait_for(|s| !s.stalled).await.is_err() {
                    return;
                }
                continue;
            }
            match take_all(&budgets, chunk.len(), &mut credits) {
                Ok(n) => {
                    let mut piece = chunk.split_to(n);
                    piece.stamp = clock.now();
                    if output.send(piece).await.is_err() {
                        return;
                    }
                    if budgets.iter().any(|b| b.is_shared()) {
                        // Let the other links of the medium have their turn.
                        tokio::task::yield_now().await;
                    }
                }
                Err(at) => {
                    tokio::select! {
                        () = clock.sleep_until(at) => {}
                        changed = shape.changed() => if changed.is_err() { return },
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::harness::{read_for, run};
    use super::*;
    use std::time::Duration;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    fn clock_at(step: u64, step_s: f64, c: &SimClock) {
        c.advance_to(SimTime::from_secs_f64(step as f64 * step_s));
    }

    #[test]
    fn a_lockstep_step_grants_exactly_its_budget_whatever_the_request_sizes() {
        let c = SimClock::lockstep();
        let b = Budget::new(1000, 1.0, false, c.clone());
        let mut total = 0;
        for step in 0..40u64 {
            clock_at(step, 1.0, &c);
            let mut this_step = 0;
            // Odd request sizes leave leftovers smaller than a quantum.
            for want in [300usize, 17, 999, 5000].iter().cycle().take(50) {
                match b.try_take(*want) {
                    Ok(n) => {
                        assert!(n >= 1 && n <= *want);
                        this_step += n;
                    }
                    Err(at) => assert!(at > c.now()),
                }
            }
            assert_eq!(this_step, 1000, "step {step}");
            total += this_step;
        }
        assert_eq!(total, 40_000);
    }

    #[tokio::test]
    async fn a_stalled_direction_spends_no_budget() {
        let clock = SimClock::lockstep();
        let budget = Budget::new(1000, 1.0, false, clock.clone());
        let shape = DirShape {
            budgets: vec![Arc::clone(&budget)],
            stalled: true,
            ..DirShape::default()
        };
        let mut h = run(shape, clock.clone(), 8192, |i, o, s, c| {
            bandwidth(i, o, s, c)
        });
        h.input.write_all(&[0u8; 5000]).await.unwrap();
        tokio::time::sleep(Duration::from_millis(20)).await;
        clock_at(3, 1.0, &clock);
        tokio::time::sleep(Duration::from_millis(20)).await;
        assert_eq!(
            budget.try_take(10_000),
            Ok(1000),
            "the whole step's budget is still there"
        );
        h.shape.send_modify(|s| s.stalled = false);
        clock_at(4, 1.0, &clock);
        let got = read_for(&mut h.output, Duration::from_millis(50))
            .await
            .len();
        assert_eq!(got, 1000, "one step's worth after the stall, not a burst");
    }

    #[test]
    fn an_idle_link_saves_up_at_most_one_step() {
        let c = SimClock::lockstep();
        let b = Budget::new(500, 1.0, false, c.clone());
        clock_at(10, 1.0, &c);
        assert_eq!(b.try_take(10_000), Ok(500));
        assert!(b.try_take(1).is_err());
    }

    #[test]
    fn high_rates_use_multi_byte_cells_and_stay_exact() {
        let c = SimClock::lockstep();
        let b = Budget::new(300_000_000, 0.5, false, c.clone());
        let mut got = 0;
        for step in 0..10u64 {
            clock_at(step, 0.5, &c);
            while let Ok(n) = b.try_take(1 << 30) {
                got += n as u64;
            }
        }
        let want = 10 * 150_000_000u64;
        assert!(got.abs_diff(want) * 1000 <= want, "{got} vs {want}");
    }

    #[test]
    fn a_chain_grants_the_minimum_and_keeps_unused_credit() {
        let c = SimClock::lockstep();
        let big = Budget::new(10_000, 1.0, false, c.clone());
        let small = Budget::new(100, 1.0, false, c.clone());
        let chain = [Arc::clone(&big), Arc::clone(&small)];
        let mut credits = Credits::default();
        let mut got = 0;
        while let Ok(n) = take_all(&chain, 4000, &mut credits) {
            got += n;
        }
        assert_eq!(got, 100);
        // The big budget lent 4000 once; the unused 3900 stay as credit, not re-taken.
        assert_eq!(big.try_take(100_000), Ok(6000));
    }

    /// Feeds `rate × 10` bytes per step for `steps` steps and returns the bytes delivered during
    /// steps `warmup..steps`, driving the clock with `pause` of wall time per step.
    async fn delivered_per_step(rate: u64, steps: u64, warmup: u64, pause: Duration) -> f64 {
        let clock = SimClock::lockstep();
        let budget = Budget::new(rate, 1.0, false, clock.clone());
        let shape = DirShape {
            budgets: vec![budget],
            ..DirShape::default()
        };
        let h = run(shape, clock.clone(), 16 * 1024, |i, o, s, c| {
            bandwidth(i, o, s, c)
        });
        let mut input = h.input;
        let writer = tokio::spawn(async move {
            let block = vec![0u8; 4096];
            while input.write_all(&block).await.is_ok() {}
        });
        let (count_tx, count_rx) = watch::channel(0u64);
        let mut out = h.output;
        let reader = tokio::spawn(async move {
            let mut buf = vec![0u8; 65536];
            let mut n_total = 0u64;
            while let Ok(n) = out.read(&mut buf).await {
                if n == 0 {
                    break;
                }
                n_total += n as u64;
                count_tx.send_replace(n_total);
            }
        });
        let mut at_warmup = 0;
        for step in 0..=steps {
            if step == warmup {
                at_warmup = *count_rx.borrow();
            }
            clock_at(step, 1.0, &clock);
            tokio::time::sleep(pause).await;
            assert!(h.buffer.held() <= 16 * 1024);
        }
        let delivered = *count_rx.borrow() - at_warmup;
        writer.abort();
        reader.abort();
        h.task.abort();
        // Bytes granted at steps warmup..=steps arrive by the end: that is steps - warmup + 1.
        delivered as f64 / (steps - warmup + 1) as f64
    }

    #[tokio::test]
    async fn rate_holds_within_5_percent_at_any_simulation_speed() {
        for rate in [1000u64, 10_000] {
            for pause in [Duration::from_millis(1), Duration::from_millis(15)] {
                let per_s = delivered_per_step(rate, 40, 5, pause).await;
                let err = (per_s - rate as f64).abs() / rate as f64;
                assert!(err <= 0.05, "rate {rate} pause {pause:?}: {per_s} B/sim s");
            }
        }
    }

    #[tokio::test(start_paused = true)]
    async fn realtime_clock_with_speedup_paces_by_simulated_seconds() {
        let clock = SimClock::realtime(4.0);
        let budget = Budget::new(2000, 1.0, false, clock.clone());
        let shape = DirShape {
            budgets: vec![budget],
            ..DirShape::default()
        };
        let mut h = run(shape, clock.clone(), 8192, |i, o, s, c| {
            bandwidth(i, o, s, c)
        });
        let mut input = h.input;
        tokio::spawn(async move {
            let block = vec![0u8; 1024];
            while input.write_all(&block).await.is_ok() {}
        });
        // 10 wall seconds = 40 simulated seconds = 80 000 bytes (+ the first burst of 2000).
        let got = read_for(&mut h.output, Duration::from_secs(10)).await.len() as f64;
        assert!((got - 82_000.0).abs() / 82_000.0 < 0.05, "{got}");
    }
}
