//! The process side shared by every binary: the scenario flags ([`ScenarioArgs`]), the zenoh
//! arguments ([`ZenohArgs`], after zenoh's own `CommonArgs`), the one place that turns them into a
//! `zenoh::Config`, payload helpers and logging.
//!
//! Two planes (docs/design.md §1): the **sim plane** is a hub — the world-server runs a zenoh
//! router, everybody else joins it as a client. The **radio plane** is peer-to-peer with every form
//! of scouting off: a robot listens on one endpoint and connects only to the endpoints the launcher
//! (later: netem) gives it, so that no byte between robots takes another path.

use std::path::{Path, PathBuf};

use zenoh::Config;

use crate::confine::{access_control, Credentials, Principal};

/// The scenario flags shared by every process (flattened into each binary's clap `Args`).
#[derive(clap::Args, Clone, Debug, Default, PartialEq)]
pub struct ScenarioArgs {
    /// Scenario TOML file (see configs/default.toml for every key).
    #[arg(long = "scenario", value_name = "FILE")]
    pub file: PathBuf,
    /// Override a scenario key, e.g. --set robots.count=8 (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
}

impl ScenarioArgs {
    /// The file with no overrides.
    pub fn file(file: PathBuf) -> ScenarioArgs {
        ScenarioArgs {
            file,
            set: Vec::new(),
        }
    }

    /// The flags that parse back into these arguments.
    pub fn to_argv(&self) -> Vec<String> {
        let mut a = vec![
            "--scenario".into(),
            self.file.to_string_lossy().into_owned(),
        ];
        for s in &self.set {
            a.extend(["--set".into(), s.clone()]);
        }
        a
    }
}

/// zenoh flags shared by every process (flattened into each binary's clap `Args`).
#[derive(clap::Args, Clone, Debug, Default, PartialEq)]
pub struct ZenohArgs {
    /// Sim-plane endpoint to connect to: the world-server's router (clients), repeatable.
    #[arg(short = 'e', long = "connect", value_name = "ENDPOINT")]
    pub connect: Vec<String>,
    /// Sim-plane endpoint to listen on (world-server only), repeatable.
    #[arg(short = 'l', long = "listen", value_name = "ENDPOINT")]
    pub listen: Vec<String>,
    /// A zenoh JSON5 configuration file applied before the flags.
    #[arg(long = "config", value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Extra zenoh configuration as KEY:VALUE with a JSON5 value, e.g. --cfg
    /// 'transport/link/tx/batch_size:1024'.
    #[arg(long = "cfg", value_name = "KEY:VALUE")]
    pub cfg: Vec<String>,
    /// Clients: log in to the sim plane's router with the `user:password` line of FILE (swarm
    /// run writes one per process to the run's secrets/).
    #[arg(long = "credentials", value_name = "FILE")]
    pub credentials: Option<PathBuf>,
    /// world-server: confine the sim plane — only the users of FILE (`user:password` lines) may
    /// join, each allowed only its own keys (see the `confine` module).
    #[arg(long = "users", value_name = "FILE")]
    pub users: Option<PathBuf>,
}

/// The default sim-plane endpoint when none is given.
pub const DEFAULT_SIM_ENDPOINT: &str = "tcp/127.0.0.1:7447";

impl ZenohArgs {
    fn or_default(v: &[String]) -> Vec<String> {
        if v.is_empty() {
            vec![DEFAULT_SIM_ENDPOINT.to_string()]
        } else {
            v.to_vec()
        }
    }

    /// The world-server's router config; with `--users`, confined to `principals` (each may
    /// use only its own keys, [`crate::confine::grants`]).
    pub fn router(&self, principals: &[Principal]) -> Result<Config, ZargsError> {
        let mut c = sim_router(
            &Self::or_default(&self.listen),
            self.config.as_deref(),
            &self.cfg,
        )?;
        if let Some(users) = &self.users {
            // zenoh reads the file when the session opens; read it here too for a clear error.
            std::fs::read_to_string(users).map_err(|e| ZargsError::File {
                path: users.clone(),
                reason: e.to_string(),
            })?;
            set(
                &mut c,
                "transport/auth/usrpwd/dictionary_file",
                &format!("{:?}", users.to_string_lossy()),
            )?;
            set(&mut c, "access_control", &access_control(principals))?;
        }
        Ok(c)
    }

