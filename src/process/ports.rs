//! Free ports for the processes of a run (on loopback, or on a host's address), so that several
//! runs (and tests) can go on side by side.
//!
//! Ports are chosen *below* the kernel's ephemeral range (`ip_local_port_range`): the kernel hands
//! ephemeral ports to every outgoing connection (every zenoh client, for one), so a port taken from
//! that range with bind-to-0 and released can be grabbed by an unrelated connection before the
//! child process binds it. Below the range only explicit binds compete; each port is checked by
//! binding it (and let go at once: a run of 128 robots needs over 8 000 ports, more than a process
//! may usually hold open), the search walks the range from a random offset, so the ports are
//! distinct and concurrent launchers rarely meet. The check binds without `SO_REUSEADDR`, so a port
//! that any socket still holds — a connection netem accepted on it after closing its listener, or
//! one in TIME_WAIT — counts as taken.
//!
//! A port checked and let go is free until a child binds it, and another launcher searching at the
//! same moment could pick it too. So ports come in blocks of
//! [`BLOCK`](crate::process::ports::BLOCK), and a process takes ports only from blocks it holds: a
//! lock (`flock`) on the block's file in `$TMPDIR/swarm-ports/`, kept until the process exits — the
//! kernel lets go of the lock of a process that died, so a crashed launcher leaves no block taken.
//! Launchers on one machine never hand out the same port; a 128-robot run holds some 130 blocks.

use std::collections::BTreeMap;
use std::fs::File;
use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

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

/// Ports per block: a process hands out only ports of the blocks it holds.
pub const BLOCK: u16 = 64;

/// The blocks this process holds, each by its locked file (kept open until the process exits).
static HELD: Mutex<BTreeMap<u16, File>> = Mutex::new(BTreeMap::new());

/// Where the blocks' lock files are.
fn lock_dir() -> PathBuf {
    std::env::temp_dir().join("swarm-ports")
}

/// Whether `held` has block `b`, taking it if no other holder has it. Without a lock file (the
/// directory cannot be written) the block counts as held: the bind check alone decides.
fn hold(held: &mut BTreeMap<u16, File>, dir: &Path, b: u16) -> bool {
    if held.contains_key(&b) {
        return true;
    }
    let Ok(file) = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(dir.join(format!("{b}.lock")))
    else {
        return true;
    };
    match file.try_lock() {
        Ok(()) => {
            held.insert(b, file);
            true
        }
        Err(std::fs::TryLockError::WouldBlock) => false,
        Err(std::fs::TryLockError::Error(_)) => true,
    }
}

/// `n` distinct free TCP ports on `ip` (an address of this host).
pub fn free_ports_on(ip: IpAddr, n: usize) -> std::io::Result<Vec<u16>> {
    let dir = lock_dir();
    let _ = std::fs::create_dir_all(&dir);
    let mut held = HELD
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    free_ports_held(ip, n, &mut held, &dir)
}

/// [`free_ports_on`] with the blocks held in `held`, their lock files in `dir`.
fn free_ports_held(
    ip: IpAddr,
    n: usize,
    held: &mut BTreeMap<u16, File>,
    dir: &Path,
) -> std::io::Result<Vec<u16>> {
    let high = ephemeral_start().max(LOW + 1024);
    let span = u64::from(high - LOW);
    let start = jitter() % span;
    let mut found = Vec::with_capacity(n);
    // Each port of the range is tried once, so the ports found are distinct.
    for k in 0..span {
        if found.len() == n {
            break;
        }
        let port = LOW + ((start + k) % span) as u16;
        if !hold(held, dir, port / BLOCK) {
            continue;
        }
        match bind_alone(SocketAddr::new(ip, port)) {
            Ok(()) => found.push(port),
            // Out of descriptors is not a taken port: say so instead of searching on.
            Err(e) if e.raw_os_error() == Some(libc::EMFILE) => return Err(e),
            Err(_) => {}
        }
    }
    if found.len() < n {
        return Err(std::io::Error::new(
            std::io::ErrorKind::AddrInUse,
            format!(
                "only {} free ports between {LOW} and {high} on {ip}, {n} wanted",
                found.len()
            ),
        ));
    }
    Ok(found)
}

/// Binds `addr` without `SO_REUSEADDR` (a socket is created and dropped).
fn bind_alone(addr: SocketAddr) -> std::io::Result<()> {
    let socket = if addr.is_ipv4() {
        tokio::net::TcpSocket::new_v4()?
    } else {
        tokio::net::TcpSocket::new_v6()?
    };
    socket.bind(addr)
}

/// The zenoh endpoint of a TCP address.
pub fn endpoint(addr: SocketAddr) -> String {
    format!("tcp/{addr}")
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::net::{TcpListener, TcpStream};

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

    #[test]
    fn ports_come_only_from_blocks_nobody_else_holds() {
        let dir = std::env::temp_dir().join(format!("swarm-ports-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{e}"));
        let ip = IpAddr::V4(Ipv4Addr::LOCALHOST);
        let mut first = BTreeMap::new();
        let a = free_ports_held(ip, 200, &mut first, &dir).unwrap_or_else(|e| panic!("{e}"));
        // Another holder (its own open files, as another launcher's) gets none of them, and
        // holds none of the first one's blocks.
        let mut second = BTreeMap::new();
        for _ in 0..20 {
            let b = free_ports_held(ip, 200, &mut second, &dir).unwrap_or_else(|e| panic!("{e}"));
            assert!(b.iter().all(|p| !a.contains(p)), "a port handed out twice");
            assert!(b.iter().all(|p| !first.contains_key(&(p / BLOCK))));
        }
        assert!(second.keys().all(|b| !first.contains_key(b)));
        // Once the first holder is gone (its files closed), its blocks can be taken again.
        let blocks: Vec<u16> = first.keys().copied().collect();
        drop(first);
        assert!(blocks.iter().all(|&b| hold(&mut second, &dir, b)));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_port_a_connection_holds_is_taken_after_its_listener_closed() {
        // As netem does with a link in use: accept, then close the listener.
        let listener = TcpListener::bind("127.0.0.1:0").unwrap_or_else(|e| panic!("{e}"));
        let addr = listener.local_addr().unwrap_or_else(|e| panic!("{e}"));
        let _client = TcpStream::connect(addr).unwrap_or_else(|e| panic!("{e}"));
        let (_held, _) = listener.accept().unwrap_or_else(|e| panic!("{e}"));
        drop(listener);
        assert!(bind_alone(addr).is_err(), "{addr} is still netem's");
        // A plain rebind (SO_REUSEADDR, as netem's own) still succeeds.
        assert!(TcpListener::bind(addr).is_ok());
    }
}
