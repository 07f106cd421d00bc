//! `swarm chaos`: a Jepsen-style campaign — a random schedule of process and link faults drawn
//! from a seed, one run of the scenario under it, then a checker that reads the run directory.
//!
//! The schedule is a function of (scenario, `--faults`, `--seed`, `--within`, `--only`): the
//! faults become `[[faults]]` tables appended to the resolved scenario (written as
//! `scenario.toml` beside `chaos.json`), and `swarm run` carries them out like any scheduled
//! fault. The checker (`check`) asks of the finished run:
//!
//! * `completes` — the exploration completed (else the reason it did not);
//! * `logs` — no op a node other than its writer ever held is gone at the end: a log whose
//!   writer is alive at the end is held whole by it; of a log whose writer's life ended, the
//!   nodes alive at the end hold at least what the others ever held (what only the writer held
//!   is lost with it, and `summary.json`'s `lost_logs` says how much);
//! * `panics` — no process log contains a Rust panic;
//! * `orphans` — no process the run started is still running;
//! * `memory` — every process's peak resident set stayed under `--max-rss-mb`.
//!
//! `chaos.json` holds the schedule (with whether the run reached each fault), every check with
//! its detail, and the verdict.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::Context;
use proto::msg::owner_life;
use proto::scenario::{Process, Scenario};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use crate::process::children::ProcessRow;
use crate::process::supervise::EventKind;
use crate::rundir::summary::{read_summary, Summary};

/// Flags of `swarm chaos`.
#[derive(clap::Args, Debug, Clone)]
pub struct ChaosArgs {
    /// Scenario TOML file; without one, the embedded default (configs/default.toml).
    pub scenario: Option<PathBuf>,
    /// How many random faults to schedule (a freeze with its thaw, a cut with its restore, a
    /// toxic with its removal count as one).
    #[arg(long, default_value_t = 20)]
    pub faults: usize,
    /// Seed of the fault schedule (the scenario's own `seed` is left as it is).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Faults start within the first STEPS steps (default: the smaller of max_steps and 300,
    /// where most runs of the embedded default are still exploring).
    #[arg(long, value_name = "STEPS")]
    pub within: Option<u32>,
    /// Only these kinds of fault (comma-separated): kill, restart, freeze, netem, cut,
    /// partition, latency, bandwidth, reset. Default: all.
    #[arg(long, value_delimiter = ',', value_name = "KINDS")]
    pub only: Vec<FaultKind>,
    /// The bound the `memory` check holds every process's peak resident set to, MB.
    #[arg(long, default_value_t = 1024, value_name = "MB")]
    pub max_rss_mb: u64,
    /// Directory to write (default: `runs/chaos-<time>-seed<S>`); the run goes to its `run/`.
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Override a scenario key, as for `swarm run` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Wall-clock limit of the run, seconds; a run still going then is stopped and fails.
    #[arg(long, default_value_t = 1800, value_name = "SECONDS")]
    pub timeout_s: u64,
}

/// A kind of fault the schedule draws from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum FaultKind {
    /// SIGKILL a robot; started again 1–5 steps later.
    Kill,
    /// SIGKILL a robot and start it again at once.
    Restart,
    /// SIGSTOP a robot, SIGCONT 3–12 steps later.
    Freeze,
    /// Restart netem.
    Netem,
    /// Cut a robot pair, restore it 5–30 steps later.
    Cut,
    /// Split the nodes into two groups, heal 5–30 steps later.
    Partition,
    /// 100–1000 ms latency on a pair for 5–30 steps.
    Latency,
    /// 100–500 B/s on a pair for 5–30 steps.
    Bandwidth,
    /// Reset every link's connections once.
    Reset,
}

impl FaultKind {
    pub const ALL: [FaultKind; 9] = [
        FaultKind::Kill,
        FaultKind::Restart,
        FaultKind::Freeze,
        FaultKind::Netem,
        FaultKind::Cut,
        FaultKind::Partition,
        FaultKind::Latency,
        FaultKind::Bandwidth,
        FaultKind::Reset,
    ];
}

