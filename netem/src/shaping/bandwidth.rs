//! The bandwidth effect: each chunk passes in the pieces its budgets ([`crate::shaping::budget`])
//! grant, each stamped with the simulated time it was granted.

use tokio::sync::{mpsc, watch};

use crate::shaping::budget::{take_all, Credits};
use crate::shaping::chunk::{Chunk, DirShape};
use proto::clock::SimClock;
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
    use super::*;
    use crate::shaping::budget::Budget;
    use crate::shaping::harness::{read_for, run};
    use proto::clock::SimTime;
    use std::sync::Arc;
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
