//! `swarm netem …`: the netem process itself (`serve`) and runtime control of a running swarm's
//! links through netem's toxiproxy-compatible HTTP API — the same API `curl` and toxiproxy's
//! clients speak (a pair is the proxy `r{i}-r{j}`, a fault is a toxic) — and of its processes
//! (`kill`, `restart`, `freeze`, `thaw`: netem hands them on to the launcher).

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
use std::path::PathBuf;
use std::time::Duration;

use anyhow::{bail, Context};
use clap::{Args, Subcommand};
use proto::scenario::Process;

/// Where the API is: `--api ADDR`, or the `netem.addr` file of a run directory.
#[derive(Args, Debug, Clone)]
pub struct ApiArgs {
    /// Address of netem's HTTP API, e.g. 127.0.0.1:8474.
    #[arg(long, value_name = "ADDR", conflicts_with = "run")]
    pub api: Option<String>,
    /// A run directory of a running `swarm run` (its netem.addr names the API; its netem.token,
    /// if there is one, is sent as the bearer token).
    #[arg(long, value_name = "DIR")]
    pub run: Option<PathBuf>,
    /// A file holding the API's bearer token (`netem.api_token = true`; default with --run: the
    /// run directory's netem.token).
    #[arg(long, value_name = "FILE")]
    pub token_file: Option<PathBuf>,
}

/// The bearer token to send: `--token-file`, else the run directory's `netem.token` if any.
fn api_token(a: &ApiArgs) -> anyhow::Result<Option<String>> {
    let file = match (&a.token_file, &a.run) {
        (Some(f), _) => f.clone(),
        (None, Some(dir)) if dir.join("netem.token").is_file() => dir.join("netem.token"),
        _ => return Ok(None),
    };
    let token =
        std::fs::read_to_string(&file).with_context(|| format!("reading {}", file.display()))?;
    Ok(Some(token.trim().to_string()))
}

#[derive(Subcommand, Debug, Clone)]
pub enum NetemCommand {
    /// Run the netem link-emulator process (what `swarm run` starts).
    Serve(Box<netem::cli::Args>),
    /// List every link (proxy) with its state and toxics.
    List(ApiArgs),
    /// Cut the link between robots A and B (reconnects held until restored).
    Cut {
        #[command(flatten)]
        api: ApiArgs,
        a: u16,
        b: u16,
    },
    /// Restore the link between robots A and B (it is up again when they are in range).
    Restore {
        #[command(flatten)]
        api: ApiArgs,
        a: u16,
        b: u16,
    },
    /// Add or replace a fault (toxic) on the link between A and B, both directions.
    Set {
        #[command(flatten)]
        api: ApiArgs,
        a: u16,
        b: u16,
        #[command(subcommand)]
        toxic: ToxicArg,
    },
    /// Remove the fault (toxic) NAME from the link between A and B.
    Unset {
        #[command(flatten)]
        api: ApiArgs,
        a: u16,
        b: u16,
        name: String,
    },
    /// Restore every link and remove every toxic (toxiproxy's POST /reset).
    Reset(ApiArgs),
    /// Kill a process of the run (SIGKILL) at its next step: `robot-<id>`, base-station, netem or
    /// world-server (which ends the run). Recorded in summary.json's process_events (cause api).
    Kill {
        #[command(flatten)]
        api: ApiArgs,
        process: Process,
        /// Start it again (same id and ports, its next life) this many steps later.
        #[arg(long, value_name = "STEPS")]
        restart_after: Option<u32>,
    },
    /// Kill a robot, the base station or netem and start it again at once (its next life).
    Restart {
        #[command(flatten)]
        api: ApiArgs,
        process: Process,
    },
    /// Freeze a robot or the base station (SIGSTOP): silent, declared dead after clock.dead_after
    /// missed steps.
    Freeze {
        #[command(flatten)]
        api: ApiArgs,
        process: Process,
    },
    /// Thaw a frozen robot or base station (SIGCONT): it goes on, and rejoins if declared dead.
    Thaw {
        #[command(flatten)]
        api: ApiArgs,
        process: Process,
    },
}

/// The toxics `swarm netem set` knows (toxiproxy's names).
#[derive(Subcommand, Debug, Clone)]
pub enum ToxicArg {
    /// Bandwidth limit in bytes per simulated second.
    Bandwidth { bytes_per_s: u64 },
    /// Added latency and jitter in simulated milliseconds.
    Latency {
        ms: u64,
        #[arg(default_value_t = 0)]
        jitter_ms: u64,
    },
    /// Stall the link without closing it (toxiproxy `timeout` 0).
    Blackhole,
    /// Close the connections after N more bytes.
    LimitData { bytes: u64 },
    /// Flip bytes with probability P per byte.
    Corrupt { probability: f64 },
    /// Reset the current connections (TCP RST).
    ResetPeer,
}

impl ToxicArg {
    fn body(&self) -> (String, String) {
        let (name, ty, attrs) = match self {
            ToxicArg::Bandwidth { bytes_per_s } => (
                "bandwidth",
                "bandwidth",
                format!("{{\"rate_bytes_per_s\":{bytes_per_s}}}"),
            ),
            ToxicArg::Latency { ms, jitter_ms } => (
                "latency",
                "latency",
                format!("{{\"latency\":{ms},\"jitter\":{jitter_ms}}}"),
            ),
            ToxicArg::Blackhole => ("blackhole", "timeout", "{\"timeout\":0}".to_string()),
            ToxicArg::LimitData { bytes } => {
                ("limit_data", "limit_data", format!("{{\"bytes\":{bytes}}}"))
            }
            ToxicArg::Corrupt { probability } => (
                "corrupt",
                "corrupt",
                format!("{{\"probability\":{probability}}}"),
            ),
            ToxicArg::ResetPeer => ("reset_peer", "reset_peer", "{\"timeout\":0}".to_string()),
        };
        (
            name.to_string(),
            format!("{{\"name\":\"{name}\",\"type\":\"{ty}\",\"stream\":\"both\",\"attributes\":{attrs}}}"),
        )
    }
}

