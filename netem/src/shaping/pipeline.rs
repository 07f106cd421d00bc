//! The shaping pipeline of one direction of one connection (docs/design.md §5 "Shaping").
//!
//! After noxious / toxiproxy: every network effect is one file
//! with one plain async function from an input stream of `Chunk`s to an output sink, reading its
//! current parameters from a `watch` of `DirShape` so that faults apply to live connections:
//!
//! ```text
//! socket ─► source ─► corrupt ─► bandwidth ─► latency ─► slicer ─► slow_close ─► sink ─► socket
//!           (reserve,  (flip     (governor    (hold until  (cut     (hold the     (stall gate,
//!            read)      bits)     budget)      due)         writes)  sender's FIN)  limit_data, write)
//! ```
//!
//! Stages are joined into one future per direction (`pipeline`); the channels between them are
//! bounded, and every byte in flight holds a `Reservation` in the direction's `Buffer`, so the
//! whole pipeline never holds more than the buffer's capacity (see `accounting.rs`). The stages
//! are tested with in-memory streams (`tokio::io::duplex`) through the one harness at the bottom
//! of this file.

use std::io;
use std::sync::{Arc, Mutex};

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::{mpsc, watch};

use crate::accounting::Buffer;
use crate::shaping::chunk::{Chunk, DirShape, Rng, CHUNK_MAX, IN_FLIGHT_CHUNKS};
use crate::shaping::{bandwidth, corrupt, latency, slicer, slow_close};
use proto::clock::SimClock;

/// How the reading end of a pipeline finished.
#[derive(Debug, PartialEq, Eq)]
pub enum SourceEnd {
    Eof,
    Error(io::ErrorKind),
    /// The rest of the pipeline went away.
    Closed,
}

/// How a whole direction finished.
#[derive(Debug, PartialEq, Eq)]
pub enum PipeEnd {
    /// The sender closed its side and everything read was delivered; the receiver got a FIN.
    Eof,
    ReadError(io::ErrorKind),
    WriteError(io::ErrorKind),
    /// A `limit_data` toxic's budget was spent; the receiver got a FIN.
    LimitReached,
}

/// Reads from `reader` into reserved chunks until EOF. Waits for room in `buffer` *before* each
/// read: that is the backpressure.
pub async fn source<R: AsyncRead + Unpin>(
    mut reader: R,
    output: mpsc::Sender<Chunk>,
    buffer: Arc<Buffer>,
    clock: SimClock,
) -> SourceEnd {
    let max = CHUNK_MAX.min(buffer.capacity());
    let mut scratch: Vec<u8> = Vec::new();
    loop {
        let res = buffer.reserve(max).await;
        if scratch.capacity() < max {
            // Uninitialised room: `read_buf` fills it without zeroing it first.
            scratch = Vec::with_capacity(max);
        }
        scratch.clear();
        // `take` caps the read at the reserved room, whatever the Vec's capacity.
        match (&mut reader)
            .take(res.len() as u64)
            .read_buf(&mut scratch)
            .await
        {
            Ok(0) => return SourceEnd::Eof,
            Ok(_) => {}
            Err(e) => return SourceEnd::Error(e.kind()),
        }
        // A mostly full read hands over the buffer itself (no copy); a short one copies out
        // exactly what was read, so a small message never pins a large allocation.
        let data = if 2 * scratch.len() >= scratch.capacity() {
            std::mem::take(&mut scratch)
        } else {
            scratch.to_vec()
        };
        if output
            .send(Chunk::reserved(data, res, clock.now()))
            .await
            .is_err()
        {
            return SourceEnd::Closed;
        }
    }
}

/// How the writing end of a pipeline finished.
#[derive(Debug, PartialEq, Eq)]
pub enum SinkEnd {
    Eof,
    Error(io::ErrorKind),
    LimitReached,
}

/// A writer that can tell how many of the bytes written to it have not left yet — for a TCP
/// socket, what waits in the kernel's send queue for the receiver's window.
pub trait Unsent {
    /// How to ask later; [`UnsentProbe::NONE`] (the default) for writers that hand bytes over
    /// at once.
    fn probe(&self) -> UnsentProbe {
        UnsentProbe::NONE
    }
}