/// One fault of the schedule: its kind, first step, what it is, and the `[[faults]]` tables
/// that make it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Planned {
    pub step: u32,
    pub kind: FaultKind,
    pub what: String,
    #[serde(skip)]
    pub tables: Vec<toml::Table>,
}

fn table(step: u32, kind: &str, fields: &[(&str, toml::Value)]) -> toml::Table {
    let mut t = toml::Table::new();
    t.insert("step".into(), toml::Value::Integer(i64::from(step)));
    t.insert("kind".into(), toml::Value::String(kind.into()));
    for (k, v) in fields {
        t.insert((*k).into(), v.clone());
    }
    t
}

fn pair_value(a: u16, b: u16) -> toml::Value {
    toml::Value::Array(vec![i64::from(a).into(), i64::from(b).into()])
}

fn toxic_value(name: &str, kind: &str, attributes: toml::Table) -> toml::Value {
    let mut t = toml::Table::new();
    t.insert("name".into(), name.into());
    t.insert("type".into(), kind.into());
    t.insert("stream".into(), "both".into());
    t.insert("attributes".into(), toml::Value::Table(attributes));
    toml::Value::Table(t)
}

/// The fault schedule of `seed`: `n` faults of the `kinds` (all if empty) starting at steps in
/// [5, `within`], in step order. Needs two nodes for link faults; kinds that the scenario
/// cannot have (a pair of nodes, a robot) are left out.
pub fn schedule(
    s: &Scenario,
    n: usize,
    seed: u64,
    within: u32,
    kinds: &[FaultKind],
) -> Vec<Planned> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let nodes = s.nodes();
    let robots = s.robots.count;
    let kinds = usable_kinds(kinds, nodes);
    if kinds.is_empty() || robots == 0 {
        return Vec::new();
    }
    let within = within.max(6);
    let mut out = Vec::with_capacity(n);
    for i in 0..n {
        let kind = kinds[rng.gen_range(0..kinds.len())];
        let d = Drawn::draw(i, &mut rng, within, robots, nodes);
        let (what, tables) = fault_tables(kind, &d, nodes, &mut rng);
        out.push(Planned {
            step: d.step,
            kind,
            what,
            tables,
        });
    }
    out.sort_by_key(|p| p.step);
    out
}

/// The kinds asked for (every kind when none is), without the link faults when there is no
/// link (fewer than two nodes).
fn usable_kinds(kinds: &[FaultKind], nodes: u16) -> Vec<FaultKind> {
    let asked = if kinds.is_empty() {
        &FaultKind::ALL[..]
    } else {
        kinds
    };
    let process = |k: &FaultKind| {
        matches!(
            k,
            FaultKind::Kill | FaultKind::Restart | FaultKind::Freeze | FaultKind::Netem
        )
    };
    asked
        .iter()
        .copied()
        .filter(|k| nodes >= 2 || process(k))
        .collect()
}

/// What every fault of a schedule draws, in this order, whatever its kind: the step, a robot,
/// a duration and a node pair.
struct Drawn {
    name: String,
    step: u32,
    robot: u16,
    lasting: u32,
    a: u16,
    b: u16,
}

impl Drawn {
    fn draw(i: usize, rng: &mut ChaCha8Rng, within: u32, robots: u16, nodes: u16) -> Drawn {
        let step = rng.gen_range(5..=within);
        let robot = rng.gen_range(0..robots);
        let lasting = rng.gen_range(5..=30u32);
        let a = rng.gen_range(0..nodes.max(2));
        let mut b = rng.gen_range(0..nodes.max(2) - 1);
        if b >= a {
            b += 1;
        }
        Drawn {
            name: format!("chaos-{i}"),
            step,
            robot,
            lasting,
            a: a.min(b),
            b: a.max(b),
        }
    }
}

