//! Starting a run's processes on the hosts of a hosts file ([`crate::process::hosts`]): the command line
//! of a process on its host, and `swarm host-info`, which a host answers before the run — its
//! protocol version (every process of a run must speak the launcher's) and free ports on its
//! address (a launcher cannot see which ports are free on another machine).
//!
//! Over ssh, two more hidden subcommands do the remote side: `swarm host-files --dir D` writes
//! the files a host's processes read (the scenario, their logins), sent as JSON on its stdin;
//! `swarm on-host -- ARGV…` runs one process of the run and keeps it on a leash — it reads
//! `stop`, `cont`, `term`, `kill` lines on its stdin (the launcher's freeze, thaw and kill reach
//! the process itself, not the local ssh client), and SIGKILLs the process when its stdin ends:
//! a launcher that dies, or a connection that drops, leaves nothing running on the host.
//!
//! **Invariant:** a process started over ssh lives only as long as its ssh connection.

use std::io::{BufRead, Write};
use std::net::IpAddr;
use std::path::{Component, Path, PathBuf};
use std::process::Stdio;
use std::time::Duration;

use anyhow::{bail, Context};
use proto::msg::PROTOCOL_VERSION;
use serde::{Deserialize, Serialize};

use crate::process::children::LEASH;
use crate::process::hosts::{Host, Start};

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
    let ports = crate::process::ports::free_ports_on(args.address, args.ports)
        .with_context(|| format!("finding {} free ports on {}", args.ports, args.address))?;
    Ok(HostInfo {
        protocol: PROTOCOL_VERSION,
        swarm: env!("CARGO_PKG_VERSION").to_string(),
        ports,
    })
}

