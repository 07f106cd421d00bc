//! Free ports for the processes of a run (on loopback, or on a host's address), so that several
//! runs (and tests) can go on side by side.
//!
//! Ports are chosen *below* the kernel's ephemeral range (`ip_local_port_range`): the kernel
//! hands ephemeral ports to every outgoing connection (every zenoh client, for one), so a port
//! taken from that range with bind-to-0 and released can be grabbed by an unrelated connection
//! before the child process binds it. Below the range only explicit binds compete; each port is
//! checked by binding it, the listeners are held until all `n` are found (so they are distinct),
//! and the search starts at a random offset so concurrent launchers rarely meet.

use std::net::{IpAddr, Ipv4Addr, SocketAddr, TcpListener};

/// Lowest port we use.
const LOW: u16 = 10_000;

/// Start of the kernel's ephemeral range (32768 if it cannot be read).
fn ephemeral_start() -> u16 {
    std::fs::read_to_string("/proc/sys/net/ipv4/ip_local_port_range")
        .ok()
        .and_then(|s| s.split_whitespace().next().and_then(|v| v.parse().ok()))
        .unwrap_or(32_768)
}

/// A pseudo-random number from the clock and the process id (no RNG crate needed for this).
fn jitter() -> u64 {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.subsec_nanos());
    (u64::from(nanos) ^ u64::from(std::process::id()).rotate_left(17))
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        >> 16
}

/// `n` distinct free TCP ports on 127.0.0.1.
pub fn free_ports(n: usize) -> std::io::Result<Vec<u16>> {
    free_ports_on(IpAddr::V4(Ipv4Addr::LOCALHOST), n)
}

/// `n` distinct free TCP ports on `ip` (an address of this host).
pub fn free_ports_on(ip: IpAddr, n: usize) -> std::io::Result<Vec<u16>> {
    let high = ephemeral_start().max(LOW + 1024);
    let span = u64::from(high - LOW);
    let start = jitter() % span;
    let mut held = Vec::with_capacity(n);
    for k in 0..span {
        if held.len() == n {
            break;
        }
        let port = LOW + ((start + k) % span) as u16;
        if let Ok(l) = TcpListener::bind((ip, port)) {
            held.push(l);
        }
    }
    if held.len() < n {
        return Err(std::io::Error::new(
            std::io::ErrorKind::AddrInUse,
            format!("only {} free ports below {high} on {ip}", held.len()),
        ));
    }
    held.iter()
        .map(|l| l.local_addr().map(|a| a.port()))
        .collect()
}

/// The zenoh endpoint of a TCP address.
pub fn endpoint(addr: SocketAddr) -> String {
    format!("tcp/{addr}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ports_are_distinct_free_and_below_the_ephemeral_range() {
        let ports = free_ports(40).unwrap_or_else(|e| panic!("{e}"));
        let mut sorted = ports.clone();
        sorted.sort_unstable();
        sorted.dedup();
        assert_eq!(sorted.len(), 40);
        assert!(ports
            .iter()
            .all(|&p| p >= LOW && p < ephemeral_start().max(LOW + 1024)));
        for p in ports {
            assert!(
                TcpListener::bind(("127.0.0.1", p)).is_ok(),
                "port {p} is free again"
            );
        }
    }
}