/// A fault of `kind` with the draws `d` (and any of its own from `rng`): what it does, in
/// words, and its `[[faults]]` tables.
fn fault_tables(
    kind: FaultKind,
    d: &Drawn,
    nodes: u16,
    rng: &mut ChaCha8Rng,
) -> (String, Vec<toml::Table>) {
    let (step, robot, lasting, (a, b)) = (d.step, d.robot, d.lasting, (d.a, d.b));
    let process = || toml::Value::String(format!("robot-{robot}"));
    match kind {
        FaultKind::Kill => {
            let k = rng.gen_range(1..=5u32);
            (
                format!("kill robot-{robot}, back {k} steps later"),
                vec![table(
                    step,
                    "kill",
                    &[
                        ("process", process()),
                        ("restart_after", i64::from(k).into()),
                    ],
                )],
            )
        }
        FaultKind::Restart => (
            format!("restart robot-{robot}"),
            vec![table(step, "restart", &[("process", process())])],
        ),
        FaultKind::Freeze => {
            let f = rng.gen_range(3..=12u32);
            (
                format!("freeze robot-{robot} for {f} steps"),
                vec![
                    table(step, "freeze", &[("process", process())]),
                    table(step + f, "thaw", &[("process", process())]),
                ],
            )
        }
        FaultKind::Netem => (
            "restart netem".into(),
            vec![table(step, "restart", &[("process", "netem".into())])],
        ),
        FaultKind::Cut => (
            format!("cut {a}-{b} for {lasting} steps"),
            vec![
                table(step, "cut", &[("pair", pair_value(a, b))]),
                table(step + lasting, "restore", &[("pair", pair_value(a, b))]),
            ],
        ),
        FaultKind::Partition => partition(d, nodes, rng),
        FaultKind::Latency | FaultKind::Bandwidth => toxic(kind, d, rng),
        FaultKind::Reset => ("reset every link".into(), vec![table(step, "reset", &[])]),
    }
}

/// A partition of the nodes into two random groups for `d.lasting` steps.
fn partition(d: &Drawn, nodes: u16, rng: &mut ChaCha8Rng) -> (String, Vec<toml::Table>) {
    let mut groups: [Vec<u16>; 2] = [Vec::new(), Vec::new()];
    for node in 0..nodes {
        groups[usize::from(rng.gen_bool(0.5))].push(node);
    }
    let what = format!(
        "partition {:?} | {:?} for {} steps",
        groups[0], groups[1], d.lasting
    );
    let group = |g: &Vec<u16>| toml::Value::Array(g.iter().map(|&n| i64::from(n).into()).collect());
    let groups = toml::Value::Array(groups.iter().map(group).collect());
    (
        what,
        vec![
            table(d.step, "partition", &[("groups", groups)]),
            table(d.step + d.lasting, "heal", &[]),
        ],
    )
}

/// A latency or bandwidth toxic on the pair `d.a`–`d.b` for `d.lasting` steps.
fn toxic(kind: FaultKind, d: &Drawn, rng: &mut ChaCha8Rng) -> (String, Vec<toml::Table>) {
    let (a, b, lasting) = (d.a, d.b, d.lasting);
    let (toxic, attr, what) = if kind == FaultKind::Latency {
        let ms = rng.gen_range(100..=1000i64);
        (
            "latency",
            ("latency", ms),
            format!("latency {ms} ms on {a}-{b} for {lasting} steps"),
        )
    } else {
        let rate = rng.gen_range(100..=500i64);
        (
            "bandwidth",
            ("rate_bytes_per_s", rate),
            format!("bandwidth {rate} B/s on {a}-{b} for {lasting} steps"),
        )
    };
    let mut attributes = toml::Table::new();
    attributes.insert(attr.0.into(), attr.1.into());
    let set = [
        ("pair", pair_value(a, b)),
        ("toxic", toxic_value(&d.name, toxic, attributes)),
    ];
    let remove = [("pair", pair_value(a, b)), ("name", d.name.as_str().into())];
    (
        what,
        vec![
            table(d.step, "set_toxic", &set),
            table(d.step + lasting, "remove_toxic", &remove),
        ],
    )
}

/// One check of the run, as `chaos.json` lists it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Check {
    pub name: &'static str,
    pub pass: bool,
    pub detail: String,
}

