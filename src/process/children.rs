//! Child processes of a run: spawned with their output in the run directory's `logs/`, watched
//! for unexpected exits, and always reaped.
//!
//! **Invariant:** no child outlives the launcher. Three layers make that hold: an orderly
//! [`Children::shutdown`](crate::process::children::Children::shutdown) (grace period, then
//! SIGKILL, then wait), `kill_on_drop` for every early return, and `PR_SET_PDEATHSIG = SIGKILL` set
//! in each child, so that even a launcher killed with SIGKILL takes its children with it.

use std::io::Write;
use std::path::Path;
use std::process::{ExitStatus, Stdio};
use std::time::Duration;

use anyhow::Context;
use tokio::process::{Child, Command};

pub struct Proc {
    pub name: String,
    /// 0 for the first process of its name, one more for each restart.
    pub life: u16,
    pub pid: u32,
    child: Child,
    pub exited: Option<ExitStatus>,
    /// The largest resident set seen while it ran (sampled, [`Children::sample_memory`]), kB.
    pub peak_rss_kb: u64,
    /// The most threads and open descriptors seen while it ran (sampled likewise).
    pub peak_threads: u32,
    pub peak_fds: u32,
    /// For a process on another host (`swarm on-host` through ssh): its leash, the pipe to
    /// its stdin that signals go down ([`leash_word`]). `pid` is then the local
    /// ssh client's, and the process's memory is not sampled.
    leash: Option<std::io::PipeWriter>,
}

/// A row of `processes.csv`: one process of the run, in one life.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ProcessRow {
    /// As its log file is named: `robot-2`, `netem`, `world-server`, `base-station`.
    pub process: String,
    /// 0 for the first process of that name, one more for each restart.
    pub life: u16,
    pub pid: u32,
    /// How it ended ("exit code 0", "signal 9 (SIGKILL)").
    pub exit: String,
    /// Its largest resident set seen (sampled every 200 ms while the run went on), kB; 0 for
    /// a process on an ssh host (not sampled; `pid` is then the local ssh client's).
    pub peak_rss_kb: u64,
    /// The most threads it had at once (sampled as `peak_rss_kb`); 0 when not sampled.
    #[serde(default)]
    pub peak_threads: u32,
    /// The most file descriptors it held open at once (sampled as `peak_rss_kb`, every
    /// [`FDS_EVERY_SAMPLES`]th sample); 0 when not sampled.
    #[serde(default)]
    pub peak_fds: u32,
}

/// A row of `memory.csv`: a process's resident set when the run reached a step (every
/// [`MEMORY_EVERY_STEPS`] steps).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MemoryRow {
    pub step: u32,
    pub process: String,
    pub life: u16,
    pub rss_kb: u64,
}

/// How often (in steps) `memory.csv` gets a row per running process.
pub const MEMORY_EVERY_STEPS: u32 = 100;

/// Descriptors are counted at every this many samples (once a second): counting lists a
/// directory entry per descriptor, thousands for netem in a big run.
pub const FDS_EVERY_SAMPLES: u32 = 5;

/// How long a process on another host may take to end after its leash said `kill`, before
/// its ssh client is killed instead (which ends it too, as its stdin closes).
const LEASH_WAIT: Duration = Duration::from_secs(10);

#[derive(Default)]
pub struct Children {
    procs: Vec<Proc>,
    /// `memory.csv` so far.
    memory: Vec<MemoryRow>,
    /// The last step a row of `memory` was taken at.
    memory_step: Option<u32>,
    /// Samples taken ([`Children::sample_memory`]).
    samples: u32,
}

/// What a child runs between fork and exec: asks the kernel to SIGKILL it when the spawning
/// thread dies, and exits at once if the parent is already gone.
fn parent_death_hook() -> impl FnMut() -> std::io::Result<()> + Send + Sync + 'static {
    let parent = std::process::id() as libc::pid_t;
    move || {
        // SAFETY: runs between fork and exec and only calls the async-signal-safe functions
        // prctl, getppid and _exit.
        #[allow(unsafe_code)]
        unsafe {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            // The parent may have died before prctl took effect.
            if libc::getppid() != parent {
                libc::_exit(1);
            }
        }
        Ok(())
    }
}

/// The child dies with its parent thread (see [`parent_death_hook`]).
#[allow(unsafe_code)]
fn die_with_parent(cmd: &mut Command) {
    // SAFETY: the hook only calls async-signal-safe functions.
    unsafe {
        cmd.pre_exec(parent_death_hook());
    }
}

/// [`die_with_parent`] for a `std` command (the sweep's runs).
#[allow(unsafe_code)]
pub fn die_with_parent_std(cmd: &mut std::process::Command) {
    use std::os::unix::process::CommandExt;
    // SAFETY: the hook only calls async-signal-safe functions.
    unsafe {
        cmd.pre_exec(parent_death_hook());
    }
}

