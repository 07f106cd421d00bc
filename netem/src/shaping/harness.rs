//! The one harness every effect is tested through: an effect runs between an in-memory writer
//! and an in-memory reader, with a lockstep clock and a shape the test controls.

use crate::accounting::DirCounters;
use crate::shaping::chunk::*;
use crate::shaping::pipeline::*;
use std::future::Future;
use std::sync::Arc;

use tokio::io::AsyncReadExt;
use tokio::sync::{mpsc, watch};

use crate::accounting::Buffer;
use proto::clock::SimClock;
use std::time::Duration;
use tokio::io::DuplexStream;
use tokio::task::JoinHandle;

pub struct Harness {
    /// Write the input here.
    pub input: DuplexStream,
    /// Read the output here.
    pub output: DuplexStream,
    pub shape: watch::Sender<DirShape>,
    pub counters: Arc<DirCounters>,
    pub buffer: Arc<Buffer>,
    pub task: JoinHandle<()>,
}

/// Runs `effect` (input chunks, output chunks, shape, clock) between a duplex writer and a
/// duplex reader, with a `buffer_bytes` buffer.
pub fn run<F, Fut>(shape: DirShape, clock: SimClock, buffer_bytes: usize, effect: F) -> Harness
where
    F: FnOnce(
            mpsc::Receiver<Chunk>,
            mpsc::Sender<Chunk>,
            watch::Receiver<DirShape>,
            SimClock,
        ) -> Fut
        + Send
        + 'static,
    Fut: Future<Output = ()> + Send + 'static,
{
    let (input, proxy_in) = tokio::io::duplex(64 * 1024);
    let (mut proxy_out, output) = tokio::io::duplex(64 * 1024);
    let (shape_tx, shape_rx) = watch::channel(shape);
    let counters = Arc::new(DirCounters::default());
    let buffer = Buffer::new(buffer_bytes, Arc::clone(&counters));
    let (buf, clk) = (Arc::clone(&buffer), clock);
    let task = tokio::spawn(async move {
        let (tx_in, rx_in) = mpsc::channel(IN_FLIGHT_CHUNKS);
        let (tx_out, rx_out) = mpsc::channel(IN_FLIGHT_CHUNKS);
        tokio::join!(
            source(proxy_in, tx_in, buf, clk.clone()),
            effect(rx_in, tx_out, shape_rx.clone(), clk),
            sink(rx_out, &mut proxy_out, shape_rx, None),
        );
    });
    Harness {
        input,
        output,
        shape: shape_tx,
        counters,
        buffer,
        task,
    }
}

/// The identity effect: the harness itself (source + sink).
pub async fn pass(
    mut input: mpsc::Receiver<Chunk>,
    output: mpsc::Sender<Chunk>,
    _shape: watch::Receiver<DirShape>,
    _clock: SimClock,
) {
    while let Some(c) = input.recv().await {
        if output.send(c).await.is_err() {
            return;
        }
    }
}

/// Reads whatever arrives within `wait` of wall time.
pub async fn read_for(r: &mut DuplexStream, wait: Duration) -> Vec<u8> {
    let mut out = Vec::new();
    let mut buf = [0u8; 4096];
    let deadline = tokio::time::Instant::now() + wait;
    while let Ok(Ok(n)) = tokio::time::timeout_at(deadline, r.read(&mut buf)).await {
        if n == 0 {
            break;
        }
        out.extend_from_slice(&buf[..n]);
    }
    out
}
