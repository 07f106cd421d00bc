//! Confinement of the sim plane (issue #17): `swarm run` gives every process its own login, and
//! the world-server's router lets each use only its own keys. A rogue process holding robot 1's
//! login joins a real run: it receives robot 1's scans (its session works) but not robot 3's,
//! its commands for robot 3 never reach anyone, and its order to stop the run is dropped. A
//! process without a login, or with a wrong password, cannot join at all. An `observer` login
//! (read-only, written by the launcher) watches the same keys as the positive control.

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use proto::keys;
use proto::msg::{encode, Control};
use proto::node::ZenohArgs;
use zenoh::handlers::FifoChannelHandler;
use zenoh::pubsub::Subscriber;
use zenoh::sample::Sample;
use zenoh::Session;

use crate::support::{kill, run_args, summary_typed, wait_file, Launcher, TempDir, SWARM};

type Sub = Subscriber<FifoChannelHandler<Sample>>;

fn login(endpoint: &str, credentials: Option<&Path>) -> ZenohArgs {
    ZenohArgs {
        connect: vec![endpoint.to_string()],
        credentials: credentials.map(Path::to_path_buf),
        ..ZenohArgs::default()
    }
}

async fn join(endpoint: &str, credentials: Option<&Path>) -> zenoh::Result<Session> {
    let cfg = login(endpoint, credentials)
        .client(2_000)
        .expect("client config");
    zenoh::open(cfg).await
}

async fn sub(s: &Session, key: &str) -> Sub {
    s.declare_subscriber(key.to_string())
        .await
        .expect("declare a subscriber")
}

/// Every payload a subscriber received within `wait`.
async fn drain(sub: &Sub, wait: Duration) -> Vec<Vec<u8>> {
    drain_keyed(sub, wait)
        .await
        .into_iter()
        .map(|(_, p)| p)
        .collect()
}

/// Every sample (key, payload) a subscriber received within `wait`.
async fn drain_keyed(sub: &Sub, wait: Duration) -> Vec<(String, Vec<u8>)> {
    let mut got = Vec::new();
    let deadline = tokio::time::Instant::now() + wait;
    while let Ok(Ok(s)) = tokio::time::timeout_at(deadline, sub.recv_async()).await {
        got.push((s.key_expr().to_string(), s.payload().to_bytes().to_vec()));
    }
    got
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_rogue_with_robot_1s_login_cannot_see_or_move_robot_3_nor_stop_the_run() {
    let dir = TempDir::new("confine");
    let run = dir.path().join("run");
    let mut cmd = Command::new(SWARM);
    // Robots that crawl: the run lasts until the test ends it.
    let sets = [
        "robots.count=4",
        "robots.speed_m_per_s=0.01",
        "max_steps=1000000",
    ];
    run_args(&mut cmd, &run, &sets);
    let mut launcher = Launcher::spawn(cmd);
    let endpoint = wait_file(&run.join("sim.endpoint"), Duration::from_secs(30));
    let secrets = run.join("secrets");
    wait_file(&secrets.join("users"), Duration::from_secs(30));
    use std::os::unix::fs::PermissionsExt;
    for f in ["users", "robot-1", "observer"] {
        let mode = std::fs::metadata(secrets.join(f)).map(|m| m.permissions().mode() & 0o777);
        assert_eq!(mode.ok(), Some(0o600), "secrets/{f} readable by others");
    }

    // The observer (read-only) sees robot 3's scans and commands once the run is going.
    let observer = join(&endpoint, Some(&secrets.join("observer")))
        .await
        .expect("the observer joins");
    let watch_scan3 = sub(&observer, &keys::scan(3)).await;
    let watch_cmd3 = sub(&observer, &keys::cmd(3)).await;
    let deadline = Instant::now() + Duration::from_secs(60);
    while drain(&watch_scan3, Duration::from_millis(500))
        .await
        .is_empty()
    {
        assert!(
            Instant::now() < deadline,
            "the observer saw no scan of robot 3"
        );
    }

    // Without a login, or with a wrong password, nobody joins.
    assert!(
        join(&endpoint, None).await.is_err(),
        "a client without a login joined"
    );
    let forged = dir.path().join("forged");
    std::fs::write(&forged, "robot-1:00000000000000000000000000000000\n").expect("forged login");
    assert!(
        join(&endpoint, Some(&forged)).await.is_err(),
        "a wrong password joined"
    );

    // The rogue: robot 1's own login.
    let rogue = join(&endpoint, Some(&secrets.join("robot-1")))
        .await
        .expect("robot 1's login joins");
    let own = sub(&rogue, &keys::scan(1)).await;
    let other = sub(&rogue, &keys::scan(3)).await;
    let everyone = sub(&rogue, "sim/robot/*/scan").await;
    let marker = b"rogue command for robot 3".to_vec();
    for _ in 0..10 {
        rogue
            .put(keys::cmd(3), marker.clone())
            .await
            .expect("the put is accepted locally");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    rogue
        .put(keys::CONTROL, encode(&Control::Stop))
        .await
        .expect("the put is accepted locally");
    let window = Duration::from_secs(3);
    let (own, other, everyone, scans3, cmds3) = tokio::join!(
        drain(&own, window),
        drain(&other, window),
        drain_keyed(&everyone, window),
        drain(&watch_scan3, window),
        drain(&watch_cmd3, window),
    );
    assert!(
        !own.is_empty(),
        "the rogue's session received none of robot 1's scans"
    );
    assert!(
        !scans3.is_empty(),
        "robot 3 received no scan while the rogue listened"
    );
    assert!(other.is_empty(), "robot 1's login received robot 3's scans");
    // The wildcard subscription is refused by the router; the rogue's own session still hands
    // it robot 1's scans, which it receives for its other subscription.
    let keys_seen: std::collections::BTreeSet<&str> =
        everyone.iter().map(|(k, _)| k.as_str()).collect();
    assert!(
        keys_seen.iter().all(|&k| k == keys::scan(1)),
        "robot 1's login subscribed everyone's scans: {keys_seen:?}"
    );
    assert!(!cmds3.is_empty(), "robot 3 sent no command in the window");
    assert!(
        !cmds3.contains(&marker),
        "the rogue's command for robot 3 reached a subscriber"
    );
    // The run went on after the rogue's stop: the world still scans, the launcher still runs.
    assert!(
        !drain(&watch_scan3, Duration::from_secs(1)).await.is_empty(),
        "the run stopped after the rogue's stop"
    );
    let pid = launcher.pid;
    assert!(
        launcher
            .child
            .as_mut()
            .and_then(|c| c.try_wait().ok())
            .flatten()
            .is_none(),
        "the launcher exited"
    );
    drop((rogue, observer));
    kill(pid, 15);
    launcher.wait_output(Duration::from_secs(60));
    let s = summary_typed(&run);
    assert_eq!(s.exit_reason, proto::exit::ExitReason::Terminated, "{s:?}");
    let world_log = std::fs::read_to_string(run.join("logs/world-server.log")).unwrap_or_default();
    assert!(
        !world_log.contains("panicked"),
        "world-server log: {world_log}"
    );
}
