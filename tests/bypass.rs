//! No bypass (issue #3, must-show 4): robots A–B–C in a line, A and C out of range. Nothing A
//! publishes on the radio plane reaches C except what B's own code forwards.
//!
//! Real processes and sockets: a `swarm netem serve` process proxies the three pairs; the test
//! plays the world-server (a zenoh router on the sim plane publishing the robots' poses) and the
//! three robots' radio sessions, configured exactly as robot-agents configure theirs (peers,
//! scouting off, connected only to netem's proxies).

use std::process::Command;
use std::time::Duration;

use proto::geom::Pose;
use proto::keys;
use proto::msg::{encode, RobotStatus, Status};
use proto::node::{radio_peer, sim_router};
use zenoh::Session;

use crate::support::{free_ports, Launcher, TempDir, SWARM};

fn ep(port: u16) -> String {
    format!("tcp/127.0.0.1:{port}")
}

async fn open(cfg: zenoh::Config) -> Session {
    zenoh::open(cfg).await.expect("open a zenoh session")
}

/// Waits up to `wait` for one sample on a subscriber; the payload if any.
async fn first(
    sub: &zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<zenoh::sample::Sample>>,
    wait: Duration,
) -> Option<Vec<u8>> {
    tokio::time::timeout(wait, sub.recv_async())
        .await
        .ok()?
        .ok()
        .map(|s| s.payload().to_bytes().to_vec())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_message_reaches_a_robot_out_of_range_only_through_the_robot_in_between() {
    let dir = TempDir::new("bypass");
    let p = free_ports(7);
    let (sim, radio, pairs, http) = (p[0], [p[1], p[2], p[3]], [p[4], p[5], p[6]], 0);
    let _ = http;
    let scenario = dir.path().join("scenario.toml");
    std::fs::write(&scenario, "[robots]\ncount = 3\n[radio]\nmodel = \"disk\"\nrange_m = 6.0\nbandwidth_bytes_per_s = 0\n").expect("scenario");
    // The sim plane: the test is the world-server's router.
    let world = open(sim_router(&[ep(sim)], None, &[]).expect("router config")).await;
    let pair_ids = [(0u16, 1u16), (0, 2), (1, 2)];
    let mut cmd = Command::new(SWARM);
    cmd.args(["netem", "serve", "--scenario"])
        .arg(&scenario)
        .args(["--connect", &ep(sim)]);
    for (k, (a, b)) in pair_ids.iter().enumerate() {
        cmd.arg("--pair").arg(format!(
            "{a}-{b}=127.0.0.1:{}>127.0.0.1:{}",
            pairs[k],
            radio[usize::from(*b)]
        ));
    }
    let _netem = Launcher::spawn(cmd);
    // Robots: A (0) at x=0, B (1) at x=5, C (2) at x=10; range 6 m: A–B and B–C up, A–C down.
    let status = |step: u32| Status {
        step,
        robots: [0.0, 5.0, 10.0]
            .iter()
            .enumerate()
            .map(|(i, &x)| RobotStatus {
                id: i as u16,
                pose: Pose {
                    x,
                    y: 0.0,
                    theta: 0.0,
                },
                alive: true,
                distance_m: 0.0,
            })
            .collect(),
        collisions_total: 0,
        blocked_total: 0,
        base: None,
        missed: Vec::new(),
    };
    let connects: [Vec<String>; 3] = [vec![ep(pairs[0]), ep(pairs[1])], vec![ep(pairs[2])], vec![]];
    // A team of one to zenoh's eyes: no access rule (which would keep A's put to C off the
    // link to B), so that this checks zenoh's own routing.
    let mut robots = Vec::new();
    for i in 0..3 {
        robots.push(
            open(
                radio_peer(i as u16, 1, &[ep(radio[i])], &connects[i], None, &[], false)
                    .expect("radio config"),
            )
            .await,
        );
    }
    let key = keys::radio_delta(2);
    let at_b = robots[1]
        .declare_subscriber(&key)
        .await
        .expect("subscribe at B");
    let at_c = robots[2]
        .declare_subscriber(&key)
        .await
        .expect("subscribe at C");
    // Drive netem's clock and range verdicts until B sees C's and A's liveliness (links up).
    let b_peers = robots[1]
        .liveliness()
        .declare_subscriber(keys::RADIO_ALIVE_ALL)
        .history(true)
        .await
        .expect("liveliness");
    let _tokens: Vec<_> = futures_tokens(&robots).await;
    let mut seen = std::collections::BTreeSet::new();
    for step in 0..100u32 {
        world
            .put(keys::STATUS, encode(&status(step)))
            .await
            .expect("status");
        while let Ok(Some(s)) = b_peers.try_recv() {
            // B's own token shows up locally; only the peers' count.
            if s.key_expr().as_str() != keys::radio_alive(1) {
                seen.insert(s.key_expr().as_str().to_string());
            }
        }
        if seen.len() >= 2 {
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert_eq!(seen.len(), 2, "B sees A and C through netem: {seen:?}");
    // Neighbour discovery: C sees B's token, never A's.
    let c_peers = robots[2]
        .liveliness()
        .get(keys::RADIO_ALIVE_ALL)
        .await
        .expect("liveliness get");
    let mut c_sees = std::collections::BTreeSet::new();
    while let Ok(r) = c_peers.recv_async().await {
        if let Ok(s) = r.result() {
            c_sees.insert(s.key_expr().as_str().to_string());
        }
    }
    assert!(
        c_sees.contains(&keys::radio_alive(1)),
        "C sees B: {c_sees:?}"
    );
    assert!(
        !c_sees.contains(&keys::radio_alive(0)),
        "C must not see A: {c_sees:?}"
    );
    // A's probe reaches B (a direct neighbour) but not C.
    robots[0]
        .put(&key, b"probe from A".to_vec())
        .await
        .expect("A publishes");
    assert_eq!(
        first(&at_b, Duration::from_secs(5)).await.as_deref(),
        Some(&b"probe from A"[..]),
        "B hears A"
    );
    assert_eq!(
        first(&at_c, Duration::from_secs(2)).await,
        None,
        "C must not hear A directly"
    );
    // What B's own code forwards does reach C.
    robots[1]
        .put(&key, b"forwarded by B".to_vec())
        .await
        .expect("B forwards");
    assert_eq!(
        first(&at_c, Duration::from_secs(5)).await.as_deref(),
        Some(&b"forwarded by B"[..]),
        "C hears B"
    );
    for r in robots {
        let _ = r.close().await;
    }
    let _ = world.close().await;
}

/// Every robot's radio liveliness token, as robot-agents declare them.
async fn futures_tokens(robots: &[Session]) -> Vec<zenoh::liveliness::LivelinessToken> {
    let mut out = Vec::new();
    for (i, r) in robots.iter().enumerate() {
        out.push(
            r.liveliness()
                .declare_token(keys::radio_alive(i as u16))
                .await
                .expect("token"),
        );
    }
    out
}
