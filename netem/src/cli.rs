//! netem's command line: flags → scenario → [`crate::netem::start`] → [`crate::node::follow`].

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context;
use clap::Parser;
use proto::msg::RobotId;
use proto::node::{close_quickly, entry, zerr, ScenarioArgs, ZenohArgs};
use proto::scenario::Scenario;
use serde::{Deserialize, Serialize};

use crate::link::LinkSnapshot;
use crate::netem::{start, NetemConfig, PairSpec};
use crate::node::{fetch_truth, follow, needs_truth};

/// The link emulator of swarm-explore: one TCP proxy per robot pair, between the lower id's
/// radio session and the higher id's radio listener. It follows the world-server's robot poses
/// on the sim plane and opens or cuts each link by the scenario's radio model, shapes its
/// bandwidth on the simulated clock, applies faults, and counts every byte. Runtime control:
/// a toxiproxy-compatible HTTP API (--http). Normally started by `swarm run`.
#[derive(Parser, Debug, Clone, PartialEq)]
#[command(name = "netem", version)]
pub struct Args {
    #[command(flatten)]
    pub scenario: ScenarioArgs,
    /// A robot pair's proxy: `A-B=LISTEN>TARGET`, e.g. `0-1=127.0.0.1:7600>127.0.0.1:7501`:
    /// robot A (the lower id) connects to LISTEN, netem forwards to robot B's radio listener
    /// TARGET. Repeat for every pair. LISTEN without a port (`0-1=127.0.0.1>127.0.0.1:7501`):
    /// the proxy listens on a free port of that address only while the link is up, and each
    /// step's plan tells robot A where (how `swarm run` starts netem).
    #[arg(long = "pair", value_name = "A-B=LISTEN>TARGET", value_parser = parse_pair)]
    pub pairs: Vec<PairSpec>,
    /// A radio node and its radio listener: `ID=TARGET`, e.g. `3=127.0.0.1:7503`. Every pair of
    /// the nodes given so gets a proxy on a free port of --proxy-host, bound only while its
    /// link is up (each step's plan tells the lower id where): netem holds descriptors for the
    /// pairs in range, not for every pair. Repeat for every node.
    #[arg(long = "node", value_name = "ID=TARGET", value_parser = parse_node)]
    pub nodes: Vec<(RobotId, SocketAddr)>,
    /// The address the proxies of --node pairs listen on.
    #[arg(long, value_name = "IP", default_value = "127.0.0.1")]
    pub proxy_host: std::net::IpAddr,
    /// Address of the toxiproxy-compatible HTTP control API (GET /proxies, /metrics, …).
    #[arg(long, value_name = "ADDR")]
    pub http: Option<SocketAddr>,
    /// A file holding the bearer token the HTTP API requires (`Authorization: Bearer <token>`);
    /// without it, the API needs none. `swarm run` passes the run's `netem.token` when
    /// `netem.api_token = true`.
    #[arg(long, value_name = "FILE")]
    pub token_file: Option<PathBuf>,
    /// At exit, after every connection is closed, write each link's final counters and
    /// addresses to this CSV file (`swarm run` keeps it as `link_totals.csv`).
    #[arg(long, value_name = "FILE")]
    pub totals_out: Option<PathBuf>,
    /// Sim-plane zenoh options (--connect the world-server's router).
    #[command(flatten)]
    pub zenoh: ZenohArgs,
}

impl Args {
    /// netem of `scenario` with every other flag at its default.
    pub fn new(scenario: PathBuf, zenoh: ZenohArgs) -> Args {
        Args {
            scenario: ScenarioArgs::file(scenario),
            pairs: Vec::new(),
            nodes: Vec::new(),
            proxy_host: std::net::Ipv4Addr::LOCALHOST.into(),
            http: None,
            token_file: None,
            totals_out: None,
            zenoh,
        }
    }

    /// The flags that parse back into these arguments (how `swarm run` starts `netem serve`).
    pub fn to_argv(&self) -> Vec<String> {
        let mut a = self.scenario.to_argv();
        for p in &self.pairs {
            a.extend(["--pair".into(), p.to_string()]);
        }
        for (id, target) in &self.nodes {
            a.extend(["--node".into(), format!("{id}={target}")]);
        }
        if !self.nodes.is_empty() {
            a.extend(["--proxy-host".into(), self.proxy_host.to_string()]);
        }
        if let Some(h) = self.http {
            a.extend(["--http".into(), h.to_string()]);
        }
        if let Some(f) = &self.token_file {
            a.extend(["--token-file".into(), f.to_string_lossy().into_owned()]);
        }
        if let Some(f) = &self.totals_out {
            a.extend(["--totals-out".into(), f.to_string_lossy().into_owned()]);
        }
        a.extend(self.zenoh.to_argv());
        a
    }
}

