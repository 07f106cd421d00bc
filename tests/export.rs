//! A run's step log and its MCAP: `swarm export-mcap` writes a file the official MCAP reader (the
//! `mcap` crate, with chunk CRCs checked) opens, in log-time order, every channel in the schema
//! Foxglove's SDK ships for its type and every message decoding in it, with a message per robot
//! report and per link step as the run's tables count them; on a shared channel that loses
//! frames, each robot's airtime on `/stats` and the links that lost a frame on `/links`, as the
//! channel's tables have them; a cut or foreign run directory gives an error naming the file.

use std::collections::{BTreeMap, BTreeSet};
use std::time::Duration;

use crate::support::{csv, export_mcap, fails_naming, stderr, swarm_run, TempDir};

#[test]
fn the_mcap_of_a_run_holds_every_report_and_link_step_of_its_tables() {
    let (dir, run, bytes) = office_run_exported("mcap", &[]);
    let counts = read_checked(&bytes);
    let metrics = csv(&run.join("metrics.csv"));
    for robot in 0..3 {
        let rows = metrics
            .iter()
            .filter(|r| r["robot"] == robot.to_string())
            .count() as u64;
        assert!(rows > 0);
        assert_eq!(
            counts.get(&format!("/robot_{robot}/pose")),
            Some(&rows),
            "{counts:?}"
        );
        assert!(counts
            .get(&format!("/robot_{robot}/grid"))
            .is_some_and(|&n| n >= rows / 10));
    }
    let steps: BTreeSet<String> = metrics.iter().map(|r| r["step"].clone()).collect();
    assert_eq!(counts.get("/robots"), Some(&(steps.len() as u64)));
    assert_eq!(counts.get("/trajectories"), Some(&(steps.len() as u64)));
    assert_eq!(counts.get("/stats"), Some(&(steps.len() as u64)));
    assert!(counts.get("/tf").is_some_and(|&n| n >= steps.len() as u64));
    let link_steps: BTreeSet<String> = csv(&run.join("links.csv"))
        .iter()
        .map(|r| r["step"].clone())
        .collect();
    assert!(!link_steps.is_empty());
    assert_eq!(
        counts.get("/links"),
        Some(&(link_steps.len() as u64)),
        "{counts:?}"
    );
    assert_eq!(counts.get("/links/bytes"), Some(&(link_steps.len() as u64)));
    assert_eq!(counts.get("/map/truth"), Some(&1));

    // A step log cut mid-record (a launcher killed) exports up to its last whole record and
    // says where it was cut; a directory that is no run is refused.
    let log = run.join("steps.log");
    let whole = std::fs::read(&log).expect("steps.log");
    std::fs::write(&log, &whole[..whole.len() * 2 / 3]).expect("cut steps.log");
    let (torn, said) = export_mcap(&run);
    assert!(
        said.contains("steps.log")
            && said.contains("cut short at byte")
            && said.contains("up to step"),
        "{said}"
    );
    let torn = read_checked(&torn);
    let (before, after) = (counts["/robots"], torn["/robots"]);
    assert!(after > 0 && after < before, "{after} of {before} steps");
    fails_naming(&["export-mcap"], dir.path(), "steps.log");
}

/// `/stats` as far as the channel test reads it: the fields' numbers are their places in
/// `swarm::view::foxglove::RunStats` and `RobotStats` (the SDK's derive numbers them in order).
#[derive(Clone, PartialEq, prost::Message)]
struct StatsAir {
    #[prost(uint32, tag = "1")]
    step: u32,
    #[prost(message, repeated, tag = "5")]
    robots: Vec<RobotAir>,
}

#[derive(Clone, PartialEq, prost::Message)]
struct RobotAir {
    #[prost(uint32, tag = "1")]
    robot: u32,
    #[prost(uint64, tag = "8")]
    airtime_share_bytes: u64,
    #[prost(uint64, tag = "9")]
    airtime_bytes: u64,
    #[prost(float, tag = "10")]
    channel_utilisation: f32,
    #[prost(uint32, tag = "11")]
    frames_lost: u32,
}

