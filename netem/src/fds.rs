//! The file descriptors netem holds, and the limit on them.
//!
//! Per pair of radio nodes netem holds two descriptors: a link that is down, its listener and
//! the robot's connection it holds until the link comes up; a link in use, the two sockets of the
//! connection it carries (the robot's, and its own to the peer's listener) — its listener is
//! closed meanwhile ([`crate::link::Link::serve`]). So a team of n nodes whose proxies have
//! fixed ports (`--pair`) needs about n(n−1) descriptors: 16 256 at 128 robots (a third more if
//! listeners stayed open: with every pair in range at once — a spawn cluster in a 10 m disk
//! range — 24 384, beyond this project's 2-core test machine's hard limit of 20 000). A proxy
//! that listens while its link is up (`--node`, how `swarm run` starts netem) holds nothing
//! while the link is down: two descriptors per pair in range (256 robots spread 1.5 m apart
//! with a 4 m range: at most 4 391 descriptors, docs/results.md T8). A process starts with a
//! soft limit of often 1 024; netem raises it to the hard limit, which only the administrator
//! can raise, and says at start when even that may not do (counting the fixed-port pairs).

/// Descriptors netem holds besides its links': the runtime, zenoh's sim-plane session, the
/// HTTP API and its clients, logs.
pub const RESERVE: u64 = 1024;

/// The descriptors netem may need for `pairs` links: two per pair (a link opening a connection
/// holds three for a moment, within [`RESERVE`]).
pub fn needed(pairs: usize) -> u64 {
    2 * pairs as u64 + RESERVE
}

/// Raises this process's soft limit on open files to its hard limit; returns the limit now in
/// force.
#[allow(unsafe_code)]
pub fn raise_limit() -> std::io::Result<u64> {
    let mut lim = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: `lim` is a valid rlimit for getrlimit to fill and setrlimit to read.
    if unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut lim) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    if lim.rlim_cur < lim.rlim_max {
        let raised = libc::rlimit {
            rlim_cur: lim.rlim_max,
            rlim_max: lim.rlim_max,
        };
        // SAFETY: as above.
        if unsafe { libc::setrlimit(libc::RLIMIT_NOFILE, &raised) } != 0 {
            return Err(std::io::Error::last_os_error());
        }
        lim = raised;
    }
    Ok(lim.rlim_cur)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_limit_rises_to_the_hard_limit_and_stays_there() {
        let first = raise_limit().unwrap_or_else(|e| panic!("{e}"));
        assert!(first >= 64, "a usable limit: {first}");
        assert_eq!(
            raise_limit().ok(),
            Some(first),
            "raising again changes nothing"
        );
    }

    #[test]
    fn two_descriptors_per_pair() {
        assert_eq!(needed(0), RESERVE);
        assert_eq!(needed(8128), 16_256 + RESERVE);
    }
}