/// `A-B=LISTEN>TARGET`, as `--pair` takes it.
impl std::fmt::Display for PairSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // A proxy that listens while up is given its address alone.
        let listen = if self.while_up {
            self.listen.ip().to_string()
        } else {
            self.listen.to_string()
        };
        write!(f, "{}-{}={listen}>{}", self.a, self.b, self.target)
    }
}

/// Parses `A-B=LISTEN>TARGET` (A the lower robot id).
impl std::str::FromStr for PairSpec {
    type Err = String;

    fn from_str(s: &str) -> Result<PairSpec, String> {
        let bad =
            || format!("{s:?}: expected A-B=LISTEN>TARGET, e.g. 0-1=127.0.0.1:7600>127.0.0.1:7501");
        let (ids, addrs) = s.split_once('=').ok_or_else(bad)?;
        let (a, b) = ids.split_once('-').ok_or_else(bad)?;
        let (listen, target) = addrs.split_once('>').ok_or_else(bad)?;
        let (a, b): (RobotId, RobotId) = (
            a.trim().parse().map_err(|_| bad())?,
            b.trim().parse().map_err(|_| bad())?,
        );
        if a >= b {
            return Err(format!("{s:?}: the first robot id must be the lower one"));
        }
        // An address alone: a proxy that listens while the link is up.
        let (listen, while_up) = match listen.trim().parse::<std::net::IpAddr>() {
            Ok(ip) => (SocketAddr::new(ip, 0), true),
            Err(_) => (listen.trim().parse().map_err(|_| bad())?, false),
        };
        Ok(PairSpec {
            a,
            b,
            listen,
            target: target.trim().parse().map_err(|_| bad())?,
            while_up,
        })
    }
}

/// A row of `--totals-out` (`link_totals.csv`): a link's addresses and final counters.
#[derive(Debug, PartialEq, Serialize, Deserialize)]
pub struct LinkTotalsCsv {
    pub a: RobotId,
    pub b: RobotId,
    pub listen: SocketAddr,
    pub target: SocketAddr,
    pub bytes_a_to_b: u64,
    pub bytes_b_to_a: u64,
    pub chunks_a_to_b: u64,
    pub chunks_b_to_a: u64,
    pub lost_bytes: u64,
    pub connects: u64,
    pub established: u64,
    pub refused: u64,
    /// Every port the proxy listened on, in order, space-separated (a proxy that listens
    /// while its link is up may change port as the link comes and goes).
    #[serde(default)]
    pub ports: String,
}

impl From<&(LinkSnapshot, Vec<u16>)> for LinkTotalsCsv {
    /// A link's last snapshot, with every port its proxy listened on.
    fn from((l, ports): &(LinkSnapshot, Vec<u16>)) -> LinkTotalsCsv {
        let [ab, ba] = l.dirs;
        LinkTotalsCsv {
            a: l.a,
            b: l.b,
            listen: l.listen,
            target: l.target,
            bytes_a_to_b: ab.bytes_total,
            bytes_b_to_a: ba.bytes_total,
            chunks_a_to_b: ab.chunks_total,
            chunks_b_to_a: ba.chunks_total,
            lost_bytes: ab.lost_bytes_total + ba.lost_bytes_total,
            connects: l.connects_total,
            established: l.established_total,
            refused: l.refused_total,
            ports: (ports.iter().map(u16::to_string))
                .collect::<Vec<_>>()
                .join(" "),
        }
    }
}

/// The column names of `--totals-out`.
pub const TOTALS_HEADER: [&str; 13] = [
    "a",
    "b",
    "listen",
    "target",
    "bytes_a_to_b",
    "bytes_b_to_a",
    "chunks_a_to_b",
    "chunks_b_to_a",
    "lost_bytes",
    "connects",
    "established",
    "refused",
    "ports",
];

/// Writes `--totals-out`: one row per link, its addresses and final counters.
fn write_totals(path: &Path, links: &[(LinkSnapshot, Vec<u16>)]) -> anyhow::Result<()> {
    let context = || format!("writing {}", path.display());
    // The header by hand too: serde writes it only with a first row, and the file has one
    // also when there is no link.
    let mut w = csv::WriterBuilder::new()
        .has_headers(false)
        .from_path(path)
        .with_context(context)?;
    w.write_record(TOTALS_HEADER).with_context(context)?;
    for l in links {
        w.serialize(LinkTotalsCsv::from(l)).with_context(context)?;
    }
    w.flush().with_context(context)
}

