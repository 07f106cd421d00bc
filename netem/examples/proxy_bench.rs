//! Unshaped throughput and added latency of one netem link, against direct loopback.
//!
//! `cargo run --release --example proxy_bench [-- MIB ROUNDS]` (default 512 MiB, 5000 round
//! trips). Throughput: a client writes MIB mebibytes in 64 KiB writes to a sink that answers
//! with the byte count once it has read everything, so the time covers delivery end to end.
//! Latency: 32-byte ping-pong with an echo server, TCP_NODELAY on every socket. The targets of
//! the netem design are ≥ 90 % of direct throughput and < 1 ms added latency.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use netem::{start, NetemConfig, PairSpec};
use proto::scenario::{Medium, Radio, RadioModel};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

type Error = Box<dyn std::error::Error>;

/// Reads until EOF, then writes the byte count back.
async fn sink() -> Result<SocketAddr, Error> {
    let l = TcpListener::bind("127.0.0.1:0").await?;
    let addr = l.local_addr()?;
    tokio::spawn(async move {
        while let Ok((mut s, _)) = l.accept().await {
            tokio::spawn(async move {
                let mut buf = vec![0u8; 256 * 1024];
                let mut total = 0u64;
                while let Ok(n) = s.read(&mut buf).await {
                    if n == 0 {
                        break;
                    }
                    total += n as u64;
                }
                let _ = s.write_all(&total.to_le_bytes()).await;
            });
        }
    });
    Ok(addr)
}

async fn echo() -> Result<SocketAddr, Error> {
    let l = TcpListener::bind("127.0.0.1:0").await?;
    let addr = l.local_addr()?;
    tokio::spawn(async move {
        while let Ok((mut s, _)) = l.accept().await {
            let _ = s.set_nodelay(true);
            tokio::spawn(async move {
                let mut buf = [0u8; 32];
                while s.read_exact(&mut buf).await.is_ok() {
                    if s.write_all(&buf).await.is_err() {
                        break;
                    }
                }
            });
        }
    });
    Ok(addr)
}

/// The reference: tokio's `examples/proxy.rs`, a plain `copy_bidirectional` proxy with 64 KiB
/// buffers and no shaping, to separate the cost of any user-space proxy from netem's own.
async fn plain_proxy(target: SocketAddr) -> Result<SocketAddr, Error> {
    let l = TcpListener::bind("127.0.0.1:0").await?;
    let addr = l.local_addr()?;
    tokio::spawn(async move {
        while let Ok((mut a, _)) = l.accept().await {
            tokio::spawn(async move {
                if let Ok(mut b) = TcpStream::connect(target).await {
                    let _ = a.set_nodelay(true);
                    let _ = b.set_nodelay(true);
                    let _ = tokio::io::copy_bidirectional_with_sizes(&mut a, &mut b, 65536, 65536)
                        .await;
                }
            });
        }
    });
    Ok(addr)
}

/// The ceiling of any proxy on this machine: a zero-copy one. Each direction is a blocking
/// thread moving bytes socket → pipe → socket with `splice(2)`, so they never enter user space
/// (what a netem fast path could do while no toxic needs to see the bytes).
fn splice_proxy(target: SocketAddr) -> Result<SocketAddr, Error> {
    let l = std::net::TcpListener::bind("127.0.0.1:0")?;
    let addr = l.local_addr()?;
    std::thread::spawn(move || {
        for a in l.incoming().flatten() {
            let Ok(b) = std::net::TcpStream::connect(target) else {
                continue;
            };
            let _ = a.set_nodelay(true);
            let _ = b.set_nodelay(true);
            if let (Ok(a2), Ok(b2)) = (a.try_clone(), b.try_clone()) {
                std::thread::spawn(move || splice_pump(&a, &b));
                std::thread::spawn(move || splice_pump(&b2, &a2));
            }
        }
    });
    Ok(addr)
}

/// Moves everything from `from` to `to` through a pipe with `splice(2)`, then half-closes `to`.
#[allow(unsafe_code)]
fn splice_pump(from: &std::net::TcpStream, to: &std::net::TcpStream) {
    use std::os::fd::AsRawFd;
    let null = std::ptr::null_mut::<libc::loff_t>();
    let mut pipe = [0 as libc::c_int; 2];
    // SAFETY: pipe() writes two descriptors into the two-element array.
    if unsafe { libc::pipe(pipe.as_mut_ptr()) } != 0 {
        return;
    }
    let (rd, wr) = (pipe[0], pipe[1]);
    'pump: loop {
        // SAFETY: every descriptor is open for the whole call; offsets are null (sockets, pipes).
        let n = unsafe {
            libc::splice(
                from.as_raw_fd(),
                null,
                wr,
                null,
                1 << 16,
                libc::SPLICE_F_MOVE,
            )
        };
        if n <= 0 {
            break;
        }
        let mut left = n as usize;
        while left > 0 {
            // SAFETY: as above.
            let m =
                unsafe { libc::splice(rd, null, to.as_raw_fd(), null, left, libc::SPLICE_F_MOVE) };
            if m <= 0 {
                break 'pump;
            }
            left -= m as usize;
        }
    }
    let _ = to.shutdown(std::net::Shutdown::Write);
    // SAFETY: the pipe's descriptors are ours and closed once.
    unsafe {
        libc::close(rd);
        libc::close(wr);
    }
}

