//! A run spread over hosts (`swarm run --hosts`), with Linux network namespaces as the hosts:
//! the test makes them itself (one veth each onto a bridge in a namespace of its own, addresses
//! it chooses, no default route), runs every process of the run inside them — the launcher
//! included — and deletes them when it ends, also on failure. One host is reached over real
//! ssh: an `sshd` the test starts inside that namespace, with a key made for the test. Nothing
//! in the root namespace sends to their addresses. They need root, iproute2, sshd and tcpdump,
//! so they are ignored by default; `.ci/run` installs the tools and runs them with
//! `--include-ignored`. Where they run, a lab that cannot be made fails the test.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use crate::capture::{compare, dropped, link_totals, segments, Capture};
use crate::support::{
    poll, run_args, stderr, summary_typed, wait_for_step, wait_steps, Launcher, TempDir, SWARM,
};

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

/// The reason every test here is ignored by default.
const NEEDS: &str = "needs root, iproute2, openssh-server and tcpdump: apt install iproute2 openssh-server openssh-client tcpdump";

/// `value`, or a failure naming what could not be made.
fn made<T>(what: &str, made: Result<T, String>) -> T {
    made.unwrap_or_else(|e| panic!("cannot make {what} ({NEEDS}): {e}"))
}

/// The lab (a failure where namespaces cannot be made).
fn lab(name: &str, hosts: usize) -> Lab {
    made("network namespaces", Lab::new(name, hosts))
}

/// An `sshd` inside one host of a lab, with a host key and a client key made for it; killed on
/// drop (and with the lab's namespace).
struct Sshd {
    child: Option<Child>,
    /// The ssh options that log in with the test's key, trusting this sshd's host key.
    options: Vec<String>,
    /// `user@address`.
    target: String,
}

impl Sshd {
    fn start(lab: &Lab, k: usize, dir: &Path) -> Result<Sshd, String> {
        let sshd = "/usr/sbin/sshd";
        if !Path::new(sshd).is_file() {
            return Err(format!("no {sshd} (apt-get install openssh-server)"));
        }
        let keygen = |name: &str| -> Result<PathBuf, String> {
            let key = dir.join(name);
            let st = Command::new("ssh-keygen")
                .args(["-q", "-t", "ed25519", "-N", "", "-f"])
                .arg(&key)
                .stdin(Stdio::null())
                .status()
                .map_err(|e| format!("ssh-keygen: {e}"))?;
            st.success()
                .then_some(key)
                .ok_or("ssh-keygen failed".into())
        };
        let (host_key, client_key) = (keygen("host_key")?, keygen("client_key")?);
        let public = std::fs::read_to_string(client_key.with_extension("pub"))
            .map_err(|e| format!("client key: {e}"))?;
        let authorized = dir.join("authorized_keys");
        std::fs::write(&authorized, public).map_err(|e| e.to_string())?;
        let known = dir.join("known_hosts");
        let host_public = std::fs::read_to_string(host_key.with_extension("pub"))
            .map_err(|e| format!("host key: {e}"))?;
        std::fs::write(&known, format!("{} {host_public}", address(k)))
            .map_err(|e| e.to_string())?;
        let user = String::from_utf8_lossy(
            &Command::new("id")
                .arg("-un")
                .output()
                .map_err(|e| format!("id -un: {e}"))?
                .stdout,
        )
        .trim()
        .to_string();
        let config = dir.join("sshd_config");
        std::fs::write(
            &config,
            format!(
                "ListenAddress {addr}:22\nHostKey {hk}\nAuthorizedKeysFile {ak}\nPidFile {dir}/sshd.pid\n\
                 StrictModes no\nUsePAM no\nPasswordAuthentication no\nKbdInteractiveAuthentication no\n\
                 PermitRootLogin prohibit-password\nAllowUsers {user}\nLogLevel ERROR\n",
                addr = address(k),
                hk = host_key.display(),
                ak = authorized.display(),
                dir = dir.display(),
            ),
        )
        .map_err(|e| e.to_string())?;
        // sshd wants its privilege separation directory.
        let _ = std::fs::create_dir_all("/run/sshd");
        let child = lab
            .exec(k, sshd)
            .args(["-D", "-e", "-f"])
            .arg(&config)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .spawn()
            .map_err(|e| format!("starting sshd: {e}"))?;
        let options = vec![
            "-i".to_string(),
            client_key.display().to_string(),
            "-o".into(),
            format!("UserKnownHostsFile={}", known.display()),
            "-o".into(),
            "StrictHostKeyChecking=yes".into(),
            "-o".into(),
            "LogLevel=ERROR".into(),
        ];
        let sshd = Sshd {
            child: Some(child),
            options,
            target: format!("{user}@{}", address(k)),
        };
        // Up once a login from host 0 works.
        let deadline = Instant::now() + Duration::from_secs(15);
        loop {
            let out = lab
                .exec(0, "ssh")
                .args(["-o", "BatchMode=yes"])
                .args(&sshd.options)
                .args([&sshd.target, "--", "true"])
                .stdin(Stdio::null())
                .output()
                .map_err(|e| format!("ssh: {e}"))?;
            if out.status.success() {
                return Ok(sshd);
            }
            if Instant::now() > deadline {
                return Err(format!(
                    "no ssh login to {} within 15 s: {}",
                    sshd.target,
                    String::from_utf8_lossy(&out.stderr).trim()
                ));
            }
            std::thread::sleep(Duration::from_millis(200));
        }
    }
}

