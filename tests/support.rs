//! Shared helpers: a temporary run directory, a launcher handle that kills its process tree on
//! drop, and readers for the run directory.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use swarm::process::supervise::EventKind;
use swarm::rundir::summary::{read_summary, Summary};

pub const SWARM: &str = env!("CARGO_BIN_EXE_swarm");

/// A fresh directory under the system temp dir, removed on drop.
pub struct TempDir(pub PathBuf);

impl TempDir {
    pub fn new(name: &str) -> TempDir {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos());
        let p =
            std::env::temp_dir().join(format!("swarm-test-{name}-{}-{nanos}", std::process::id()));
        std::fs::create_dir_all(&p).expect("create temp dir");
        TempDir(p)
    }

    pub fn path(&self) -> &Path {
        &self.0
    }
}

/// Removed when dropped — except while its test panics: a failed test leaves its run
/// directory (logs, tables) for diagnosis and says where.
impl Drop for TempDir {
    fn drop(&mut self) {
        if std::thread::panicking() {
            eprintln!("kept for diagnosis: {}", self.0.display());
            return;
        }
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Adds `run --quiet --out OUT --set …` to a command that runs `swarm`.
pub fn run_args(cmd: &mut Command, out: &Path, sets: &[&str]) {
    cmd.args(["run", "--quiet", "--out"]).arg(out);
    for s in sets {
        cmd.arg("--set").arg(s);
    }
}

/// `swarm run` into `dir/run` with overrides, waiting at most `limit`.
pub fn swarm_run(
    dir: &TempDir,
    scenario: Option<&str>,
    sets: &[&str],
    limit: Duration,
) -> (Output, PathBuf) {
    let out = dir.path().join("run");
    let mut cmd = Command::new(SWARM);
    run_args(&mut cmd, &out, sets);
    if let Some(s) = scenario {
        cmd.arg(s);
    }
    let child = Launcher::spawn(cmd);
    (child.wait_output(limit), out)
}

/// A running launcher; on drop it and every process it started are killed.
pub struct Launcher {
    pub child: Option<Child>,
    pub pid: u32,
}

impl Launcher {
    pub fn spawn(mut cmd: Command) -> Launcher {
        cmd.stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        let child = cmd.spawn().expect("start swarm");
        let pid = child.id();
        Launcher {
            child: Some(child),
            pid,
        }
    }

    /// Waits for the launcher to exit within `limit` (panics, killing everything, otherwise).
    pub fn wait_output(mut self, limit: Duration) -> Output {
        let deadline = Instant::now() + limit;
        loop {
            let child = self.child.as_mut().expect("child present");
            if let Ok(Some(_)) = child.try_wait() {
                let child = self.child.take().expect("child present");
                return child.wait_with_output().expect("collect output");
            }
            if Instant::now() > deadline {
                panic!("swarm did not finish within {limit:?}");
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }
}

impl Drop for Launcher {
    fn drop(&mut self) {
        if let Some(mut child) = self.child.take() {
            for pid in descendants(self.pid) {
                kill(pid, 9);
            }
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

/// Asks `f` every `every` until it answers `Ok`, for at most `wait`; then fails with its last
/// `Err` (what did not happen).
pub fn poll<T>(wait: Duration, every: Duration, mut f: impl FnMut() -> Result<T, String>) -> T {
    let deadline = Instant::now() + wait;
    loop {
        match f() {
            Ok(v) => return v,
            Err(why) => assert!(Instant::now() < deadline, "{why}"),
        }
        std::thread::sleep(every);
    }
}

/// Waits up to `wait` for a file to hold something and returns its trimmed text.
pub fn wait_file(path: &Path, wait: Duration) -> String {
    poll(wait, Duration::from_millis(100), || {
        let text = std::fs::read_to_string(path).unwrap_or_default();
        let text = text.trim();
        (!text.is_empty())
            .then(|| text.to_string())
            .ok_or_else(|| format!("{} never appeared", path.display()))
    })
}

/// Waits up to `wait` until the run writing `run` (its directory) has come to step `step` — its
/// `steps.log` holds that step's world status — and returns the step it is at. A test acts at a
/// step of the run this way, never at a wall-clock moment.
pub fn wait_for_step(run: &Path, step: u32, wait: Duration) -> u32 {
    poll(wait, Duration::from_millis(50), || {
        let at = swarm::rundir::steplog::read(run)
            .ok()
            .and_then(|log| log.reached());
        at.filter(|&at| at >= step).ok_or_else(|| {
            format!(
                "the run in {} did not come to step {step} (at {at:?})",
                run.display()
            )
        })
    })
}

/// Waits until the run writing `run` has gone `steps` steps further than where it is now.
pub fn wait_steps(run: &Path, steps: u32, wait: Duration) -> u32 {
    let now = wait_for_step(run, 0, wait);
    wait_for_step(run, now + steps, wait)
}

pub fn kill(pid: u32, sig: i32) {
    let _ = Command::new("kill")
        .arg(format!("-{sig}"))
        .arg(pid.to_string())
        .status();
}

/// Direct children of a process (from /proc).
pub fn children_of(pid: u32) -> Vec<u32> {
    let mut out = Vec::new();
    let Ok(entries) = std::fs::read_dir("/proc") else {
        return out;
    };
    for e in entries.flatten() {
        let Some(p) = e.file_name().to_str().and_then(|s| s.parse::<u32>().ok()) else {
            continue;
        };
        if let Ok(stat) = std::fs::read_to_string(format!("/proc/{p}/stat")) {
            // Fields after the command name (which may contain spaces) start after the last ')'.
            let rest = stat.rsplit_once(')').map_or("", |(_, r)| r);
            let ppid = rest
                .split_whitespace()
                .nth(1)
                .and_then(|s| s.parse::<u32>().ok());
            if ppid == Some(pid) {
                out.push(p);
            }
        }
    }
    out
}

pub fn descendants(pid: u32) -> Vec<u32> {
    let mut all = Vec::new();
    let mut frontier = vec![pid];
    while let Some(p) = frontier.pop() {
        for c in children_of(p) {
            all.push(c);
            frontier.push(c);
        }
    }
    all
}

/// A process exists and is not a zombie.
pub fn running(pid: u32) -> bool {
    match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
        Ok(stat) => !matches!(
            stat.rsplit_once(')')
                .map(|(_, r)| r.trim_start().chars().next()),
            Some(Some('Z'))
        ),
        Err(_) => false,
    }
}

/// Asserts that `summary.json` records each of `processes` as killed by SIGKILL and started
/// again by supervision.
pub fn assert_killed_and_supervised(s: &Summary, processes: &[&str]) {
    let events = &s.process_events;
    for &p in processes {
        let seen = |event: EventKind, cause: &dyn Fn(&str) -> bool| {
            events
                .iter()
                .any(|e| e.process.to_string() == p && e.event == event && cause(&e.cause))
        };
        assert!(
            seen(EventKind::Died, &|c| c.contains("SIGKILL")),
            "{p}: {events:?}"
        );
        assert!(
            seen(EventKind::Started, &|c| c == "supervised"),
            "{p}: {events:?}"
        );
    }
}

/// `summary.json`, typed: a field missing, renamed or mistyped fails here, naming it.
pub fn summary_typed(run: &Path) -> Summary {
    read_summary(run).unwrap_or_else(|e| panic!("{e:#}"))
}

/// `swarm export-mcap RUN`, which must succeed: the bytes of the `run.mcap` it writes, and what
/// it said on stderr.
pub fn export_mcap(run: &Path) -> (Vec<u8>, String) {
    let export = Command::new(SWARM)
        .arg("export-mcap")
        .arg(run)
        .output()
        .expect("swarm export-mcap runs");
    let said = stderr(&export);
    assert!(export.status.success(), "{said}");
    let bytes = std::fs::read(run.join("run.mcap")).expect("run.mcap is written");
    (bytes, said)
}

pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// `n` distinct free loopback ports.
pub fn free_ports(n: usize) -> Vec<u16> {
    swarm::process::ports::free_ports(n).expect("free ports")
}

/// A CSV file of the run directory as rows of column → value.
pub fn csv(path: &Path) -> Vec<std::collections::HashMap<String, String>> {
    csv::Reader::from_path(path)
        .and_then(|mut r| r.deserialize().collect())
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// A numeric column of a [`csv`] row.
pub fn num(row: &std::collections::HashMap<String, String>, k: &str) -> f64 {
    row.get(k)
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("column {k} in {row:?}"))
}

/// A map_server PGM the launcher wrote (`grids/…`): row 0 is the top (largest y); cells are 254
/// free, 0 occupied, 205 unknown.
pub struct Pgm {
    pub width: usize,
    pub cells: Vec<u8>,
}

pub fn pgm(path: &Path) -> Pgm {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut fields = Vec::new();
    let mut i = 0;
    // Header: magic, width, height, maxval, each followed by whitespace.
    while fields.len() < 4 && i < bytes.len() {
        while i < bytes.len() && bytes[i].is_ascii_whitespace() {
            i += 1;
        }
        let start = i;
        while i < bytes.len() && !bytes[i].is_ascii_whitespace() {
            i += 1;
        }
        fields.push(String::from_utf8_lossy(&bytes[start..i]).into_owned());
    }
    let width = fields[1]
        .parse()
        .unwrap_or_else(|_| panic!("{}: width {:?}", path.display(), fields[1]));
    let cells = bytes[i + 1..].to_vec();
    assert_eq!(cells.len() % width, 0, "{}", path.display());
    Pgm { width, cells }
}

/// Runs `swarm ARGS… PATH`, which must fail (exit code 1) with an error naming `file`; returns
/// its stderr.
pub fn fails_naming(args: &[&str], path: &Path, file: &str) -> String {
    let out = Command::new(SWARM)
        .args(args)
        .arg(path)
        .output()
        .expect("swarm runs");
    let e = stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{args:?}: {e}");
    assert!(e.contains(file), "{args:?}: {e}");
    e
}

/// Waits for a launcher that was cut a link to finish (exit 0 or 2), then checks that
/// `links.csv` goes on after the cut at `step` and has the pair `a`-`b` down from `step + 4` on.
pub fn ended_with_link_down(launcher: Launcher, run: &Path, (a, b): (u64, u64), step: u64) {
    let out = launcher.wait_output(Duration::from_secs(180));
    assert!(
        out.status.code().is_some_and(|c| c == 0 || c == 2),
        "{}",
        stderr(&out)
    );
    let rows: Vec<_> = csv(&run.join("links.csv"))
        .into_iter()
        .filter(|r| r["a"] == a.to_string() && r["b"] == b.to_string())
        .filter(|r| r["step"].parse::<u64>().is_ok_and(|s| s > step + 3))
        .collect();
    assert!(
        !rows.is_empty(),
        "links.csv goes on after the cut at step {step}"
    );
    let up: Vec<&String> = rows
        .iter()
        .filter(|r| r["up"] != "0")
        .map(|r| &r["step"])
        .collect();
    assert!(
        up.is_empty(),
        "r{a}-r{b} up after the cut at step {step}: steps {up:?}"
    );
}

/// `swarm run --view` of 3 robots on `office` (radio always in range, realtime) with `sets` on
/// top, into `dir/run`; waits for the viewer's and netem's addresses.
pub fn viewed_run(
    dir: &TempDir,
    sets: &[&str],
) -> (
    Launcher,
    PathBuf,
    std::net::SocketAddr,
    std::net::SocketAddr,
) {
    let run = dir.path().join("run");
    let mut cmd = Command::new(SWARM);
    let base = [
        "world.map=office",
        "robots.count=3",
        "radio.model=always",
        "clock.mode=realtime",
        "done_pct=100",
    ];
    run_args(&mut cmd, &run, &[&base[..], sets].concat());
    cmd.arg("--view");
    let launcher = Launcher::spawn(cmd);
    let addr = |file: &str| {
        wait_file(&run.join(file), Duration::from_secs(60))
            .parse()
            .unwrap_or_else(|e| panic!("{file} holds an address: {e}"))
    };
    let (view, netem) = (addr("view.addr"), addr("netem.addr"));
    (launcher, run, view, netem)
}
