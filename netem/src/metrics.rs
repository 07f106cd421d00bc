//! The link counters for Prometheus (`GET /metrics`), so a Prometheus server, `promtool` or a plain
//! `curl` can watch a run: bytes and chunks delivered per link and direction, bytes lost, bytes
//! queued inside netem, whether each link is up, and — when the radio channel is shared or lossy —
//! each node's airtime, share, lost frames and how busy the channel is where it is (docs/design.md
//! §5 "Publishes per-step link telemetry"; the per-step view itself goes through
//! `Netem::telemetry`).
//!
//! Two expositions of the same families, chosen by the request's `Accept`
//! ([`Format::negotiate`](crate::metrics::Format::negotiate)): OpenMetrics text, the
//! `prometheus-client` crate's (what a Prometheus scrape asks for first), and Prometheus's classic
//! text format 0.0.4 (what a client asks for that does not list OpenMetrics, or prefers the classic
//! one), written here. They differ in how a counter is declared: OpenMetrics names the family
//! without `_total` and its samples with it; the classic format names family and samples alike,
//! with `_total`, and knows no `# UNIT` or `# EOF`. A classic parser reading OpenMetrics sees every
//! counter as a `# TYPE` without samples and its samples as untyped families — hence the
//! negotiation.
//!
//! Names follow Prometheus's conventions: base units spelled out as suffixes (`_bytes`, `_seconds`,
//! `_meters`), counters ending `_total`, HELP on every family. netem's counters live in its links
//! and are read as snapshots, so each scrape is one list of `Family`s over the snapshots of that
//! moment, written by [`render`](crate::metrics::render) in either format. Label values are escaped
//! here (the crate writes them as given).

use prometheus_client::collector::Collector;
use prometheus_client::encoding::text::encode;
use prometheus_client::encoding::{DescriptorEncoder, EncodeMetric, MetricEncoder};
use prometheus_client::metrics::counter::ConstCounter;
use prometheus_client::metrics::gauge::ConstGauge;
use prometheus_client::metrics::MetricType;
use prometheus_client::registry::{Registry, Unit};

use std::collections::BTreeMap;

use proto::msg::{RobotId, Step};

use crate::accounting::Dir;
use crate::channel::NodeTotals;
use crate::link::LinkSnapshot;
use proto::clock::SimTime;

/// The content type of OpenMetrics text.
pub const OPENMETRICS: &str = "application/openmetrics-text; version=1.0.0; charset=utf-8";
/// The content type of Prometheus's classic text format.
pub const CLASSIC: &str = "text/plain; version=0.0.4; charset=utf-8";

/// An exposition format of `GET /metrics`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    OpenMetrics,
    /// Prometheus's text format 0.0.4.
    Classic,
}

impl Format {
    pub fn content_type(self) -> &'static str {
        match self {
            Format::OpenMetrics => OPENMETRICS,
            Format::Classic => CLASSIC,
        }
    }

    /// The format for a request with this `Accept` header: classic when it weighs `text/plain`
    /// above `application/openmetrics-text` (one it does not list weighs 0) or refuses
    /// OpenMetrics (`q=0`); OpenMetrics otherwise — also with no `Accept`, `*/*`, or a header
    /// that cannot be read. Prometheus's scraper lists OpenMetrics first unless told otherwise,
    /// and falls back to the classic format; promtool-style clients ask for `text/plain`.
    pub fn negotiate(accept: Option<&str>) -> Format {
        let (mut openmetrics, mut text): (Option<f64>, Option<f64>) = (None, None);
        for range in accept.unwrap_or_default().split(',') {
            let mut parts = range.split(';');
            let media = parts.next().unwrap_or_default().trim().to_ascii_lowercase();
            let q = parts
                .filter_map(|p| p.split_once('='))
                .find(|(k, _)| k.trim().eq_ignore_ascii_case("q"))
                .map_or(Some(1.0), |(_, v)| {
                    v.trim()
                        .parse::<f64>()
                        .ok()
                        .filter(|q| (0.0..=1.0).contains(q))
                });
            let Some(q) = q else { continue };
            let slot = match media.as_str() {
                "application/openmetrics-text" => &mut openmetrics,
                "text/plain" => &mut text,
                _ => continue,
            };
            *slot = Some(slot.map_or(q, |old: f64| old.max(q)));
        }
        let prefers_text = text.is_some_and(|t| t > 0.0 && t > openmetrics.unwrap_or(0.0));
        if prefers_text || openmetrics == Some(0.0) {
            Format::Classic
        } else {
            Format::OpenMetrics
        }
    }
}