    /// The flags that parse back into these arguments (for a process that starts another).
    pub fn to_argv(&self) -> Vec<String> {
        let mut a = Vec::new();
        for e in &self.connect {
            a.extend(["--connect".into(), e.clone()]);
        }
        for e in &self.listen {
            a.extend(["--listen".into(), e.clone()]);
        }
        if let Some(f) = &self.config {
            a.extend(["--config".into(), f.to_string_lossy().into_owned()]);
        }
        for c in &self.cfg {
            a.extend(["--cfg".into(), c.clone()]);
        }
        if let Some(f) = &self.credentials {
            a.extend(["--credentials".into(), f.to_string_lossy().into_owned()]);
        }
        if let Some(f) = &self.users {
            a.extend(["--users".into(), f.to_string_lossy().into_owned()]);
        }
        a
    }

    /// A client config that waits up to `wait_ms` for the router.
    pub fn client(&self, wait_ms: u64) -> Result<Config, ZargsError> {
        let mut c = sim_client(
            &Self::or_default(&self.connect),
            self.config.as_deref(),
            &self.cfg,
            wait_ms,
        )?;
        if let Some(path) = &self.credentials {
            let file = |reason: String| ZargsError::File {
                path: path.clone(),
                reason,
            };
            let text = std::fs::read_to_string(path).map_err(|e| file(e.to_string()))?;
            let login = Credentials::parse(&text).map_err(file)?;
            set(
                &mut c,
                "transport/auth/usrpwd/user",
                &format!("{:?}", login.user),
            )?;
            set(
                &mut c,
                "transport/auth/usrpwd/password",
                &format!("{:?}", login.password),
            )?;
        }
        Ok(c)
    }
}

/// zenoh's boxed error as an `anyhow`-friendly error with context.
pub fn zerr(e: zenoh::Error) -> ZenohError {
    ZenohError(e.to_string())
}

/// A zenoh operation failed.
#[derive(Debug, thiserror::Error)]
#[error("zenoh: {0}")]
pub struct ZenohError(pub String);

/// Asks `key` once (2 s timeout) and decodes the first good reply; `Ok(None)` when nobody
/// answered.
pub async fn query_once<T: serde::de::DeserializeOwned>(
    session: &zenoh::Session,
    key: &str,
) -> Result<Option<T>, ZenohError> {
    let replies = session
        .get(key)
        .timeout(std::time::Duration::from_secs(2))
        .await
        .map_err(zerr)?;
    while let Ok(reply) = replies.recv_async().await {
        if let Ok(sample) = reply.result() {
            return crate::msg::decode::<T>(&sample.payload().to_bytes())
                .map(Some)
                .map_err(|e| ZenohError(format!("{key}: {e}")));
        }
    }
    Ok(None)
}

/// [`query_once`] until answered or `wait` has passed (the answering process may still be
/// starting).
pub async fn query_retry<T: serde::de::DeserializeOwned>(
    session: &zenoh::Session,
    key: &str,
    wait: std::time::Duration,
) -> Result<T, ZenohError> {
    let deadline = tokio::time::Instant::now() + wait;
    loop {
        if let Some(v) = query_once(session, key).await? {
            return Ok(v);
        }
        if tokio::time::Instant::now() >= deadline {
            return Err(ZenohError(format!("nobody answered {key} within {wait:?}")));
        }
        tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    }
}

/// Closes a session, giving up after a second: when the other end is already gone (the run is
/// over), zenoh's orderly close can wait for it much longer, and the process should just exit.
pub async fn close_quickly(session: zenoh::Session) {
    let close = async move { session.close().await };
    if let Ok(Err(e)) = tokio::time::timeout(std::time::Duration::from_secs(1), close).await {
        tracing::debug!("closing zenoh session: {e}");
    }
}

/// The one entry of every process of swarm-explore: logs to stderr ([`init_logging`]), runs `body`
/// on one tokio runtime and turns its outcome into the exit code ([`outcome`]).
pub fn entry<E: std::fmt::Display>(
    name: &str,
    body: impl std::future::Future<Output = Result<std::process::ExitCode, E>>,
) -> std::process::ExitCode {
    init_logging();
    entry_logged(name, body)
}