impl Children {
    /// Spawns `exe args…` with stdout and stderr appended to `log`. A `leashed` process
    /// (`swarm on-host` through ssh) gets a pipe as stdin that [`Self::signal`] and
    /// [`Self::kill`] write to, and that closes when the launcher goes; any other gets none.
    ///
    /// Must be called from the thread that lives as long as the launcher (the runtime's
    /// `block_on` thread): the kernel's parent-death signal follows the spawning thread.
    pub fn spawn(
        &mut self,
        name: &str,
        exe: &Path,
        args: &[String],
        log: &Path,
        leashed: bool,
    ) -> anyhow::Result<u32> {
        // Appended: a restarted process keeps its earlier lives' output in the same log.
        let out = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(log)
            .with_context(|| format!("opening {}", log.display()))?;
        let err = out.try_clone()?;
        let (stdin, leash) = if leashed {
            let (reader, writer) = std::io::pipe().context("making a leash pipe")?;
            (Stdio::from(reader), Some(writer))
        } else {
            (Stdio::null(), None)
        };
        let mut cmd = Command::new(exe);
        cmd.args(args)
            .stdin(stdin)
            .stdout(out)
            .stderr(err)
            .kill_on_drop(true);
        die_with_parent(&mut cmd);
        let child = cmd
            .spawn()
            .with_context(|| format!("starting {name} ({})", exe.display()))?;
        let pid = child.id().unwrap_or(0);
        let life = self.procs.iter().filter(|p| p.name == name).count();
        self.procs.push(Proc {
            name: name.to_string(),
            life: u16::try_from(life).unwrap_or(u16::MAX),
            pid,
            child,
            exited: None,
            peak_rss_kb: 0,
            peak_threads: 0,
            peak_fds: 0,
            leash,
        });
        Ok(pid)
    }

    /// Children that exited since the last call (non-blocking).
    pub fn newly_exited(&mut self) -> Vec<(String, u32, ExitStatus)> {
        let mut out = Vec::new();
        for p in &mut self.procs {
            if p.exited.is_none() {
                if let Ok(Some(status)) = p.child.try_wait() {
                    p.exited = Some(status);
                    out.push((p.name.clone(), p.pid, status));
                }
            }
        }
        out
    }

    /// The running process named `name` (the newest, if it was restarted).
    fn running(&mut self, name: &str) -> Option<&mut Proc> {
        self.procs
            .iter_mut()
            .rev()
            .find(|p| p.name == name && p.exited.is_none())
    }

    /// Sends `signal` to the running process named `name`; `false` if there is none (it
    /// exited, or was never started) or the signal could not be sent.
    pub fn signal(&mut self, name: &str, signal: libc::c_int) -> bool {
        let Some(p) = self.running(name) else {
            return false;
        };
        if let Some(leash) = &mut p.leash {
            return leash_word(signal)
                .is_some_and(|w| leash.write_all(format!("{w}\n").as_bytes()).is_ok());
        }
        let Ok(pid) = libc::pid_t::try_from(p.pid) else {
            return false;
        };
        // SAFETY: kill(2) on a child we spawned and have not reaped (its pid is still ours).
        #[allow(unsafe_code)]
        let r = unsafe { libc::kill(pid, signal) };
        r == 0
    }

    /// SIGKILLs the running process named `name` and reaps it; its exit is not reported by
    /// [`Self::newly_exited`] (whoever killed it knows). `false` if none was running.
    pub async fn kill(&mut self, name: &str) -> bool {
        let Some(p) = self.running(name) else {
            return false;
        };
        if let Some(leash) = &mut p.leash {
            // The process itself is killed on its host; its ssh client then ends by itself.
            let _ = leash.write_all(b"kill\n");
            if let Ok(Ok(status)) = tokio::time::timeout(LEASH_WAIT, p.child.wait()).await {
                p.exited = Some(status);
                return true;
            }
        }
        let _ = p.child.start_kill();
        if let Ok(status) = p.child.wait().await {
            p.exited = Some(status);
        }
        true
    }

    /// Samples the resident set and threads of every running child (`VmRSS`, `Threads` in
    /// `/proc/<pid>/status`) and, every [`FDS_EVERY_SAMPLES`]th time, its open descriptors,
    /// keeping each one's peaks; the run being at `step`, every [`MEMORY_EVERY_STEPS`] steps
    /// also a row of `memory.csv` per process.
    pub fn sample_memory(&mut self, step: Option<u32>) {
        let row_due = step.filter(|&s| {
            self.memory_step
                .is_none_or(|m| s / MEMORY_EVERY_STEPS > m / MEMORY_EVERY_STEPS)
        });
        let fds_due = self.samples.is_multiple_of(FDS_EVERY_SAMPLES);
        self.samples = self.samples.wrapping_add(1);
        for p in self.procs.iter_mut() {
            if p.exited.is_some() || p.leash.is_some() {
                continue;
            }
            if fds_due {
                p.peak_fds = p.peak_fds.max(fds(p.pid).unwrap_or(0));
            }
            if let Some(Sample {
                rss_kb: kb,
                threads,
            }) = sample(p.pid)
            {
                p.peak_rss_kb = p.peak_rss_kb.max(kb);
                p.peak_threads = p.peak_threads.max(threads);
                if let Some(step) = row_due {
                    self.memory.push(MemoryRow {
                        step,
                        process: p.name.clone(),
                        life: p.life,
                        rss_kb: kb,
                    });
                }
            }
        }
        if row_due.is_some() {
            self.memory_step = row_due;
        }
    }

