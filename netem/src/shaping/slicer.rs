//! Slicing: what arrives is written in smaller pieces, spaced in time (toxiproxy's `slicer`
//! toxic: `average_size` ± `size_variation` bytes per slice, `delay` µs between slices). It
//! exercises the receivers' framing: a message may reach them in any number of reads.
//!
//! The spacing is a schedule on the simulated clock: a slice goes `delay` after the one before it
//! was due (and never before its bytes reached this stage), so a sender that is behind the
//! schedule catches up instead of falling further behind. In lockstep, simulated time moves a
//! whole step at a time, so the slices due within a step all go at its boundary, like
//! `latency`; with step markers the link drops the delay altogether (`link.rs`) and only the
//! cutting remains. Without a slicer a chunk passes whole, untouched.

use tokio::sync::{mpsc, watch};

use crate::shaping::chunk::{Chunk, DirShape, Rng, Slicing};
use proto::clock::{SimClock, SimTime};

/// The size of the next slice: uniform in `average_size ± size_variation`, at least 1.
pub fn slice_len(s: &Slicing, rng: &mut Rng) -> u64 {
    if s.size_variation == 0 {
        return s.average_size.max(1);
    }
    let span = s.size_variation.saturating_mul(2).saturating_add(1);
    let offset = rng.next_u64() % span;
    s.average_size
        .saturating_add(offset)
        .saturating_sub(s.size_variation)
        .max(1)
}

/// The slicer effect.
pub async fn slicer(
    mut input: mpsc::Receiver<Chunk>,
    output: mpsc::Sender<Chunk>,
    mut shape: watch::Receiver<DirShape>,
    clock: SimClock,
    mut rng: Rng,
) {
    // When the next slice is due.
    let mut due = SimTime::ZERO;
    while let Some(mut chunk) = input.recv().await {
        let arrived = clock.now();
        while !chunk.is_empty() {
            // Read per slice: a slicer removed (or changed) mid-chunk applies at once.
            let slicing = shape.borrow_and_update().slicer;
            let Some(s) = slicing else {
                break;
            };
            if due > clock.now() {
                tokio::select! {
                    () = clock.sleep_until(due) => {}
                    changed = shape.changed() => {
                        if changed.is_err() {
                            return;
                        }
                        continue;
                    }
                }
            }
            let n = usize::try_from(slice_len(&s, &mut rng)).unwrap_or(usize::MAX);
            let piece = chunk.split_to(n);
            if output.send(piece).await.is_err() {
                return;
            }
            due = due.max(arrived).saturating_add_ns(s.delay_ns);
        }
        if !chunk.is_empty() && output.send(chunk).await.is_err() {
            return;
        }
    }
}

