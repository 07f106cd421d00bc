//! Prometheus text exposition of the link counters (`GET /metrics`, format 0.0.4), so a
//! Prometheus server or a plain `curl` can watch a run: bytes and chunks delivered per link and
//! direction, bytes lost, bytes queued inside netem, and whether each link is up (DESIGN.md §5
//! "Publishes per-step link telemetry"; the per-step view itself goes through
//! `Netem::telemetry`).

use std::fmt::Write;

use proto::msg::Step;

use crate::accounting::Dir;
use crate::clock::SimTime;
use crate::link::LinkSnapshot;

/// The content type of [`render`]'s output.
pub const CONTENT_TYPE: &str = "text/plain; version=0.0.4; charset=utf-8";

/// Escapes a label value (backslash, double quote, newline).
fn label(v: &str) -> String {
    v.replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
}

fn family(out: &mut String, name: &str, kind: &str, help: &str) {
    let _ = writeln!(out, "# HELP {name} {help}");
    let _ = writeln!(out, "# TYPE {name} {kind}");
}

/// Renders every metric for `links`.
pub fn render(links: &[LinkSnapshot], step: Option<Step>, now: SimTime) -> String {
    let mut out = String::with_capacity(512 + links.len() * 1024);
    type PerDir = fn(&LinkSnapshot, Dir) -> u64;
    let per_dir: [(&str, &str, &str, PerDir); 5] = [
        (
            "netem_link_bytes_total",
            "counter",
            "Bytes delivered across the link.",
            |l, d| l.dirs[d.index()].bytes_total,
        ),
        (
            "netem_link_chunks_total",
            "counter",
            "Writes to the receiving robot.",
            |l, d| l.dirs[d.index()].chunks_total,
        ),
        (
            "netem_link_lost_bytes_total",
            "counter",
            "Bytes read from the sender and dropped by a cut, reset or limit_data.",
            |l, d| l.dirs[d.index()].lost_bytes_total,
        ),
        (
            "netem_link_queued_bytes",
            "gauge",
            "Bytes held inside netem now.",
            |l, d| l.dirs[d.index()].queued_bytes,
        ),
        (
            "netem_link_queued_max_bytes",
            "gauge",
            "The most bytes ever held inside netem at once.",
            |l, d| l.dirs[d.index()].queued_max_bytes,
        ),
    ];
    for (name, kind, help, get) in per_dir {
        family(&mut out, name, kind, help);
        for l in links {
            for d in Dir::BOTH {
                let _ = writeln!(
                    out,
                    "{name}{{link=\"{}\",direction=\"{}\"}} {}",
                    label(&l.name),
                    d.label(),
                    get(l, d)
                );
            }
        }
    }
    type PerLink = fn(&LinkSnapshot) -> Option<f64>;
    let per_link: [(&str, &str, &str, PerLink); 8] = [
        (
            "netem_link_up",
            "gauge",
            "1 if the link is up (enabled, in range, robots alive).",
            |l| Some(f64::from(u8::from(l.up))),
        ),
        (
            "netem_link_enabled",
            "gauge",
            "0 if the link is cut by a fault or partition.",
            |l| Some(f64::from(u8::from(l.enabled))),
        ),
        (
            "netem_link_connections",
            "gauge",
            "Open connections through the link.",
            |l| Some(l.connections as f64),
        ),
        (
            "netem_link_connects_total",
            "counter",
            "Connections accepted and forwarded.",
            |l| Some(l.connects_total as f64),
        ),
        (
            "netem_link_established_total",
            "counter",
            "Accepted connections that reached the higher id's radio listener.",
            |l| Some(l.established_total as f64),
        ),
        (
            "netem_link_refused_total",
            "counter",
            "Connections refused (link down or full).",
            |l| Some(l.refused_total as f64),
        ),
        (
            "netem_link_toxics",
            "gauge",
            "Toxics installed on the link.",
            |l| Some(l.toxics.len() as f64),
        ),
        (
            "netem_link_distance_m",
            "gauge",
            "Distance between the two robots, metres.",
            |l| l.verdict.map(|v| v.distance_m).filter(|d| d.is_finite()),
        ),
    ];
    for (name, kind, help, get) in per_link {
        family(&mut out, name, kind, help);
        for l in links {
            if let Some(v) = get(l) {
                let _ = writeln!(out, "{name}{{link=\"{}\"}} {v}", label(&l.name));
            }
        }
    }
    family(
        &mut out,
        "netem_step",
        "gauge",
        "The last step netem was told about (-1: none).",
    );
    let _ = writeln!(out, "netem_step {}", step.map_or(-1, i64::from));
    family(
        &mut out,
        "netem_sim_time_seconds",
        "gauge",
        "Simulated time.",
    );
    let _ = writeln!(out, "netem_sim_time_seconds {}", now.as_secs_f64());
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
        // Every sample line is `name{labels} value` or `name value`, every family typed once.
        for line in text.lines().filter(|l| !l.starts_with('#')) {
            let (series, value) = line.rsplit_once(' ').unwrap();
            assert!(value.parse::<f64>().is_ok(), "{line}");
            let name = series.split('{').next().unwrap();
            assert!(text.contains(&format!("# TYPE {name} ")), "{line}");
        }
    }

    #[test]
    fn label_values_are_escaped() {
        assert_eq!(label("a\"b\\c\nd"), "a\\\"b\\\\c\\nd");
    }
}