/// A run on a shared channel that loses frames: its MCAP's `/stats` has each robot's use of the
/// channel as `channel_nodes.csv` has it, and `/links` marks links that lost a frame in a step
/// `channel_links.csv` says one did, drawn in the lossy links' colour.
#[test]
fn the_mcap_of_a_run_on_a_lossy_shared_channel_shows_each_robots_airtime_and_lost_frames() {
    let (_dir, run, bytes) = office_run_exported(
        "mcap-air",
        &[
            "radio.medium=airtime",
            "radio.frame_loss=0.2",
            "clock.step_seconds=1.0",
        ],
    );
    let nodes: BTreeMap<(String, String), u64> = csv(&run.join("channel_nodes.csv"))
        .iter()
        .map(|r| {
            let airtime = r["airtime_bytes"].parse().expect("airtime_bytes");
            ((r["step"].clone(), r["node"].clone()), airtime)
        })
        .collect();
    let lost_steps: BTreeSet<String> = csv(&run.join("channel_links.csv"))
        .iter()
        .filter(|r| r["lost_a_to_b"] == "1" || r["lost_b_to_a"] == "1")
        .map(|r| r["step"].clone())
        .collect();
    assert!(!lost_steps.is_empty(), "a frame lost in 40 steps at 20 %");
    the_stats_and_links_show_the_air(&bytes, &nodes, &lost_steps);
    // netem's report of a step comes once the next step opens, later on a loaded machine: the
    // same run with step 0's link and channel records written after step 6's still exports
    // each robot's airtime at step 0.
    late_netem_records(&run.join("steps.log"), 0, 6);
    let (late, _) = export_mcap(&run);
    the_stats_and_links_show_the_air(&late, &nodes, &lost_steps);
}

/// The MCAP `bytes` has each robot's airtime of `channel_nodes.csv` (`nodes`) in `/stats`, and
/// marks lost frames only at `lost_steps`, in the lossy links' colour.
fn the_stats_and_links_show_the_air(
    bytes: &[u8],
    nodes: &BTreeMap<(String, String), u64>,
    lost_steps: &BTreeSet<String>,
) {
    use prost::Message;
    let (mut compared, mut shares, mut marked, mut lossy) = (0, 0, 0, 0);
    for m in mcap::MessageStream::new(bytes).expect("an MCAP file") {
        let m = m.expect("every message reads");
        match m.channel.topic.as_str() {
            "/stats" => {
                let s = StatsAir::decode(&m.data[..]).expect("/stats decodes");
                for r in &s.robots {
                    let key = (s.step.to_string(), r.robot.to_string());
                    if let Some(&airtime) = nodes.get(&key) {
                        assert_eq!(
                            r.airtime_bytes, airtime,
                            "step {} robot {}",
                            s.step, r.robot
                        );
                        compared += 1;
                    }
                    shares += usize::from(r.airtime_share_bytes > 0);
                }
            }
            "/links" => {
                let u = foxglove::messages::SceneUpdate::decode(&m.data[..]).expect("/links");
                let step = m.log_time / 1_000_000_000; // one simulated second a step
                for e in &u.entities {
                    if e.texts.iter().any(|t| t.text == "lost") {
                        assert!(lost_steps.contains(&step.to_string()), "step {step}");
                        marked += 1;
                    }
                    let orange = |l: &foxglove::messages::LinePrimitive| {
                        l.color.as_ref().is_some_and(|c| c.r > 0.9)
                    };
                    lossy += e.lines.iter().filter(|l| orange(l)).count();
                }
            }
            _ => {}
        }
    }
    assert!(
        compared > 0 && shares > 0,
        "{compared} robot steps compared, {shares} with a share"
    );
    assert!(
        marked > 0 && lossy > 0,
        "{marked} steps marked lost, {lossy} lossy lines"
    );
}

/// Rewrites the step log at `path` with netem's records of step `step` moved after the last
/// record of step `after`.
fn late_netem_records(path: &std::path::Path, step: u32, after: u32) {
    use swarm::rundir::steplog::Record;
    let bytes = std::fs::read(path).expect("steps.log");
    let mut records: Vec<Record> = Vec::new();
    let mut rest = &bytes[..];
    while let Some((len, tail)) = rest.split_first_chunk::<4>() {
        let len = u32::from_le_bytes(*len) as usize;
        records.push(postcard::from_bytes(&tail[..len]).expect("a record"));
        rest = &tail[len..];
    }
    let netem = |r: &Record| matches!(r, Record::Links { .. } | Record::Channel { .. });
    let (moved, mut kept): (Vec<Record>, Vec<Record>) = records
        .into_iter()
        .partition(|r| netem(r) && r.step() == Some(step));
    assert!(!moved.is_empty(), "netem's records of step {step}");
    let at = kept
        .iter()
        .rposition(|r| r.step() == Some(after))
        .expect("records of the later step");
    kept.splice(at + 1..at + 1, moved);
    let mut out = Vec::new();
    for r in &kept {
        let body = postcard::to_stdvec(r).expect("encodes");
        out.extend_from_slice(&(body.len() as u32).to_le_bytes());
        out.extend_from_slice(&body);
    }
    std::fs::write(path, out).expect("steps.log rewritten");
}