/// [`entry`] for a process that installed its own `tracing` subscriber ([`stderr_log`] and
/// layers of its own).
pub fn entry_logged<E: std::fmt::Display>(
    name: &str,
    body: impl std::future::Future<Output = Result<std::process::ExitCode, E>>,
) -> std::process::ExitCode {
    match tokio::runtime::Runtime::new() {
        Ok(runtime) => outcome(name, runtime.block_on(body)),
        Err(e) => outcome(name, Err(format!("cannot start the runtime: {e}"))),
    }
}

/// Sets zenoh's thread pools for this process to [`LEAN_ZENOH_RUNTIME`] unless the user set
/// `ZENOH_RUNTIME` (why: docs/design.md §1.1). zenoh reads the variable once, when it first
/// starts a pool.
///
/// Call first thing in `main`, before any thread is started (the environment is the process's).
pub fn lean_zenoh_threads() {
    if std::env::var_os(ZENOH_RUNTIME).is_none() {
        std::env::set_var(ZENOH_RUNTIME, LEAN_ZENOH_RUNTIME);
    }
}

/// The variable zenoh reads its thread pools from.
const ZENOH_RUNTIME: &str = "ZENOH_RUNTIME";

/// One thread reads the links and also takes the acceptor's and the network tasks' work (RON,
/// zenoh's format); the transmit pool stays its own (docs/design.md §1.1).
const LEAN_ZENOH_RUNTIME: &str =
    "(rx: (worker_threads: 1), acc: (handover: rx), net: (handover: rx))";

/// A command's result as its exit code: an error is printed once, as `{name}: {error:#}` (the
/// whole chain of an `anyhow` error), with exit code 1.
pub fn outcome<E: std::fmt::Display>(
    name: &str,
    result: Result<std::process::ExitCode, E>,
) -> std::process::ExitCode {
    result.unwrap_or_else(|e| {
        eprintln!("{name}: {e:#}");
        std::process::ExitCode::FAILURE
    })
}

/// Logs to stderr ([`stderr_log`]).
pub fn init_logging() {
    use tracing_subscriber::layer::SubscriberExt;
    use tracing_subscriber::util::SubscriberInitExt;
    let _ = tracing_subscriber::registry().with(stderr_log()).try_init();
}

/// The stderr log as a layer with its own filter: `RUST_LOG`, or by default `warn` (zenoh's own
/// messages from `error`). A process adds layers of its own beside it, each with its own filter.
pub fn stderr_log<S>() -> impl tracing_subscriber::Layer<S> + Send + Sync
where
    S: tracing::Subscriber + for<'a> tracing_subscriber::registry::LookupSpan<'a>,
{
    use tracing_subscriber::Layer;
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn,zenoh=error"));
    tracing_subscriber::fmt::layer()
        .with_writer(std::io::stderr)
        .with_target(false)
        .with_filter(filter)
}

/// Errors while building a zenoh configuration.
#[derive(Debug, thiserror::Error)]
pub enum ZargsError {
    #[error("zenoh config file {path}: {reason}")]
    File { path: PathBuf, reason: String },
    #[error("zenoh config key `{key}` = {value}: {reason}")]
    Key {
        key: String,
        value: String,
        reason: String,
    },
}

fn set(config: &mut Config, key: &str, value: &str) -> Result<(), ZargsError> {
    config
        .insert_json5(key, value)
        .map_err(|e| ZargsError::Key {
            key: key.into(),
            value: value.into(),
            reason: e.to_string(),
        })
}

fn json_list(items: &[String]) -> String {
    let quoted: Vec<String> = items.iter().map(|s| format!("{s:?}")).collect();
    format!("[{}]", quoted.join(","))
}

fn base(file: Option<&Path>) -> Result<Config, ZargsError> {
    match file {
        Some(path) => Config::from_file(path).map_err(|e| ZargsError::File {
            path: path.to_path_buf(),
            reason: e.to_string(),
        }),
        None => Ok(Config::default()),
    }
}

/// Applies `KEY:VALUE` pairs (JSON5 values) given with `--cfg`.
fn apply_cfg(config: &mut Config, cfg: &[String]) -> Result<(), ZargsError> {
    for kv in cfg {
        let (k, v) = kv.split_once(':').ok_or_else(|| ZargsError::Key {
            key: kv.clone(),
            value: String::new(),
            reason: "expected KEY:VALUE".into(),
        })?;
        set(config, k, v)?;
    }
    Ok(())
}

