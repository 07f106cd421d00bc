//! Confinement of the sim plane (issue #17): `swarm run` gives every process its own login, and
//! the world-server's router lets each use only its own keys. A rogue process holding robot 1's
//! login joins a real run: it receives robot 1's scans (its session works) but not robot 3's,
//! its commands for robot 3 never reach anyone, and its order to stop the run is dropped. A
//! process without a login, or with a wrong password, cannot join at all. An `observer` login
//! (read-only, written by the launcher) watches the same keys as the positive control. Every
//! refused login is in the world-server's log, once per address and then counted, and an
//! attacked run has the digest of a quiet one.

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use proto::keys;
use proto::msg::{encode, Control};
use proto::node::ZenohArgs;
use zenoh::handlers::{FifoChannel, FifoChannelHandler};
use zenoh::pubsub::Subscriber;
use zenoh::sample::Sample;
use zenoh::Session;

use crate::support::{
    kill, run_args, stderr, summary_typed, swarm_run, wait_file, wait_for_step, Launcher, TempDir,
    SWARM,
};

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

/// Samples a test's subscriber holds until it reads them: more than a run publishes on one key
/// while the test is busy elsewhere (a lockstep run steps several hundred times a second).
/// zenoh's default channel would fill, and a client that stops reading stalls the run it
/// observes (docs/design.md §7, "Limit: a login that stops reading holds the run").
const SUB_CAPACITY: usize = 1 << 16;

async fn sub(s: &Session, key: &str) -> Sub {
    s.declare_subscriber(key.to_string())
        .with(FifoChannel::new(SUB_CAPACITY))
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
        "robots.speed_m_per_s=0.001",
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

/// One login attempt (no retry), as zenoh id `zid` when given.
async fn knock(endpoint: &str, credentials: Option<&Path>, zid: Option<&str>) -> bool {
    let mut cfg = login(endpoint, credentials)
        .client(0)
        .expect("client config");
    if let Some(zid) = zid {
        cfg.insert_json5("id", &format!("{zid:?}"))
            .expect("a zenoh id");
    }
    zenoh::open(cfg).await.is_ok()
}

/// Issue #38: refused logins leave a trace an operator can read — the world-server logs who
/// (the zenoh id), from where and why, the first refusal from an address at once and later ones
/// only counted — and leave the run as it was: an attacked run has the digest of a quiet one.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn refused_logins_are_logged_once_per_address_and_change_nothing() {
    // Explored in about 200 steps: a run of a second or two, long enough for the intruder to
    // knock during it, and a function of its scenario. (It ends explored, not at max_steps:
    // links.csv's last step of a run stopped at max_steps can differ between two quiet runs.)
    let sets = [
        "world.map=office",
        "world.width_m=30",
        "world.height_m=20",
        "robots.count=2",
        "max_steps=2000",
        "clock.step_timeout_ms=10000",
    ];
    let quiet_dir = TempDir::new("refusals-quiet");
    let quiet_run = quiet_dir.path().join("run");
    let (out, quiet, _quiet_dir) = tokio::task::spawn_blocking(move || {
        let (out, run) = swarm_run(&quiet_dir, None, &sets, Duration::from_secs(180));
        (out, summary_typed(&run), quiet_dir)
    })
    .await
    .expect("the quiet run");
    assert!(out.status.success(), "{}", stderr(&out));

    let dir = TempDir::new("refusals");
    let run = dir.path().join("run");
    let mut cmd = Command::new(SWARM);
    run_args(&mut cmd, &run, &sets);
    let mut launcher = Launcher::spawn(cmd);
    let endpoint = wait_file(&run.join("sim.endpoint"), Duration::from_secs(30));
    let secrets = run.join("secrets");
    wait_for_step(&run, 1, Duration::from_secs(60));

    // The intruder: robot 1's name with a wrong password, first once alone (the line logged at
    // once), then again, as an unknown user, and without a login, all from 127.0.0.1.
    let forged = dir.path().join("forged");
    std::fs::write(&forged, "robot-1:00000000000000000000000000000000\n").expect("forged login");
    let stranger = dir.path().join("stranger");
    std::fs::write(&stranger, "mallory:00000000000000000000000000000000\n").expect("a login");
    let zid = "5ca1ab1e0ddba11";
    assert!(!knock(&endpoint, Some(&forged), Some(zid)).await);
    let (a, b, c, d, e) = tokio::join!(
        knock(&endpoint, Some(&forged), None),
        knock(&endpoint, Some(&forged), None),
        knock(&endpoint, Some(&forged), None),
        knock(&endpoint, Some(&stranger), None),
        knock(&endpoint, None, None),
    );
    assert!(!(a || b || c || d || e), "an intruder joined");
    // The positive control: a login of the run still joins.
    assert!(
        knock(&endpoint, Some(&secrets.join("observer")), None).await,
        "the observer's login was refused"
    );
    assert!(
        launcher
            .child
            .as_mut()
            .and_then(|c| c.try_wait().ok())
            .flatten()
            .is_none(),
        "the run ended before the intruder was done"
    );

    let out = launcher.wait_output(Duration::from_secs(180));
    assert!(out.status.success(), "{}", stderr(&out));
    let log = std::fs::read_to_string(run.join("logs/world-server.log")).expect("its log");
    let first: Vec<&str> = log
        .lines()
        .filter(|l| l.contains("refused login from "))
        .collect();
    assert_eq!(first.len(), 1, "one line at once for 127.0.0.1:\n{log}");
    assert!(
        first[0].contains("refused login from 127.0.0.1:")
            && first[0].contains(&format!("(zenoh id {zid}): wrong password")),
        "{}",
        first[0]
    );
    // The other five only counted, by reason, in one line every 10 s (and one at the end).
    let mut counted = std::collections::BTreeMap::new();
    let count_lines: Vec<&str> = log
        .lines()
        .filter(|l| l.contains("refused logins from "))
        .collect();
    for line in &count_lines {
        assert!(line.contains("refused logins from 127.0.0.1: "), "{line}");
        let by = line
            .split_once(" more (")
            .and_then(|(_, r)| r.split_once(')'))
            .map_or("", |(by, _)| by);
        for item in by.split(", ") {
            let (reason, n) = item.rsplit_once(' ').expect("reason count");
            *counted.entry(reason.to_string()).or_insert(0) += n.parse::<u32>().expect("a count");
        }
    }
    assert!(
        (1..=2).contains(&count_lines.len()),
        "{count_lines:?}\n{log}"
    );
    let want: std::collections::BTreeMap<String, u32> = [
        ("no login offered", 1),
        ("unknown user", 1),
        ("wrong password", 3),
    ]
    .into_iter()
    .map(|(r, n)| (r.to_string(), n))
    .collect();
    assert_eq!(counted, want, "{log}");

    let s = summary_typed(&run);
    assert!(s.deterministic && quiet.deterministic, "{s:?}");
    assert_eq!(s.exit_reason, proto::exit::ExitReason::Explored, "{s:?}");
    let differ: Vec<&str> = swarm::rundir::summary::DIGESTED
        .iter()
        .copied()
        .filter(|f| std::fs::read(run.join(f)).ok() != std::fs::read(quiet_run.join(f)).ok())
        .collect();
    assert_eq!(
        s.run_digest, quiet.run_digest,
        "the intruder changed the run: {differ:?} differ"
    );
}
