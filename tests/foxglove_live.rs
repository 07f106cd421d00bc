//! `swarm run --foxglove`: the run served live over the Foxglove WebSocket protocol (by Foxglove's
//! SDK) reaches a client that subscribes to every advertised channel — at least one message of
//! each, every well-known one decoding in the schema the SDK ships — and serving it changes
//! nothing in the run (the same `run_digest` without it). The client here speaks the protocol
//! (`foxglove.sdk.v1`, the SDK's name for `foxglove.websocket.v1`) over tokio-tungstenite; tests/clients/foxglove drives the same with
//! Foxglove's own client library.

use std::collections::{BTreeMap, BTreeSet};
use std::net::SocketAddr;
use std::process::Command;
use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::Message;

use crate::support::{run_args, stderr, summary_typed, wait_file, Launcher, TempDir, SWARM};

/// The default scenario (intel_lab, 4 robots) to its end — about 260 steps, long enough for a
/// client to join early; explored to the end, so that two runs are the same to the byte.
const SETS: [&str; 1] = ["clock.step_timeout_ms=10000"];
const ROBOTS: u16 = 4;

/// A channel as the server advertised it.
struct Advertised {
    topic: String,
    schema_name: String,
}

/// Connects to the Foxglove server at `addr`, subscribes to every channel it advertises and
/// takes messages until the server closes (the run ended) or `limit` passes; the messages per
/// topic, and every advertised topic.
async fn follow(addr: SocketAddr, limit: Duration) -> (BTreeMap<String, u64>, BTreeSet<String>) {
    let mut req = format!("ws://{addr}")
        .into_client_request()
        .expect("a request");
    req.headers_mut().insert(
        "Sec-WebSocket-Protocol",
        "foxglove.sdk.v1".parse().expect("a header"),
    );
    let (mut ws, resp) = tokio_tungstenite::connect_async(req)
        .await
        .expect("the Foxglove server takes the connection");
    assert_eq!(
        resp.headers()
            .get("Sec-WebSocket-Protocol")
            .and_then(|v| v.to_str().ok()),
        Some("foxglove.sdk.v1")
    );
    let mut channels: BTreeMap<u64, Advertised> = BTreeMap::new();
    let mut subscriptions: BTreeMap<u32, u64> = BTreeMap::new();
    let mut counts: BTreeMap<String, u64> = BTreeMap::new();
    let deadline = tokio::time::Instant::now() + limit;
    loop {
        let next = tokio::time::timeout_at(deadline, ws.next()).await;
        let Ok(Some(Ok(msg))) = next else { break };
        match msg {
            Message::Text(t) => {
                let v: serde_json::Value = serde_json::from_str(&t).expect("JSON");
                if v["op"] != "advertise" {
                    continue;
                }
                let mut subscribe = Vec::new();
                for c in v["channels"].as_array().expect("channels") {
                    let id = c["id"].as_u64().expect("a channel id");
                    assert_eq!(c["encoding"], "protobuf", "{c}");
                    assert_eq!(c["schemaEncoding"], "protobuf", "{c}");
                    channels.insert(
                        id,
                        Advertised {
                            topic: c["topic"].as_str().expect("a topic").into(),
                            schema_name: c["schemaName"].as_str().expect("a name").into(),
                        },
                    );
                    let sub = subscriptions.len() as u32 + 1;
                    subscriptions.insert(sub, id);
                    subscribe.push(serde_json::json!({ "id": sub, "channelId": id }));
                }
                let req = serde_json::json!({ "op": "subscribe", "subscriptions": subscribe });
                ws.send(Message::Text(req.to_string().into()))
                    .await
                    .expect("subscribe");
            }
            Message::Binary(b) => {
                // Message data: opcode 1, subscription id (u32 LE), time (u64 LE), payload.
                if b.first() != Some(&1) || b.len() < 13 {
                    continue;
                }
                let sub = u32::from_le_bytes(b[1..5].try_into().expect("4 bytes"));
                let c = &channels[&subscriptions[&sub]];
                let data = &b[13..];
                crate::export::decode_well_known(&c.topic, &c.schema_name, data);
                *counts.entry(c.topic.clone()).or_default() += 1;
            }
            Message::Close(_) => break,
            _ => {}
        }
    }
    let topics = channels.into_values().map(|c| c.topic).collect();
    (counts, topics)
}

#[test]
fn a_live_run_reaches_a_foxglove_client_on_every_channel_and_stays_the_same_run() {
    let dir = TempDir::new("foxglove-live");
    let (launcher, run, addr) = foxglove_run(&dir);
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("a runtime");
    let (counts, topics) = rt.block_on(follow(addr, Duration::from_secs(240)));
    let out = launcher.wait_output(Duration::from_secs(60));
    assert!(
        out.status.code().is_some_and(|c| c == 0 || c == 2),
        "{}",
        stderr(&out)
    );
    let mut want: BTreeSet<String> = swarm::view::foxglove::TEAM_TOPICS.map(String::from).into();
    for r in 0..ROBOTS {
        want.insert(format!("/robot_{r}/grid"));
        want.insert(format!("/robot_{r}/pose"));
    }
    assert_eq!(topics, want, "advertised channels");
    let silent: Vec<&String> = want.iter().filter(|t| !counts.contains_key(*t)).collect();
    assert!(silent.is_empty(), "no message on {silent:?}: {counts:?}");

    // The same run without the server: the same files.
    let again = TempDir::new("foxglove-without");
    let run2 = again.path().join("run");
    let mut cmd = Command::new(SWARM);
    run_args(&mut cmd, &run2, &SETS);
    let out = Launcher::spawn(cmd).wait_output(Duration::from_secs(240));
    assert!(
        out.status.code().is_some_and(|c| c == 0 || c == 2),
        "{}",
        stderr(&out)
    );
    let (with, without) = (summary_typed(&run), summary_typed(&run2));
    assert!(with.deterministic && without.deterministic);
    assert_eq!(with.run_digest, without.run_digest);
}