/// The world-server's sim-plane session: a router listening on `listen`.
pub fn sim_router(
    listen: &[String],
    file: Option<&Path>,
    cfg: &[String],
) -> Result<Config, ZargsError> {
    let mut c = base(file)?;
    set(&mut c, "mode", "\"router\"")?;
    set(&mut c, "listen/endpoints", &json_list(listen))?;
    set(&mut c, "scouting/multicast/enabled", "false")?;
    set(&mut c, "scouting/gossip/enabled", "false")?;
    apply_cfg(&mut c, cfg)?;
    Ok(c)
}

/// A sim-plane client of the world-server's router (robots, netem, launcher). It waits up to
/// `wait_ms` for the router to come up instead of failing at once.
pub fn sim_client(
    connect: &[String],
    file: Option<&Path>,
    cfg: &[String],
    wait_ms: u64,
) -> Result<Config, ZargsError> {
    let mut c = base(file)?;
    set(&mut c, "mode", "\"client\"")?;
    set(&mut c, "connect/endpoints", &json_list(connect))?;
    set(&mut c, "connect/timeout_ms", &wait_ms.to_string())?;
    set(&mut c, "scouting/multicast/enabled", "false")?;
    set(&mut c, "scouting/gossip/enabled", "false")?;
    apply_cfg(&mut c, cfg)?;
    Ok(c)
}

/// A robot's radio-plane session: a peer that listens on `listen`, connects to `connect` and
/// nothing else (no multicast, no gossip: peers learn no endpoint they were not given).
/// Reconnects quickly (10 ms, backing off to 20 ms) so a link that comes back into range is used
/// again within two steps in lockstep (measured: `reconnect` in summary.json; 50/200 ms took up
/// to 10 steps). An attempt on a link that is down is held by netem until the link comes up
/// (then the session opens at once), so a robot does not retry a pair out of range; in lockstep
/// its opening handshake may wait as long as the lease ([`LOCKSTEP_RADIO_LEASE_MS`]): one that
/// gave up would be dropped by netem and tried again at a moment the wall clock decides. Tuned
/// for slow links (docs/design.md §1, "zenoh facts"): a batch is only counted when it has
/// fully arrived, so batches are kept small ([`RADIO_BATCH_BYTES`]) for keep-alives to get
/// through a 1 kB/s link well within the lease; in realtime runs messages are published with
/// `CongestionControl::Drop` by the robot. `lockstep`: no batching, an hour's lease
/// ([`LOCKSTEP_RADIO_LEASE_MS`]) and the largest batches ([`LOCKSTEP_RADIO_BATCH_BYTES`]), so
/// that none of zenoh's own wall-clock traffic crosses a link during a run, a message's bytes do
/// not depend on timing and a step's frame is one batch.
///
/// `me` of a team of `team` robots: the session's zenoh id is [`radio_zid`]`(me)`, and an access
/// rule lets a put addressed to robot `j` (`radio/j/…`) leave only on the session to `j`. zenoh
/// sends a publication to every peer whose interest in it is not settled yet (a session that
/// has just come up), so without the rule a message could cross another robot's link.
pub fn radio_peer(
    me: crate::msg::RobotId,
    team: u16,
    listen: &[String],
    connect: &[String],
    file: Option<&Path>,
    cfg: &[String],
    lockstep: bool,
) -> Result<Config, ZargsError> {
    let mut c = base(file)?;
    set(&mut c, "id", &format!("{:?}", radio_zid(me)))?;
    if team > 1 {
        set(&mut c, "access_control", &addressed_only(me, team))?;
    }
    set(&mut c, "mode", "\"peer\"")?;
    set(&mut c, "listen/endpoints", &json_list(listen))?;
    set(&mut c, "connect/endpoints", &json_list(connect))?;
    set(&mut c, "scouting/multicast/enabled", "false")?;
    set(&mut c, "scouting/gossip/enabled", "false")?;
    set(&mut c, "scouting/delay", "0")?;
    set(
        &mut c,
        "connect/retry",
        "{period_init_ms: 10, period_max_ms: 20, period_increase_factor: 2}",
    )?;
    let batch = if lockstep {
        LOCKSTEP_RADIO_BATCH_BYTES
    } else {
        RADIO_BATCH_BYTES
    };
    set(&mut c, "transport/link/tx/batch_size", &batch.to_string())?;
    if lockstep {
        // A lockstep link carries a frame a step, each with zenoh's sequence number: 8 bits
        // (TCP keeps the order) save 3.2 bytes a frame over the default 32, 3 % of the
        // default run's wire bytes.
        set(
            &mut c,
            "transport/link/tx/sequence_number_resolution",
            "\"8bit\"",
        )?;
    }
    let lease = if lockstep {
        LOCKSTEP_RADIO_LEASE_MS
    } else {
        RADIO_LEASE_MS
    };
    set(&mut c, "transport/link/tx/lease", &lease.to_string())?;
    set(&mut c, "transport/link/tx/keep_alive", "4")?;
    // Every peer may open its session at once (the whole team in range at the first step): a
    // robot takes them all into its handshake queue rather than turning some away to retry.
    set(
        &mut c,
        "transport/unicast/accept_pending",
        &usize::from(team).max(100).to_string(),
    )?;
    if lockstep {
        // A message's bytes on the wire must not depend on what else happened to be queued.
        set(&mut c, "transport/link/tx/queue/batching/enabled", "false")?;
        // Handshakes may be slow when a big team's sessions all form at once (8 000 at 128
        // robots on two cores); one that failed would be tried again at a moment the wall
        // clock decides.
        for key in ["open_timeout", "accept_timeout"] {
            set(
                &mut c,
                &format!("transport/unicast/{key}"),
                &LOCKSTEP_RADIO_LEASE_MS.to_string(),
            )?;
        }
    }
    apply_cfg(&mut c, cfg)?;
    Ok(c)
}

