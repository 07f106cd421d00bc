//! What flows through a shaping pipeline and what shapes it: chunks of bytes holding room in
//! their buffer ([`Chunk`]), a direction's live parameters ([`DirShape`], [`Limit`]) and the
//! seeded generator of its random effects ([`Rng`]).

use std::sync::Arc;

use crate::accounting::Reservation;
use crate::shaping::budget::Budget;
use proto::clock::SimTime;

/// Largest read from a socket, in bytes.
pub const CHUNK_MAX: usize = 64 * 1024;

/// Capacity (in chunks) of the channel into the latency stage: it holds the pieces "on the air".
pub const IN_FLIGHT_CHUNKS: usize = 256;

/// A run of bytes read from one socket, with the room it holds in its
/// [`Buffer`](crate::accounting::Buffer).
#[derive(Debug)]
pub struct Chunk {
    data: Vec<u8>,
    start: usize,
    res: Option<Reservation>,
    /// When the bytes entered the current stage (read, or granted by the bandwidth stage).
    pub stamp: SimTime,
}

impl Chunk {
    /// A chunk that is not accounted in any buffer (tests, synthetic data).
    pub fn new(data: Vec<u8>, stamp: SimTime) -> Chunk {
        Chunk {
            data,
            start: 0,
            res: None,
            stamp,
        }
    }

    pub(crate) fn reserved(data: Vec<u8>, mut res: Reservation, stamp: SimTime) -> Chunk {
        res.fill(data.len());
        Chunk {
            data,
            start: 0,
            res: Some(res),
            stamp,
        }
    }

    pub fn len(&self) -> usize {
        self.data.len() - self.start
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn bytes(&self) -> &[u8] {
        &self.data[self.start..]
    }

    pub fn bytes_mut(&mut self) -> &mut [u8] {
        &mut self.data[self.start..]
    }

    /// Splits off the first `k` bytes (all of them if `k >= len`).
    pub fn split_to(&mut self, k: usize) -> Chunk {
        let res = self.res.as_mut().map(|r| r.split_to(k));
        let data = if k >= self.len() && self.start == 0 {
            std::mem::take(&mut self.data)
        } else {
            let k = k.min(self.len());
            let front = self.data[self.start..self.start + k].to_vec();
            self.start += k;
            front
        };
        Chunk {
            data,
            start: 0,
            res,
            stamp: self.stamp,
        }
    }

    /// Drops every byte after the first `k` (they count as lost).
    pub fn truncate(&mut self, k: usize) {
        if k < self.len() {
            self.data.truncate(self.start + k);
            if let Some(r) = self.res.as_mut() {
                let kept = r.split_to(k);
                // The rest is dropped here: lost.
                *r = kept;
            }
        }
    }

    /// The counters its bytes count in (`None` for an unaccounted chunk).
    pub(crate) fn counters(&self) -> Option<Arc<crate::accounting::DirCounters>> {
        self.res.as_ref().map(|r| Arc::clone(r.counters()))
    }

    /// The bytes were handed to the kernel (see [`Reservation::into_kernel`]): their length, and
    /// the counters to count them in once sent (`None` for an unaccounted chunk).
    pub(crate) fn into_kernel(mut self) -> (usize, Option<Arc<crate::accounting::DirCounters>>) {
        (self.len(), self.res.take().map(Reservation::into_kernel))
    }

    /// The bytes reached the receiver.
    pub fn delivered(mut self) {
        if let Some(r) = self.res.take() {
            r.delivered();
        }
    }
}

/// The toxic-limited byte budget of a connection direction (`limit_data`): `id` names the toxic
/// instance so that a new or updated toxic starts counting afresh.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limit {
    pub id: u64,
    pub bytes: u64,
}

/// The effective parameters of one direction of one connection, folded from the link's
/// configuration and its toxics (`faults.rs`).
#[derive(Clone, Debug, Default)]
pub struct DirShape {
    /// Every budget a byte must be granted by (per-link or toxic rate, shared medium); empty =
    /// unlimited.
    pub budgets: Vec<Arc<Budget>>,
    pub latency_ns: u64,
    pub jitter_ns: u64,
    /// Probability that a byte gets one bit flipped.
    pub corrupt_probability: f64,
    /// Blackhole: nothing is written, nothing closed; the buffer fills and the sender stalls.
    pub stalled: bool,
    pub limit: Option<Limit>,
    /// `slicer`: writes cut smaller, and spaced.
    pub slicer: Option<Slicing>,
    /// `slow_close`: how long (simulated ns) the sender's close waits before it is passed on.
    pub close_delay_ns: u64,
}

/// How a `slicer` toxic cuts a direction's writes: slices of `average_size ± size_variation`
/// bytes (at least one), `delay_ns` of simulated time apart.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Slicing {
    pub average_size: u64,
    pub size_variation: u64,
    pub delay_ns: u64,
}

/// A small deterministic PRNG (SplitMix64) for jitter and corruption: no dependency, and a run
/// is reproducible from its seed.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(seed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}
