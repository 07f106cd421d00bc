//! Slurm, a cluster's scheduler, as a way to start processes (docs/guide/slurm.md): the hosts
//! of the allocation a launcher runs in (`swarm run --hosts slurm`), each process started on
//! its node as a step of the job by `srun`; and the client commands (`sbatch`, `squeue`,
//! `scontrol`) a sweep's job arrays use ([`crate::sweep::slurm`]).
//!
//! A step is on the leash of `swarm on-host`, as an ssh process is ([`crate::process::remote`]):
//! srun carries its stdin, so the launcher's freeze, thaw and kill reach the process, and a
//! launcher that dies closes it. `scancel` of the job ends every step and the launcher with it.
//!
//! **Invariant:** a process started through `srun` lives only as long as its `srun` and its job.

use std::net::{IpAddr, ToSocketAddrs};
use std::path::PathBuf;
use std::process::{Command, Stdio};

use anyhow::{bail, Context};

use crate::process::hosts::{Host, Hosts, Start, DEFAULT_REMOTE_DIR};

/// The value of `swarm run --hosts` that means "the nodes of this Slurm allocation".
pub const ALLOCATION: &str = "slurm";

/// Whether `--hosts VALUE` names the Slurm allocation rather than a hosts file.
pub fn is_allocation(value: &std::path::Path) -> bool {
    value.as_os_str() == ALLOCATION
}

/// Runs Slurm's client `program args…` and returns what it printed; an error names the
/// command and says what it printed on stderr (or that it is not installed).
pub fn tool(program: &str, args: &[String]) -> anyhow::Result<String> {
    let out = Command::new(program)
        .args(args)
        .stdin(Stdio::null())
        .output()
        .with_context(|| format!("running {program}: is Slurm's client installed here?"))?;
    if !out.status.success() {
        bail!(
            "`{program} {}` failed ({}): {}",
            args.join(" "),
            out.status,
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

/// The words that run one task on `node` as a step of the allocation, before the program:
/// one node, one task, sharing the allocation's CPUs with the run's other steps (`--overlap`:
/// a node runs several of the run's processes).
pub fn srun_words(node: &str) -> Vec<String> {
    [
        "srun",
        "--nodes=1",
        "--ntasks=1",
        "--overlap",
        "--quiet",
        "--cpu-bind=none",
    ]
    .map(String::from)
    .into_iter()
    .chain([format!("--nodelist={node}")])
    .collect()
}

/// The node names of a Slurm node list (`n[1-3],gpu7`), as `scontrol show hostnames` expands it.
fn node_names(list: &str) -> anyhow::Result<Vec<String>> {
    let out = tool(
        "scontrol",
        &["show".into(), "hostnames".into(), list.into()],
    )?;
    let names: Vec<String> = out.split_whitespace().map(String::from).collect();
    if names.is_empty() {
        bail!("the node list {list:?} names no node");
    }
    Ok(names)
}

/// `NodeAddr=` of one line of `scontrol show node -o`.
fn node_addr_field(line: &str) -> Option<&str> {
    line.split_whitespace()
        .find_map(|w| w.strip_prefix("NodeAddr="))
}

/// The address a node's processes bind and are reached at: its `NodeAddr`, resolved.
fn node_address(name: &str) -> anyhow::Result<IpAddr> {
    let line = tool(
        "scontrol",
        &["show".into(), "node".into(), "-o".into(), name.into()],
    )?;
    let addr = node_addr_field(&line)
        .with_context(|| format!("`scontrol show node {name}` gives no NodeAddr"))?;
    if let Ok(ip) = addr.parse() {
        return Ok(ip);
    }
    (addr, 0)
        .to_socket_addrs()
        .ok()
        .and_then(|mut a| a.next())
        .map(|a| a.ip())
        .with_context(|| format!("node {name}: its NodeAddr {addr:?} does not resolve"))
}

/// The hosts of the Slurm allocation this process runs in (`SLURM_JOB_NODELIST`): one per
/// node, at its `NodeAddr`; the node the launcher runs on (`SLURMD_NODENAME`, in a batch
/// script) starts its processes itself and takes the world-server and netem, every other node
/// through `srun`. Robots go round-robin over every node.
pub fn allocation() -> anyhow::Result<Hosts> {
    let Ok(list) = std::env::var("SLURM_JOB_NODELIST") else {
        bail!(
            "--hosts slurm: not inside a Slurm allocation (SLURM_JOB_NODELIST is not set): \
             run it in an `sbatch` script or under `salloc`"
        );
    };
    let here = std::env::var("SLURMD_NODENAME").ok();
    let names = node_names(&list)?;
    let sim = match &here {
        Some(h) if names.contains(h) => h.clone(),
        _ => names[0].clone(),
    };
    let hosts = names
        .iter()
        .map(|name| {
            Ok(Host {
                name: name.clone(),
                address: node_address(name)?,
                start: if here.as_ref() == Some(name) {
                    Start::Local
                } else {
                    Start::Srun { node: name.clone() }
                },
                dir: PathBuf::from(DEFAULT_REMOTE_DIR),
            })
        })
        .collect::<anyhow::Result<Vec<Host>>>()?;
    let job = std::env::var("SLURM_JOB_ID").unwrap_or_default();
    Ok(Hosts::assemble(
        &format!("the Slurm allocation {job} ({list})"),
        hosts,
        &sim,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_step_is_one_task_on_its_node_sharing_the_allocation() {
        let w = srun_words("n2");
        assert_eq!(w[0], "srun");
        for flag in ["--nodes=1", "--ntasks=1", "--overlap", "--nodelist=n2"] {
            assert!(w.iter().any(|x| x == flag), "{flag} in {w:?}");
        }
    }

    #[test]
    fn the_node_address_is_read_from_scontrols_line() {
        let line = "NodeName=n1 Arch=x86_64 CoresPerSocket=2 NodeAddr=10.1.2.3 \
                    NodeHostName=vm Version=22.05.8";
        assert_eq!(node_addr_field(line), Some("10.1.2.3"));
        assert_eq!(node_addr_field("NodeName=n1 State=IDLE"), None);
    }

    #[test]
    fn only_the_word_slurm_names_the_allocation() {
        assert!(is_allocation(std::path::Path::new("slurm")));
        for file in ["./slurm", "slurm.toml", "hosts/slurm"] {
            assert!(!is_allocation(std::path::Path::new(file)), "{file}");
        }
    }
}