/// The zenoh id of robot `id`'s radio session (fixed, so that a robot can tell which peers it
/// has a session with, and the access rules can name them).
pub fn radio_zid(id: crate::msg::RobotId) -> String {
    format!("5a{id:04x}")
}

/// zenoh access control (JSON5) for robot `me` of `team`: towards peer `j` only puts and
/// deletes on `radio/j/**` leave, from any peer only those on `radio/me/**` are taken (the radio
/// takes only what is addressed to its robot); every other kind of message is allowed both ways;
/// a session that is not one of the team's gets nothing.
///
/// Written as allowances under a default of deny, so each peer's rules hold three keys: zenoh
/// looks a message's key up in its peer's rules on every message, and the same rule written as
/// denials names every other robot's key (127 keys per peer at 128 robots): that lookup was 15 %
/// of the CPU of a 128-robot run.
fn addressed_only(me: crate::msg::RobotId, team: u16) -> String {
    const NOT_DATA: &str = "\"declare_subscriber\",\"query\",\"declare_queryable\",\"reply\",\
         \"liveliness_token\",\"declare_liveliness_subscriber\",\"liveliness_query\"";
    let mut rules = vec![
        format!(
            "{{id:\"not_data\",messages:[{NOT_DATA}],flows:[\"ingress\",\"egress\"],\
             permission:\"allow\",key_exprs:[\"**\"]}}"
        ),
        format!(
            "{{id:\"for_me\",messages:[\"put\",\"delete\"],flows:[\"ingress\"],\
             permission:\"allow\",key_exprs:[\"{}\"]}}",
            crate::keys::radio_inbox(me)
        ),
    ];
    let mut subjects = Vec::new();
    let mut policies = Vec::new();
    for j in (0..team).filter(|&j| j != me) {
        rules.push(format!(
            "{{id:\"to_{j}\",messages:[\"put\",\"delete\"],flows:[\"egress\"],\
             permission:\"allow\",key_exprs:[\"{}\"]}}",
            crate::keys::radio_inbox(j)
        ));
        subjects.push(format!("{{id:\"peer_{j}\",zids:[\"{}\"]}}", radio_zid(j)));
        policies.push(format!(
            "{{rules:[\"to_{j}\",\"for_me\",\"not_data\"],subjects:[\"peer_{j}\"]}}"
        ));
    }
    format!(
        "{{enabled:true,default_permission:\"deny\",rules:[{}],subjects:[{}],policies:[{}]}}",
        rules.join(","),
        subjects.join(","),
        policies.join(",")
    )
}

pub use crate::scenario::{LOCKSTEP_RADIO_LEASE_MS, SIM_LEASE_MS};

