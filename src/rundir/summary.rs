//! `summary.json`: what a run ended with, typed ([`Summary`](crate::rundir::summary::Summary));
//! written by the launcher and read back through the same type by every reader (chaos checker,
//! sweep results, tests).

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::Context;
use proto::exit::ExitReason;
use proto::msg::{RobotId, Step, Traffic};
use serde::{Deserialize, Serialize};

/// Coverage thresholds reported in `summary.json` (`coverage_steps`).
pub const THRESHOLDS: [u32; 4] = [50, 90, 95, 100];

/// Version of the run-directory schema, written into `summary.json` (8: `collisions` split into
/// `collisions_robots` and `collisions_walls`, `fidelity`, and `metrics.csv`'s fidelity columns).
pub const SCHEMA_VERSION: u32 = 8;

/// `summary.json`. Read back with [`read_summary`]: a field missing or renamed (an `Option` one
/// too: it is written as `null`, never left out) or one the type does not know is an error.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Summary {
    pub schema_version: u32,
    pub complete: bool,
    pub exit_reason: ExitReason,
    pub robots: u16,
    pub robots_alive_at_end: usize,
    pub steps: u32,
    pub wall_seconds: f64,
    #[serde(deserialize_with = "required")]
    pub exploration_steps: Option<u32>,
    pub coverage_steps: BTreeMap<String, Option<u32>>,
    pub best_coverage_pct: f64,
    pub reachable_cells: usize,
    /// Bytes netem forwarded between robots (both directions, all links): the radio plane's
    /// real TCP payload, zenoh's framing included.
    #[serde(deserialize_with = "required")]
    pub bytes_wire_total: Option<u64>,
    pub bytes_payload_total: u64,
    pub bytes_by_type: BTreeMap<String, u64>,
    /// Thesis eq. 6.1, the mean over the robots of their own approximation's e_avg; `null`
    /// unless `exchange.mode = "polygon"`.
    #[serde(deserialize_with = "required")]
    pub approx_error_avg: Option<f64>,
    /// Thesis Tables 6.2–6.6: each package type's share of the polygon exchange's payload bytes,
    /// in percent, with the vertex / object / overhead sums; `null` without polygon traffic.
    #[serde(deserialize_with = "required")]
    pub traffic_shares_pct: Option<BTreeMap<String, f64>>,
    /// Per robot, the splitting frequency s it ended with (polygon exchange; thesis §5.3).
    pub splits_per_step_final: BTreeMap<String, Option<f64>>,
    /// What waited for links: the largest backlog (bytes of log entries a neighbour lacked after
    /// a robot's sending) over the run, and its mean over robot-steps that had neighbours.
    pub backlog_max_bytes: u64,
    pub backlog_mean_bytes: f64,
    /// Per robot, per owner: how many records of the owner's log the robot held at the end.
    pub logs_held: BTreeMap<String, BTreeMap<String, u32>>,
    /// Moves the world refused because the robot would come too close to another robot.
    pub collisions_robots: u64,
    /// Moves the world refused because their straight segment crosses a cell that is not free
    /// (the robot planned through what it believed free).
    pub collisions_walls: u64,
    /// How true the robots' planning grids are at the end ([`FidelitySummary`]).
    pub fidelity: FidelitySummary,
    pub distance_m: Vec<f64>,
    pub radio_decode_errors: u64,
    /// How many steps links needed to reconnect after coming back into range or being restored.
    pub reconnect: ReconnectSummary,
    /// Team awareness (de Hoog et al. 2010, Fig. 5); `null` without a base station.
    #[serde(deserialize_with = "required")]
    pub awareness: Option<AwarenessSummary>,
    /// Rooker and Birk 2005, Fig. 6: the communication level over the steps (`metrics.csv`'s
    /// `comm_level_pct`), its lowest and its mean.
    #[serde(deserialize_with = "required")]
    pub comm_level_pct: Option<CommLevel>,
    /// `pack`: the leaders' judgements of their links against netem's; `null` for the others.
    #[serde(deserialize_with = "required")]
    pub link_judgement: Option<crate::score::connectivity::LinkJudgement>,
    /// The radio channel when netem shared it or lost frames ([`ChannelSummary`]); `null`
    /// otherwise (and in runs written before it existed).
    #[serde(default)]
    pub channel: Option<ChannelSummary>,
    pub failed_processes: Vec<String>,
    /// What was done to the processes — the scenario's process faults and supervised restarts —
    /// in order ([`crate::process::supervise::Event`]).
    pub process_events: Vec<crate::process::supervise::Event>,
    /// Per robot life that ended before the run did: how much of its own log the team still
    /// holds at the end, and what was lost with it (what only it held).
    pub lost_logs: Vec<LostLog>,
    /// {owner: ops}: the most of each owner's log a node other than its writer reported holding
    /// at any step (what the team had; a checker compares it with `logs_held` at the end).
    pub logs_held_by_others: BTreeMap<String, u32>,
    /// {node: {owner: ops}}: like `logs_held`, the most each node (in its last life) held of
    /// each owner's log at any step; a node that holds less at the end forgot something.
    pub logs_held_max: BTreeMap<String, BTreeMap<String, u32>>,
    /// The nodes (robots, then the base station) alive at the end.
    pub nodes_alive_at_end: Vec<RobotId>,
    /// Lockstep: whether nothing but the scenario decided the run. `false` in realtime mode, and
    /// when a wall-clock timeout decided something or a process failed; `nondeterministic` says
    /// what and where.
    pub deterministic: bool,
    pub nondeterministic: Vec<String>,
    /// sha256 of the run's outputs ([`DIGESTED`] and `grids/`): two runs with the same digest
    /// wrote the same tables and grids, byte for byte.
    pub run_digest: String,
}