/// Escapes a label value (backslash, double quote, newline).
fn label(v: &str) -> String {
    v.replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
}

/// One sample's value.
#[derive(Clone, Copy, Debug)]
enum Value {
    Count(u64),
    Int(i64),
    Real(f64),
}

impl Value {
    /// The value as the classic format writes it (Go's float syntax for the infinities).
    fn text(self) -> String {
        match self {
            Value::Count(v) => v.to_string(),
            Value::Int(v) => v.to_string(),
            Value::Real(v) if v.is_nan() => "NaN".into(),
            Value::Real(v) if v.is_infinite() => if v > 0.0 { "+Inf" } else { "-Inf" }.into(),
            Value::Real(v) => v.to_string(),
        }
    }
}

fn int(v: u64) -> Value {
    Value::Int(i64::try_from(v).unwrap_or(i64::MAX))
}

/// What describes a family: its name without the unit (and, for a counter, without `_total`),
/// help, type, unit.
type Desc = (&'static str, &'static str, MetricType, Option<Unit>);

/// One family's description and samples (label pairs, value).
struct Family {
    desc: Desc,
    samples: Vec<(Vec<(&'static str, String)>, Value)>,
}

impl Family {
    /// The family's name as OpenMetrics declares it (with the unit, without `_total`).
    fn name(&self) -> String {
        match &self.desc.3 {
            Some(u) => format!("{}_{}", self.desc.0, u.as_str()),
            None => self.desc.0.to_string(),
        }
    }

    fn is_counter(&self) -> bool {
        matches!(self.desc.2, MetricType::Counter)
    }
}

type PerDir = (Desc, fn(&LinkSnapshot, Dir) -> Value);
type PerLink = (Desc, fn(&LinkSnapshot) -> Option<Value>);

/// The families with a series per link and direction.
fn per_dir() -> [PerDir; 5] {
    use MetricType::{Counter, Gauge};
    [
        (
            (
                "netem_link",
                "Bytes delivered across the link (sent by the kernel to the receiving robot).",
                Counter,
                Some(Unit::Bytes),
            ),
            |l, d| Value::Count(l.dirs[d.index()].bytes_total),
        ),
        (
            (
                "netem_link_chunks",
                "Writes to the receiving robot.",
                Counter,
                None,
            ),
            |l, d| Value::Count(l.dirs[d.index()].chunks_total),
        ),
        (
            (
                "netem_link_lost",
                "Bytes read from the sender and dropped by a cut, reset or limit_data.",
                Counter,
                Some(Unit::Bytes),
            ),
            |l, d| Value::Count(l.dirs[d.index()].lost_bytes_total),
        ),
        (
            (
                "netem_link_queued",
                "Bytes held inside netem now.",
                Gauge,
                Some(Unit::Bytes),
            ),
            |l, d| int(l.dirs[d.index()].queued_bytes),
        ),
        (
            (
                "netem_link_queued_max",
                "The most bytes ever held inside netem at once.",
                Gauge,
                Some(Unit::Bytes),
            ),
            |l, d| int(l.dirs[d.index()].queued_max_bytes),
        ),
    ]
}

/// The families with a series per link; `None` leaves a link out (its value is unknown).
fn per_link() -> [PerLink; 8] {
    use MetricType::{Counter, Gauge};
    [
        (
            (
                "netem_link_up",
                "1 if the link is up (enabled, in range, robots alive).",
                Gauge,
                None,
            ),
            |l| Some(Value::Int(i64::from(l.up))),
        ),
        (
            (
                "netem_link_enabled",
                "0 if the link is cut by a fault or partition.",
                Gauge,
                None,
            ),
            |l| Some(Value::Int(i64::from(l.enabled))),
        ),
        (
            (
                "netem_link_connections",
                "Open connections through the link.",
                Gauge,
                None,
            ),
            |l| Some(int(l.connections as u64)),
        ),
        (
            (
                "netem_link_connects",
                "Connections accepted and forwarded.",
                Counter,
                None,
            ),
            |l| Some(Value::Count(l.connects_total)),
        ),
        (
            (
                "netem_link_established",
                "Accepted connections that reached the higher id's radio listener.",
                Counter,
                None,
            ),
            |l| Some(Value::Count(l.established_total)),
        ),
        (
            (
                "netem_link_refused",
                "Connections refused (too many at once; a link that is down holds them).",
                Counter,
                None,
            ),
            |l| Some(Value::Count(l.refused_total)),
        ),
        (
            (
                "netem_link_toxics",
                "Toxics installed on the link.",
                Gauge,
                None,
            ),
            |l| Some(int(l.toxics.len() as u64)),
        ),
        (
            (
                "netem_link_distance",
                "Distance between the two robots (absent until both positions are known).",
                Gauge,
                Some(Unit::Meters),
            ),
            |l| {
                l.verdict
                    .map(|v| v.distance_m)
                    .filter(|d| d.is_finite())
                    .map(Value::Real)
            },
        ),
    ]
}

type PerNode = (Desc, fn(&NodeTotals) -> Value);

/// The families with a series per node, when the channel is shared or lossy
/// (docs/guide/radio.md).
fn per_node() -> [PerNode; 5] {
    use MetricType::{Counter, Gauge};
    [
        (
            (
                "netem_node_airtime",
                "Airtime the node used on the radio channel: its frames beyond their headers, and frames sent again.",
                Counter,
                Some(Unit::Bytes),
            ),
            |t| Value::Count(t.airtime_bytes),
        ),
        (
            (
                "netem_node_frames_lost",
                "The node's frames lost once (each sent again a step later).",
                Counter,
                None,
            ),
            |t| Value::Count(t.frames_lost),
        ),
        (
            (
                "netem_node_retransmitted",
                "Bytes of the node's frames sent again.",
                Counter,
                Some(Unit::Bytes),
            ),
            |t| Value::Count(t.retransmitted_bytes),
        ),
        (
            (
                "netem_node_airtime_share",
                "The airtime shares of the node's links in the last step (0: the channel is not shared).",
                Gauge,
                Some(Unit::Bytes),
            ),
            |t| int(t.share_bytes),
        ),
        (
            (
                "netem_node_channel_busy",
                "How busy the channel was where the node is in the last step: the airtime of every sender it hears, itself included, over the capacity.",
                Gauge,
                Some(Unit::Other("ratio".into())),
            ),
            |t| Value::Real(t.utilisation),
        ),
    ]
}

/// Every family of one scrape.
fn families(
    links: &[LinkSnapshot],
    nodes: &BTreeMap<RobotId, NodeTotals>,
    step: Option<Step>,
    now: SimTime,
) -> Vec<Family> {
    let names: Vec<String> = links.iter().map(|l| label(&l.name)).collect();
    let mut out = Vec::new();
    for (desc, get) in per_dir() {
        let mut samples = Vec::new();
        for (l, link) in links.iter().zip(&names) {
            for d in Dir::BOTH {
                let labels = vec![("link", link.clone()), ("direction", d.label().to_string())];
                samples.push((labels, get(l, d)));
            }
        }
        out.push(Family { desc, samples });
    }
    for (desc, get) in per_link() {
        let samples = links
            .iter()
            .zip(&names)
            .filter_map(|(l, link)| Some((vec![("link", link.clone())], get(l)?)))
            .collect();
        out.push(Family { desc, samples });
    }
    if !nodes.is_empty() {
        for (desc, get) in per_node() {
            let samples = (nodes.iter())
                .map(|(id, t)| (vec![("node", id.to_string())], get(t)))
                .collect();
            out.push(Family { desc, samples });
        }
    }
    use MetricType::Gauge;
    out.push(Family {
        desc: (
            "netem_step",
            "The last step netem was told about (-1: none).",
            Gauge,
            None,
        ),
        samples: vec![(vec![], Value::Int(step.map_or(-1, i64::from)))],
    });
    out.push(Family {
        desc: (
            "netem_sim_time",
            "Simulated time.",
            Gauge,
            Some(Unit::Seconds),
        ),
        samples: vec![(vec![], Value::Real(now.as_secs_f64()))],
    });
    out
}

/// One scrape for the crate's OpenMetrics encoder.
struct Scrape(Vec<Family>);

impl std::fmt::Debug for Scrape {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Scrape({} families)", self.0.len())
    }
}

impl Value {
    fn encode(self, m: MetricEncoder) -> std::fmt::Result {
        match self {
            Value::Count(v) => ConstCounter::new(v).encode(m),
            Value::Int(v) => ConstGauge::new(v).encode(m),
            Value::Real(v) => ConstGauge::new(v).encode(m),
        }
    }
}

impl Collector for Scrape {
    fn encode(&self, mut encoder: DescriptorEncoder) -> std::fmt::Result {
        for fam in &self.0 {
            let (name, help, kind, unit) = &fam.desc;
            let mut family = encoder.encode_descriptor(name, help, unit.as_ref(), *kind)?;
            // A family without labels has one sample, written on the descriptor's own encoder
            // (a family encoder would write `{}`).
            if let [(labels, value)] = fam.samples.as_slice() {
                if labels.is_empty() {
                    value.encode(family)?;
                    continue;
                }
            }
            for (labels, value) in &fam.samples {
                let labels: Vec<(&str, &str)> =
                    labels.iter().map(|(k, v)| (*k, v.as_str())).collect();
                value.encode(family.encode_family(&labels)?)?;
            }
        }
        Ok(())
    }
}

/// The families in the classic text format: a counter's family is named with `_total`, like its
/// samples.
fn classic(families: &[Family]) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    for fam in families {
        let (name, kind) = if fam.is_counter() {
            (format!("{}_total", fam.name()), "counter")
        } else {
            (fam.name(), "gauge")
        };
        let help = fam.desc.1.replace('\\', "\\\\").replace('\n', "\\n");
        // Writing into a String cannot fail.
        let _ = writeln!(out, "# HELP {name} {help}\n# TYPE {name} {kind}");
        for (labels, value) in &fam.samples {
            out.push_str(&name);
            if !labels.is_empty() {
                let pairs: Vec<String> =
                    labels.iter().map(|(k, v)| format!("{k}=\"{v}\"")).collect();
                let _ = write!(out, "{{{}}}", pairs.join(","));
            }
            let _ = writeln!(out, " {}", value.text());
        }
    }
    out
}

