//! Starting a run's processes on the hosts of a hosts file ([`crate::hosts`]): the command line
//! of a process on its host, and `swarm host-info`, which a host answers before the run — its
//! protocol version (every process of a run must speak the launcher's) and free ports on its
//! address (a launcher cannot see which ports are free on another machine).

use std::net::IpAddr;
use std::path::Path;
use std::process::Stdio;
use std::time::Duration;

use anyhow::{bail, Context};
use proto::msg::PROTOCOL_VERSION;
use serde::{Deserialize, Serialize};

use crate::hosts::{Host, Start};

/// What `swarm host-info` prints (one JSON line).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct HostInfo {
    /// The wire protocol its swarm speaks ([`PROTOCOL_VERSION`]).
    pub protocol: u16,
    /// Its swarm's version.
    pub swarm: String,
    /// Free ports on the address asked for.
    pub ports: Vec<u16>,
}

/// Flags of `swarm host-info`.
#[derive(clap::Args, Debug, Clone)]
pub struct HostInfoArgs {
    /// The address (of this host) to find free ports on.
    #[arg(long, default_value = "127.0.0.1")]
    pub address: IpAddr,
    /// How many free ports to find.
    #[arg(long, default_value_t = 0)]
    pub ports: usize,
}

/// This host's answer.
pub fn host_info(args: &HostInfoArgs) -> anyhow::Result<HostInfo> {
    let ports = crate::ports::free_ports_on(args.address, args.ports)
        .with_context(|| format!("finding {} free ports on {}", args.ports, args.address))?;
    Ok(HostInfo {
        protocol: PROTOCOL_VERSION,
        swarm: env!("CARGO_PKG_VERSION").to_string(),
        ports,
    })
}

/// The command that runs `swarm argv…` on `host`: (program, its arguments). `exe` is the
/// launcher's own binary (what a local host, and a prefix host without `swarm`, run).
pub fn command(host: &Host, exe: &Path, argv: &[String]) -> (String, Vec<String>) {
    let own = exe.to_string_lossy().into_owned();
    match &host.start {
        Start::Local => (own, argv.to_vec()),
        Start::Prefix { command, swarm } => {
            let mut args: Vec<String> = command[1..].to_vec();
            args.push(swarm.clone().unwrap_or(own));
            args.extend(argv.iter().cloned());
            (command[0].clone(), args)
        }
        Start::Ssh {
            target,
            options,
            swarm,
        } => {
            // ssh hands the remote side one shell command line: every word quoted.
            let remote: Vec<String> = std::iter::once(swarm.as_str())
                .chain(argv.iter().map(String::as_str))
                .map(quote)
                .collect();
            let mut args = vec!["-o".to_string(), "BatchMode=yes".to_string()];
            args.extend(options.iter().cloned());
            args.extend([target.clone(), "--".to_string(), remote.join(" ")]);
            ("ssh".to_string(), args)
        }
    }
}

/// One word for a POSIX shell, quoted where it needs it.
fn quote(word: &str) -> String {
    let plain = !word.is_empty()
        && word
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b"-_./=:,@+%".contains(&b));
    if plain {
        word.to_string()
    } else {
        format!("'{}'", word.replace('\'', r"'\''"))
    }
}