/// Reads an MCAP as Foxglove would: chunk CRCs checked, `log_time` never going back, each
/// channel's schema the one Foxglove's SDK ships for its type (protobuf), and every message of
/// a well-known type decoding in it. The messages per topic.
fn read_checked(bytes: &[u8]) -> BTreeMap<String, u64> {
    use foxglove::messages as fx;
    use foxglove::Encode;
    use swarm::view::foxglove::{LinkBytes, RunStats};

    let schemas: BTreeMap<&str, foxglove::Schema> = [
        ("/map/truth", fx::Grid::get_schema()),
        ("/tf", fx::FrameTransforms::get_schema()),
        ("/robots", fx::SceneUpdate::get_schema()),
        ("/trajectories", fx::SceneUpdate::get_schema()),
        ("/links", fx::SceneUpdate::get_schema()),
        ("/links/bytes", LinkBytes::get_schema()),
        ("/stats", RunStats::get_schema()),
    ]
    .into_iter()
    .map(|(t, s)| (t, s.expect("a schema")))
    .collect();
    let (grid, pose) = (
        fx::Grid::get_schema().expect("a schema"),
        fx::PoseInFrame::get_schema().expect("a schema"),
    );
    let mut counts: BTreeMap<String, u64> = BTreeMap::new();
    let mut last = 0u64;
    let crc = mcap::read::Options::ValidateChunkCrcs.into();
    for m in mcap::MessageStream::new_with_options(bytes, crc).expect("an MCAP file") {
        let m = m.expect("every message reads, its chunk's CRC right");
        let topic = m.channel.topic.as_str();
        assert!(
            m.log_time >= last,
            "{topic}: log_time {} after {last}",
            m.log_time
        );
        last = m.log_time;
        assert_eq!(m.channel.message_encoding, "protobuf", "{topic}");
        let want = if topic.ends_with("/grid") {
            &grid
        } else if topic.ends_with("/pose") {
            &pose
        } else {
            schemas
                .get(topic)
                .unwrap_or_else(|| panic!("an unexpected topic {topic}"))
        };
        let have = m
            .channel
            .schema
            .as_ref()
            .expect("every channel has a schema");
        assert_eq!(have.name, want.name, "{topic}");
        assert_eq!(have.encoding, want.encoding, "{topic}");
        assert_eq!(&have.data[..], &want.data[..], "{topic}: the SDK's schema");
        decode_well_known(topic, &have.name, &m.data);
        *counts.entry(topic.to_string()).or_default() += 1;
    }
    counts
}

/// Decodes a message of one of Foxglove's well-known types with the SDK's own protobuf types
/// (a grid also whole rows); panics naming `topic` if it does not decode. Other types pass.
pub fn decode_well_known(topic: &str, schema_name: &str, data: &[u8]) {
    use foxglove::messages as fx;
    use prost::Message;
    let decoded = match schema_name {
        "foxglove.Grid" => fx::Grid::decode(data).map(|g| {
            assert!(
                g.row_stride > 0 && g.data.len() % g.row_stride as usize == 0,
                "{topic}"
            );
        }),
        "foxglove.PoseInFrame" => fx::PoseInFrame::decode(data).map(drop),
        "foxglove.SceneUpdate" => fx::SceneUpdate::decode(data).map(drop),
        "foxglove.FrameTransforms" => fx::FrameTransforms::decode(data).map(drop),
        _ => Ok(()),
    };
    decoded.unwrap_or_else(|e| panic!("{topic}: {e}"));
}

/// 40 steps of 3 robots in a 14 × 10 m office with `extra` settings, exported: the temporary
/// directory (removed when dropped), the run directory in it and its `run.mcap`'s bytes.
fn office_run_exported(name: &str, extra: &[&str]) -> (TempDir, std::path::PathBuf, Vec<u8>) {
    let dir = TempDir::new(name);
    let mut sets = vec![
        "world.map=office",
        "world.width_m=14",
        "world.height_m=10",
        "robots.count=3",
        "max_steps=40",
        "clock.step_timeout_ms=10000",
    ];
    sets.extend_from_slice(extra);
    let (out, run) = swarm_run(&dir, None, &sets, Duration::from_secs(300));
    assert!(
        out.status.code().is_some_and(|c| c == 0 || c == 2),
        "{}",
        stderr(&out)
    );
    let (bytes, _) = export_mcap(&run);
    (dir, run, bytes)
}