fn check(name: &'static str, problems: Vec<String>, ok: String) -> Check {
    Check {
        name,
        pass: problems.is_empty(),
        detail: if problems.is_empty() {
            ok
        } else {
            problems.join("; ")
        },
    }
}

/// The `logs` check on a run's `summary.json`: no node alive at the end holds less of a log
/// than it once held (`logs_held` against `logs_held_max`), and a writer alive at the end holds
/// at least as much of its own log as anyone else ever did. What is gone of an ended life's log
/// is lost with its holders: only with the writer (`lost_logs`), or with every node that had it
/// (counted here; a second fault took the last copy).
pub fn check_logs(summary: &Summary) -> Check {
    let alive: Vec<String> = summary
        .nodes_alive_at_end
        .iter()
        .map(|n| n.to_string())
        .collect();
    let mut problems = forgotten(summary, &alive);
    let (owners, with_holders) = writers_hold_their_logs(summary, &alive, &mut problems);
    for l in &summary.lost_logs {
        if l.ops_lost != l.ops_written.saturating_sub(l.ops_held) {
            let l = serde_json::to_string(l).unwrap_or_default();
            problems.push(format!("lost_logs does not add up: {l}"));
        }
    }
    let with_writers: u64 = summary
        .lost_logs
        .iter()
        .map(|l| u64::from(l.ops_lost))
        .sum();
    check(
        "logs",
        problems,
        format!(
            "{owners} logs: no live node forgot an op, every live writer holds its whole log; \
             of ended lives, {with_writers} ops are gone (lost_logs), {with_holders} of them \
             held by others that died too"
        ),
    )
}

/// How many ops of `owner`'s log `node` holds at the end. A node's entry lists the owners it
/// holds ops of: an owner it does not list, it holds none of.
fn held(summary: &Summary, node: &str, owner: &str) -> u64 {
    summary
        .logs_held
        .get(node)
        .and_then(|h| h.get(owner))
        .map_or(0, |&n| u64::from(n))
}

/// No live node forgets: the live nodes that hold less of a log than they once did.
fn forgotten(summary: &Summary, alive: &[String]) -> Vec<String> {
    let mut problems = Vec::new();
    for node in alive {
        for (owner, &most) in summary.logs_held_max.get(node).into_iter().flatten() {
            let (most, now) = (u64::from(most), held(summary, node, owner));
            if now < most {
                problems.push(format!(
                    "node {node} held {most} ops of log {owner} and holds {now}"
                ));
            }
        }
    }
    problems
}

/// A live writer holds its whole log (a problem each where not); of ended lives, counts the
/// ops that went with every holder. Returns (logs, ops gone with their holders).
fn writers_hold_their_logs(
    summary: &Summary,
    alive: &[String],
    problems: &mut Vec<String>,
) -> (u64, u64) {
    let process = |robot: u16| {
        if robot == summary.robots {
            Process::BaseStation
        } else {
            Process::Robot(robot)
        }
    };
    // Each process's life after its last start.
    let mut current: BTreeMap<Process, u16> = BTreeMap::new();
    for e in &summary.process_events {
        if e.event == EventKind::Started {
            current.insert(e.process, e.life);
        }
    }
    let (mut owners, mut with_holders) = (0, 0);
    for (owner, &others) in &summary.logs_held_by_others {
        let Ok(o) = owner.parse::<u16>() else {
            problems.push(format!("logs_held_by_others: {owner:?} is not a log owner"));
            continue;
        };
        let others = u64::from(others);
        owners += 1;
        let (robot, life) = owner_life(o);
        let writer_alive = alive.contains(&robot.to_string())
            && current.get(&process(robot)).copied().unwrap_or(0) == life;
        if writer_alive {
            let own = held(summary, &robot.to_string(), owner);
            if own < others {
                problems.push(format!(
                    "{} (life {life}) holds {own} ops of its own log, others held {others}",
                    process(robot)
                ));
            }
        } else {
            let end = alive
                .iter()
                .map(|n| held(summary, n, owner))
                .max()
                .unwrap_or(0);
            with_holders += others.saturating_sub(end);
        }
    }
    (owners, with_holders)
}