/// Parses `A-B=LISTEN>TARGET` (see [`PairSpec`]'s `FromStr`).
pub fn parse_pair(s: &str) -> Result<PairSpec, String> {
    s.parse()
}

/// Parses `ID=TARGET` (`--node`).
pub fn parse_node(s: &str) -> Result<(RobotId, SocketAddr), String> {
    let bad = || format!("{s:?}: expected ID=TARGET, e.g. 3=127.0.0.1:7503");
    let (id, target) = s.split_once('=').ok_or_else(bad)?;
    Ok((
        id.trim().parse().map_err(|_| bad())?,
        target.trim().parse().map_err(|_| bad())?,
    ))
}

impl Args {
    /// Every pair: those given with --pair, then every pair of the --node nodes (lower id
    /// first), their proxies listening on --proxy-host while their links are up.
    pub fn all_pairs(&self) -> Vec<PairSpec> {
        let mut nodes = self.nodes.clone();
        nodes.sort_unstable();
        let mut pairs = self.pairs.clone();
        for (i, &(a, _)) in nodes.iter().enumerate() {
            for &(b, target) in &nodes[i + 1..] {
                pairs.push(PairSpec {
                    a,
                    b,
                    listen: SocketAddr::new(self.proxy_host, 0),
                    target,
                    while_up: true,
                });
            }
        }
        pairs
    }
}

async fn run(args: Args) -> anyhow::Result<()> {
    let scenario = Scenario::load(&args.scenario.file, &args.scenario.set)?;
    // Check the scenario's faults before joining anything.
    NetemConfig::from_scenario(&scenario, Vec::new(), None, None)?;
    let sim = zenoh::open(args.zenoh.client(20_000)?)
        .await
        .map_err(zerr)
        .context("joining the sim plane")?;
    let truth = if needs_truth(&scenario) {
        Some(fetch_truth(&sim, Duration::from_secs(30)).await?)
    } else {
        None
    };
    let mut cfg = NetemConfig::from_scenario(&scenario, args.all_pairs(), truth, args.http)?;
    if let Some(f) = &args.token_file {
        let token = std::fs::read_to_string(f)
            .with_context(|| format!("reading the API token from {}", f.display()))?
            .trim()
            .to_string();
        anyhow::ensure!(!token.is_empty(), "{} holds no token", f.display());
        cfg.api_token = Some(token);
    }
    // A proxy that listens while its link is up holds descriptors only then.
    descriptors(cfg.pairs.iter().filter(|p| !p.while_up).count());
    let netem = start(cfg).await.context("starting the link proxies")?;
    let orders = netem.process_orders(&scenario);
    let result = follow(&sim, &netem, orders).await;
    let links = netem.shutdown().await;
    close_quickly(sim).await;
    if let Some(path) = &args.totals_out {
        write_totals(path, &links)?;
    }
    Ok(result?)
}

/// Raises the limit on open files as far as it goes, and warns if netem may still run out
/// (links whose connections fail to open, then: every accept that fails is logged).
fn descriptors(pairs: usize) {
    let needed = crate::fds::needed(pairs);
    match crate::fds::raise_limit() {
        Ok(limit) if limit < needed => tracing::warn!(
            "{pairs} links may need up to {needed} open files at once (two per pair), but \
             netem may open only {limit}: raise the hard limit (ulimit -Hn)"
        ),
        Ok(limit) => tracing::info!(limit, needed, "open files"),
        Err(e) => tracing::warn!("cannot raise the limit on open files: {e}"),
    }
}