/// `swarm host-info`: the host's answer as one JSON line.
pub fn host_info_command(args: &HostInfoArgs) -> anyhow::Result<std::process::ExitCode> {
    println!("{}", serde_json::to_string(&host_info(args)?)?);
    Ok(std::process::ExitCode::SUCCESS)
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
        Start::Srun { node } => {
            let mut args: Vec<String> = crate::process::slurm::srun_words(node);
            let program = args.remove(0);
            args.push(own);
            args.extend(argv.iter().cloned());
            (program, args)
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

/// The command that runs process `argv…` of the run whose directory is `local_dir` on `host`:
/// (program, arguments, whether it is on a leash — `swarm on-host`, see the module). On an ssh
/// host every path under `local_dir` becomes the same path under the host's copy of the run
/// directory ([`remote_dir`]).
pub fn process_command(
    host: &Host,
    exe: &Path,
    argv: &[String],
    local_dir: &Path,
) -> (String, Vec<String>, bool) {
    match &host.start {
        Start::Ssh { .. } => {
            let there = remote_dir(host, local_dir);
            let relocated = argv.iter().map(|w| relocate(w, local_dir, &there));
            let wrapped: Vec<String> = ["on-host".to_string(), "--".to_string()]
                .into_iter()
                .chain(relocated)
                .collect();
            let (program, args) = command(host, exe, &wrapped);
            (program, args, true)
        }
        // A step of the Slurm job: the same files (a shared file system), on the leash.
        Start::Srun { .. } => {
            let wrapped: Vec<String> = ["on-host".to_string(), "--".to_string()]
                .into_iter()
                .chain(argv.iter().cloned())
                .collect();
            let (program, args) = command(host, exe, &wrapped);
            (program, args, true)
        }
        Start::Local | Start::Prefix { .. } => {
            let (program, args) = command(host, exe, argv);
            (program, args, false)
        }
    }
}

/// Where an ssh host keeps its copy of the run directory `local_dir`: its `dir`, then the run
/// directory's name.
pub fn remote_dir(host: &Host, local_dir: &Path) -> PathBuf {
    host.dir
        .join(local_dir.file_name().unwrap_or(std::ffi::OsStr::new("run")))
}

/// `word` with a leading `from` (a whole path prefix) replaced by `to`.
fn relocate(word: &str, from: &Path, to: &Path) -> String {
    match Path::new(word).strip_prefix(from) {
        Ok(rest) if !from.as_os_str().is_empty() => to.join(rest).to_string_lossy().into_owned(),
        _ => word.to_string(),
    }
}

/// One word for a POSIX shell, quoted where it needs it.
pub(crate) fn quote(word: &str) -> String {
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
    let out = run_swarm(host, exe, &argv, None, "`swarm host-info`", wait)?;
    let stdout = String::from_utf8_lossy(&out.stdout);
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

/// Runs `swarm argv…` on `host` (`what`, for messages), writes `input` to its stdin, and
/// returns its output; bounded by `wait` ([`bounded`]).
fn run_swarm(
    host: &Host,
    exe: &Path,
    argv: &[String],
    input: Option<&[u8]>,
    what: &str,
    wait: Duration,
) -> anyhow::Result<std::process::Output> {
    let (program, args) = command(host, exe, argv);
    let mut child = std::process::Command::new(&program)
        .args(&args)
        .stdin(if input.is_some() {
            Stdio::piped()
        } else {
            Stdio::null()
        })
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .with_context(|| format!("host {}: starting {program}", host.name))?;
    if let (Some(input), Some(mut stdin)) = (input, child.stdin.take()) {
        // A failed write shows as the remote side's failure in `bounded`.
        let _ = stdin.write_all(input);
    }
    bounded(child, host, what, wait)
}

/// Waits up to `wait` for `child` (`what`, on `host`) and returns its output; an error if it
/// did not finish in time (it is killed) or failed (with its last line on stderr).
fn bounded(
    mut child: std::process::Child,
    host: &Host,
    what: &str,
    wait: Duration,
) -> anyhow::Result<std::process::Output> {
    let deadline = std::time::Instant::now() + wait;
    let status = loop {
        if let Some(status) = child.try_wait()? {
            break status;
        }
        if std::time::Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            bail!("host {}: no answer to {what} within {wait:?}", host.name);
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let out = child.wait_with_output()?;
    if !status.success() {
        let stderr = String::from_utf8_lossy(&out.stderr);
        bail!(
            "host {}: {what} failed ({status}): {}",
            host.name,
            stderr.trim().lines().last().unwrap_or("no message")
        );
    }
    Ok(out)
}

/// A file of the run that a host's processes read, as `swarm host-files` receives it.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct SentFile {
    /// Relative to the run directory, without `..`.
    pub path: String,
    pub text: String,
}

/// Flags of `swarm host-files` (what the launcher runs on an ssh host before and after a run).
#[derive(clap::Args, Debug, Clone)]
pub struct HostFilesArgs {
    /// This host's copy of the run directory.
    #[arg(long, value_name = "DIR")]
    pub dir: PathBuf,
    /// Remove that directory instead of writing files into it (after the run).
    #[arg(long)]
    pub remove: bool,
}

/// The most `swarm host-files` reads from its stdin.
const MOST_SENT_BYTES: u64 = 16 << 20;

/// `swarm host-files`: writes the JSON list of [`SentFile`]s on `input` under `--dir`, each
/// readable by the owner only (they include logins); or removes `--dir`. Returns how many
/// files it wrote.
pub fn host_files(args: &HostFilesArgs, input: impl std::io::Read) -> anyhow::Result<usize> {
    use std::io::Read;
    use std::os::unix::fs::{DirBuilderExt, OpenOptionsExt};
    if args.remove {
        return match std::fs::remove_dir_all(&args.dir) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                Err(e).with_context(|| format!("removing {}", args.dir.display()))
            }
            _ => Ok(0),
        };
    }
    let mut text = String::new();
    input
        .take(MOST_SENT_BYTES)
        .read_to_string(&mut text)
        .context("reading the files on stdin")?;
    let files: Vec<SentFile> =
        serde_json::from_str(&text).context("the files on stdin are not a JSON list")?;
    for f in &files {
        let rel = Path::new(&f.path);
        let plain =
            !f.path.is_empty() && rel.components().all(|c| matches!(c, Component::Normal(_)));
        if !plain {
            bail!(
                "{:?}: a file must be a plain path inside the run directory",
                f.path
            );
        }
        let path = args.dir.join(rel);
        if let Some(parent) = path.parent() {
            std::fs::DirBuilder::new()
                .recursive(true)
                .mode(0o700)
                .create(parent)
                .with_context(|| format!("creating {}", parent.display()))?;
        }
        std::fs::OpenOptions::new()
            .create(true)
            .write(true)
            .truncate(true)
            .mode(0o600)
            .open(&path)
            .and_then(|mut out| out.write_all(f.text.as_bytes()))
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(files.len())
}

/// `swarm host-files`: the run's files from stdin.
pub fn host_files_command(args: &HostFilesArgs) -> anyhow::Result<std::process::ExitCode> {
    host_files(args, std::io::stdin())?;
    Ok(std::process::ExitCode::SUCCESS)
}

/// Copies `files` of the run directory `local_dir` to `host`'s copy of it ([`remote_dir`]).
pub fn send_files(
    host: &Host,
    exe: &Path,
    local_dir: &Path,
    files: &[SentFile],
    wait: Duration,
) -> anyhow::Result<()> {
    let there = remote_dir(host, local_dir);
    let argv = [
        "host-files".to_string(),
        "--dir".to_string(),
        there.to_string_lossy().into_owned(),
    ];
    let json = serde_json::to_vec(files)?;
    run_swarm(host, exe, &argv, Some(&json), "`swarm host-files`", wait)?;
    Ok(())
}

/// Removes `host`'s copy of the run directory `local_dir` (its logins with it).
pub fn remove_files(
    host: &Host,
    exe: &Path,
    local_dir: &Path,
    wait: Duration,
) -> anyhow::Result<()> {
    let there = remote_dir(host, local_dir);
    let argv = [
        "host-files".to_string(),
        "--remove".to_string(),
        "--dir".to_string(),
        there.to_string_lossy().into_owned(),
    ];
    run_swarm(host, exe, &argv, None, "`swarm host-files --remove`", wait)?;
    Ok(())
}

/// Flags of `swarm on-host`.
#[derive(clap::Args, Debug, Clone)]
pub struct OnHostArgs {
    /// The process to run: `robot-agent` or `base-station`, and its flags.
    #[arg(trailing_var_arg = true, allow_hyphen_values = true, required = true)]
    pub argv: Vec<String>,
}

/// The processes `swarm on-host` runs.
const LEASHED: [&str; 2] = ["robot-agent", "base-station"];

/// `swarm on-host`: runs the process on a leash (see the module); returns its exit code
/// (128 + the signal that ended it, as a shell says).
pub fn on_host(args: &OnHostArgs) -> anyhow::Result<i32> {
    use std::os::unix::process::ExitStatusExt;
    let what = args.argv.first().map(String::as_str).unwrap_or_default();
    if !LEASHED.contains(&what) {
        bail!("on-host runs {}, not {what:?}", LEASHED.join(" or "));
    }
    let exe = std::env::current_exe().context("locating the swarm binary")?;
    let mut cmd = std::process::Command::new(exe);
    cmd.args(&args.argv).stdin(Stdio::null());
    crate::process::children::die_with_parent_std(&mut cmd);
    let mut child = cmd.spawn().with_context(|| format!("starting {what}"))?;
    let pid = libc::pid_t::try_from(child.id()).context("pid out of range")?;
    std::thread::spawn(move || {
        let send = |signal| {
            // SAFETY: kill(2) on our own child, which the main thread reaps only after it ended;
            // then this process exits at once.
            #[allow(unsafe_code)]
            unsafe {
                libc::kill(pid, signal);
            }
        };
        for line in std::io::stdin().lock().lines() {
            let Ok(line) = line else { break };
            match LEASH.iter().find(|(w, _)| *w == line.trim()) {
                Some(&(_, signal)) => send(signal),
                None => eprintln!("swarm on-host: ignored {line:?} on stdin"),
            }
        }
        // Stdin ended: the launcher is gone, or its connection to this host.
        send(libc::SIGCONT);
        send(libc::SIGKILL);
    });
    let status = child.wait().context("waiting for the process")?;
    Ok(status
        .code()
        .unwrap_or_else(|| 128 + status.signal().unwrap_or(0)))
}

/// `swarm on-host`: the leashed process's exit code as this one's.
pub fn on_host_command(args: &OnHostArgs) -> anyhow::Result<std::process::ExitCode> {
    Ok(std::process::ExitCode::from(
        u8::try_from(on_host(args)?).unwrap_or(1),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::process::children::leash_word;
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
    fn a_process_over_ssh_goes_on_a_leash_and_reads_the_hosts_copy_of_the_run() {
        let exe = Path::new("/build/swarm");
        let ssh = host(Start::Ssh {
            target: "robot@10.0.0.2".into(),
            options: Vec::new(),
            swarm: "swarm".into(),
        });
        let local = Path::new("runs/17-intel_lab-8r");
        let argv = vec![
            "robot-agent".to_string(),
            "--scenario".into(),
            "runs/17-intel_lab-8r/scenario.toml".into(),
            "--credentials".into(),
            "runs/17-intel_lab-8r/secrets/robot-3".into(),
            "runs/17-intel_lab-8r-other/x".into(),
        ];
        let (p, a, leashed) = process_command(&ssh, exe, &argv, local);
        assert!(leashed);
        assert_eq!(p, "ssh");
        assert_eq!(
            a.last().map(String::as_str),
            Some(
                "swarm on-host -- robot-agent --scenario /tmp/swarm-runs/17-intel_lab-8r/scenario.toml \
                 --credentials /tmp/swarm-runs/17-intel_lab-8r/secrets/robot-3 \
                 runs/17-intel_lab-8r-other/x"
            )
        );
        let prefix = host(Start::Prefix {
            command: vec!["ip".into(), "netns".into(), "exec".into(), "h1".into()],
            swarm: None,
        });
        let (_, a, leashed) = process_command(&prefix, exe, &argv, local);
        assert!(!leashed);
        assert_eq!(&a[4..], &argv[..], "same file system: paths unchanged");
    }

    #[test]
    fn host_files_writes_private_files_inside_its_directory_only() {
        use std::os::unix::fs::PermissionsExt;
        let dir = std::env::temp_dir().join(format!("swarm-host-files-{}", std::process::id()));
        let args = HostFilesArgs {
            dir: dir.join("run"),
            remove: false,
        };
        let files = vec![
            SentFile {
                path: "scenario.toml".into(),
                text: "seed = 1\n".into(),
            },
            SentFile {
                path: "secrets/robot-3".into(),
                text: "robot-3:abc\n".into(),
            },
        ];
        let json = serde_json::to_vec(&files).unwrap_or_default();
        assert_eq!(host_files(&args, &json[..]).ok(), Some(2));
        let login = args.dir.join("secrets/robot-3");
        assert_eq!(
            std::fs::read_to_string(&login).ok().as_deref(),
            Some("robot-3:abc\n")
        );
        let mode = std::fs::metadata(&login).map(|m| m.permissions().mode() & 0o777);
        assert_eq!(mode.ok(), Some(0o600));
        for path in ["../escape", "/etc/passwd", "", "a/../../b", "./x"] {
            let bad = serde_json::to_vec(&[SentFile {
                path: path.into(),
                text: String::new(),
            }])
            .unwrap_or_default();
            let err = host_files(&args, &bad[..]).err().map(|e| format!("{e:#}"));
            assert!(err.is_some_and(|e| e.contains("plain path")), "{path:?}");
        }
        for junk in [&b"not json"[..], b"{\"path\": 1}", b""] {
            assert!(host_files(&args, junk).is_err());
        }
        assert!(!dir.join("escape").exists());
        let remove = HostFilesArgs {
            dir: args.dir.clone(),
            remove: true,
        };
        assert_eq!(host_files(&remove, &b""[..]).ok(), Some(0));
        assert!(!args.dir.exists());
        assert_eq!(host_files(&remove, &b""[..]).ok(), Some(0), "already gone");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn every_signal_the_launcher_sends_has_a_leash_word() {
        for signal in [libc::SIGSTOP, libc::SIGCONT, libc::SIGTERM, libc::SIGKILL] {
            let word = leash_word(signal);
            assert!(word.is_some(), "{signal}");
            assert_eq!(
                LEASH
                    .iter()
                    .find(|(w, _)| Some(*w) == word)
                    .map(|(_, s)| *s),
                Some(signal)
            );
        }
        assert_eq!(leash_word(libc::SIGUSR1), None);
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