/// Every check of a finished run in `run` (its `summary.json`, `processes.csv`, `logs/`).
pub fn check_run(run: &Path, max_rss_kb: u64) -> anyhow::Result<Vec<Check>> {
    let summary = read_summary(run)?;
    let complete = summary.complete;
    let mut checks = vec![Check {
        name: "completes",
        pass: complete,
        detail: format!(
            "{}: {} after {} steps",
            if complete { "complete" } else { "incomplete" },
            summary.exit_reason,
            summary.steps
        ),
    }];
    checks.push(check_logs(&summary));
    let mut panicked = Vec::new();
    for e in std::fs::read_dir(run.join("logs"))
        .context("reading logs/")?
        .flatten()
    {
        let text = std::fs::read_to_string(e.path()).unwrap_or_default();
        if let Some(line) = text.lines().find(|l| l.contains("panicked at")) {
            panicked.push(format!("{}: {line}", e.file_name().to_string_lossy()));
        }
    }
    checks.push(check("panics", panicked, "no panic in any log".into()));
    let processes: Vec<ProcessRow> = crate::rundir::tables::read_rows(&run.join("processes.csv"))
        .context("reading processes.csv")?;
    let orphans: Vec<String> = processes
        .iter()
        .filter(|p| still_running(p.pid))
        .map(|p| format!("{} (life {}) pid {} still runs", p.process, p.life, p.pid))
        .collect();
    checks.push(check(
        "orphans",
        orphans,
        format!("all {} processes gone", processes.len()),
    ));
    let heavy: Vec<String> = processes
        .iter()
        .filter(|p| p.peak_rss_kb > max_rss_kb)
        .map(|p| {
            format!(
                "{} (life {}) peaked at {} MB",
                p.process,
                p.life,
                p.peak_rss_kb / 1024
            )
        })
        .collect();
    let peak = processes.iter().max_by_key(|p| p.peak_rss_kb);
    checks.push(check(
        "memory",
        heavy,
        peak.map_or("no process".into(), |p| {
            format!(
                "largest peak {} MB ({}), bound {} MB",
                p.peak_rss_kb / 1024,
                p.process,
                max_rss_kb / 1024
            )
        }),
    ));
    Ok(checks)
}

/// Whether `pid` is a live process that is not a zombie.
fn still_running(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat")).is_ok_and(|stat| {
        let state = stat
            .rsplit_once(')')
            .and_then(|(_, r)| r.split_whitespace().next());
        !matches!(state, Some("Z" | "X") | None)
    })
}

/// `chaos.json`.
#[derive(Debug, Serialize)]
pub struct Report {
    pub scenario: String,
    pub seed: u64,
    pub faults: Vec<ScheduledReport>,
    pub run: PathBuf,
    pub checks: Vec<Check>,
    pub pass: bool,
}

/// A fault of the schedule and whether the run got to it.
#[derive(Debug, Serialize)]
pub struct ScheduledReport {
    #[serde(flatten)]
    pub fault: Planned,
    pub reached: bool,
}

