//! Real bytes on a wire: a `tcpdump` capture, the TCP segments of its pcap file, and their
//! comparison with netem's per-link byte counters (`link_totals.csv`).
//!
//! netem writes a link's b→a bytes to robot a's connection on the link's listen address, and
//! its a→b bytes to robot b's radio listener (from an ephemeral port). So the captured payload
//! of the packets *from* a listen address must equal that link's `bytes_b_to_a`, and the
//! payload of the packets *to* robot b's radio address must equal the sum of `bytes_a_to_b`
//! over the links into b (nothing but netem connects to a radio listener). Addresses and final
//! counters come from the run's `link_totals.csv`, which netem writes after closing every
//! connection.

use std::collections::HashMap;
use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use crate::support::kill;

/// A `tcpdump` capture; killed on drop.
pub struct Capture {
    child: Option<Child>,
    stderr: mpsc::Receiver<String>,
}

impl Capture {
    /// Starts tcpdump on `iface`, capturing what `filter` selects into `pcap`, run behind
    /// `prefix` (e.g. `ip netns exec NS`; empty: here); `Err` with the reason if it cannot
    /// capture.
    pub fn start(
        prefix: &[&str],
        iface: &str,
        filter: &str,
        pcap: &Path,
    ) -> Result<Capture, String> {
        let (program, first) = match prefix.split_first() {
            Some((p, rest)) => (*p, rest.iter().chain(["tcpdump"].iter()).copied().collect()),
            None => ("tcpdump", Vec::new()),
        };
        let mut child = Command::new(program)
            .args(first)
            .args([
                "-i", iface, "-n", "-U", "-B", "32768", "-s", "128", "-Z", "root", "-w",
            ])
            .arg(pcap)
            .arg(filter)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| format!("cannot start tcpdump: {e}"))?;
        let (tx, rx) = mpsc::channel();
        let err = child.stderr.take().ok_or("no stderr")?;
        std::thread::spawn(move || {
            for line in BufReader::new(err).lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        let cap = Capture {
            child: Some(child),
            stderr: rx,
        };
        // tcpdump says "listening on <iface>" once the capture runs.
        let mut said = Vec::new();
        loop {
            match cap.stderr.recv_timeout(Duration::from_secs(10)) {
                Ok(l) if l.contains("listening on") => return Ok(cap),
                Ok(l) => said.push(l),
                Err(_) => return Err(format!("tcpdump did not start: {}", said.join(" / "))),
            }
        }
    }

    /// Stops the capture once `pcap` has stopped growing (tcpdump may still be reading packets
    /// from the kernel's buffer after the traffic ended), with SIGINT so tcpdump flushes the
    /// file; returns what it said at exit (its packet counts).
    pub fn stop(mut self, pcap: &Path) -> String {
        let size = || std::fs::metadata(pcap).map_or(0, |m| m.len());
        let (mut last, mut since) = (size(), std::time::Instant::now());
        let give_up = std::time::Instant::now() + Duration::from_secs(20);
        while since.elapsed() < Duration::from_secs(1) && std::time::Instant::now() < give_up {
            std::thread::sleep(Duration::from_millis(100));
            let now = size();
            if now != last {
                (last, since) = (now, std::time::Instant::now());
            }
        }
        let mut child = self.child.take().expect("capture running");
        kill(child.id(), 2);
        let deadline = std::time::Instant::now() + Duration::from_secs(10);
        while std::time::Instant::now() < deadline {
            if let Ok(Some(_)) = child.try_wait() {
                break;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        let _ = child.kill();
        let _ = child.wait();
        let mut said = Vec::new();
        while let Ok(l) = self.stderr.recv_timeout(Duration::from_millis(500)) {
            said.push(l);
        }
        said.join("\n")
    }
}

impl Drop for Capture {
    fn drop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

/// One TCP segment: its ends, sequence number and payload length.
#[derive(Debug, PartialEq, Eq)]
pub struct Segment {
    pub src: SocketAddr,
    pub dst: SocketAddr,
    pub seq: u32,
    pub payload: u64,
}

/// The TCP/IPv4 segments of a pcap file (Ethernet link type, as Linux's `lo` and veths have).
/// The payload length comes from the IP header, so a short snapshot length is enough.
pub fn segments(pcap: &[u8]) -> Result<Vec<Segment>, String> {
    let head = pcap.get(..24).ok_or("pcap shorter than its header")?;
    let magic = u32::from_le_bytes([head[0], head[1], head[2], head[3]]);
    let le = match magic {
        0xa1b2_c3d4 | 0xa1b2_3c4d => true,
        0xd4c3_b2a1 | 0x4d3c_b2a1 => false,
        m => return Err(format!("not a pcap file (magic {m:#x})")),
    };
    let u32_at = |b: &[u8], i: usize| {
        let w = [b[i], b[i + 1], b[i + 2], b[i + 3]];
        if le {
            u32::from_le_bytes(w)
        } else {
            u32::from_be_bytes(w)
        }
    };
    let linktype = u32_at(head, 20);
    if linktype != 1 {
        return Err(format!("link type {linktype}, expected Ethernet (1)"));
    }
    let mut out = Vec::new();
    let mut at = 24;
    while at + 16 <= pcap.len() {
        let incl = u32_at(pcap, at + 8) as usize;
        let frame = pcap
            .get(at + 16..at + 16 + incl)
            .ok_or("truncated record")?;
        at += 16 + incl;
        // Ethernet: type at 12; IPv4 = 0x0800.
        if frame.len() < 14 + 20 || frame[12..14] != [0x08, 0x00] {
            continue;
        }
        let ip = &frame[14..];
        let ihl = usize::from(ip[0] & 0x0f) * 4;
        let total = usize::from(u16::from_be_bytes([ip[2], ip[3]]));
        if ip[9] != 6 || ip.len() < ihl + 14 {
            continue;
        }
        let tcp = &ip[ihl..];
        let doff = usize::from(tcp[12] >> 4) * 4;
        let addr = |at: usize, port: usize| {
            SocketAddr::from((
                [ip[at], ip[at + 1], ip[at + 2], ip[at + 3]],
                u16::from_be_bytes([tcp[port], tcp[port + 1]]),
            ))
        };
        out.push(Segment {
            src: addr(12, 0),
            dst: addr(16, 2),
            seq: u32::from_be_bytes([tcp[4], tcp[5], tcp[6], tcp[7]]),
            payload: total.saturating_sub(ihl + doff) as u64,
        });
    }
    Ok(out)
}

/// A row of `link_totals.csv`.
pub struct LinkTotal {
    pub a: u64,
    pub b: u64,
    pub listen: SocketAddr,
    /// Every port the proxy listened on (it listens while its link is up, and may change port
    /// as the link comes and goes).
    pub ports: Vec<u16>,
    pub target: SocketAddr,
    pub a_to_b: u64,
    pub b_to_a: u64,
}

pub fn link_totals(path: &Path) -> Vec<LinkTotal> {
    let rows: Vec<netem::cli::LinkTotalsCsv> = swarm::rundir::tables::read_rows(path)
        .unwrap_or_else(|e| panic!("{}: {e:#}", path.display()));
    rows.into_iter()
        .map(|r| LinkTotal {
            a: r.a.into(),
            b: r.b.into(),
            listen: r.listen,
            ports: (r.ports.split_whitespace())
                .filter_map(|p| p.parse().ok())
                .collect(),
            target: r.target,
            a_to_b: r.bytes_a_to_b,
            b_to_a: r.bytes_b_to_a,
        })
        .collect()
}

fn within_1pct(counted: u64, captured: u64) -> bool {
    counted.abs_diff(captured) as f64 <= 0.01 * counted.max(captured) as f64
}

/// netem's counters beside a capture's segments: every link's b→a bytes and every robot's
/// incoming a→b bytes, each within 1 %.
pub struct Comparison {
    pub ok: bool,
    /// One line per comparison, the ones off by more than 1 % marked.
    pub report: String,
    pub counted_total: u64,
    pub captured_total: u64,
}

pub fn compare(totals: &[LinkTotal], segs: &[Segment]) -> Comparison {
    let mut from: HashMap<SocketAddr, u64> = HashMap::new();
    let mut to: HashMap<SocketAddr, u64> = HashMap::new();
    let (fresh, resent) = first_sendings(segs);
    // A proxy's port is one the kernel hands out (it listens while its link is up), so a
    // robot's own connection may once have come from it: what a proxy sends goes to a robot's
    // ephemeral port, never to a proxy or a radio listener.
    let listening: std::collections::HashSet<SocketAddr> = (totals.iter())
        .flat_map(|l| {
            let ip = l.listen.ip();
            (l.ports.iter().map(move |&p| SocketAddr::new(ip, p))).chain([l.target])
        })
        .collect();
    for (s, &n) in segs.iter().zip(&fresh) {
        if !listening.contains(&s.dst) {
            *from.entry(s.src).or_default() += n;
        }
        *to.entry(s.dst).or_default() += n;
    }
    let mark = |good: bool| {
        if good {
            ""
        } else {
            "  <-- off by more than 1 %"
        }
    };
    let mut report = Vec::new();
    let (mut ok, mut counted_total, mut captured_total) = (true, 0, 0);
    for l in totals {
        let captured: u64 = (l.ports.iter())
            .map(|&p| {
                from.get(&SocketAddr::new(l.listen.ip(), p))
                    .copied()
                    .unwrap_or(0)
            })
            .sum();
        let good = within_1pct(l.b_to_a, captured);
        ok &= good;
        report.push(format!(
            "link {}-{} b→a: counted {} captured {captured}{}",
            l.a,
            l.b,
            l.b_to_a,
            mark(good)
        ));
        counted_total += l.a_to_b + l.b_to_a;
        captured_total += captured;
    }
    let mut into: HashMap<(u64, SocketAddr), u64> = HashMap::new();
    for l in totals {
        *into.entry((l.b, l.target)).or_default() += l.a_to_b;
    }
    let mut into: Vec<_> = into.into_iter().collect();
    into.sort();
    for ((b, addr), counted) in into {
        let captured = to.get(&addr).copied().unwrap_or(0);
        captured_total += captured;
        let good = within_1pct(counted, captured);
        ok &= good;
        report.push(format!(
            "into robot {b} (all a→b): counted {counted} captured {captured}{}",
            mark(good)
        ));
    }
    report.push(format!(
        "(TCP sent {resent} payload bytes again — retransmissions and probes — not counted twice)"
    ));
    Comparison {
        ok,
        report: report.join("\n"),
        counted_total,
        captured_total,
    }
}

/// Per segment, how many of its payload bytes the capture sees for the first time in its
/// connection direction (by sequence number: TCP's retransmissions and tail-loss probes send
/// bytes again, which a counter of bytes forwarded counts once); and the bytes sent again.
pub fn first_sendings(segs: &[Segment]) -> (Vec<u64>, u64) {
    let mut high: HashMap<(SocketAddr, SocketAddr), u32> = HashMap::new();
    let mut resent = 0;
    let fresh = segs
        .iter()
        .map(|s| {
            let end = s.seq.wrapping_add(s.payload as u32);
            let new = match high.get(&(s.src, s.dst)) {
                // Ahead of what was seen, within a window: the part beyond it is new.
                Some(&h) => match end.wrapping_sub(h) {
                    d if d > 0 && d < 1 << 30 => u64::from(d).min(s.payload),
                    _ => 0,
                },
                None => s.payload,
            };
            if new > 0 || !high.contains_key(&(s.src, s.dst)) {
                high.insert((s.src, s.dst), end);
            }
            resent += s.payload - new;
            new
        })
        .collect();
    (fresh, resent)
}

/// The packets tcpdump said at exit that the kernel dropped.
pub fn dropped(said: &str) -> Option<u64> {
    said.lines()
        .find(|l| l.contains("dropped by kernel"))
        .and_then(|l| l.split_whitespace().next())
        .and_then(|n| n.parse::<u64>().ok())
}

#[test]
fn the_pcap_reader_finds_ports_and_payload() {
    // A pcap header and one Ethernet/IPv4/TCP frame: 127.0.0.1:1000 → :2000, 5 payload bytes.
    let mut p = Vec::new();
    p.extend_from_slice(&0xa1b2_c3d4u32.to_le_bytes());
    p.extend_from_slice(&[2, 0, 4, 0]);
    p.extend_from_slice(&[0; 8]);
    p.extend_from_slice(&128u32.to_le_bytes());
    p.extend_from_slice(&1u32.to_le_bytes());
    let mut frame = vec![0u8; 12];
    frame.extend_from_slice(&[0x08, 0x00]);
    let mut ip = vec![0x45, 0, 0, 20 + 20 + 5, 0, 0, 0, 0, 64, 6, 0, 0];
    ip.extend_from_slice(&[127, 0, 0, 1, 127, 0, 0, 1]);
    let mut tcp = vec![0u8; 20];
    tcp[0..2].copy_from_slice(&1000u16.to_be_bytes());
    tcp[2..4].copy_from_slice(&2000u16.to_be_bytes());
    tcp[12] = 5 << 4;
    frame.extend(ip);
    frame.extend(tcp);
    frame.extend_from_slice(b"hello");
    p.extend_from_slice(&[0; 8]);
    p.extend_from_slice(&(frame.len() as u32).to_le_bytes());
    p.extend_from_slice(&(frame.len() as u32).to_le_bytes());
    p.extend(frame);
    assert_eq!(
        segments(&p),
        Ok(vec![Segment {
            src: SocketAddr::from(([127, 0, 0, 1], 1000)),
            dst: SocketAddr::from(([127, 0, 0, 1], 2000)),
            seq: 0,
            payload: 5
        }])
    );
    assert!(segments(b"not a pcap at all, really").is_err());
}

#[test]
fn bytes_tcp_sends_again_are_counted_once() {
    let a = SocketAddr::from(([10, 0, 0, 1], 1000));
    let b = SocketAddr::from(([10, 0, 0, 2], 2000));
    let seg = |src, dst, seq: u32, payload| Segment {
        src,
        dst,
        seq,
        payload,
    };
    let segs = [
        seg(a, b, u32::MAX - 9, 0),  // SYN
        seg(a, b, u32::MAX - 8, 10), // 10 new, across the wrap of the sequence space
        seg(b, a, 7, 4),             // the other direction: its own sequence
        seg(a, b, 1, 5),             // 5 new
        seg(a, b, 1, 5),             // sent again
        seg(a, b, 4, 6),             // 2 again, 4 new
        seg(a, b, 8, 0),             // a pure ACK
    ];
    let (fresh, resent) = first_sendings(&segs);
    assert_eq!(fresh, [0, 10, 4, 5, 0, 4, 0]);
    assert_eq!(resent, 7);
}