/// One ended life of a robot in `summary.json`'s `lost_logs`: its own log as it last reported
/// it, and the most of it any node alive at the end holds (the team holds prefixes of a log, so
/// what is beyond the longest one is lost). Bytes are the ops' compact encoding (polygon
/// exchange; `null` for the other modes).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LostLog {
    pub robot: RobotId,
    pub life: u16,
    pub ops_written: u32,
    pub ops_held: u32,
    pub ops_lost: u32,
    #[serde(deserialize_with = "required")]
    pub bytes_written: Option<u64>,
    #[serde(deserialize_with = "required")]
    pub bytes_lost: Option<u64>,
}

/// `awareness` in `summary.json`: the team-awareness metrics of de Hoog, Cameron and Visser
/// (TAROS 2010, Fig. 5), over the run. Step means weigh every step the same.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AwarenessSummary {
    /// Fig. 5b: the share of the reachable free cells the base station knew at its last step.
    #[serde(deserialize_with = "required")]
    pub base_known_pct: Option<f64>,
    /// Its mean over the steps.
    #[serde(deserialize_with = "required")]
    pub base_known_pct_mean: Option<f64>,
    /// Fig. 5c: the mean over steps of the robots' mean `shared_pct`.
    #[serde(deserialize_with = "required")]
    pub shared_pct_mean: Option<f64>,
    /// Fig. 5d: the mean over steps of the robots' mean `steps_since_base`, and its largest
    /// value.
    #[serde(deserialize_with = "required")]
    pub steps_since_base_mean: Option<f64>,
    #[serde(deserialize_with = "required")]
    pub steps_since_base_max: Option<Step>,
    /// Fig. 5a: the mean over steps of `team_pct` (what the team knows together).
    #[serde(deserialize_with = "required")]
    pub team_pct_mean: Option<f64>,
}

/// `fidelity` in `summary.json` ([`crate::score::fidelity`]): of each robot's last report, the
/// share of the cells its planning grid holds free that are not free in the truth, and that are
/// occupied in it — the median robot and the worst. `null` when no robot believed a cell free.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FidelitySummary {
    #[serde(deserialize_with = "required")]
    pub false_free_pct_median: Option<f64>,
    #[serde(deserialize_with = "required")]
    pub false_free_pct_worst: Option<f64>,
    #[serde(deserialize_with = "required")]
    pub on_walls_pct_median: Option<f64>,
    #[serde(deserialize_with = "required")]
    pub on_walls_pct_worst: Option<f64>,
}

