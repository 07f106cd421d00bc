//! Real bytes: netem's per-link byte counters against the TCP payload `tcpdump` captures on the
//! loopback interface during a whole run (issue #3, "what it must show" 1); how the two are
//! compared: `capture.rs`.
//!
//! Needs `tcpdump` and the right to capture (root or CAP_NET_RAW), so it is ignored by default;
//! `.ci/run` installs tcpdump and runs it with `--include-ignored`.

use std::time::Duration;

use crate::capture::{compare, dropped, link_totals, segments, Capture};
use crate::support::{stderr, swarm_run, TempDir};

#[test]
#[ignore = "needs tcpdump and root (or CAP_NET_RAW): apt install tcpdump"]
fn netem_counters_equal_the_tcp_payload_tcpdump_captures() {
    let dir = TempDir::new("wire");
    let pcap = dir.path().join("run.pcap");
    let capture = Capture::start(&[], "lo", "tcp and host 127.0.0.1", &pcap)
        .unwrap_or_else(|why| panic!("{why}"));
    let (out, run) = swarm_run(&dir, None, &["max_steps=300"], Duration::from_secs(120));
    let said = capture.stop(&pcap);
    assert!(
        out.status.code().is_some_and(|c| c != 1),
        "{}",
        stderr(&out)
    );
    if let Some(n) = dropped(&said) {
        assert_eq!(n, 0, "the capture lost packets: {said}");
    }
    let bytes = std::fs::read(&pcap).expect("pcap written");
    let segs = segments(&bytes).unwrap_or_else(|e| panic!("{e}"));
    let totals = link_totals(&run.join("link_totals.csv"));
    assert!(!totals.is_empty());
    let c = compare(&totals, &segs);
    assert!(
        c.counted_total > 10_000,
        "too little traffic to compare:\n{}",
        c.report
    );
    assert!(
        c.ok,
        "netem's counters and the capture disagree:\n{}\ntcpdump said:\n{said}",
        c.report
    );
    eprintln!(
        "{}\ntotal: counted {}, captured {}",
        c.report, c.counted_total, c.captured_total
    );
}