/// Asks `host` for `n` free ports on its address and checks that its swarm speaks this one's
/// protocol; bounded by `wait`.
pub fn ask(host: &Host, exe: &Path, n: usize, wait: Duration) -> anyhow::Result<HostInfo> {
    let argv = [
        "host-info".to_string(),
        "--address".to_string(),
        host.address.to_string(),
        "--ports".to_string(),
        n.to_string(),
    ];
    let (program, args) = command(host, exe, &argv);
    let mut child = std::process::Command::new(&program)
        .args(&args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .with_context(|| format!("host {}: starting {program}", host.name))?;
    let deadline = std::time::Instant::now() + wait;
    let status = loop {
        if let Some(status) = child.try_wait()? {
            break status;
        }
        if std::time::Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            bail!(
                "host {}: no answer to `swarm host-info` within {wait:?} ({program} {})",
                host.name,
                args.join(" ")
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let out = child.wait_with_output()?;
    let stdout = String::from_utf8_lossy(&out.stdout);
    if !status.success() {
        let stderr = String::from_utf8_lossy(&out.stderr);
        bail!(
            "host {}: `swarm host-info` failed ({status}): {}",
            host.name,
            stderr.trim().lines().last().unwrap_or("no message")
        );
    }
    let info: HostInfo = serde_json::from_str(stdout.trim()).with_context(|| {
        format!(
            "host {}: `swarm host-info` answered {:?}: is its swarm this version?",
            host.name,
            stdout.trim()
        )
    })?;
    if info.protocol != PROTOCOL_VERSION {
        bail!(
            "host {} runs swarm {} (protocol {}), this launcher speaks protocol {PROTOCOL_VERSION}: \
             install the same swarm there",
            host.name,
            info.swarm,
            info.protocol
        );
    }
    if info.ports.len() != n {
        bail!(
            "host {}: asked for {n} free ports, got {}",
            host.name,
            info.ports.len()
        );
    }
    Ok(info)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    fn host(start: Start) -> Host {
        Host {
            name: "h1".into(),
            address: "10.0.0.2".parse().unwrap_or(IpAddr::from([0, 0, 0, 0])),
            start,
            dir: PathBuf::from("/tmp/swarm-runs"),
        }
    }

    #[test]
    fn a_process_is_started_as_its_host_says() {
        let exe = Path::new("/build/swarm");
        let argv = vec!["robot-agent".to_string(), "--id".into(), "3".into()];
        assert_eq!(
            command(&host(Start::Local), exe, &argv),
            ("/build/swarm".into(), argv.clone())
        );
        let prefix = Start::Prefix {
            command: vec!["ip".into(), "netns".into(), "exec".into(), "h1".into()],
            swarm: None,
        };
        let (p, a) = command(&host(prefix), exe, &argv);
        assert_eq!(p, "ip");
        assert_eq!(
            a,
            [
                "netns",
                "exec",
                "h1",
                "/build/swarm",
                "robot-agent",
                "--id",
                "3"
            ]
        );
        let ssh = Start::Ssh {
            target: "robot@10.0.0.2".into(),
            options: vec!["-p".into(), "2222".into()],
            swarm: "/opt/swarm".into(),
        };
        let mut odd = argv.clone();
        odd.push("it's a dir/with space".into());
        let (p, a) = command(&host(ssh), exe, &odd);
        assert_eq!(p, "ssh");
        assert_eq!(
            a,
            [
                "-o",
                "BatchMode=yes",
                "-p",
                "2222",
                "robot@10.0.0.2",
                "--",
                r"/opt/swarm robot-agent --id 3 'it'\''s a dir/with space'"
            ]
        );
    }

    #[test]
    fn words_are_quoted_for_the_remote_shell() {
        for (word, quoted) in [
            ("plain-word_1.toml", "plain-word_1.toml"),
            ("", "''"),
            ("a b", "'a b'"),
            ("$(rm -rf /)", "'$(rm -rf /)'"),
            ("it's", r"'it'\''s'"),
            ("robots.count=8", "robots.count=8"),
        ] {
            assert_eq!(quote(word), quoted, "{word}");
        }
    }

    #[test]
    fn a_local_host_answers_its_protocol_and_free_ports() {
        let info = host_info(&HostInfoArgs {
            address: IpAddr::from([127, 0, 0, 1]),
            ports: 3,
        })
        .unwrap_or_else(|e| panic!("{e:#}"));
        assert_eq!(info.protocol, PROTOCOL_VERSION);
        assert_eq!(info.ports.len(), 3);
        let line = serde_json::to_string(&info).unwrap_or_default();
        assert_eq!(serde_json::from_str::<HostInfo>(&line).ok(), Some(info));
    }
}