impl Unsent for tokio::net::tcp::OwnedWriteHalf {
    fn probe(&self) -> UnsentProbe {
        use std::os::fd::AsRawFd;
        UnsentProbe(Some(self.as_ref().as_raw_fd()))
    }
}

/// In-memory streams (tests) hand bytes over at once.
impl Unsent for tokio::io::DuplexStream {}

/// Asks a socket how much of what was written to it is still unsent. It holds the descriptor of
/// a writer that [`sink`] borrows for its whole life, and is only used while that descriptor is
/// open: by the sink itself, and by a step's count through `InKernel`'s shared state, under
/// its lock and only while it is marked open — the mark is cleared, under the same lock, by
/// `InKernel`'s `Drop`, which runs inside `sink`.
#[derive(Clone, Copy, Debug)]
pub struct UnsentProbe(Option<std::os::fd::RawFd>);

impl UnsentProbe {
    pub const NONE: Self = Self(None);

    /// Bytes written that the kernel has not sent yet (Linux `SIOCOUTQNSD`; 0 if unknown).
    #[allow(unsafe_code)]
    fn unsent(self) -> usize {
        let Some(fd) = self.0 else {
            return 0;
        };
        // linux/sockios.h: SIOCOUTQNSD, "output queue size, not sent only".
        const SIOCOUTQNSD: libc::Ioctl = 0x894B;
        let mut n: libc::c_int = 0;
        // SAFETY: the descriptor belongs to the writer `sink` borrows, open whenever the probe
        // is used (see the type's doc), and SIOCOUTQNSD writes exactly one c_int through the
        // pointer, which points to `n`.
        let r = unsafe { libc::ioctl(fd, SIOCOUTQNSD, &mut n as *mut libc::c_int) };
        if r == 0 {
            usize::try_from(n).unwrap_or(0)
        } else {
            0
        }
    }
}

/// Bytes written to a socket that the kernel has not yet confirmed as sent. They are out of
/// netem's buffer (the kernel holds them, bounded by the socket's send buffer) but counted only
/// once sent: when the sink looks ([`InKernel::confirm`]), or when a step's count is taken
/// ([`crate::accounting::DirCounters::take_step`] settles every connection's). When this is
/// dropped (the end of the sink, a cut) the socket is asked one last time: what left by then
/// counts as delivered, what is still unsent as lost.
struct InKernel {
    pending: Arc<Mutex<Pending>>,
}

/// The state [`InKernel`] shares with its direction's counters.
struct Pending {
    counters: Option<Arc<crate::accounting::DirCounters>>,
    bytes: usize,
    probe: UnsentProbe,
    /// False once the sink is gone: its socket may be closed, it is not asked any more.
    open: bool,
}

impl Pending {
    /// Counts as delivered whatever of the written bytes has left the socket.
    fn confirm(&mut self) {
        if self.bytes == 0 || !self.open {
            return;
        }
        let unsent = self.probe.unsent().min(self.bytes);
        let sent = self.bytes - unsent;
        if sent > 0 {
            if let Some(c) = &self.counters {
                c.sent(sent);
            }
            self.bytes = unsent;
        }
    }
}

impl crate::accounting::InFlight for Mutex<Pending> {
    fn settle(&self) {
        self.lock().unwrap_or_else(|p| p.into_inner()).confirm();
    }
}

impl Drop for InKernel {
    fn drop(&mut self) {
        let mut p = self.lock();
        p.confirm();
        if let (Some(c), true) = (&p.counters, p.bytes > 0) {
            c.lost(p.bytes);
        }
        p.bytes = 0;
        p.open = false;
    }
}