/// MB/s (10^6 bytes per second) for `bytes` written to `addr`.
async fn throughput(addr: SocketAddr, bytes: u64) -> Result<f64, Error> {
    let s = TcpStream::connect(addr).await?;
    let (mut r, mut w) = s.into_split();
    let block = vec![0xA5u8; 64 * 1024];
    let start = Instant::now();
    let mut left = bytes;
    while left > 0 {
        let n = left.min(block.len() as u64) as usize;
        w.write_all(&block[..n]).await?;
        left -= n as u64;
    }
    w.shutdown().await?;
    let mut count = [0u8; 8];
    r.read_exact(&mut count).await?;
    let secs = start.elapsed().as_secs_f64();
    let got = u64::from_le_bytes(count);
    if got != bytes {
        return Err(format!("sink got {got} of {bytes} bytes").into());
    }
    Ok(bytes as f64 / secs / 1e6)
}

/// Round-trip times of `rounds` 32-byte ping-pongs.
async fn rtts(addr: SocketAddr, rounds: usize) -> Result<Vec<Duration>, Error> {
    let mut s = TcpStream::connect(addr).await?;
    s.set_nodelay(true)?;
    let mut buf = [7u8; 32];
    let mut out = Vec::with_capacity(rounds);
    for _ in 0..rounds {
        let t = Instant::now();
        s.write_all(&buf).await?;
        s.read_exact(&mut buf).await?;
        out.push(t.elapsed());
    }
    out.sort();
    Ok(out)
}

fn us(d: Duration) -> f64 {
    d.as_secs_f64() * 1e6
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> Result<(), Error> {
    let args: Vec<String> = std::env::args().collect();
    let mib: u64 = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(512);
    let rounds: usize = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(5000);
    let (sink, echo) = (sink().await?, echo().await?);
    let any: SocketAddr = "127.0.0.1:0".parse()?;
    let pairs = vec![
        PairSpec {
            a: 0,
            b: 1,
            listen: any,
            target: sink,
            while_up: false,
        },
        PairSpec {
            a: 0,
            b: 2,
            listen: any,
            target: echo,
            while_up: false,
        },
    ];
    let radio = Radio {
        model: RadioModel::Always,
        range_m: 1.0,
        bandwidth_bytes_per_s: 0,
        medium: Medium::PerLink,
        ..Radio::default()
    };
    let netem = start(NetemConfig::new(pairs, radio)).await?;
    netem.on_step(0, &[]);
    let via_sink = netem.listen_addr(0, 1).ok_or("no link r0-r1")?;
    let via_echo = netem.listen_addr(0, 2).ok_or("no link r0-r2")?;

    let (plain_sink, plain_echo) = (plain_proxy(sink).await?, plain_proxy(echo).await?);
    let zero_copy_sink = splice_proxy(sink)?;

    let bytes = mib << 20;
    // Warm up every path once, then alternate and keep the best of five.
    for addr in [sink, plain_sink, zero_copy_sink, via_sink] {
        throughput(addr, bytes / 8).await?;
    }
    let (mut direct, mut plain, mut zero_copy, mut proxied) = (0f64, 0f64, 0f64, 0f64);
    for _ in 0..5 {
        direct = direct.max(throughput(sink, bytes).await?);
        plain = plain.max(throughput(plain_sink, bytes).await?);
        zero_copy = zero_copy.max(throughput(zero_copy_sink, bytes).await?);
        proxied = proxied.max(throughput(via_sink, bytes).await?);
    }
    let pct = |x: f64| 100.0 * x / direct;
    println!("throughput, {mib} MiB in 64 KiB writes (best of 5):");
    println!("  direct loopback       {direct:9.1} MB/s");
    println!(
        "  plain copy proxy      {plain:9.1} MB/s  ({:.1} % of direct)",
        pct(plain)
    );
    println!(
        "  zero-copy proxy       {zero_copy:9.1} MB/s  ({:.1} % of direct; splice(2), the ceiling)",
        pct(zero_copy)
    );
    println!(
        "  through netem         {proxied:9.1} MB/s  ({:.1} % of direct, {:.1} % of the plain proxy)",
        pct(proxied),
        100.0 * proxied / plain
    );

    for addr in [echo, plain_echo, via_echo] {
        rtts(addr, rounds / 10).await?;
    }
    let d = rtts(echo, rounds).await?;
    let c = rtts(plain_echo, rounds).await?;
    let p = rtts(via_echo, rounds).await?;
    let q = |v: &[Duration], f: f64| v[((v.len() - 1) as f64 * f) as usize];
    println!("round trip, 32-byte ping-pong x {rounds} (median / p99):");
    println!(
        "  direct loopback       {:8.1} us / {:8.1} us",
        us(q(&d, 0.5)),
        us(q(&d, 0.99))
    );
    println!(
        "  plain copy proxy      {:8.1} us / {:8.1} us",
        us(q(&c, 0.5)),
        us(q(&c, 0.99))
    );
    println!(
        "  through netem         {:8.1} us / {:8.1} us",
        us(q(&p, 0.5)),
        us(q(&p, 0.99))
    );
    let added = (us(q(&p, 0.5)) - us(q(&d, 0.5))) / 2.0;
    println!("  added latency per direction (median): {added:.1} us");
    let t = &netem.telemetry()[0];
    println!(
        "netem counted {} bytes a->b on r0-r1 in {} writes",
        t.bytes_a_to_b_total, t.chunks_a_to_b_total
    );
    netem.shutdown().await;
    Ok(())
}