/// `channel` in `summary.json`, from `channel_nodes.csv` and `channel_links.csv`: how busy the
/// shared channel was and how many frames were lost (docs/guide/radio.md).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelSummary {
    /// The mean over steps and live nodes of the channel's utilisation where the node is.
    pub utilisation_mean: f64,
    /// The mean over steps of the busiest node's utilisation.
    pub utilisation_busiest_mean: f64,
    /// Airtime used by every node, bytes (frames beyond their headers, frames sent again).
    pub airtime_bytes: u64,
    pub frames_lost: u64,
    /// Frames lost over the frames of links that could carry them (a link direction a step).
    pub frames_lost_pct: f64,
    pub retransmitted_bytes: u64,
}

/// `comm_level_pct` in `summary.json`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CommLevel {
    pub min: f64,
    pub mean: f64,
}

/// The run directory's tables that a run's digest covers (none of them holds a wall-clock
/// field), with every grid in `grids/`.
pub const DIGESTED: [&str; 5] = [
    "links.csv",
    "metrics.csv",
    "traffic_by_type.csv",
    "saves.csv",
    "views.csv",
];

/// Tables a run writes only with some scenarios (a shared or lossy channel), digested when
/// they are there (after [`DIGESTED`], before the grids) and not named when they are not, so
/// that runs without them keep their digests.
pub const DIGESTED_IF_PRESENT: [&str; 2] = ["channel_nodes.csv", "channel_links.csv"];

/// sha256 over the [`DIGESTED`] tables, those of [`DIGESTED_IF_PRESENT`] there are, and
/// `grids/*.pgm`, each as its name, length and bytes, in
/// a fixed order (a missing table counts as empty).
pub fn run_digest(dir: &Path) -> anyhow::Result<String> {
    use sha2::{Digest, Sha256};
    let mut names: Vec<String> = DIGESTED.iter().map(|s| s.to_string()).collect();
    names.extend(
        (DIGESTED_IF_PRESENT.iter())
            .filter(|n| dir.join(n).exists())
            .map(|s| s.to_string()),
    );
    if let Ok(rd) = std::fs::read_dir(dir.join("grids")) {
        let mut grids: Vec<String> = rd
            .filter_map(|e| e.ok())
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".pgm"))
            .map(|n| format!("grids/{n}"))
            .collect();
        grids.sort();
        names.extend(grids);
    }
    let mut h = Sha256::new();
    for name in &names {
        let bytes = match std::fs::read(dir.join(name)) {
            Ok(b) => b,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Vec::new(),
            Err(e) => return Err(anyhow::anyhow!("reading {name} for the run digest: {e}")),
        };
        h.update((name.len() as u64).to_le_bytes());
        h.update(name.as_bytes());
        h.update((bytes.len() as u64).to_le_bytes());
        h.update(&bytes);
    }
    Ok(h.finalize().iter().map(|b| format!("{b:02x}")).collect())
}

pub fn coverage_steps(reached: &BTreeMap<u32, u32>) -> BTreeMap<String, Option<u32>> {
    THRESHOLDS
        .iter()
        .map(|t| (t.to_string(), reached.get(t).copied()))
        .collect()
}

/// The groups of Tables 6.2–6.6 and their members.
const SHARE_GROUPS: [(&str, [&str; 3]); 3] = [
    ("vertex", ["ins", "rep", "del"]),
    ("object", ["em", "chg", "rm"]),
    ("overhead", ["conn", "targ", "save"]),
];

/// Each package type's share of the polygon exchange's bytes (`by_type` as in `summary.json`),
/// with the group sums, in percent; `None` if no vertex or object bytes were sent.
pub fn traffic_shares(by_type: &BTreeMap<String, u64>) -> Option<BTreeMap<String, f64>> {
    let get = |k: &str| by_type.get(k).copied().unwrap_or(0) as f64;
    let polygon: f64 = SHARE_GROUPS[..2]
        .iter()
        .flat_map(|(_, m)| m.iter())
        .map(|k| get(k))
        .sum();
    if polygon == 0.0 {
        return None;
    }
    let total: f64 = SHARE_GROUPS
        .iter()
        .flat_map(|(_, m)| m.iter())
        .map(|k| get(k))
        .sum();
    let mut out = BTreeMap::new();
    for (group, members) in SHARE_GROUPS {
        let mut sum = 0.0;
        for k in members {
            let pct = 100.0 * get(k) / total;
            sum += pct;
            out.insert(k.to_string(), pct);
        }
        out.insert(group.to_string(), sum);
    }
    Some(out)
}