impl InKernel {
    fn new(probe: UnsentProbe) -> Self {
        Self {
            pending: Arc::new(Mutex::new(Pending {
                counters: None,
                bytes: 0,
                probe,
                open: true,
            })),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Pending> {
        self.pending.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Bytes still in the kernel, not yet counted.
    fn bytes(&self) -> usize {
        self.lock().bytes
    }

    /// Registers with the counters `chunk`'s bytes count in, if this connection has none yet
    /// (outside our lock: `take_step` takes the registry's lock, then ours).
    fn register_for(&mut self, chunk: &Chunk) {
        let Some(c) = chunk.counters() else {
            return;
        };
        {
            let mut p = self.lock();
            if p.counters.is_some() {
                return;
            }
            p.counters = Some(Arc::clone(&c));
        }
        let weak: std::sync::Weak<dyn crate::accounting::InFlight> =
            Arc::downgrade(&self.pending) as _;
        c.register(weak);
    }

    /// Writes what `writer` takes of `chunk` now, and moves those bytes from netem's buffer to
    /// the kernel's account under the lock a step's count takes too: the count sees them either
    /// not written (queued) or written (in the kernel, counted once sent) — never already with
    /// their receiver while still queued here, which would put them in the next step.
    fn poll_write<W: AsyncWrite + Unpin>(
        &self,
        cx: &mut std::task::Context<'_>,
        writer: &mut W,
        chunk: &mut Chunk,
    ) -> std::task::Poll<io::Result<usize>> {
        let mut p = self.lock();
        let r = std::pin::Pin::new(writer).poll_write(cx, chunk.bytes());
        if let std::task::Poll::Ready(Ok(n)) = r {
            if n > 0 {
                let (k, _) = chunk.split_to(n).into_kernel();
                p.bytes += k;
            }
        }
        r
    }

    /// Counts as delivered whatever of the written bytes has left the socket.
    fn confirm(&mut self) {
        self.lock().confirm();
    }

    /// Waits until the kernel has sent everything written (true), or `gate` carries a kill
    /// (false: what is still unsent never leaves and counts as lost when `self` is dropped).
    async fn drain(
        &mut self,
        gate: &mut Option<watch::Receiver<Option<crate::faults::Kill>>>,
    ) -> bool {
        let mut polls = 0u32;
        loop {
            self.confirm();
            if self.bytes() == 0 {
                return true;
            }
            if gate.as_ref().is_some_and(|g| g.borrow().is_some()) {
                return false;
            }
            // The receiver's window is full: it is not reading. Look again soon (a few quick
            // looks, then once a millisecond), or stop at a cut.
            polls += 1;
            if polls < 8 {
                tokio::task::yield_now().await;
            } else {
                tokio::select! {
                    biased;
                    () = cut(gate) => {}
                    () = tokio::time::sleep(std::time::Duration::from_millis(1)) => {}
                }
            }
        }
    }
}

/// Completes once `gate` carries a kill (or its sender is gone); never without a gate.
async fn cut(gate: &mut Option<watch::Receiver<Option<crate::faults::Kill>>>) {
    match gate {
        Some(g) => {
            let _ = g.wait_for(Option::is_some).await;
        }
        None => std::future::pending().await,
    }
}

/// Writes chunks to `writer`: waits while the direction is stalled (blackhole), enforces
/// `limit_data`, counts delivered bytes. On the end of its input it shuts `writer` down (FIN).
///
/// `gate` is the connection's kill signal, set synchronously by the link when it goes down.
/// Every write to the socket races it, with the gate polled first: a write that has not
/// happened when the link is cut never happens (a socket write is cancel-safe).
///
/// Bytes count as delivered once the kernel has *sent* them, not when it accepted them: after
/// each write, while it waits for the next chunk, and once more when it ends or is dropped (a
/// cut), the sink asks the socket how much of what it was given is still queued
/// (`SIOCOUTQNSD`) and counts the rest. So the counters equal the TCP payload on the wire: what
/// a reset discards from the send queue (a cut, a receiver that stopped reading and went away)
/// never counts, what the kernel sent just before a cut does, and nothing is written to a link
/// after it was cut.
pub async fn sink<W: AsyncWrite + Unsent + Unpin>(
    mut input: mpsc::Receiver<Chunk>,
    writer: &mut W,
    mut shape: watch::Receiver<DirShape>,
    mut gate: Option<watch::Receiver<Option<crate::faults::Kill>>>,
) -> SinkEnd {
    let mut limit: Option<(u64, u64)> = None;
    let mut in_kernel = InKernel::new(writer.probe());
    loop {
        // Take the next chunk; while none is ready, finish counting what was written.
        let next = if in_kernel.bytes() == 0 {
            input.recv().await
        } else {
            tokio::select! {
                biased;
                c = input.recv() => c,
                drained = in_kernel.drain(&mut gate) => {
                    if !drained {
                        return SinkEnd::Eof;
                    }
                    continue;
                }
            }
        };
        let Some(mut chunk) = next else {
            break;
        };
        // Copy the flag out first: a watch borrow must never be held across an await.
        let stalled = shape.borrow_and_update().stalled;
        if stalled && shape.wait_for(|s| !s.stalled).await.is_err() {
            return SinkEnd::Eof;
        }
        let current = shape.borrow().limit;
        limit = match (current, limit) {
            (None, _) => None,
            (Some(l), Some((id, left))) if id == l.id => Some((id, left)),
            (Some(l), _) => Some((l.id, l.bytes)),
        };
        let mut last = false;
        if let Some((_, left)) = limit.as_mut() {
            if chunk.len() as u64 >= *left {
                chunk.truncate(*left as usize);
                last = true;
            }
            *left -= chunk.len() as u64;
        }
        in_kernel.register_for(&chunk);
        while !chunk.is_empty() {
            let written = tokio::select! {
                biased;
                // Cut: the rest is dropped (counted as lost), nothing more is written.
                () = cut(&mut gate) => return SinkEnd::Eof,
                r = std::future::poll_fn(|cx| in_kernel.poll_write(cx, writer, &mut chunk)) => r,
            };
            match written {
                Ok(0) => return SinkEnd::Error(io::ErrorKind::WriteZero),
                Ok(_) => {}
                Err(e) => return SinkEnd::Error(e.kind()),
            }
            in_kernel.confirm();
        }
        if last {
            if in_kernel.drain(&mut gate).await {
                let _ = writer.shutdown().await;
            }
            return SinkEnd::LimitReached;
        }
    }
    if in_kernel.drain(&mut gate).await {
        let _ = writer.shutdown().await;
    }
    SinkEnd::Eof
}

/// Runs one direction: `reader` → corrupt → bandwidth → latency → slicer → slow_close →
/// `writer`, until the sender's
/// EOF has been delivered, a write fails, or `limit_data` is reached. Dropping the future drops
/// every byte in flight (counted as lost).
pub async fn pipeline<R, W>(
    reader: R,
    writer: &mut W,
    buffer: Arc<Buffer>,
    shape: watch::Receiver<DirShape>,
    clock: SimClock,
    seed: u64,
    gate: Option<watch::Receiver<Option<crate::faults::Kill>>>,
) -> PipeEnd
where
    R: AsyncRead + Unpin,
    W: AsyncWrite + Unsent + Unpin,
{
    let (tx_read, rx_read) = mpsc::channel(4);
    let (tx_corrupt, rx_corrupt) = mpsc::channel(4);
    let (tx_shaped, rx_shaped) = mpsc::channel(IN_FLIGHT_CHUNKS);
    let (tx_due, rx_due) = mpsc::channel(4);
    let (tx_sliced, rx_sliced) = mpsc::channel(4);
    let (tx_out, rx_out) = mpsc::channel(4);
    let mut rng = Rng::new(seed);
    let stages = {
        let (s1, s2, s3) = (shape.clone(), shape.clone(), shape.clone());
        let (s4, s5) = (shape.clone(), shape.clone());
        // Drawn in this order so that the older stages' seeds stay what they were.
        let (r1, r2) = (Rng::new(rng.next_u64()), Rng::new(rng.next_u64()));
        let r3 = Rng::new(rng.next_u64());
        let clock = clock.clone();
        async move {
            let (end, (), (), (), (), ()) = tokio::join!(
                source(reader, tx_read, buffer, clock.clone()),
                corrupt::corrupt(rx_read, tx_corrupt, s1, r1),
                bandwidth::bandwidth(rx_corrupt, tx_shaped, s2, clock.clone()),
                latency::latency(rx_shaped, tx_due, s3, clock.clone(), r2),
                slicer::slicer(rx_due, tx_sliced, s4, clock.clone(), r3),
                slow_close::slow_close(rx_sliced, tx_out, s5, clock),
            );
            end
        }
    };
    let sink = sink(rx_out, writer, shape, gate);
    tokio::pin!(stages, sink);
    let mut source_end = None;
    loop {
        tokio::select! {
            end = &mut sink => {
                return match (end, source_end) {
                    (SinkEnd::Error(k), _) => PipeEnd::WriteError(k),
                    (SinkEnd::LimitReached, _) => PipeEnd::LimitReached,
                    (SinkEnd::Eof, Some(SourceEnd::Error(k))) => PipeEnd::ReadError(k),
                    (SinkEnd::Eof, _) => PipeEnd::Eof,
                };
            }
            end = &mut stages, if source_end.is_none() => source_end = Some(end),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shaping::chunk::Limit;
    use crate::shaping::harness::*;
    use proto::clock::SimTime;
    use std::time::Duration;

    #[tokio::test]
    async fn harness_passes_bytes_through_and_counts_them() {
        let mut h = run(DirShape::default(), SimClock::lockstep(), 1024, pass);
        h.input.write_all(b"hello, robot").await.unwrap();
        let got = read_for(&mut h.output, Duration::from_millis(50)).await;
        assert_eq!(got, b"hello, robot");
        assert_eq!(h.counters.snapshot().bytes_total, 12);
        assert_eq!(h.counters.snapshot().queued_bytes, 0);
    }

    #[tokio::test]
    async fn stall_holds_bytes_without_closing_and_releases_them_later() {
        let shape = DirShape {
            stalled: true,
            ..DirShape::default()
        };
        let mut h = run(shape, SimClock::lockstep(), 1024, pass);
        h.input.write_all(&[7u8; 100]).await.unwrap();
        assert!(read_for(&mut h.output, Duration::from_millis(50))
            .await
            .is_empty());
        assert_eq!(h.counters.snapshot().queued_bytes, 100);
        h.shape.send_modify(|s| s.stalled = false);
        assert_eq!(
            read_for(&mut h.output, Duration::from_millis(50))
                .await
                .len(),
            100
        );
    }

    #[tokio::test]
    async fn limit_data_delivers_exactly_n_bytes_then_closes() {
        let shape = DirShape {
            limit: Some(Limit { id: 1, bytes: 10 }),
            ..DirShape::default()
        };
        let mut h = run(shape, SimClock::lockstep(), 1024, pass);
        h.input.write_all(&[1u8; 25]).await.unwrap();
        let got = read_for(&mut h.output, Duration::from_millis(200)).await;
        assert_eq!(got.len(), 10);
        let mut b = [0u8; 1];
        let n = tokio::time::timeout(Duration::from_secs(1), h.output.read(&mut b))
            .await
            .unwrap()
            .unwrap();
        assert_eq!(n, 0, "the receiver sees EOF");
        assert_eq!(h.counters.snapshot().lost_bytes_total, 15);
    }

    #[test]
    fn chunk_split_and_truncate_keep_the_bytes_in_order() {
        let mut c = Chunk::new((0u8..10).collect(), SimTime::ZERO);
        let a = c.split_to(3);
        assert_eq!(a.bytes(), &[0, 1, 2]);
        c.truncate(4);
        assert_eq!(c.bytes(), &[3, 4, 5, 6]);
        let b = c.split_to(100);
        assert_eq!(b.bytes(), &[3, 4, 5, 6]);
        assert!(c.is_empty());
    }

    #[test]
    fn rng_is_deterministic_and_in_range() {
        let (mut a, mut b) = (Rng::new(3), Rng::new(3));
        for _ in 0..1000 {
            let x = a.unit();
            assert_eq!(x, b.unit());
            assert!((0.0..1.0).contains(&x));
        }
    }
}
