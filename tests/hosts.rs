//! A run spread over hosts (`swarm run --hosts`), with Linux network namespaces as the hosts:
//! the test makes them itself (one veth each onto a bridge in a namespace of its own, addresses
//! it chooses, no default route), runs every process of the run inside them — the launcher
//! included — and deletes them when it ends, also on failure. Nothing in the root namespace
//! sends to their addresses. Where namespaces cannot be made (not root), the tests say so and
//! pass without running — unless `SWARM_REQUIRE_NETNS` is set (CI sets it).

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use crate::support::{run_args, stderr, summary, Launcher, TempDir, SWARM};

/// Namespaces made by one test: `<tag>-h0` … (the hosts) and `<tag>-sw` (their switch).
struct Lab {
    tag: String,
    hosts: usize,
}

/// The address of host `k` in the lab's subnet.
fn address(k: usize) -> String {
    format!("10.77.0.{}", k + 1)
}

fn ip(args: &[&str]) -> Result<(), String> {
    let out = Command::new("ip")
        .args(args)
        .stdin(Stdio::null())
        .output()
        .map_err(|e| format!("ip {}: {e}", args.join(" ")))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "ip {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        ))
    }
}

impl Lab {
    /// `hosts` namespaces on one bridge; `Err` with the reason when this machine cannot.
    fn new(name: &str, hosts: usize) -> Result<Lab, String> {
        let tag = format!("sx{}{name}", std::process::id() % 100_000);
        let lab = Lab { tag, hosts: 0 };
        let sw = lab.switch();
        ip(&["netns", "add", &sw])?;
        let mut lab = lab;
        ip(&["-n", &sw, "link", "add", "br0", "type", "bridge"])?;
        ip(&["-n", &sw, "link", "set", "br0", "up"])?;
        for k in 0..hosts {
            let h = lab.host(k);
            ip(&["netns", "add", &h])?;
            lab.hosts = k + 1;
            let (inner, outer) = (format!("v{k}"), format!("p{k}"));
            ip(&[
                "-n", &h, "link", "add", &inner, "type", "veth", "peer", "name", &outer,
            ])?;
            ip(&["-n", &h, "link", "set", &outer, "netns", &sw])?;
            ip(&["-n", &sw, "link", "set", &outer, "master", "br0", "up"])?;
            ip(&[
                "-n",
                &h,
                "addr",
                "add",
                &format!("{}/24", address(k)),
                "dev",
                &inner,
            ])?;
            ip(&["-n", &h, "link", "set", &inner, "up"])?;
            ip(&["-n", &h, "link", "set", "lo", "up"])?;
        }
        Ok(lab)
    }

    fn switch(&self) -> String {
        format!("{}-sw", self.tag)
    }

    fn host(&self, k: usize) -> String {
        format!("{}-h{k}", self.tag)
    }

    /// A command run inside host `k`.
    fn exec(&self, k: usize, program: &str) -> Command {
        let mut c = Command::new("ip");
        c.args(["netns", "exec", &self.host(k), program]);
        c
    }
}

impl Drop for Lab {
    fn drop(&mut self) {
        // Whatever still runs in a namespace goes with it.
        for k in 0..self.hosts {
            let h = self.host(k);
            if let Ok(out) = Command::new("ip").args(["netns", "pids", &h]).output() {
                for pid in String::from_utf8_lossy(&out.stdout).split_whitespace() {
                    let _ = Command::new("kill").args(["-9", pid]).status();
                }
            }
            let _ = ip(&["netns", "del", &h]);
        }
        let _ = ip(&["netns", "del", &self.switch()]);
    }
}

/// The lab, or `None` after saying why the test cannot run here.
fn lab(name: &str, hosts: usize) -> Option<Lab> {
    match Lab::new(name, hosts) {
        Ok(l) => Some(l),
        Err(e) if std::env::var_os("SWARM_REQUIRE_NETNS").is_some() => {
            panic!("cannot make network namespaces, and SWARM_REQUIRE_NETNS is set: {e}")
        }
        Err(e) => {
            eprintln!("SKIPPED: cannot make network namespaces on this machine ({e}); run as root");
            None
        }
    }
}

/// A hosts file: host `h0` is where the launcher runs (local to it), `h1…` are reached with
/// `ip netns exec`; the world-server and netem on `h0`, robots as `robots` says.
fn hosts_file(lab: &Lab, path: &Path, robots: &str) {
    let mut text = format!("[hosts.h0]\naddress = \"{}\"\n", address(0));
    for k in 1..lab.hosts {
        text.push_str(&format!(
            "[hosts.h{k}]\naddress = \"{}\"\ncommand = [\"ip\", \"netns\", \"exec\", \"{}\"]\n",
            address(k),
            lab.host(k)
        ));
    }
    text.push_str(&format!(
        "[placement]\nworld-server = \"h0\"\nnetem = \"h0\"\nrobots = {robots}\n"
    ));
    std::fs::write(path, text).expect("write hosts.toml");
}

#[test]
fn a_run_over_four_namespaces_completes_and_equals_the_same_run_on_one_host() {
    let Some(lab) = lab("four", 4) else {
        return;
    };
    let dir = TempDir::new("hosts-four");
    let hosts = dir.path().join("hosts.toml");
    hosts_file(
        &lab,
        &hosts,
        "{ h1 = [0, 3, 6], h2 = [1, 4, 7], h3 = \"rest\" }",
    );
    let sets = ["robots.count=8"];
    let spread = dir.path().join("spread");
    let mut cmd = lab.exec(0, SWARM);
    run_args(&mut cmd, &spread, &sets);
    cmd.arg("--hosts").arg(&hosts);
    let out = Launcher::spawn(cmd).wait_output(Duration::from_secs(600));
    let s = summary(&spread);
    assert_eq!(out.status.code(), Some(0), "{}\n{s}", stderr(&out));
    assert_eq!(s["complete"], true, "{s}");
    assert_eq!(s["robots_alive_at_end"], 8, "{s}");
    // The sim plane's router listened on h0's address, not loopback.
    let endpoint = std::fs::read_to_string(spread.join("sim.endpoint")).unwrap_or_default();
    assert!(endpoint.contains(&address(0)), "{endpoint}");
    // The same scenario on one host (loopback), in the first namespace.
    let single = dir.path().join("single");
    let mut cmd = lab.exec(0, SWARM);
    run_args(&mut cmd, &single, &sets);
    let out = Launcher::spawn(cmd).wait_output(Duration::from_secs(600));
    let one = summary(&single);
    assert_eq!(out.status.code(), Some(0), "{}\n{one}", stderr(&out));
    assert_eq!(s["deterministic"], true, "{s}");
    assert_eq!(one["deterministic"], true, "{one}");
    assert_eq!(
        s["run_digest"], one["run_digest"],
        "the spread run differs from the run on one host"
    );
}
