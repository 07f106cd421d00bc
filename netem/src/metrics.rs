//! The link counters for Prometheus (`GET /metrics`), so a Prometheus server or a plain `curl`
//! can watch a run: bytes and chunks delivered per link and direction, bytes lost, bytes queued
//! inside netem, and whether each link is up (docs/design.md §5 "Publishes per-step link telemetry";
//! the per-step view itself goes through `Netem::telemetry`).
//!
//! The exposition is the `prometheus-client` crate's (OpenMetrics text, which Prometheus scrapes
//! natively). netem's counters live in its links and are read as snapshots, so each scrape is one
//! [`Collector`] over the snapshots of that moment: counters are [`ConstCounter`]s (the crate adds
//! the `_total` suffix; the series names are the ones netem always published), everything else
//! [`ConstGauge`]s. The crate writes label values as given, so link names are escaped here.

use prometheus_client::collector::Collector;
use prometheus_client::encoding::text::encode;
use prometheus_client::encoding::{DescriptorEncoder, EncodeMetric, MetricEncoder};
use prometheus_client::metrics::counter::ConstCounter;
use prometheus_client::metrics::gauge::ConstGauge;
use prometheus_client::metrics::MetricType;
use prometheus_client::registry::Registry;

use proto::msg::Step;

use crate::accounting::Dir;
use crate::link::LinkSnapshot;
use proto::clock::SimTime;

/// The content type of [`render`]'s output.
pub const CONTENT_TYPE: &str = "application/openmetrics-text; version=1.0.0; charset=utf-8";

/// Escapes a label value (backslash, double quote, newline).
fn label(v: &str) -> String {
    v.replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
}