pub fn bytes_by_type(per_robot: &[Vec<u64>]) -> BTreeMap<String, u64> {
    Traffic::ALL
        .iter()
        .enumerate()
        .map(|(i, t)| {
            (
                t.name().to_string(),
                per_robot
                    .iter()
                    .map(|v| v.get(i).copied().unwrap_or(0))
                    .sum(),
            )
        })
        .collect()
}

pub fn write_summary(dir: &Path, s: &Summary) -> anyhow::Result<()> {
    let text = serde_json::to_string_pretty(s)?;
    std::fs::write(dir.join("summary.json"), text + "\n").context("writing summary.json")
}

/// Reads `dir`'s `summary.json` as a [`Summary`]; errors name the file (and serde's message
/// the field: a missing, renamed or unknown one is an error, never a default).
pub fn read_summary(dir: &Path) -> anyhow::Result<Summary> {
    let path = dir.join("summary.json");
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("reading {}", path.display()))
}

/// Whether the run in `dir` is finished: it wrote its summary and was not interrupted (Ctrl-C
/// or SIGTERM reach the run, which then writes an `interrupted` summary). A summary that does
/// not read (another schema) counts as not finished. What `swarm sweep` runs again.
pub fn finished(dir: &Path) -> bool {
    read_summary(dir).is_ok_and(|s| s.exit_reason != ExitReason::Interrupted)
}

/// Deserializes an `Option` field that must be present (`null` when empty): without this, serde
/// reads a missing `Option` field as `None`, and a renamed one would go unnoticed.
fn required<'de, D, T>(d: D) -> Result<Option<T>, D::Error>
where
    D: serde::Deserializer<'de>,
    T: Deserialize<'de>,
{
    Option::<T>::deserialize(d)
}

/// An empty run's summary (no step, nothing sent, every optional field `null`): what tests
/// start from.
impl Default for Summary {
    fn default() -> Summary {
        Summary {
            schema_version: SCHEMA_VERSION,
            complete: false,
            exit_reason: ExitReason::MaxSteps,
            robots: 0,
            robots_alive_at_end: 0,
            steps: 0,
            wall_seconds: 0.0,
            exploration_steps: None,
            coverage_steps: BTreeMap::new(),
            best_coverage_pct: 0.0,
            reachable_cells: 0,
            bytes_wire_total: None,
            bytes_payload_total: 0,
            bytes_by_type: BTreeMap::new(),
            approx_error_avg: None,
            traffic_shares_pct: None,
            splits_per_step_final: BTreeMap::new(),
            backlog_max_bytes: 0,
            backlog_mean_bytes: 0.0,
            logs_held: BTreeMap::new(),
            collisions_robots: 0,
            collisions_walls: 0,
            fidelity: FidelitySummary::default(),
            distance_m: Vec::new(),
            radio_decode_errors: 0,
            reconnect: ReconnectSummary::default(),
            awareness: None,
            comm_level_pct: None,
            link_judgement: None,
            channel: None,
            failed_processes: Vec::new(),
            process_events: Vec::new(),
            lost_logs: Vec::new(),
            logs_held_by_others: BTreeMap::new(),
            logs_held_max: BTreeMap::new(),
            nodes_alive_at_end: Vec::new(),
            deterministic: false,
            nondeterministic: Vec::new(),
            run_digest: String::new(),
        }
    }
}

