//! Byte accounting: what crossed each link in each direction, what is held inside netem, and the
//! bound on the latter (docs/design.md §5: "per direction it keeps counters (bytes, chunks) per step";
//! "bounded buffers: when a link's budget is spent, netem stops reading from the sender").
//!
//! Every byte netem reads from a socket is first *reserved* in the `Buffer` of its connection
//! direction, a semaphore of `capacity` byte permits. The reservation travels with the bytes
//! through the shaping pipeline and is released when they are written to the receiver
//! (`Reservation::delivered`) or dropped (a cut, a reset: counted as lost). The reader waits for
//! a permit before it reads, so when the budget is spent the buffer fills, netem stops reading,
//! and the kernel's TCP window pushes back on the sender: memory stays flat whatever the sender
//! offers. **Invariant:** the bytes held for one connection direction never exceed its capacity.

use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::{Arc, Mutex, Weak};

use serde::Serialize;
use tokio::sync::Semaphore;

/// One direction of a link. `a` is the lower robot id, the side that connects to netem.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
pub enum Dir {
    /// a → b: toxiproxy's "upstream" (client to server).
    AtoB,
    /// b → a: toxiproxy's "downstream".
    BtoA,
}

impl Dir {
    pub const BOTH: [Dir; 2] = [Dir::AtoB, Dir::BtoA];

    /// The label used in metrics and CSV columns.
    pub fn label(self) -> &'static str {
        match self {
            Dir::AtoB => "a_to_b",
            Dir::BtoA => "b_to_a",
        }
    }

    pub fn index(self) -> usize {
        match self {
            Dir::AtoB => 0,
            Dir::BtoA => 1,
        }
    }
}

/// Bytes a connection handed to the kernel that are not yet counted as sent: asked to count
/// what has left by now.
pub trait InFlight: Send + Sync {
    fn settle(&self);
}

/// Counters of one direction of one link, shared by all its connections.
#[derive(Default)]
pub struct DirCounters {
    /// The connections' bytes in the kernel, settled before a step's count is taken.
    in_flight: Mutex<Vec<Weak<dyn InFlight>>>,
    bytes_total: AtomicU64,
    chunks_total: AtomicU64,
    bytes_step: AtomicU64,
    queued: AtomicU64,
    queued_max: AtomicU64,
    lost_total: AtomicU64,
}

/// A copy of [`DirCounters`] at one moment.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct DirSnapshot {
    /// Bytes written to the receiver since start.
    pub bytes_total: u64,
    /// Writes to the receiver since start.
    pub chunks_total: u64,
    /// Bytes read from the sender and not yet delivered or dropped.
    pub queued_bytes: u64,
    /// The largest `queued_bytes` ever seen.
    pub queued_max_bytes: u64,
    /// Bytes read from the sender and then dropped (cut, reset, limit_data).
    pub lost_bytes_total: u64,
}

impl std::fmt::Debug for DirCounters {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DirCounters")
            .field("snapshot", &self.snapshot())
            .finish()
    }
}

impl DirCounters {
    /// Records one write of `n` bytes to the receiver.
    pub fn delivered(&self, n: usize) {
        self.sent(n);
        self.wrote();
    }

    /// `n` bytes written earlier reached the receiver (the kernel sent them).
    pub fn sent(&self, n: usize) {
        self.bytes_total.fetch_add(n as u64, Relaxed);
        self.bytes_step.fetch_add(n as u64, Relaxed);
    }

    /// One write to the receiver (its bytes count once [`DirCounters::sent`]).
    pub fn wrote(&self) {
        self.chunks_total.fetch_add(1, Relaxed);
    }

    /// `n` bytes given to the kernel were never sent (a reset discarded them).
    pub fn lost(&self, n: usize) {
        self.lost_total.fetch_add(n as u64, Relaxed);
    }

    fn hold(&self, n: usize) {
        let q = self.queued.fetch_add(n as u64, Relaxed) + n as u64;
        self.queued_max.fetch_max(q, Relaxed);
    }

    fn release(&self, n: usize, lost: bool) {
        self.queued.fetch_sub(n as u64, Relaxed);
        if lost {
            self.lost_total.fetch_add(n as u64, Relaxed);
        }
    }

    /// Registers a connection's bytes in the kernel, to be settled by [`Self::take_step`].
    pub fn register(&self, f: Weak<dyn InFlight>) {
        let mut v = self.in_flight.lock().unwrap_or_else(|p| p.into_inner());
        v.retain(|w| w.strong_count() > 0);
        v.push(f);
    }

    /// Bytes delivered since the previous call (the per-step counter), resetting it. What the
    /// kernel sent by now counts, even where the connection's writer has not looked yet: a step's
    /// bytes that its receiver already holds are never counted in the next step.
    pub fn take_step(&self) -> u64 {
        let live: Vec<Arc<dyn InFlight>> = {
            let v = self.in_flight.lock().unwrap_or_else(|p| p.into_inner());
            v.iter().filter_map(Weak::upgrade).collect()
        };
        for f in live {
            f.settle();
        }
        self.bytes_step.swap(0, Relaxed)
    }

    pub fn snapshot(&self) -> DirSnapshot {
        DirSnapshot {
            bytes_total: self.bytes_total.load(Relaxed),
            chunks_total: self.chunks_total.load(Relaxed),
            queued_bytes: self.queued.load(Relaxed),
            queued_max_bytes: self.queued_max.load(Relaxed),
            lost_bytes_total: self.lost_total.load(Relaxed),
        }
    }
}