fn api_addr(a: &ApiArgs) -> anyhow::Result<SocketAddr> {
    let text = match (&a.api, &a.run) {
        (Some(api), _) => api.clone(),
        (None, Some(dir)) => std::fs::read_to_string(dir.join("netem.addr"))
            .with_context(|| format!("reading {}", dir.join("netem.addr").display()))?
            .trim()
            .to_string(),
        (None, None) => bail!("say where netem's API is: --api ADDR or --run RUN_DIR"),
    };
    text.to_socket_addrs()
        .ok()
        .and_then(|mut a| a.next())
        .with_context(|| format!("{text:?} is not an address (HOST:PORT)"))
}

/// One HTTP/1.1 request; returns (status, body).
pub fn http(
    addr: SocketAddr,
    token: Option<&str>,
    method: &str,
    path: &str,
    body: &str,
) -> anyhow::Result<(u16, String)> {
    let mut s = TcpStream::connect_timeout(&addr, Duration::from_secs(5))
        .with_context(|| format!("connecting to netem at {addr}"))?;
    s.set_read_timeout(Some(Duration::from_secs(10)))?;
    let auth = token.map_or_else(String::new, |t| format!("Authorization: Bearer {t}\r\n"));
    write!(s, "{method} {path} HTTP/1.1\r\nHost: {addr}\r\n{auth}Content-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}", body.len())?;
    let mut resp = String::new();
    s.take(16 << 20)
        .read_to_string(&mut resp)
        .context("reading netem's answer")?;
    let (head, body) = resp.split_once("\r\n\r\n").unwrap_or((resp.as_str(), ""));
    let status = head
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .context("malformed HTTP answer")?;
    Ok((status, body.to_string()))
}

fn call(a: &ApiArgs, method: &str, path: &str, body: &str) -> anyhow::Result<String> {
    let token = api_token(a)?;
    let (status, text) = http(api_addr(a)?, token.as_deref(), method, path, body)?;
    if !(200..300).contains(&status) {
        bail!(
            "netem answered {status} to {method} {path}: {}",
            text.trim()
        );
    }
    Ok(text)
}

/// `POST /processes/<process>` with `{"kind": kind[, "restart_after": k]}`.
fn process_fault(
    a: &ApiArgs,
    process: Process,
    kind: &str,
    restart_after: Option<u32>,
) -> anyhow::Result<String> {
    let mut body = serde_json::json!({ "kind": kind });
    if let Some(k) = restart_after {
        body["restart_after"] = k.into();
    }
    call(
        a,
        "POST",
        &format!("/processes/{process}"),
        &body.to_string(),
    )
}

fn link(a: u16, b: u16) -> String {
    format!("r{}-r{}", a.min(b), a.max(b))
}

/// Runs a control command (not `serve`), printing netem's answer.
pub fn control(cmd: &NetemCommand) -> anyhow::Result<()> {
    let out = match cmd {
        NetemCommand::Serve(_) => bail!("serve is a process, not a control command"),
        NetemCommand::List(api) => call(api, "GET", "/proxies", "")?,
        NetemCommand::Cut { api, a, b } => call(
            api,
            "POST",
            &format!("/proxies/{}", link(*a, *b)),
            "{\"enabled\":false}",
        )?,
        NetemCommand::Restore { api, a, b } => call(
            api,
            "POST",
            &format!("/proxies/{}", link(*a, *b)),
            "{\"enabled\":true}",
        )?,
        NetemCommand::Set { api, a, b, toxic } => {
            let (name, body) = toxic.body();
            let path = format!("/proxies/{}/toxics", link(*a, *b));
            // Replace a toxic of the same name if there is one (toxiproxy refuses duplicates).
            let _ = call(api, "DELETE", &format!("{path}/{name}"), "");
            call(api, "POST", &path, &body)?
        }
        NetemCommand::Unset { api, a, b, name } => call(
            api,
            "DELETE",
            &format!("/proxies/{}/toxics/{name}", link(*a, *b)),
            "",
        )?,
        NetemCommand::Reset(api) => call(api, "POST", "/reset", "")?,
        NetemCommand::Kill {
            api,
            process,
            restart_after,
        } => process_fault(api, *process, "kill", *restart_after)?,
        NetemCommand::Restart { api, process } => process_fault(api, *process, "restart", None)?,
        NetemCommand::Freeze { api, process } => process_fault(api, *process, "freeze", None)?,
        NetemCommand::Thaw { api, process } => process_fault(api, *process, "thaw", None)?,
    };
    match serde_json::from_str::<serde_json::Value>(&out) {
        Ok(v) => println!("{}", serde_json::to_string_pretty(&v).unwrap_or(out)),
        Err(_) if out.trim().is_empty() => println!("ok"),
        Err(_) => println!("{}", out.trim()),
    }
    Ok(())
}

/// `swarm netem <order>`: one order to a running netem.
pub fn command(cmd: &NetemCommand) -> anyhow::Result<std::process::ExitCode> {
    control(cmd)?;
    Ok(std::process::ExitCode::SUCCESS)
}