/// A summary with every optional field present and every map holding its keys: the fixed ones
/// (coverage thresholds, traffic types, share groups) as they are, the per-run ones (a node, an
/// owner, a step) as placeholders in angle brackets. What [`number_paths`] walks.
fn exemplar() -> Summary {
    let one = |k: &str| BTreeMap::from([(k.to_string(), 0)]);
    let by_type = bytes_by_type(&[]);
    let all_sent: BTreeMap<String, u64> = by_type.keys().map(|k| (k.clone(), 1)).collect();
    Summary {
        exploration_steps: Some(0),
        coverage_steps: coverage_steps(&THRESHOLDS.iter().map(|&t| (t, 0)).collect()),
        bytes_wire_total: Some(0),
        bytes_by_type: by_type,
        approx_error_avg: Some(0.0),
        traffic_shares_pct: traffic_shares(&all_sent),
        splits_per_step_final: BTreeMap::from([("<robot>".to_string(), Some(0.0))]),
        logs_held: BTreeMap::from([("<node>".to_string(), one("<owner>"))]),
        reconnect: ReconnectSummary {
            mean_steps: Some(0.0),
            max_steps: Some(0),
            histogram: BTreeMap::from([("<steps>".to_string(), 0)]),
            ..ReconnectSummary::default()
        },
        awareness: Some(AwarenessSummary {
            base_known_pct: Some(0.0),
            base_known_pct_mean: Some(0.0),
            shared_pct_mean: Some(0.0),
            steps_since_base_mean: Some(0.0),
            steps_since_base_max: Some(0),
            team_pct_mean: Some(0.0),
        }),
        comm_level_pct: Some(CommLevel::default()),
        fidelity: FidelitySummary {
            false_free_pct_median: Some(0.0),
            false_free_pct_worst: Some(0.0),
            on_walls_pct_median: Some(0.0),
            on_walls_pct_worst: Some(0.0),
        },
        link_judgement: Some(crate::score::connectivity::LinkJudgement::default()),
        channel: Some(ChannelSummary::default()),
        logs_held_by_others: one("<owner>"),
        logs_held_max: BTreeMap::from([("<node>".to_string(), one("<owner>"))]),
        ..Summary::default()
    }
}

/// The dotted paths of `summary.json`'s numbers (`steps`, `awareness.team_pct_mean`,
/// `coverage_steps.90`, `logs_held.<node>.<owner>`), sorted: what an
/// experiment file may name as a field. A segment in angle brackets stands for any key.
pub fn number_paths() -> Vec<String> {
    fn walk(v: &serde_json::Value, at: &str, out: &mut Vec<String>) {
        match v {
            serde_json::Value::Number(_) | serde_json::Value::Null => out.push(at.to_string()),
            serde_json::Value::Object(m) => {
                for (k, v) in m {
                    let path = if at.is_empty() {
                        k.clone()
                    } else {
                        format!("{at}.{k}")
                    };
                    walk(v, &path, out);
                }
            }
            _ => {}
        }
    }
    let mut out = Vec::new();
    if let Ok(v) = serde_json::to_value(exemplar()) {
        walk(&v, "", &mut out);
    }
    out
}

/// Whether `path` names a number of `summary.json` ([`number_paths`]); an error that names it
/// and lists the paths there are otherwise.
pub fn check_number_path(path: &str) -> anyhow::Result<()> {
    let paths = number_paths();
    let matches = |pattern: &str| {
        let (mut p, mut q) = (pattern.split('.'), path.split('.'));
        loop {
            match (p.next(), q.next()) {
                (None, None) => return true,
                (Some(a), Some(b)) if a == b || (a.starts_with('<') && !b.is_empty()) => {}
                _ => return false,
            }
        }
    };
    anyhow::ensure!(
        paths.iter().any(|p| matches(p)),
        "summary field {path:?} is not a number in summary.json; the fields are: {}",
        paths.join(", ")
    );
    Ok(())
}

/// Reconnection after a link re-enters range (or is restored): for every time a link that had
/// been connected went down and came back up, the steps from its first step up again to the
/// first step whose end finds a connection through netem open (0: reconnected within the step).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Reconnects {
    pub steps: Vec<Step>,
    /// The link went down again before a connection was open.
    pub lost_before_reconnect: usize,
    /// Still waiting when the run ended.
    pub pending_at_end: usize,
}

/// `reconnect` in `summary.json`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReconnectSummary {
    /// Down-then-up events that reconnected.
    pub events: usize,
    #[serde(deserialize_with = "required")]
    pub mean_steps: Option<f64>,
    #[serde(deserialize_with = "required")]
    pub max_steps: Option<Step>,
    /// Steps → events, e.g. {"0": 40, "1": 3}.
    pub histogram: BTreeMap<String, usize>,
    pub lost_before_reconnect: usize,
    pub pending_at_end: usize,
}