/// The whole process: one tokio runtime, logging, exit code.
pub fn main(args: Args) -> ExitCode {
    entry("netem", async {
        run(args).await?;
        anyhow::Ok(ExitCode::SUCCESS)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pair_specs_parse_and_bad_ones_say_why() {
        let p = parse_pair("0-3=127.0.0.1:7600>127.0.0.1:7503").unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(
            (p.a, p.b, p.listen.port(), p.target.port()),
            (0, 3, 7600, 7503)
        );
        for bad in [
            "",
            "0-1",
            "1-0=127.0.0.1:1>127.0.0.1:2",
            "0-1=x>y",
            "a-b=127.0.0.1:1>127.0.0.1:2",
        ] {
            assert!(parse_pair(bad).is_err(), "{bad:?}");
        }
        assert_eq!(p.to_string().parse::<PairSpec>(), Ok(p));
    }

    #[test]
    fn totals_rows_have_the_documented_columns_and_read_back() {
        let row = LinkTotalsCsv {
            a: 0,
            b: 2,
            listen: SocketAddr::from(([127, 0, 0, 1], 7600)),
            target: SocketAddr::from(([127, 0, 0, 1], 7502)),
            bytes_a_to_b: 10,
            bytes_b_to_a: 20,
            chunks_a_to_b: 1,
            chunks_b_to_a: 2,
            lost_bytes: 3,
            connects: 4,
            established: 5,
            refused: 6,
            ports: "7600 7611".into(),
        };
        let mut w = csv::Writer::from_writer(Vec::new());
        w.serialize(&row).unwrap_or_else(|e| panic!("{e}"));
        let text = String::from_utf8(w.into_inner().unwrap_or_default()).unwrap_or_default();
        assert_eq!(
            text,
            format!(
                "{}\n0,2,127.0.0.1:7600,127.0.0.1:7502,10,20,1,2,3,4,5,6,7600 7611\n",
                TOTALS_HEADER.join(",")
            )
        );
        let back: Vec<LinkTotalsCsv> = csv::Reader::from_reader(text.as_bytes())
            .deserialize()
            .collect::<Result<_, _>>()
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(back, vec![row]);
    }

    #[test]
    fn flags_round_trip_through_to_argv() {
        let pair = |a, b, l: u16, t: u16| PairSpec {
            a,
            b,
            listen: SocketAddr::from(([127, 0, 0, 1], l)),
            target: SocketAddr::from(([127, 0, 0, 1], t)),
            while_up: false,
        };
        let mut args = Args::new(
            PathBuf::from("/tmp/run/scenario.toml"),
            ZenohArgs {
                connect: vec!["tcp/127.0.0.1:7447".into()],
                ..ZenohArgs::default()
            },
        );
        args.scenario.set = vec!["radio.bandwidth_bytes_per_s=500".into()];
        args.pairs = vec![pair(0, 1, 7600, 7501), pair(1, 2, 7601, 7502)];
        // A pair given its host alone listens while its link is up.
        args.pairs.push(PairSpec {
            while_up: true,
            ..pair(0, 2, 0, 7502)
        });
        args.nodes = vec![
            (5, SocketAddr::from(([10, 0, 0, 6], 7505))),
            (3, pair(0, 3, 0, 7503).target),
        ];
        args.proxy_host = [10, 0, 0, 5].into();
        args.http = Some(SocketAddr::from(([127, 0, 0, 1], 8474)));
        args.totals_out = Some(PathBuf::from("/tmp/run/link_totals.csv"));
        for args in [
            args.clone(),
            Args::new(args.scenario.file.clone(), ZenohArgs::default()),
        ] {
            let argv = ["netem".to_string()].into_iter().chain(args.to_argv());
            assert_eq!(Args::parse_from(argv), args);
        }
        // Every pair of the nodes, lower id first, on the proxy host while up.
        let all = args.all_pairs();
        assert_eq!(all.len(), 4);
        assert_eq!(
            all[3],
            PairSpec {
                a: 3,
                b: 5,
                listen: SocketAddr::from(([10, 0, 0, 5], 0)),
                target: SocketAddr::from(([10, 0, 0, 6], 7505)),
                while_up: true,
            }
        );
        assert_eq!(all[2].to_string(), "0-2=127.0.0.1>127.0.0.1:7502");
        assert!(parse_node("3=nowhere").is_err() && parse_node("x=127.0.0.1:1").is_err());
    }

    #[test]
    fn scheduled_faults_come_from_the_scenario_and_errors_name_the_entry() {
        let s = Scenario::from_toml(
            "[[faults]]\nstep = 5\nkind = \"cut\"\npair = [0, 1]\n[[faults]]\nstep = 9\nkind = \"heal\"\n",
            &[],
        )
        .unwrap_or_else(|e| panic!("{e}"));
        let cfg = NetemConfig::from_scenario(&s, Vec::new(), None, None)
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(cfg.faults.len(), 2);
        let bad = Scenario::from_toml("[[faults]]\nstep = 5\nkind = \"explode\"\n", &[])
            .unwrap_or_else(|e| panic!("{e}"));
        let err = NetemConfig::from_scenario(&bad, Vec::new(), None, None)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(err.contains('0') && err.contains("explode"), "{err}");
    }
}