/// One sample's value.
enum Value {
    Count(u64),
    Int(i64),
    Real(f64),
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

fn int(v: u64) -> Value {
    Value::Int(i64::try_from(v).unwrap_or(i64::MAX))
}

/// A family: name (counters without `_total`, which the crate adds), help, type.
type Family = (&'static str, &'static str, MetricType);

/// What one scrape shows.
#[derive(Debug)]
struct Scrape {
    links: Vec<LinkSnapshot>,
    step: Option<Step>,
    now: SimTime,
}

type PerDir = (Family, fn(&LinkSnapshot, Dir) -> Value);
type PerLink = (Family, fn(&LinkSnapshot) -> Option<Value>);

/// The families with a series per link and direction.
fn per_dir() -> [PerDir; 5] {
    use MetricType::{Counter, Gauge};
    [
        (
            (
                "netem_link_bytes",
                "Bytes delivered across the link.",
                Counter,
            ),
            |l, d| Value::Count(l.dirs[d.index()].bytes_total),
        ),
        (
            (
                "netem_link_chunks",
                "Writes to the receiving robot.",
                Counter,
            ),
            |l, d| Value::Count(l.dirs[d.index()].chunks_total),
        ),
        (
            (
                "netem_link_lost_bytes",
                "Bytes read from the sender and dropped by a cut, reset or limit_data.",
                Counter,
            ),
            |l, d| Value::Count(l.dirs[d.index()].lost_bytes_total),
        ),
        (
            (
                "netem_link_queued_bytes",
                "Bytes held inside netem now.",
                Gauge,
            ),
            |l, d| int(l.dirs[d.index()].queued_bytes),
        ),
        (
            (
                "netem_link_queued_max_bytes",
                "The most bytes ever held inside netem at once.",
                Gauge,
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
            ),
            |l| Some(Value::Int(i64::from(l.up))),
        ),
        (
            (
                "netem_link_enabled",
                "0 if the link is cut by a fault or partition.",
                Gauge,
            ),
            |l| Some(Value::Int(i64::from(l.enabled))),
        ),
        (
            (
                "netem_link_connections",
                "Open connections through the link.",
                Gauge,
            ),
            |l| Some(int(l.connections as u64)),
        ),
        (
            (
                "netem_link_connects",
                "Connections accepted and forwarded.",
                Counter,
            ),
            |l| Some(Value::Count(l.connects_total)),
        ),
        (
            (
                "netem_link_established",
                "Accepted connections that reached the higher id's radio listener.",
                Counter,
            ),
            |l| Some(Value::Count(l.established_total)),
        ),
        (
            (
                "netem_link_refused",
                "Connections refused (too many at once; a link that is down holds them).",
                Counter,
            ),
            |l| Some(Value::Count(l.refused_total)),
        ),
        (
            ("netem_link_toxics", "Toxics installed on the link.", Gauge),
            |l| Some(int(l.toxics.len() as u64)),
        ),
        (
            (
                "netem_link_distance_m",
                "Distance between the two robots, metres.",
                Gauge,
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

impl Collector for Scrape {
    fn encode(&self, mut encoder: DescriptorEncoder) -> std::fmt::Result {
        use MetricType::Gauge;
        let names: Vec<String> = self.links.iter().map(|l| label(&l.name)).collect();
        for ((name, help, kind), get) in per_dir() {
            let mut family = encoder.encode_descriptor(name, help, None, kind)?;
            for (l, link) in self.links.iter().zip(&names) {
                for d in Dir::BOTH {
                    let labels = [("link", link.as_str()), ("direction", d.label())];
                    get(l, d).encode(family.encode_family(&labels)?)?;
                }
            }
        }
        for ((name, help, kind), get) in per_link() {
            let mut family = encoder.encode_descriptor(name, help, None, kind)?;
            for (l, link) in self.links.iter().zip(&names) {
                if let Some(v) = get(l) {
                    v.encode(family.encode_family(&[("link", link.as_str())])?)?;
                }
            }
        }
        let step = self.step.map_or(-1, i64::from);
        Value::Int(step).encode(encoder.encode_descriptor(
            "netem_step",
            "The last step netem was told about (-1: none).",
            None,
            Gauge,
        )?)?;
        Value::Real(self.now.as_secs_f64()).encode(encoder.encode_descriptor(
            "netem_sim_time_seconds",
            "Simulated time.",
            None,
            Gauge,
        )?)
    }
}

/// Renders every metric for `links`.
pub fn render(links: &[LinkSnapshot], step: Option<Step>, now: SimTime) -> String {
    let mut registry = Registry::default();
    registry.register_collector(Box::new(Scrape {
        links: links.to_vec(),
        step,
        now,
    }));
    let mut out = String::with_capacity(512 + links.len() * 1024);
    // Writing into a String cannot fail.
    let _ = encode(&mut out, &registry);
    out
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

    #[test]
    fn renders_per_link_per_direction_series_in_text_format() {
        let text = render(&[snapshot()], Some(5), SimTime::from_secs_f64(5.0));
        assert!(text.contains("netem_link_bytes_total{link=\"r0-r1\",direction=\"a_to_b\"} 123\n"));
        assert!(text.contains("netem_link_bytes_total{link=\"r0-r1\",direction=\"b_to_a\"} 0\n"));
        assert!(text.contains("netem_link_queued_bytes{link=\"r0-r1\",direction=\"a_to_b\"} 7\n"));
        assert!(text.contains("netem_link_up{link=\"r0-r1\"} 1\n"));
        assert!(text.contains("netem_step 5\n"));
        assert!(
            !text.contains("netem_link_distance_m{"),
            "unknown distance is omitted"
        );
        assert!(
            text.contains("netem_link_distance_m"),
            "the family is still described"
        );
        assert!(text.ends_with("# EOF\n"), "OpenMetrics ends with EOF");
        // Every sample line is `name{labels} value` or `name value`, every family typed once
        // (a counter's family is its name without `_total`).
        for line in text.lines().filter(|l| !l.starts_with('#')) {
            let (series, value) = line.rsplit_once(' ').unwrap();
            assert!(value.parse::<f64>().is_ok(), "{line}");
            let name = series.split('{').next().unwrap();
            let counter = name
                .strip_suffix("_total")
                .is_some_and(|f| text.contains(&format!("# TYPE {f} counter\n")));
            assert!(
                counter || text.contains(&format!("# TYPE {name} gauge\n")),
                "{line}"
            );
        }
    }

    #[test]
    fn label_values_are_escaped() {
        assert_eq!(label("a\"b\\c\nd"), "a\\\"b\\\\c\\nd");
    }
}