impl From<&Reconnects> for ReconnectSummary {
    fn from(r: &Reconnects) -> ReconnectSummary {
        let mut histogram: BTreeMap<Step, usize> = BTreeMap::new();
        for &s in &r.steps {
            *histogram.entry(s).or_default() += 1;
        }
        ReconnectSummary {
            events: r.steps.len(),
            mean_steps: (!r.steps.is_empty())
                .then(|| r.steps.iter().map(|&s| f64::from(s)).sum::<f64>() / r.steps.len() as f64),
            max_steps: r.steps.iter().copied().max(),
            histogram: histogram
                .into_iter()
                .map(|(k, v)| (k.to_string(), v))
                .collect(),
            lost_before_reconnect: r.lost_before_reconnect,
            pending_at_end: r.pending_at_end,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::process::supervise::{Event, EventKind};
    use proto::scenario::Process;

    fn nulls(v: &serde_json::Value, at: &str, out: &mut Vec<String>) {
        match v {
            serde_json::Value::Null => out.push(at.to_string()),
            serde_json::Value::Object(m) => m
                .iter()
                .for_each(|(k, v)| nulls(v, &format!("{at}.{k}"), out)),
            serde_json::Value::Array(a) => a.iter().for_each(|v| nulls(v, &format!("{at}[]"), out)),
            _ => {}
        }
    }

    /// [`number_paths`] sees every field only if the exemplar fills every optional one: a new
    /// `Option` field must be given a value there.
    #[test]
    fn the_exemplar_fills_every_optional_field() {
        let mut found = Vec::new();
        nulls(
            &serde_json::to_value(exemplar()).unwrap_or_default(),
            "",
            &mut found,
        );
        assert!(found.is_empty(), "null in the exemplar: {found:?}");
        let paths = number_paths();
        for p in [
            "steps",
            "coverage_steps.90",
            "awareness.team_pct_mean",
            "reconnect.events",
        ] {
            assert!(paths.iter().any(|x| x == p), "{p}: {paths:?}");
        }
        assert!(!paths.iter().any(|x| x == "complete" || x == "run_digest"));
    }

    #[test]
    fn a_summary_reads_back_as_it_was_written() {
        let mut s = exemplar();
        s.process_events.push(Event {
            step: 3,
            process: Process::Netem,
            event: EventKind::NotRestarted,
            cause: "supervised: it had its 1 restarts".into(),
            life: 1,
        });
        s.lost_logs.push(LostLog {
            robot: 1,
            life: 0,
            ops_written: 10,
            ops_held: 8,
            ops_lost: 2,
            bytes_written: None,
            bytes_lost: None,
        });
        s.nodes_alive_at_end = vec![0, 2];
        s.run_digest = "ab".into();
        let dir = std::env::temp_dir().join(format!("swarm-summary-rt-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{e}"));
        let back = write_summary(&dir, &s).and_then(|()| read_summary(&dir));
        let _ = std::fs::remove_dir_all(&dir);
        assert_eq!(back.map_err(|e| format!("{e:#}")), Ok(s.clone()));
        assert_eq!(
            serde_json::from_value::<Summary>(
                serde_json::to_value(Summary::default()).unwrap_or_default()
            )
            .ok(),
            Some(Summary::default())
        );
    }

    type Edit = dyn Fn(&mut serde_json::Value);

    /// Every field must be there, `null` for an empty optional one; a field the type does not
    /// know is refused too (a renamed field is both).
    #[test]
    fn a_field_missing_or_unknown_does_not_read() {
        let good = serde_json::to_value(exemplar()).unwrap_or_default();
        let read = |edit: &Edit| {
            let mut v = good.clone();
            edit(&mut v);
            serde_json::from_value::<Summary>(v).map_err(|e| e.to_string())
        };
        assert!(read(&|_| {}).is_ok());
        let cases: [(&str, &Edit); 5] = [
            ("exploration_steps", &|v| {
                v.as_object_mut().map(|m| m.remove("exploration_steps"));
            }),
            ("collisions_walls", &|v| {
                v.as_object_mut().map(|m| m.remove("collisions_walls"));
            }),
            ("team_pct_mean", &|v| {
                v["awareness"]
                    .as_object_mut()
                    .map(|m| m.remove("team_pct_mean"));
            }),
            ("bytes_lost_total", &|v| v["bytes_lost_total"] = 3.into()),
            ("max_steps", &|v| {
                v["reconnect"]
                    .as_object_mut()
                    .map(|m| m.remove("max_steps"));
            }),
        ];
        for (field, edit) in cases {
            let e = read(edit).expect_err(field);
            assert!(e.contains(field), "{field}: {e}");
        }
    }
}