impl Drop for Sshd {
    fn drop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

/// A hosts file: host `h0` is where the launcher runs (local to it), `h1…` are reached with
/// `ip netns exec`, but host `ssh.0` over ssh with `ssh.1`'s login; the world-server and netem
/// on `h0`, robots as `robots` says.
fn hosts_file(lab: &Lab, path: &Path, robots: &str, ssh: Option<(usize, &Sshd, &Path)>) {
    let mut text = format!("[hosts.h0]\naddress = \"{}\"\n", address(0));
    for k in 1..lab.hosts {
        text.push_str(&format!("[hosts.h{k}]\naddress = \"{}\"\n", address(k)));
        match ssh {
            Some((s, sshd, dir)) if s == k => text.push_str(&format!(
                "ssh = \"{}\"\nssh_options = {:?}\nswarm = {:?}\ndir = {:?}\n",
                sshd.target,
                sshd.options,
                SWARM,
                dir.display().to_string()
            )),
            _ => text.push_str(&format!(
                "command = [\"ip\", \"netns\", \"exec\", \"{}\"]\n",
                lab.host(k)
            )),
        }
    }
    text.push_str(&format!(
        "[placement]\nworld-server = \"h0\"\nnetem = \"h0\"\nrobots = {robots}\n"
    ));
    std::fs::write(path, text).expect("write hosts.toml");
}

/// Four hosts, the last (h3) reached over ssh: `h0` runs the launcher, the world-server and
/// netem; robots as `robots` places them.
struct SshLab {
    sshd: Sshd,
    lab: Lab,
    /// Where h3 keeps its copy of a run.
    remote: PathBuf,
    hosts: PathBuf,
    dir: TempDir,
}

/// The [`SshLab`] (a failure where it cannot be made).
fn ssh_lab(name: &str, robots: &str) -> SshLab {
    let lab = lab(name, 4);
    let dir = TempDir::new(&format!("hosts-{name}"));
    let sshd = made("an sshd in a namespace", Sshd::start(&lab, 3, dir.path()));
    let remote = dir.path().join("remote");
    let hosts = dir.path().join("hosts.toml");
    hosts_file(&lab, &hosts, robots, Some((3, &sshd, &remote)));
    SshLab {
        sshd,
        lab,
        remote,
        hosts,
        dir,
    }
}

#[test]
#[ignore = "needs root, iproute2, openssh-server and tcpdump: apt install iproute2 openssh-server openssh-client tcpdump"]
fn a_run_over_four_namespaces_one_over_ssh_crosses_netem_and_equals_the_same_run_on_one_host() {
    // Bound in this order, dropped in the reverse: sshd, the namespaces, then the files.
    let SshLab {
        dir,
        hosts,
        remote,
        lab,
        sshd,
    } = ssh_lab("four", "{ h1 = [0, 3, 6], h2 = [1, 4, 7], h3 = \"rest\" }");
    // Every radio byte crosses h0's port of the bridge: netem runs on h0, every robot elsewhere.
    let pcap = dir.path().join("bridge.pcap");
    let capture = made(
        "a capture on the lab's bridge",
        Capture::start(&["ip", "netns", "exec", &lab.switch()], "p0", "tcp", &pcap),
    );
    let sets = ["robots.count=8"];
    let spread = dir.path().join("spread");
    let mut cmd = lab.exec(0, SWARM);
    run_args(&mut cmd, &spread, &sets);
    cmd.arg("--hosts").arg(&hosts);
    let out = Launcher::spawn(cmd).wait_output(Duration::from_secs(600));
    let said = capture.stop(&pcap);
    let s = summary_typed(&spread);
    assert_eq!(out.status.code(), Some(0), "{}\n{s:?}", stderr(&out));
    assert!(s.complete, "{s:?}");
    assert_eq!(s.robots_alive_at_end, 8, "{s:?}");
    // The sim plane's router listened on h0's address, not loopback.
    let endpoint = std::fs::read_to_string(spread.join("sim.endpoint")).unwrap_or_default();
    assert!(endpoint.contains(&address(0)), "{endpoint}");
    // The robots on h3 ran over ssh, on a leash (their memory is not sampled: the launcher's
    // child is the ssh client) and ended well; the host's copy of the run (with their logins)
    // is gone.
    let rows: Vec<swarm::process::children::ProcessRow> =
        swarm::rundir::tables::read_rows(&spread.join("processes.csv")).expect("processes.csv");
    for r in &rows {
        let over_ssh = ["robot-2", "robot-5"].contains(&r.process.as_str());
        assert_eq!(r.exit, "exit code 0", "{r:?}");
        assert_eq!(r.peak_rss_kb == 0, over_ssh, "{r:?}");
        assert_eq!(r.peak_threads == 0, over_ssh, "{r:?}");
        assert_eq!(r.peak_fds == 0, over_ssh, "{r:?}");
    }
    let leftover: Vec<_> = std::fs::read_dir(&remote)
        .map(|d| d.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    assert!(leftover.is_empty(), "left on the ssh host: {leftover:?}");
    // Every pair's link crossed netem, and netem's counters equal the bridge's bytes.
    let totals = link_totals(&spread.join("link_totals.csv"));
    assert_eq!(totals.len(), 8 * 7 / 2);
    if let Some(n) = dropped(&said) {
        assert_eq!(n, 0, "the capture lost packets: {said}");
    }
    let segs =
        segments(&std::fs::read(&pcap).expect("pcap written")).unwrap_or_else(|e| panic!("{e}"));
    let c = compare(&totals, &segs);
    assert!(
        c.counted_total > 10_000,
        "too little traffic:\n{}",
        c.report
    );
    assert!(
        c.ok,
        "netem's counters and the bridge disagree:\n{}\ntcpdump said:\n{said}",
        c.report
    );
    eprintln!(
        "bridge: counted {}, captured {}",
        c.counted_total, c.captured_total
    );

    // The same scenario on one host (loopback), in the first namespace.
    let single = dir.path().join("single");
    let mut cmd = lab.exec(0, SWARM);
    run_args(&mut cmd, &single, &sets);
    let out = Launcher::spawn(cmd).wait_output(Duration::from_secs(600));
    let one = summary_typed(&single);
    assert_eq!(out.status.code(), Some(0), "{}\n{one:?}", stderr(&out));
    assert!(s.deterministic, "{s:?}");
    assert!(one.deterministic, "{one:?}");
    assert_eq!(
        s.run_digest, one.run_digest,
        "the spread run differs from the run on one host"
    );
    // Nothing of either run is left on any host (h3 runs only its sshd).
    let sshd_pid: Vec<u32> = sshd.child.as_ref().map(Child::id).into_iter().collect();
    assert_eq!(
        lab.leftover(&sshd_pid),
        Vec::<(usize, u32)>::new(),
        "left (host, pid)"
    );
}

impl Lab {
    /// The processes running in host `k`'s namespace.
    fn pids(&self, k: usize) -> Vec<u32> {
        Command::new("ip")
            .args(["netns", "pids", &self.host(k)])
            .output()
            .map(|o| {
                String::from_utf8_lossy(&o.stdout)
                    .split_whitespace()
                    .filter_map(|p| p.parse().ok())
                    .collect()
            })
            .unwrap_or_default()
    }

    /// The processes running in any host's namespace, but those `except`, as (host, pid).
    fn leftover(&self, except: &[u32]) -> Vec<(usize, u32)> {
        (0..self.hosts)
            .flat_map(|k| self.pids(k).into_iter().map(move |p| (k, p)))
            .filter(|(_, p)| !except.contains(p))
            .collect()
    }

    /// SIGKILLs every process in host `k`'s namespace (the host drops); how many there were.
    fn kill_host(&self, k: usize) -> usize {
        let pids = self.pids(k);
        for &pid in &pids {
            // Quietly: a process may end by itself meanwhile.
            let _ = Command::new("kill")
                .args(["-9", &pid.to_string()])
                .stderr(Stdio::null())
                .status();
        }
        pids.len()
    }
}

/// Waits until host `k` runs at least `n` processes.
fn wait_for_processes(lab: &Lab, k: usize, n: usize) {
    poll(Duration::from_secs(60), Duration::from_millis(100), || {
        (lab.pids(k).len() >= n)
            .then_some(())
            .ok_or_else(|| format!("host {k} never ran {n} processes"))
    })
}

/// A host's processes SIGKILLed mid-run, as a local kill: the robots of a command-prefix host
/// (the host still up) are started again by supervision and rejoin; an ssh host that drops
/// whole (its sshd with it) loses its robots for good — their restarts fail, the run goes on
/// with the rest. Afterwards no process of the run is left on any host.
#[test]
#[ignore = "needs root, iproute2, openssh-server and tcpdump: apt install iproute2 openssh-server openssh-client tcpdump"]
fn a_host_killed_mid_run_degrades_the_run_like_a_local_kill_and_leaves_no_process() {
    // Bound in this order, dropped in the reverse: sshd, the namespaces, then the files.
    let SshLab {
        dir,
        hosts,
        remote: _,
        lab,
        sshd,
    } = ssh_lab("drop", "{ h1 = [0, 3, 6], h2 = [1, 4, 7], h3 = \"rest\" }");
    let run = dir.path().join("run");
    let mut cmd = lab.exec(0, SWARM);
    run_args(&mut cmd, &run, &["robots.count=8"]);
    cmd.arg("--hosts").arg(&hosts);
    let launcher = Launcher::spawn(cmd);
    // h2 runs robots 1, 4, 7; h3 its sshd and, for robots 2 and 5, a session, `swarm on-host`
    // and the robot each.
    wait_for_processes(&lab, 2, 3);
    wait_for_processes(&lab, 3, 5);
    // At steps of the run, not at wall-clock moments (after 3 s and 2 s more the run could be
    // ending): h2 at step 10, h3 ten steps later.
    wait_for_step(&run, 10, Duration::from_secs(120));
    assert_eq!(lab.kill_host(2), 3, "h2's robots");
    wait_steps(&run, 10, Duration::from_secs(120));
    assert!(lab.kill_host(3) >= 5, "h3's sshd, sessions and robots");
    drop(sshd);
    let out = launcher.wait_output(Duration::from_secs(600));
    let s = summary_typed(&run);
    assert!(
        matches!(out.status.code(), Some(0 | 2)),
        "{}\n{s:?}",
        stderr(&out)
    );
    crate::support::assert_killed_and_supervised(&s, &["robot-1", "robot-4", "robot-7"]);
    assert_eq!(s.nodes_alive_at_end, [0, 1, 3, 4, 6, 7], "{s:?}");
    assert_eq!(
        lab.leftover(&[]),
        Vec::<(usize, u32)>::new(),
        "left (host, pid)"
    );
}

/// A launcher killed with SIGKILL mid-run leaves nothing on any host: the processes it
/// started by a command prefix die with it (parent-death signal), those on the ssh host when
/// their ssh connections end (`swarm on-host`).
#[test]
#[ignore = "needs root, iproute2, openssh-server and tcpdump: apt install iproute2 openssh-server openssh-client tcpdump"]
fn a_launcher_killed_mid_run_leaves_no_process_on_any_host() {
    // Bound in this order, dropped in the reverse: sshd, the namespaces, then the files.
    let SshLab {
        dir,
        hosts,
        remote: _,
        lab,
        sshd,
    } = ssh_lab("orphan", "{ h1 = [0, 3], h2 = [1, 4], h3 = \"rest\" }");
    let run = dir.path().join("run");
    let mut cmd = lab.exec(0, SWARM);
    run_args(&mut cmd, &run, &["robots.count=6"]);
    cmd.arg("--hosts").arg(&hosts);
    let launcher = Launcher::spawn(cmd);
    wait_for_processes(&lab, 3, 5);
    wait_for_step(&run, 10, Duration::from_secs(120));
    crate::support::kill(launcher.pid, 9);
    let mut except: Vec<u32> = sshd.child.as_ref().map(Child::id).into_iter().collect();
    except.push(launcher.pid);
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let left = lab.leftover(&except);
        if left.is_empty() {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "20 s after the launcher was killed, still running (host, pid): {left:?}"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    drop(launcher);
}

/// The mean bytes per step robot 0 sent robot 1 over steps `from..` of a run (`links.csv`).
fn a_to_b_per_step(run: &Path, from: u64) -> f64 {
    let rows: Vec<swarm::rundir::tables::LinkCsv> =
        swarm::rundir::tables::read_rows(&run.join("links.csv")).expect("links.csv");
    let bytes: Vec<u64> = rows
        .iter()
        .filter(|r| r.a == 0 && r.b == 1 && u64::from(r.step) >= from)
        .map(|r| r.bytes_a_to_b)
        .collect();
    assert!(bytes.len() > 20, "too few steps: {}", bytes.len());
    bytes.iter().sum::<u64>() as f64 / bytes.len() as f64
}

/// A second, independent shaper: the Linux kernel's token bucket filter (`tc tbf`) on the veth
/// of robot 0's namespace, at the rate netem shapes the link to, with netem's own shaping off —
/// the link carries what netem's shaping lets it carry, within 5 %. Realtime clock; robot 0
/// offers its raw scans, about twice the rate, to the base station (which offers little back,
/// so robot 0's acknowledgements hardly cost tbf anything). Robots pace themselves to the
/// scenario's rate, so the scenario's is unlimited (0) and netem's rate is a bandwidth toxic on
/// the link; the control run, with neither shaper, shows what robot 0 offers. tbf counts whole
/// frames; a size table (`stab overhead`) takes the Ethernet, IP and TCP headers of each packet
/// off, so that it counts what netem counts: TCP payload.
#[test]
#[ignore = "needs root, iproute2, openssh-server and tcpdump: apt install iproute2 openssh-server openssh-client tcpdump"]
fn the_kernels_tbf_shapes_a_link_as_netem_does() {
    let lab = lab("tbf", 4);
    let dir = TempDir::new("hosts-tbf");
    let hosts = dir.path().join("hosts.toml");
    let mut text = String::new();
    for k in 0..lab.hosts {
        text.push_str(&format!("[hosts.h{k}]\naddress = \"{}\"\n", address(k)));
        if k > 0 {
            text.push_str(&format!(
                "command = [\"ip\", \"netns\", \"exec\", \"{}\"]\n",
                lab.host(k)
            ));
        }
    }
    text.push_str(
        "[placement]\nworld-server = \"h0\"\nnetem = \"h1\"\nbase-station = \"h3\"\nrobots = { h2 = [0] }\n",
    );
    std::fs::write(&hosts, text).expect("write hosts.toml");
    const RATE: u64 = 300;
    const SPEEDUP: u64 = 5;
    let sets = [
        "robots.count=1".to_string(),
        "base_station.enabled=true".into(),
        "exchange.mode=raw-scans".into(),
        "radio.model=always".into(),
        "radio.bandwidth_bytes_per_s=0".into(),
        "robots.speed_m_per_s=0.001".into(),
        "clock.mode=realtime".into(),
        format!("clock.speedup={SPEEDUP}"),
        "max_steps=150".into(),
    ];
    let sets: Vec<&str> = sets.iter().map(String::as_str).collect();
    let run = |name: &str, scenario: Option<&Path>| -> PathBuf {
        let out = dir.path().join(name);
        let mut cmd = lab.exec(0, SWARM);
        run_args(&mut cmd, &out, &sets);
        cmd.arg("--hosts").arg(&hosts);
        if let Some(s) = scenario {
            cmd.arg(s);
        }
        let o = Launcher::spawn(cmd).wait_output(Duration::from_secs(300));
        assert!(matches!(o.status.code(), Some(0 | 2)), "{}", stderr(&o));
        out
    };
    let offered = a_to_b_per_step(&run("unshaped", None), 50);
    assert!(
        offered > 1.5 * RATE as f64,
        "robot 0 offers only {offered:.1} B/s: the comparison needs a link it saturates"
    );
    let by_netem_file = dir.path().join("netem.toml");
    std::fs::write(
        &by_netem_file,
        format!(
            "[[faults]]\nstep = 0\nkind = \"set_toxic\"\npair = [0, 1]\n\
             toxic = {{ type = \"bandwidth\", stream = \"both\", attributes = {{ rate_bytes_per_s = {RATE} }} }}\n"
        ),
    )
    .expect("write scenario");
    let by_netem = a_to_b_per_step(&run("netem", Some(&by_netem_file)), 50);
    let h2 = lab.host(2);
    let tc = |args: &str| {
        let st = Command::new("ip")
            .args(["netns", "exec", &h2, "tc"])
            .args(args.split_whitespace())
            .status()
            .expect("tc");
        assert!(st.success(), "tc {args}");
    };
    // The wall-clock rate is the scenario's times the clock's speed-up.
    let bits = RATE * SPEEDUP * 8;
    // One TCP segment per packet (no segmentation offload), so that the size table takes the
    // headers off each segment.
    let st = Command::new("ip")
        .args(["-n", &h2, "link", "set", "dev", "v2", "gso_max_segs", "1"])
        .status()
        .expect("ip link");
    assert!(st.success(), "ip link set gso_max_segs");
    // htb only sorts: what goes to netem's host into class 1:10, under tbf; the rest (the sim
    // plane) into 1:20, unshaped.
    tc("qdisc add dev v2 root handle 1: stab overhead -66 htb default 20 r2q 100000");
    tc("class add dev v2 parent 1: classid 1:10 htb rate 1gbit");
    tc("class add dev v2 parent 1: classid 1:20 htb rate 1gbit");
    tc(&format!(
        "qdisc add dev v2 parent 1:10 handle 10: tbf rate {bits}bit burst 1600 latency 2s"
    ));
    tc(&format!(
        "filter add dev v2 parent 1: protocol ip prio 1 u32 match ip dst {}/32 flowid 1:10",
        address(1)
    ));
    let by_tbf = a_to_b_per_step(&run("tbf", None), 50);
    let _ = Command::new("ip")
        .args([
            "netns", "exec", &h2, "tc", "-s", "qdisc", "show", "dev", "v2",
        ])
        .status();
    eprintln!(
        "robot 0 → base station, bytes per simulated second: netem {by_netem:.1}, tbf {by_tbf:.1} \
         (rate {RATE}; offered {offered:.1})"
    );
    assert!(
        (by_tbf - by_netem).abs() <= 0.05 * by_netem,
        "netem {by_netem:.1} B/s, tbf {by_tbf:.1} B/s"
    );
}

/// 32 robots (496 links) over four namespaces, one over ssh, beside the same run on one host:
/// both complete, with the same `run_digest`; prints the wall times. Long (minutes): run by
/// hand, `cargo test --release --test integration -- --ignored hosts::thirty_two --nocapture`
/// (docs/results.md, X1).
#[test]
#[ignore = "minutes long: a measurement (docs/results.md, X1)"]
fn thirty_two_robots_over_four_namespaces_complete_as_on_one_host() {
    // Bound in this order, dropped in the reverse: sshd, the namespaces, then the files.
    let SshLab {
        dir,
        hosts,
        remote: _,
        lab,
        sshd: _sshd,
    } = ssh_lab("x32", "{ h1 = [0, 3, 6, 9, 12, 15, 18, 21, 24, 27, 30], h2 = [1, 4, 7, 10, 13, 16, 19, 22, 25, 28, 31], h3 = \"rest\" }");
    // Two cores run 32 robots, netem and the world-server: a step may take seconds, and a robot
    // that misses the step time-out would make the run depend on the load.
    let sets = ["robots.count=32", "clock.step_timeout_ms=60000"];
    let mut digests = Vec::new();
    for (name, spread) in [("spread", true), ("single", false)] {
        let out = dir.path().join(name);
        let mut cmd = lab.exec(0, SWARM);
        run_args(&mut cmd, &out, &sets);
        if spread {
            cmd.arg("--hosts").arg(&hosts);
        }
        let o = Launcher::spawn(cmd).wait_output(Duration::from_secs(1800));
        let s = summary_typed(&out);
        assert_eq!(o.status.code(), Some(0), "{name}: {}\n{s:?}", stderr(&o));
        assert_eq!(s.robots_alive_at_end, 32, "{s:?}");
        eprintln!(
            "{name}: {} steps, {:.1} s wall, {:?} bytes on the wire, deterministic {} {:?}, digest {}",
            s.steps,
            s.wall_seconds,
            s.bytes_wire_total,
            s.deterministic,
            s.nondeterministic,
            s.run_digest
        );
        assert!(s.deterministic, "{name}: {:?}", s.nondeterministic);
        digests.push(s.run_digest.clone());
    }
    if digests[0] != digests[1] {
        // Kept for a look at which table differs (`cmp`), as the lab's files go with the test.
        let kept = std::env::temp_dir().join(format!("x32-kept-{}", std::process::id()));
        let copied = Command::new("cp")
            .arg("-r")
            .arg(dir.path())
            .arg(&kept)
            .status();
        eprintln!("both runs kept in {} ({copied:?})", kept.display());
    }
    assert_eq!(
        digests[0], digests[1],
        "the spread run differs from one host"
    );
}