/// Largest zenoh batch on the radio plane: at 1 000 bytes/s one batch crosses in half a second.
pub const RADIO_BATCH_BYTES: u16 = 512;
/// Largest zenoh batch on the radio plane in lockstep with step markers: zenoh's largest, so
/// that a step's frame is rarely fragmented (every further fragment costs its own headers).
/// No keep-alive has to cross a link within a lease there ([`LOCKSTEP_RADIO_LEASE_MS`]).
pub const LOCKSTEP_RADIO_BATCH_BYTES: u16 = u16::MAX;
/// Radio link lease (wall milliseconds); 4 keep-alives per lease.
pub const RADIO_LEASE_MS: u64 = 10_000;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn configs_build_and_bad_keys_are_named() {
        let e = vec!["tcp/127.0.0.1:7447".to_string()];
        assert!(sim_router(&e, None, &[]).is_ok());
        assert!(sim_client(&e, None, &[], 1000).is_ok());
        assert!(radio_peer(0, 1, &e, &e, None, &[], false).is_ok());
        assert!(radio_peer(3, 8, &e, &e, None, &[], true).is_ok());
        let err = sim_client(&e, None, &["no_such/key:1".into()], 0)
            .err()
            .map(|e| e.to_string());
        assert!(err.unwrap_or_default().contains("no_such/key"));
        let err = sim_client(&e, Some(Path::new("/nonexistent.json5")), &[], 0).err();
        assert!(err
            .map(|e| e.to_string())
            .unwrap_or_default()
            .contains("/nonexistent.json5"));
    }

    #[test]
    fn confinement_adds_the_dictionary_the_rules_and_each_clients_login() {
        let d = std::env::temp_dir().join(format!("confine-cfg-{}", std::process::id()));
        std::fs::create_dir_all(&d).expect("temp dir");
        let (users, cred, bad) = (d.join("users"), d.join("robot-0"), d.join("bad"));
        std::fs::write(&users, "robot-0:pw0\nnetem:pw1\n").expect("users");
        std::fs::write(&cred, "robot-0:pw0\n").expect("login");
        std::fs::write(&bad, "robot-0\n").expect("bad login");
        let e = vec!["tcp/127.0.0.1:7447".to_string()];
        let team = crate::confine::Principal::of_run(1, None);
        let router = ZenohArgs {
            listen: e.clone(),
            users: Some(users.clone()),
            ..ZenohArgs::default()
        };
        let c = router.router(&team).expect("router config");
        assert_eq!(
            c.get_json("access_control/enabled").ok().as_deref(),
            Some("true")
        );
        let open = ZenohArgs {
            listen: e.clone(),
            ..ZenohArgs::default()
        };
        let c = open.router(&team).expect("router config");
        assert_eq!(
            c.get_json("access_control/enabled").ok().as_deref(),
            Some("false")
        );
        let client = |credentials: &Path| {
            ZenohArgs {
                connect: e.clone(),
                credentials: Some(credentials.to_path_buf()),
                ..ZenohArgs::default()
            }
            .client(0)
        };
        let c = client(&cred).expect("client config");
        assert_eq!(
            c.get_json("transport/auth/usrpwd/user").ok().as_deref(),
            Some("\"robot-0\"")
        );
        for missing in [bad, d.join("none")] {
            let err = client(&missing).err().map(|e| e.to_string());
            assert!(err
                .unwrap_or_default()
                .contains(&*missing.to_string_lossy()));
        }
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn zenoh_flags_round_trip_through_to_argv() {
        use clap::Parser;
        #[derive(clap::Parser, Debug, PartialEq)]
        struct Cli {
            #[command(flatten)]
            zenoh: ZenohArgs,
        }
        let z = ZenohArgs {
            connect: vec!["tcp/127.0.0.1:1".into(), "tcp/127.0.0.1:2".into()],
            listen: vec!["tcp/127.0.0.1:3".into()],
            config: Some(PathBuf::from("/etc/z.json5")),
            cfg: vec!["transport/link/tx/batch_size:1024".into()],
            credentials: Some(PathBuf::from("/run/x/secrets/robot-1")),
            users: Some(PathBuf::from("/run/x/secrets/users")),
        };
        for z in [z, ZenohArgs::default()] {
            let argv = std::iter::once("x".to_string()).chain(z.to_argv());
            assert_eq!(Cli::parse_from(argv).zenoh, z);
        }
    }
}