/// Starts the default run with `--foxglove` into `dir/run`: the launcher, the run directory and
/// the server's address.
fn foxglove_run(dir: &TempDir) -> (Launcher, std::path::PathBuf, SocketAddr) {
    let run = dir.path().join("run");
    let mut cmd = Command::new(SWARM);
    run_args(&mut cmd, &run, &SETS);
    cmd.arg("--foxglove=127.0.0.1:0");
    let launcher = Launcher::spawn(cmd);
    let addr = wait_file(&run.join("foxglove.addr"), Duration::from_secs(60))
        .parse()
        .expect("foxglove.addr holds an address");
    (launcher, run, addr)
}

/// `node tests/clients/foxglove/check.mjs MODE ARG`: the topics it read, each with its schema and
/// message count, and the log-time regressions it saw.
fn node_check(mode: &str, arg: &str) -> serde_json::Value {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/clients/foxglove");
    let out = Command::new("node")
        .current_dir(&dir)
        .args(["check.mjs", mode, arg])
        .output()
        .expect("node runs (install Node.js, then `npm ci` in tests/clients/foxglove)");
    assert!(out.status.success(), "check.mjs {mode}: {}", stderr(&out));
    serde_json::from_slice(&out.stdout).expect("check.mjs prints JSON")
}

fn assert_all_read(v: &serde_json::Value, what: &str) {
    let topics = v["topics"].as_object().expect("topics");
    assert_eq!(
        topics.len(),
        swarm::view::foxglove::TEAM_TOPICS.len() + 2 * usize::from(ROBOTS),
        "{what}: {v}"
    );
    for (topic, t) in topics {
        assert!(
            t["messages"].as_u64().is_some_and(|n| n > 0),
            "{what}: nothing read on {topic}: {v}"
        );
    }
    assert_eq!(v["logTimeRegressions"], 0, "{what}: {v}");
}

#[test]
#[ignore = "needs Node.js and `npm ci --prefix tests/clients/foxglove` (Foxglove's client libraries from npm; .ci/run does both)"]
fn foxglove_s_own_libraries_read_the_live_run_and_its_mcap() {
    let dir = TempDir::new("foxglove-node");
    let (launcher, run, addr) = foxglove_run(&dir);
    let live = node_check("live", &format!("ws://{addr}"));
    let out = launcher.wait_output(Duration::from_secs(120));
    assert!(
        out.status.code().is_some_and(|c| c == 0 || c == 2),
        "{}",
        stderr(&out)
    );
    assert_all_read(&live, "@foxglove/ws-protocol, live");
    crate::support::export_mcap(&run);
    let file = node_check("mcap", &run.join("run.mcap").to_string_lossy());
    assert_all_read(&file, "@mcap/core");
}

#[test]
fn swarm_view_replays_a_finished_run_to_a_foxglove_client() {
    use std::io::{BufRead, BufReader};
    let dir = TempDir::new("foxglove-replay");
    let (out, run) = crate::support::swarm_run(
        &dir,
        None,
        &["max_steps=30", "clock.step_timeout_ms=10000"],
        Duration::from_secs(120),
    );
    assert!(
        out.status.code().is_some_and(|c| c == 0 || c == 2),
        "{}",
        stderr(&out)
    );
    let mut cmd = Command::new(SWARM);
    cmd.arg("view")
        .arg(&run)
        .args(["--addr=127.0.0.1:0", "--foxglove=127.0.0.1:0", "--rate=100"]);
    let mut view = Launcher::spawn(cmd);
    let stdout = view
        .child
        .as_mut()
        .and_then(|c| c.stdout.take())
        .expect("swarm view's stdout");
    let mut lines = BufReader::new(stdout).lines();
    let addr: SocketAddr = lines
        .find_map(|l| {
            l.ok()?
                .strip_prefix("Foxglove WebSocket replay at ws://")
                .map(str::to_string)
        })
        .expect("swarm view prints the Foxglove address")
        .parse()
        .expect("an address");
    // 30 steps at 100 a second: the play is over in well under 5 s; the server stays up.
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("a runtime");
    let (counts, topics) = rt.block_on(follow(addr, Duration::from_secs(5)));
    drop(view);
    assert_eq!(
        topics.len(),
        swarm::view::foxglove::TEAM_TOPICS.len() + 2 * usize::from(ROBOTS),
        "{topics:?}"
    );
    let silent: Vec<&String> = topics.iter().filter(|t| !counts.contains_key(*t)).collect();
    assert!(silent.is_empty(), "no message on {silent:?}: {counts:?}");
    // The play repeats while a client stays: each play sends the truth again.
    assert!(
        counts.get("/map/truth").is_some_and(|&n| n >= 1),
        "{counts:?}"
    );
}
