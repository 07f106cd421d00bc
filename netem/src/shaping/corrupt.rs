//! Corruption: flips one random bit in a byte with a given probability (our `corrupt` toxic, after
//! `tc netem corrupt`; docs/design.md §5 "corrupt bytes"). It exercises the receivers' promise that a
//! payload that fails to decode is counted and never panics (docs/design.md §1 "Wire format", §7).
//! Bytes are neither added nor removed, so the TCP stream stays the same length.

use tokio::sync::{mpsc, watch};

use crate::shaping::chunk::{Chunk, DirShape, Rng};

/// Flips one random bit in each byte of `data` with probability `p`; returns how many bytes were
/// changed. Skips geometrically between hits, so a small `p` costs little per byte.
pub fn flip(data: &mut [u8], p: f64, rng: &mut Rng) -> usize {
    if p.is_nan() || p <= 0.0 || data.is_empty() {
        return 0;
    }
    let mut hits = 0;
    if p >= 1.0 {
        for b in data.iter_mut() {
            *b ^= 1 << (rng.next_u64() % 8);
        }
        return data.len();
    }
    let ln_q = (1.0 - p).ln();
    let mut i = 0usize;
    loop {
        // The gap to the next hit is geometric: floor(ln U / ln(1 - p)).
        let u = rng.unit().max(f64::MIN_POSITIVE);
        let gap = (u.ln() / ln_q).floor();
        if !gap.is_finite() || gap >= (data.len() - i) as f64 {
            return hits;
        }
        i += gap as usize;
        data[i] ^= 1 << (rng.next_u64() % 8);
        hits += 1;
        i += 1;
        if i >= data.len() {
            return hits;
        }
    }
}

/// The corrupt effect.
pub async fn corrupt(
    mut input: mpsc::Receiver<Chunk>,
    output: mpsc::Sender<Chunk>,
    shape: watch::Receiver<DirShape>,
    mut rng: Rng,
) {
    while let Some(mut chunk) = input.recv().await {
        let p = shape.borrow().corrupt_probability;
        flip(chunk.bytes_mut(), p, &mut rng);
        if output.send(chunk).await.is_err() {
            return;
        }
    }
}

/// [`corrupt`] in the harness's shape (seed fixed).
#[cfg(test)]
pub async fn corrupt_effect(
    input: mpsc::Receiver<Chunk>,
    output: mpsc::Sender<Chunk>,
    shape: watch::Receiver<DirShape>,
    _clock: proto::clock::SimClock,
) {
    corrupt(input, output, shape, Rng::new(42)).await;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shaping::harness::{read_for, run};
    use proto::clock::SimClock;
    use std::time::Duration;
    use tokio::io::AsyncWriteExt;

    #[test]
    fn flip_rate_matches_the_probability_and_changes_one_bit_per_hit() {
        let mut rng = Rng::new(7);
        let mut data = vec![0u8; 200_000];
        let hits = flip(&mut data, 0.01, &mut rng);
        let changed = data.iter().filter(|&&b| b != 0).count();
        assert_eq!(hits, changed);
        assert!(data.iter().all(|b| b.count_ones() <= 1));
        assert!((1700..2300).contains(&hits), "{hits}");
        assert_eq!(flip(&mut data, 0.0, &mut rng), 0);
        let mut all = vec![0u8; 10];
        assert_eq!(flip(&mut all, 1.0, &mut rng), 10);
        assert!(all.iter().all(|b| b.count_ones() == 1));
    }

    #[tokio::test]
    async fn corrupt_effect_keeps_the_length_and_flips_some_bytes() {
        let shape = DirShape {
            corrupt_probability: 0.1,
            ..DirShape::default()
        };
        let mut h = run(shape, SimClock::lockstep(), 4096, corrupt_effect);
        h.input.write_all(&[0u8; 3000]).await.unwrap();
        let got = read_for(&mut h.output, Duration::from_millis(100)).await;
        assert_eq!(got.len(), 3000);
        let changed = got.iter().filter(|&&b| b != 0).count();
        assert!((150..450).contains(&changed), "{changed}");
        h.shape.send_modify(|s| s.corrupt_probability = 0.0);
        h.input.write_all(&[0u8; 3000]).await.unwrap();
        let got = read_for(&mut h.output, Duration::from_millis(100)).await;
        assert!(
            got.iter().all(|&b| b == 0),
            "turning it off applies at once"
        );
    }
}