/// The bounded buffer of one direction of one connection.
#[derive(Debug)]
pub struct Buffer {
    counters: Arc<DirCounters>,
    permits: Semaphore,
    capacity: usize,
}

impl Buffer {
    /// A buffer of `capacity` bytes (at least 1) accounted to `counters`.
    pub fn new(capacity: usize, counters: Arc<DirCounters>) -> Arc<Buffer> {
        let capacity = capacity.clamp(1, Semaphore::MAX_PERMITS);
        Arc::new(Buffer {
            counters,
            permits: Semaphore::new(capacity),
            capacity,
        })
    }

    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Bytes currently held.
    pub fn held(&self) -> usize {
        self.capacity - self.permits.available_permits()
    }

    /// Waits until there is room for at least one byte, then reserves as many as are free, up to
    /// `max` (at least 1).
    pub async fn reserve(self: &Arc<Self>, max: usize) -> Reservation {
        let max = max.max(1);
        let mut n = 0;
        if let Ok(p) = self.permits.acquire().await {
            p.forget();
            n = 1;
        }
        // Only the one reader of this direction takes permits, so what is available stays available.
        let extra = (max - n).min(self.permits.available_permits());
        if extra > 0 {
            if let Ok(p) = self.permits.try_acquire_many(extra as u32) {
                p.forget();
                n += extra;
            }
        }
        Reservation {
            buf: Arc::clone(self),
            n,
            filled: false,
            delivered: false,
        }
    }

    fn release(&self, n: usize, filled: bool, lost: bool) {
        if n > 0 {
            if filled {
                self.counters.release(n, lost);
            }
            self.permits.add_permits(n);
        }
    }
}

/// Room for `len()` bytes in a [`Buffer`]. Once [`Reservation::fill`]ed it holds data: counted
/// as queued, and on drop as lost unless [`Reservation::delivered`] was called.
#[derive(Debug)]
pub struct Reservation {
    buf: Arc<Buffer>,
    n: usize,
    filled: bool,
    delivered: bool,
}

impl Reservation {
    pub fn len(&self) -> usize {
        self.n
    }

    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// Gives back the room beyond `n` bytes (not lost if never filled), then marks the rest as
    /// holding data read from the sender.
    pub fn fill(&mut self, n: usize) {
        self.shrink_to(n);
        if !self.filled {
            self.filled = true;
            self.buf.counters.hold(self.n);
        }
    }

    /// Gives back everything beyond `n` bytes.
    pub fn shrink_to(&mut self, n: usize) {
        if n < self.n {
            self.buf.release(self.n - n, self.filled, true);
            self.n = n;
        }
    }

    /// Splits off the first `k` bytes into a reservation of their own.
    pub fn split_to(&mut self, k: usize) -> Reservation {
        let k = k.min(self.n);
        self.n -= k;
        Reservation {
            buf: Arc::clone(&self.buf),
            n: k,
            filled: self.filled,
            delivered: false,
        }
    }

    /// The counters these bytes count in.
    pub fn counters(&self) -> &Arc<DirCounters> {
        &self.buf.counters
    }

    /// The bytes were handed to the kernel in one write: count the write, free their room
    /// without counting the bytes yet; the returned counters are where to count them once the
    /// kernel has sent them ([`DirCounters::sent`]) or to lose them ([`DirCounters::lost`]).
    pub fn into_kernel(mut self) -> Arc<DirCounters> {
        self.buf.counters.wrote();
        self.buf.release(self.n, self.filled, false);
        self.n = 0;
        self.delivered = true;
        Arc::clone(&self.buf.counters)
    }

    /// The bytes were written to the receiver: count them and free their room.
    pub fn delivered(mut self) {
        self.buf.counters.delivered(self.n);
        self.delivered = true;
    }
}

impl Drop for Reservation {
    fn drop(&mut self) {
        self.buf.release(self.n, self.filled, !self.delivered);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[tokio::test]
    async fn reservations_bound_the_held_bytes_and_count_delivery_and_loss() {
        let c = Arc::new(DirCounters::default());
        let b = Buffer::new(100, Arc::clone(&c));
        let mut r1 = b.reserve(60).await;
        assert_eq!(r1.len(), 60);
        assert_eq!(c.snapshot().queued_bytes, 0, "room is not data");
        r1.fill(60);
        let mut r2 = b.reserve(60).await;
        assert_eq!(r2.len(), 40, "only what is free");
        r2.fill(40);
        assert_eq!(b.held(), 100);
        let b2 = Arc::clone(&b);
        let blocked = tokio::spawn(async move {
            let mut r = b2.reserve(10).await;
            r.fill(10);
            r.len()
        });
        tokio::time::sleep(Duration::from_millis(10)).await;
        assert!(
            !blocked.is_finished(),
            "a full buffer makes the reader wait"
        );
        let head = r1.split_to(20);
        head.delivered();
        assert_eq!(blocked.await.expect("joined"), 10);
        r1.shrink_to(30);
        drop(r1);
        drop(r2);
        let s = c.snapshot();
        assert_eq!(s.bytes_total, 20);
        assert_eq!(s.chunks_total, 1);
        // Shrinking filled room drops data: lost too.
        assert_eq!(s.lost_bytes_total, 10 + 30 + 40 + 10);
        assert_eq!(s.queued_bytes, 0);
        assert_eq!(s.queued_max_bytes, 100);
        assert_eq!(b.held(), 0);
        assert_eq!(c.take_step(), 20);
        assert_eq!(c.take_step(), 0);
    }
}
