//! A slow close: when the sender closes its side, the close (FIN) is passed on only `delay`
//! later, on the simulated clock (toxiproxy's `slow_close` toxic, `delay` in milliseconds). The
//! bytes before it pass as they come; the receiver just sees the stream end late. Removing the
//! toxic while a close waits lets it go at once.

use tokio::sync::{mpsc, watch};

use crate::shaping::chunk::{Chunk, DirShape};
use proto::clock::SimClock;

/// The slow-close effect: passes chunks on; once its input ends, holds its output open for the
/// direction's `close_delay_ns` (as it is then), and dropping the output passes the close on.
pub async fn slow_close(
    mut input: mpsc::Receiver<Chunk>,
    output: mpsc::Sender<Chunk>,
    mut shape: watch::Receiver<DirShape>,
    clock: SimClock,
) {
    while let Some(chunk) = input.recv().await {
        if output.send(chunk).await.is_err() {
            return;
        }
    }
    let delay = shape.borrow_and_update().close_delay_ns;
    if delay == 0 {
        return;
    }
    let due = clock.now().saturating_add_ns(delay);
    tokio::select! {
        () = clock.sleep_until(due) => {}
        // The toxic went (or the connection is going away).
        _ = shape.wait_for(|s| s.close_delay_ns == 0) => {}
        () = output.closed() => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shaping::harness::{read_for, run};
    use proto::clock::SimTime;
    use std::time::Duration;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    /// Whether the reader sees the end of the stream within `wait`, after `bytes` bytes.
    async fn ends_within(r: &mut tokio::io::DuplexStream, bytes: usize, wait: Duration) -> bool {
        let got = read_for(r, wait).await;
        assert_eq!(got.len(), bytes);
        let mut b = [0u8; 1];
        matches!(
            tokio::time::timeout(Duration::from_millis(1), r.read(&mut b)).await,
            Ok(Ok(0))
        )
    }

    #[tokio::test]
    async fn the_close_waits_for_the_clock_and_the_bytes_before_it_do_not() {
        let shape = DirShape {
            close_delay_ns: 2_500_000_000,
            ..DirShape::default()
        };
        let clock = SimClock::lockstep();
        let mut h = run(shape, clock.clone(), 4096, slow_close);
        h.input.write_all(b"last words").await.unwrap();
        h.input.shutdown().await.unwrap();
        assert!(!ends_within(&mut h.output, 10, Duration::from_millis(50)).await);
        clock.advance_to(SimTime::from_secs_f64(2.0));
        assert!(!ends_within(&mut h.output, 0, Duration::from_millis(50)).await);
        clock.advance_to(SimTime::from_secs_f64(3.0));
        assert!(ends_within(&mut h.output, 0, Duration::from_millis(200)).await);
    }

    #[tokio::test]
    async fn without_the_toxic_or_once_it_goes_the_close_passes_at_once() {
        let clock = SimClock::lockstep();
        let mut h = run(DirShape::default(), clock.clone(), 4096, slow_close);
        h.input.shutdown().await.unwrap();
        assert!(ends_within(&mut h.output, 0, Duration::from_millis(200)).await);

        let shape = DirShape {
            close_delay_ns: 60_000_000_000,
            ..DirShape::default()
        };
        let mut h = run(shape, clock, 4096, slow_close);
        h.input.shutdown().await.unwrap();
        assert!(!ends_within(&mut h.output, 0, Duration::from_millis(50)).await);
        h.shape.send_modify(|s| s.close_delay_ns = 0);
        assert!(ends_within(&mut h.output, 0, Duration::from_millis(200)).await);
    }
}