/// Renders every metric for `links` and `nodes` (the channel's, empty if it is idle) in
/// `format`.
pub fn render(
    format: Format,
    links: &[LinkSnapshot],
    nodes: &BTreeMap<RobotId, NodeTotals>,
    step: Option<Step>,
    now: SimTime,
) -> String {
    let families = families(links, nodes, step, now);
    match format {
        Format::Classic => classic(&families),
        Format::OpenMetrics => {
            let mut registry = Registry::default();
            registry.register_collector(Box::new(Scrape(families)));
            let mut out = String::with_capacity(512 + links.len() * 1024);
            // Writing into a String cannot fail.
            let _ = encode(&mut out, &registry);
            out
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accounting::DirSnapshot;

    fn snapshot() -> LinkSnapshot {
        LinkSnapshot {
            a: 0,
            b: 1,
            name: "r0-r1".into(),
            listen: "127.0.0.1:1".parse().unwrap(),
            target: "127.0.0.1:2".parse().unwrap(),
            up: true,
            enabled: true,
            down_reason: None,
            verdict: None,
            dirs: [
                DirSnapshot {
                    bytes_total: 123,
                    queued_bytes: 7,
                    ..DirSnapshot::default()
                },
                DirSnapshot::default(),
            ],
            connections: 1,
            connects_total: 2,
            established_total: 2,
            refused_total: 0,
            toxics: vec![],
            held: false,
        }
    }

    fn scrape(format: Format) -> String {
        let mut far = snapshot();
        far.name = "r0-r2".into();
        far.verdict = Some(crate::radio::Verdict {
            in_range: false,
            distance_m: 12.5,
            walls: None,
            signal_dbm: None,
            margin_db: None,
        });
        let nodes = BTreeMap::from([(
            3,
            NodeTotals {
                airtime_bytes: 900,
                frames_lost: 2,
                retransmitted_bytes: 80,
                share_bytes: 150,
                utilisation: 0.75,
            },
        )]);
        render(
            format,
            &[snapshot(), far],
            &nodes,
            Some(5),
            SimTime::from_secs_f64(5.0),
        )
    }

    /// (family, type) of every `# TYPE` line, and every family with a `# HELP`.
    fn declared(text: &str) -> (Vec<(String, String)>, Vec<String>) {
        let mut types = Vec::new();
        let mut helps = Vec::new();
        for line in text.lines() {
            let mut w = line.split(' ');
            match (w.next(), w.next(), w.next(), w.next()) {
                (Some("#"), Some("TYPE"), Some(f), Some(t)) => types.push((f.into(), t.into())),
                (Some("#"), Some("HELP"), Some(f), Some(_)) => helps.push(f.into()),
                _ => {}
            }
        }
        (types, helps)
    }

    #[test]
    fn openmetrics_declares_counters_without_total_and_ends_with_eof() {
        let text = scrape(Format::OpenMetrics);
        assert!(text.contains("netem_link_bytes_total{link=\"r0-r1\",direction=\"a_to_b\"} 123\n"));
        assert!(text.contains("netem_link_bytes_total{link=\"r0-r1\",direction=\"b_to_a\"} 0\n"));
        assert!(text.contains("netem_link_queued_bytes{link=\"r0-r1\",direction=\"a_to_b\"} 7\n"));
        assert!(text.contains("netem_link_up{link=\"r0-r1\"} 1\n"));
        assert!(text.contains("netem_step 5\n"));
        assert!(text.contains("# TYPE netem_link_bytes counter\n"));
        assert!(text.contains("# UNIT netem_link_distance_meters meters\n"));
        assert!(text.contains("netem_link_distance_meters{link=\"r0-r2\"} 12.5"));
        assert!(
            !text.contains("netem_link_distance_meters{link=\"r0-r1\"}"),
            "unknown distance is omitted"
        );
        assert!(text.contains("netem_node_airtime_bytes_total{node=\"3\"} 900\n"));
        assert!(text.contains("netem_node_channel_busy_ratio{node=\"3\"} 0.75\n"));
        assert!(text.ends_with("# EOF\n"), "OpenMetrics ends with EOF");
        // Every sample line is `name{labels} value` or `name value`, every family typed and
        // helped once (a counter's family is its name without `_total`).
        let (types, helps) = declared(&text);
        assert_eq!(types.len(), 20);
        assert_eq!(
            helps,
            types.iter().map(|(f, _)| f.clone()).collect::<Vec<_>>()
        );
        for line in text.lines().filter(|l| !l.starts_with('#')) {
            let (series, value) = line.rsplit_once(' ').unwrap();
            assert!(value.parse::<f64>().is_ok(), "{line}");
            let name = series.split('{').next().unwrap();
            let counter = name
                .strip_suffix("_total")
                .is_some_and(|f| types.contains(&(f.into(), "counter".into())));
            assert!(
                counter || types.contains(&(name.into(), "gauge".into())),
                "{line}"
            );
        }
    }

    #[test]
    fn the_classic_format_names_counter_families_with_total_and_types_every_sample() {
        let text = scrape(Format::Classic);
        let (types, helps) = declared(&text);
        assert_eq!(types.len(), 20);
        assert_eq!(
            helps,
            types.iter().map(|(f, _)| f.clone()).collect::<Vec<_>>()
        );
        assert!(text.contains("# TYPE netem_link_bytes_total counter\n"));
        assert!(text.contains("netem_link_bytes_total{link=\"r0-r1\",direction=\"a_to_b\"} 123\n"));
        assert!(text.contains("# TYPE netem_link_distance_meters gauge\n"));
        assert!(text.contains("netem_link_distance_meters{link=\"r0-r2\"} 12.5\n"));
        assert!(text.contains("netem_sim_time_seconds 5\n"));
        assert!(text.contains("netem_node_frames_lost_total{node=\"3\"} 2\n"));
        assert!(!text.contains("# EOF") && !text.contains("# UNIT"));
        // Every sample belongs to the family typed by its own name; counters end `_total`,
        // and each family's samples follow its declaration.
        let mut current = String::new();
        for line in text.lines() {
            if let Some(f) = line.strip_prefix("# TYPE ") {
                current = f.split(' ').next().unwrap().to_string();
                continue;
            }
            if line.starts_with('#') {
                continue;
            }
            let (series, value) = line.rsplit_once(' ').unwrap();
            assert!(value.parse::<f64>().is_ok(), "{line}");
            assert_eq!(series.split('{').next().unwrap(), current, "{line}");
        }
        for (f, t) in &types {
            assert_eq!(t == "counter", f.ends_with("_total"), "{f} {t}");
        }
        // The same samples, the same values, as OpenMetrics.
        let samples = |t: &str| {
            let mut v: Vec<(String, f64)> = t
                .lines()
                .filter(|l| !l.starts_with('#'))
                .map(|l| {
                    let (series, value) = l.rsplit_once(' ').unwrap();
                    (series.to_string(), value.parse().unwrap())
                })
                .collect();
            v.sort_by(|a, b| a.0.cmp(&b.0));
            v
        };
        assert_eq!(samples(&text), samples(&scrape(Format::OpenMetrics)));
    }

    #[test]
    fn accept_chooses_the_format() {
        use Format::{Classic, OpenMetrics};
        for (accept, want) in [
            (None, OpenMetrics),
            (Some(""), OpenMetrics),
            (Some("*/*"), OpenMetrics),
            (Some("application/json"), OpenMetrics),
            // Prometheus 2's scraper.
            (
                Some("application/openmetrics-text;version=1.0.0,application/openmetrics-text;version=0.0.1;q=0.75,text/plain;version=0.0.4;q=0.5,*/*;q=0.1"),
                OpenMetrics,
            ),
            // Prometheus 3 with its default protocols, and told to prefer the classic format.
            (
                Some("application/openmetrics-text;version=1.0.0;escaping=allow-utf-8;q=0.5,application/openmetrics-text;version=0.0.1;q=0.4,text/plain;version=1.0.0;escaping=allow-utf-8;q=0.3,text/plain;version=0.0.4;q=0.2,*/*;q=0.1"),
                OpenMetrics,
            ),
            (
                Some("text/plain;version=0.0.4;q=0.5,application/openmetrics-text;version=1.0.0;q=0.4,*/*;q=0.1"),
                Classic,
            ),
            // Clients that do not list OpenMetrics.
            (Some("text/plain;version=0.0.4;q=1,*/*;q=0.1"), Classic),
            (Some("text/plain"), Classic),
            (Some("Text/Plain ; Version=0.0.4"), Classic),
            (Some("text/plain;q=0, */*"), OpenMetrics),
            (Some("application/openmetrics-text;q=0, */*"), Classic),
            // Equal weights: OpenMetrics; a weight that is no number does not count.
            (Some("text/plain, application/openmetrics-text"), OpenMetrics),
            (Some("text/plain;q=x, application/openmetrics-text;q=0.1"), OpenMetrics),
            (Some("text/plain;q=2"), OpenMetrics),
        ] {
            assert_eq!(Format::negotiate(accept), want, "{accept:?}");
        }
        assert_eq!(
            Classic.content_type(),
            "text/plain; version=0.0.4; charset=utf-8"
        );
        assert!(OpenMetrics
            .content_type()
            .starts_with("application/openmetrics-text"));
    }

    /// `promtool check metrics` (Prometheus's own linter, which reads the classic format) has
    /// nothing to say about the classic exposition: every family helped and typed, counters
    /// named `_total`, units spelled out. Given OpenMetrics it must complain — a classic parser
    /// reads an OpenMetrics counter as a family without samples plus an untyped one — which is
    /// why netem negotiates.
    #[test]
    #[ignore = "needs promtool (Debian package prometheus; .ci/run installs it)"]
    fn promtool_finds_the_classic_format_clean() {
        use std::io::Write;
        let check = |text: String| {
            let mut child = std::process::Command::new("promtool")
                .args(["check", "metrics"])
                .stdin(std::process::Stdio::piped())
                .stdout(std::process::Stdio::piped())
                .stderr(std::process::Stdio::piped())
                .spawn()
                .expect("promtool runs");
            child
                .stdin
                .take()
                .unwrap()
                .write_all(text.as_bytes())
                .unwrap();
            let out = child.wait_with_output().unwrap();
            let said = String::from_utf8_lossy(&out.stdout).into_owned()
                + &String::from_utf8_lossy(&out.stderr);
            (out.status.success(), said)
        };
        let (clean, said) = check(scrape(Format::Classic));
        assert!(clean && said.trim().is_empty(), "classic: {said}");
        let (clean, said) = check(scrape(Format::OpenMetrics));
        assert!(
            !clean && said.contains("netem_link_bytes_total"),
            "promtool took OpenMetrics counters for classic ones: {said}"
        );
    }

    #[test]
    fn label_values_are_escaped() {
        assert_eq!(label("a\"b\\c\nd"), "a\\\"b\\\\c\\nd");
    }
}