    /// `memory.csv`: each process's resident set every [`MEMORY_EVERY_STEPS`] steps.
    pub fn memory(&self) -> &[MemoryRow] {
        &self.memory
    }

    /// Every process started, in order, with its life, exit and peak memory (`processes.csv`).
    pub fn table(&self) -> Vec<ProcessRow> {
        self.procs
            .iter()
            .map(|p| ProcessRow {
                process: p.name.clone(),
                life: p.life,
                pid: p.pid,
                exit: p.exited.map_or_else(|| "running".into(), describe),
                peak_rss_kb: p.peak_rss_kb,
                peak_threads: p.peak_threads,
                peak_fds: p.peak_fds,
            })
            .collect()
    }

    pub fn pids(&self) -> Vec<u32> {
        self.procs.iter().map(|p| p.pid).collect()
    }

    /// Waits up to `grace` for every child to exit by itself, then kills the rest; always reaps.
    /// Returns the names of the children that had to be killed.
    pub async fn shutdown(&mut self, grace: Duration) -> Vec<String> {
        let deadline = tokio::time::Instant::now() + grace;
        let mut killed = Vec::new();
        for p in &mut self.procs {
            if p.exited.is_some() {
                continue;
            }
            match tokio::time::timeout_at(deadline, p.child.wait()).await {
                Ok(Ok(status)) => p.exited = Some(status),
                _ => {
                    let _ = p.child.start_kill();
                    killed.push(p.name.clone());
                    if let Ok(status) = p.child.wait().await {
                        p.exited = Some(status);
                    }
                }
            }
        }
        killed
    }
}

/// What `/proc/<pid>/status` says of a process: its resident set (kB) and threads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sample {
    pub rss_kb: u64,
    pub threads: u32,
}

/// The resident set and threads of process `pid`, from `/proc/<pid>/status`.
pub fn sample(pid: u32) -> Option<Sample> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let field = |name: &str| {
        (status.lines())
            .find_map(|l| l.strip_prefix(name))
            .and_then(|v| v.split_whitespace().next())
    };
    Some(Sample {
        rss_kb: field("VmRSS:")?.parse().ok()?,
        threads: field("Threads:")?.parse().ok()?,
    })
}

/// How many file descriptors process `pid` holds open (the entries of `/proc/<pid>/fd`).
pub fn fds(pid: u32) -> Option<u32> {
    let entries = std::fs::read_dir(format!("/proc/{pid}/fd")).ok()?;
    u32::try_from(entries.count()).ok()
}

/// A human description of an exit status ("exit code 1", "signal 9 (SIGKILL)").
pub fn describe(status: ExitStatus) -> String {
    use std::os::unix::process::ExitStatusExt;
    match (status.code(), status.signal()) {
        (Some(c), _) => format!("exit code {c}"),
        (None, Some(9)) => "signal 9 (SIGKILL)".into(),
        (None, Some(15)) => "signal 15 (SIGTERM)".into(),
        (None, Some(s)) => format!("signal {s}"),
        _ => "unknown status".into(),
    }
}

/// The word on a leashed process's stdin that makes `swarm on-host` send it `signal`.
pub fn leash_word(signal: libc::c_int) -> Option<&'static str> {
    LEASH.iter().find(|(_, s)| *s == signal).map(|(w, _)| *w)
}

pub const LEASH: [(&str, libc::c_int); 4] = [
    ("stop", libc::SIGSTOP),
    ("cont", libc::SIGCONT),
    ("term", libc::SIGTERM),
    ("kill", libc::SIGKILL),
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_process_s_memory_threads_and_descriptors_are_read_from_proc() {
        let me = std::process::id();
        let s = sample(me).expect("this process's status");
        assert!(s.rss_kb > 0, "{s:?}");
        assert!(s.threads >= 1, "{s:?}");
        assert!(
            fds(me).is_some_and(|n| n >= 3),
            "stdin, stdout, stderr at least"
        );
        // No such process: nothing, not a zero.
        assert_eq!(sample(u32::MAX), None);
        assert_eq!(fds(u32::MAX), None);
    }
}