/// Runs a campaign; returns the report (also written as `chaos.json`) and its directory.
pub fn chaos(args: &ChaosArgs) -> anyhow::Result<(Report, PathBuf)> {
    let resolved = world_server::scenario::resolve(args.scenario.as_deref(), &args.set)?;
    let mut scenario = resolved.scenario;
    let within = args.within.unwrap_or(scenario.step_limit().min(300));
    let planned = schedule(&scenario, args.faults, args.seed, within, &args.only);
    scenario
        .faults
        .extend(planned.iter().flat_map(|p| p.tables.iter().cloned()));
    scenario
        .validate()
        .context("the fault schedule does not fit the scenario")?;
    let dir = args.out.clone().unwrap_or_else(|| default_dir(args.seed));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let scenario_file = dir.join("scenario.toml");
    std::fs::write(&scenario_file, scenario.to_toml()).context("writing scenario.toml")?;
    let run = dir.join("run");
    let _ = std::fs::remove_dir_all(&run);
    eprintln!(
        "swarm chaos: seed {}, {} faults within {within} steps on {}; run directory {}",
        args.seed,
        planned.len(),
        resolved_name(&scenario),
        run.display()
    );
    for p in &planned {
        eprintln!("  step {:>4}: {}", p.step, p.what);
    }
    let status = run_within(&run, &scenario_file, Duration::from_secs(args.timeout_s))?;
    let mut checks = match check_run(&run, args.max_rss_mb.saturating_mul(1024)) {
        Ok(c) => c,
        Err(e) => vec![Check {
            name: "run",
            pass: false,
            detail: format!("no run directory to check: {e:#}"),
        }],
    };
    if status.is_none() {
        checks.push(Check {
            name: "timeout",
            pass: false,
            detail: format!("the run was still going after {} s", args.timeout_s),
        });
    }
    let steps = read_steps(&run);
    let report = Report {
        scenario: args
            .scenario
            .as_ref()
            .map_or("(embedded default)".into(), |p| p.display().to_string()),
        seed: args.seed,
        faults: planned
            .into_iter()
            .map(|fault| ScheduledReport {
                reached: steps.is_some_and(|s| fault.step <= s),
                fault,
            })
            .collect(),
        run,
        pass: checks.iter().all(|c| c.pass),
        checks,
    };
    std::fs::write(
        dir.join("chaos.json"),
        serde_json::to_string_pretty(&report)?,
    )
    .context("writing chaos.json")?;
    Ok((report, dir))
}

/// `runs/chaos-<unix seconds>-seed<seed>`.
fn default_dir(seed: u64) -> PathBuf {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    PathBuf::from("runs").join(format!("chaos-{secs}-seed{seed}"))
}