/// [`slicer`] in the harness's shape (seed fixed).
#[cfg(test)]
pub async fn slicer_effect(
    input: mpsc::Receiver<Chunk>,
    output: mpsc::Sender<Chunk>,
    shape: watch::Receiver<DirShape>,
    clock: SimClock,
) {
    slicer(input, output, shape, clock, Rng::new(5)).await;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shaping::harness::{read_for, run};
    use std::time::Duration;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    fn slicing(average_size: u64, size_variation: u64, delay_us: u64) -> Slicing {
        Slicing {
            average_size,
            size_variation,
            delay_ns: delay_us * 1000,
        }
    }

    #[test]
    fn slice_sizes_stay_within_the_variation_and_average_out() {
        let mut rng = Rng::new(3);
        let s = slicing(100, 40, 0);
        let sizes: Vec<u64> = (0..10_000).map(|_| slice_len(&s, &mut rng)).collect();
        assert!(sizes.iter().all(|n| (60..=140).contains(n)));
        let mean = sizes.iter().sum::<u64>() as f64 / sizes.len() as f64;
        assert!((mean - 100.0).abs() < 2.0, "{mean}");
        assert!(sizes.iter().any(|&n| n < 70) && sizes.iter().any(|&n| n > 130));
        assert_eq!(slice_len(&slicing(7, 0, 0), &mut rng), 7);
        // A variation past the average never gives an empty slice; huge values saturate.
        assert!((0..1000).all(|_| slice_len(&slicing(2, 50, 0), &mut rng) >= 1));
        assert!(slice_len(&slicing(u64::MAX, u64::MAX, 0), &mut rng) >= 1);
    }

    /// Reads one write at a time (a read never spans two of the effect's writes while the test
    /// reads faster than they come), returning the sizes of the reads.
    async fn read_sizes(h: &mut crate::shaping::harness::Harness, total: usize) -> Vec<usize> {
        let mut sizes = Vec::new();
        let mut buf = vec![0u8; 4096];
        let mut got = 0;
        while got < total {
            let n = tokio::time::timeout(Duration::from_secs(5), h.output.read(&mut buf))
                .await
                .expect("the slices arrive")
                .unwrap();
            assert!(n > 0);
            sizes.push(n);
            got += n;
        }
        sizes
    }

    #[tokio::test]
    async fn writes_come_out_sliced_and_in_order() {
        let shape = DirShape {
            slicer: Some(slicing(10, 3, 0)),
            ..DirShape::default()
        };
        let mut h = run(shape, SimClock::lockstep(), 4096, slicer_effect);
        let data: Vec<u8> = (0..=255u8).cycle().take(1000).collect();
        h.input.write_all(&data).await.unwrap();
        let got = read_for(&mut h.output, Duration::from_millis(100)).await;
        assert_eq!(got, data, "every byte, in order");
        assert_eq!(h.counters.snapshot().bytes_total, 1000);
        let chunks = h.counters.snapshot().chunks_total;
        assert!(
            (1000 / 13..=1000 / 7 + 1).contains(&chunks),
            "{chunks} writes of about 10 bytes"
        );
    }

    #[tokio::test]
    async fn lockstep_slices_wait_for_the_step_their_schedule_reaches() {
        // 100-byte slices 400 ms apart: 1000 bytes are 10 slices over 3.6 s.
        let shape = DirShape {
            slicer: Some(slicing(100, 0, 400_000)),
            ..DirShape::default()
        };
        let clock = SimClock::lockstep();
        let mut h = run(shape, clock.clone(), 4096, slicer_effect);
        h.input.write_all(&[1u8; 1000]).await.unwrap();
        let mut per_step = Vec::new();
        for step in 0..5u64 {
            clock.advance_to(SimTime(step * 1_000_000_000));
            per_step.push(
                read_for(&mut h.output, Duration::from_millis(40))
                    .await
                    .len(),
            );
        }
        // Due at 0, 0.4, 0.8 | 1.2, 1.6, 2.0 | 2.4, 2.8 | 3.2, 3.6 s.
        assert_eq!(per_step, [100, 200, 300, 200, 200]);
    }

    #[tokio::test(start_paused = true)]
    async fn realtime_slices_are_spaced_by_the_delay() {
        let shape = DirShape {
            slicer: Some(slicing(50, 0, 20_000)),
            ..DirShape::default()
        };
        let mut h = run(shape, SimClock::realtime(1.0), 4096, slicer_effect);
        let start = tokio::time::Instant::now();
        h.input.write_all(&[2u8; 500]).await.unwrap();
        let sizes = read_sizes(&mut h, 500).await;
        assert_eq!(sizes, vec![50; 10]);
        // Ten slices, 20 ms apart: the last goes 180 ms after the first.
        let took = start.elapsed().as_millis();
        assert!((180..=200).contains(&took), "{took} ms");
    }

    #[tokio::test]
    async fn without_a_slicer_a_write_passes_whole_and_removing_it_frees_the_rest() {
        let clock = SimClock::lockstep();
        let mut h = run(DirShape::default(), clock.clone(), 8192, slicer_effect);
        h.input.write_all(&[3u8; 3000]).await.unwrap();
        assert_eq!(read_sizes(&mut h, 3000).await, vec![3000]);
        // One byte a simulated second: the second slice waits for the clock...
        h.shape
            .send_modify(|s| s.slicer = Some(slicing(1, 0, 1_000_000)));
        h.input.write_all(&[4u8; 300]).await.unwrap();
        assert_eq!(
            read_for(&mut h.output, Duration::from_millis(40))
                .await
                .len(),
            1
        );
        // ... until the toxic goes: the rest at once, the clock still where it was.
        h.shape.send_modify(|s| s.slicer = None);
        assert_eq!(read_sizes(&mut h, 299).await, vec![299]);
        assert_eq!(clock.now(), SimTime::ZERO);
    }
}
