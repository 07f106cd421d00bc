//! Latency and jitter: each piece is held until its send time plus a delay on the simulated clock
//! (toxiproxy's `latency` toxic: `latency` ± uniform `jitter` milliseconds; docs/design.md §5
//! "optional latency + jitter").
//!
//! A TCP stream must not reorder, so a piece is never released before the one ahead of it:
//! release times are made monotonic. Pieces wait in the bounded channel in front of this stage,
//! which is what lets a link keep sending while earlier bytes are still "on the air".
//! In lockstep, simulated time moves a whole step at a time, so any latency > 0 delivers at the
//! first step boundary at or after the due time: latency is quantized to steps (use realtime mode
//! for sub-step latencies).

use tokio::sync::{mpsc, watch};

use crate::shaping::chunk::{Chunk, DirShape, Rng};
use proto::clock::{SimClock, SimTime};

/// The delay of one piece: `latency ± U(jitter)`, never negative.
pub fn delay_ns(latency_ns: u64, jitter_ns: u64, rng: &mut Rng) -> u64 {
    if jitter_ns == 0 {
        return latency_ns;
    }
    let span = jitter_ns.saturating_mul(2).saturating_add(1);
    let offset = rng.next_u64() % span;
    (latency_ns.saturating_add(offset)).saturating_sub(jitter_ns)
}

/// The latency effect.
pub async fn latency(
    mut input: mpsc::Receiver<Chunk>,
    output: mpsc::Sender<Chunk>,
    shape: watch::Receiver<DirShape>,
    clock: SimClock,
    mut rng: Rng,
) {
    let mut last_due = SimTime::ZERO;
    while let Some(chunk) = input.recv().await {
        let (lat, jit) = {
            let s = shape.borrow();
            (s.latency_ns, s.jitter_ns)
        };
        if lat > 0 || jit > 0 || last_due > clock.now() {
            let due = chunk
                .stamp
                .saturating_add_ns(delay_ns(lat, jit, &mut rng))
                .max(last_due);
            last_due = due;
            clock.sleep_until(due).await;
        }
        if output.send(chunk).await.is_err() {
            return;
        }
    }
}

/// [`latency`] in the harness's shape (seed fixed).
#[cfg(test)]
pub async fn latency_effect(
    input: mpsc::Receiver<Chunk>,
    output: mpsc::Sender<Chunk>,
    shape: watch::Receiver<DirShape>,
    clock: SimClock,
) {
    latency(input, output, shape, clock, Rng::new(9)).await;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shaping::harness::{read_for, run};
    use std::time::Duration;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    #[test]
    fn delay_stays_within_latency_plus_minus_jitter() {
        let mut rng = Rng::new(1);
        for _ in 0..10_000 {
            let d = delay_ns(100, 30, &mut rng);
            assert!((70..=130).contains(&d));
        }
        assert_eq!(delay_ns(5, 0, &mut rng), 5);
        assert!(delay_ns(5, 50, &mut rng) <= 55);
    }

    #[tokio::test]
    async fn lockstep_latency_holds_bytes_until_the_clock_reaches_their_due_time() {
        let shape = DirShape {
            latency_ns: 1_500_000_000,
            ..DirShape::default()
        };
        let clock = SimClock::lockstep();
        let mut h = run(shape, clock.clone(), 4096, latency_effect);
        h.input.write_all(b"ping").await.unwrap();
        assert!(read_for(&mut h.output, Duration::from_millis(30))
            .await
            .is_empty());
        clock.advance_to(SimTime::from_secs_f64(1.0));
        assert!(read_for(&mut h.output, Duration::from_millis(30))
            .await
            .is_empty());
        clock.advance_to(SimTime::from_secs_f64(2.0));
        assert_eq!(
            read_for(&mut h.output, Duration::from_millis(30)).await,
            b"ping"
        );
    }

    #[tokio::test(start_paused = true)]
    async fn realtime_latency_with_jitter_keeps_order_and_pipelines() {
        let shape = DirShape {
            latency_ns: 100_000_000,
            jitter_ns: 50_000_000,
            ..DirShape::default()
        };
        let clock = SimClock::realtime(1.0);
        let mut h = run(shape, clock, 1 << 20, latency_effect);
        let start = tokio::time::Instant::now();
        let mut input = h.input;
        tokio::spawn(async move {
            for i in 0..50u8 {
                input.write_all(&[i]).await.unwrap();
                tokio::time::sleep(Duration::from_millis(10)).await;
            }
        });
        let mut got = Vec::new();
        let mut b = [0u8; 64];
        while got.len() < 50 {
            let n = tokio::time::timeout(Duration::from_secs(5), h.output.read(&mut b))
                .await
                .unwrap()
                .unwrap();
            got.extend_from_slice(&b[..n]);
        }
        assert_eq!(got, (0..50u8).collect::<Vec<_>>(), "no reordering");
        let took = start.elapsed().as_millis();
        // 50 pieces 10 ms apart, each delayed 50..150 ms: pipelined, not 50 × 100 ms.
        assert!((540..=700).contains(&took), "{took} ms");
    }
}