/// `swarm run` of `scenario_file` into `run`; its exit status, or `None` when it was still
/// going after `timeout` (then it was sent SIGTERM: the launcher stops its processes and
/// writes the run directory).
fn run_within(
    run: &Path,
    scenario_file: &Path,
    timeout: Duration,
) -> anyhow::Result<Option<std::process::ExitStatus>> {
    let exe = std::env::current_exe().context("finding the swarm binary")?;
    let mut cmd = Command::new(exe);
    cmd.arg("run")
        .args(["--quiet", "--out"])
        .arg(run)
        .arg("--")
        .arg(scenario_file)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::inherit());
    crate::process::children::die_with_parent_std(&mut cmd);
    let mut child = cmd.spawn().context("starting swarm run")?;
    let deadline = Instant::now() + timeout;
    let status = loop {
        if let Some(status) = child.try_wait()? {
            break Some(status);
        }
        if Instant::now() > deadline {
            // SIGTERM: the launcher stops its processes and writes the run directory.
            let _ = Command::new("kill").arg(child.id().to_string()).status();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    Ok(status)
}

fn resolved_name(s: &Scenario) -> String {
    Path::new(&s.world.map)
        .file_stem()
        .map_or_else(|| s.world.map.clone(), |n| n.to_string_lossy().into_owned())
}

fn read_steps(run: &Path) -> Option<u32> {
    read_summary(run).ok().map(|s| s.steps)
}

/// The one line `swarm chaos` prints.
pub fn summary_line(r: &Report, dir: &Path) -> String {
    let failed: Vec<String> = r
        .checks
        .iter()
        .filter(|c| !c.pass)
        .map(|c| format!("{}: {}", c.name, c.detail))
        .collect();
    let reached = r.faults.iter().filter(|f| f.reached).count();
    format!(
        "chaos seed {}: {} ({} of {} faults reached; {}) — {}",
        r.seed,
        if r.pass { "PASS" } else { "FAIL" },
        reached,
        r.faults.len(),
        r.checks
            .iter()
            .map(|c| format!("{} {}", c.name, if c.pass { "ok" } else { "FAILED" }))
            .collect::<Vec<_>>()
            .join(", "),
        if failed.is_empty() {
            format!("{}", dir.join("chaos.json").display())
        } else {
            failed.join("; ")
        }
    )
}

/// `swarm chaos`: the campaign's one-line verdict; exit code 0 when every check passed, 2 when one
/// failed.
pub fn command(args: &ChaosArgs) -> anyhow::Result<std::process::ExitCode> {
    let (report, dir) = chaos(args)?;
    println!("{}", summary_line(&report, &dir));
    Ok(if report.pass {
        std::process::ExitCode::SUCCESS
    } else {
        std::process::ExitCode::from(2)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::process::supervise::Event;
    use crate::rundir::summary::LostLog;

    fn scenario() -> Scenario {
        let mut s = Scenario::default();
        s.robots.count = 4;
        s
    }

    #[test]
    fn a_schedule_is_a_function_of_its_seed_and_fits_the_scenario() {
        let s = scenario();
        let a = schedule(&s, 20, 7, 200, &[]);
        assert_eq!(a, schedule(&s, 20, 7, 200, &[]));
        assert_ne!(a, schedule(&s, 20, 8, 200, &[]));
        assert_eq!(a.len(), 20);
        assert!(a.windows(2).all(|w| w[0].step <= w[1].step));
        assert!(a.iter().all(|p| (5..=200).contains(&p.step)));
        let mut with = s.clone();
        with.faults = a.iter().flat_map(|p| p.tables.clone()).collect();
        with.validate().expect("process faults valid");
        netem::faults::parse_faults(&with.faults).expect("link faults valid");
        let only = schedule(&s, 10, 7, 200, &[FaultKind::Freeze]);
        assert!(only
            .iter()
            .all(|p| p.kind == FaultKind::Freeze && p.tables.len() == 2));
        // One robot and no base station: no pair, so no link fault.
        let mut alone = s;
        alone.robots.count = 1;
        assert!(schedule(&alone, 30, 1, 100, &[]).iter().all(|p| matches!(
            p.kind,
            FaultKind::Kill | FaultKind::Restart | FaultKind::Freeze | FaultKind::Netem
        )));
    }

    fn owners(held: &[(&str, u32)]) -> BTreeMap<String, u32> {
        held.iter().map(|&(o, n)| (o.to_string(), n)).collect()
    }

    /// Robot 2 was restarted into life 1; its first life (owner 2) had 100 ops, of which the
    /// others held 90.
    fn summary(held_at_end_of_owner_2: u32, robot_2_own: u32) -> Summary {
        let event = |step, event, life| Event {
            step,
            process: Process::Robot(2),
            event,
            cause: "fault".into(),
            life,
        };
        let most = owners(&[("0", 50), ("1", 40), ("2", 90), ("1026", 20)]);
        Summary {
            robots: 3,
            nodes_alive_at_end: vec![0, 1, 2],
            process_events: vec![
                event(30, EventKind::Killed, 0),
                event(33, EventKind::Started, 1),
            ],
            logs_held_by_others: most.clone(),
            logs_held_max: BTreeMap::from([
                ("0".to_string(), most.clone()),
                ("1".to_string(), most.clone()),
                (
                    "2".to_string(),
                    owners(&[("0", 50), ("1", 40), ("2", 90), ("1026", 25)]),
                ),
            ]),
            logs_held: BTreeMap::from([
                (
                    "0".to_string(),
                    owners(&[
                        ("0", 50),
                        ("1", 40),
                        ("2", held_at_end_of_owner_2),
                        ("1026", 20),
                    ]),
                ),
                ("1".to_string(), most),
                (
                    "2".to_string(),
                    owners(&[("0", 50), ("1", 40), ("2", 90), ("1026", robot_2_own)]),
                ),
            ]),
            lost_logs: vec![LostLog {
                robot: 2,
                life: 0,
                ops_written: 100,
                ops_held: 90,
                ops_lost: 10,
                bytes_written: Some(400),
                bytes_lost: Some(40),
            }],
            ..Summary::default()
        }
    }

    fn set(s: &mut BTreeMap<String, BTreeMap<String, u32>>, node: &str, owner: &str, n: u32) {
        s.entry(node.to_string())
            .or_default()
            .insert(owner.to_string(), n);
    }

    #[test]
    fn the_log_check_passes_a_recovery_that_keeps_what_others_held() {
        let c = check_logs(&summary(90, 25));
        assert!(c.pass, "{c:?}");
        assert!(c.detail.contains("10 ops are gone"), "{c:?}");
        // Robot 1 and every other holder of robot 2's first life died: lost with its holders.
        let mut s = summary(90, 25);
        s.nodes_alive_at_end = vec![0, 2];
        set(&mut s.logs_held, "0", "2", 60);
        set(&mut s.logs_held_max, "0", "2", 60);
        set(&mut s.logs_held, "2", "2", 60);
        set(&mut s.logs_held_max, "2", "2", 60);
        let c = check_logs(&s);
        assert!(
            c.pass && c.detail.contains("30 of them held by others"),
            "{c:?}"
        );
    }

    #[test]
    fn the_log_check_fails_a_recovery_that_forgets_what_others_held() {
        // Robot 0 forgot robot 2's first life once robot 2 came back.
        let c = check_logs(&summary(0, 25));
        assert!(
            !c.pass && c.detail.contains("node 0 held 90 ops of log 2 and holds 0"),
            "{c:?}"
        );
        // A restarted robot whose log is behind what others hold of it (it reused its old
        // owner, forgetting what it had written).
        let mut s = summary(90, 10);
        set(&mut s.logs_held_max, "2", "1026", 10);
        let c = check_logs(&s);
        assert!(
            !c.pass && c.detail.contains("robot-2 (life 1) holds 10"),
            "{c:?}"
        );
        // lost_logs that do not add up.
        let mut s = summary(90, 25);
        s.lost_logs[0].ops_lost = 3;
        let c = check_logs(&s);
        assert!(
            !c.pass
                && c.detail
                    .contains(r#"lost_logs does not add up: {"robot":2"#),
            "{c:?}"
        );
    }

    /// The checker once read `summary.json` as untyped JSON, a number it did not find as 0: a
    /// renamed field would have passed the `logs` check on nothing. Now the summary does not read.
    #[test]
    fn a_summary_with_a_renamed_or_missing_field_is_an_error_not_zero() {
        let dir = std::env::temp_dir().join(format!("swarm-chaos-schema-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{e}"));
        let good = serde_json::to_value(summary(0, 25)).unwrap_or_default();
        let check_with = |edit: &dyn Fn(&mut serde_json::Map<String, serde_json::Value>)| {
            let mut v = good.clone();
            if let Some(m) = v.as_object_mut() {
                edit(m);
            }
            std::fs::write(dir.join("summary.json"), v.to_string())
                .unwrap_or_else(|e| panic!("{e}"));
            check_run(&dir, u64::MAX).map_err(|e| format!("{e:#}"))
        };
        let renamed = check_with(&|m| {
            let held = m.remove("logs_held").unwrap_or_default();
            m.insert("logs_kept".into(), held);
        });
        let missing_option = check_with(&|m| {
            m.remove("awareness");
        });
        let wrong_type = check_with(&|m| {
            m.insert("robots".into(), "three".into());
        });
        let round_trip = read_summary(&dir.join("nowhere")).map_err(|e| format!("{e:#}"));
        std::fs::write(dir.join("summary.json"), good.to_string())
            .unwrap_or_else(|e| panic!("{e}"));
        let back = read_summary(&dir).ok();
        let _ = std::fs::remove_dir_all(&dir);
        for (what, r, field) in [
            ("renamed", renamed, "logs_kept"),
            ("missing", missing_option, "awareness"),
            ("mistyped", wrong_type, "three"),
        ] {
            let e = r.expect_err(what);
            assert!(
                e.contains("summary.json") && e.contains(field),
                "{what}: {e}"
            );
        }
        assert!(round_trip.is_err_and(|e| e.contains("summary.json")));
        // The failing summary itself reads back whole, and the check fails it as before.
        assert_eq!(back, Some(summary(0, 25)));
        assert!(!check_logs(&summary(0, 25)).pass);
    }
}
