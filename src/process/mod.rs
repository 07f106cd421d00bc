//! The processes of a run: starting them here or on other hosts, watching them, faults and
//! restarts.

/// Child processes: spawn, watch, reap.
pub mod children;
/// Where the processes of a run go: the hosts file (`swarm run --hosts`) and its placement.
pub mod hosts;
/// Free ports (loopback, or a host's address), reserved across launchers.
pub mod ports;
/// Starting processes on a host (ssh, a command prefix) and `swarm host-info`.
pub mod remote;
/// Slurm: the hosts of an allocation, its processes started by srun; the client commands.
pub mod slurm;
/// Supervision and process faults: kill, restart, freeze, thaw; restarts by policy.
pub mod supervise;
