//! The run viewer: a web page that follows a run live (`swarm run --view`) or replays a finished
//! one (`swarm view RUN_DIR`), served by this process on axum. The page (`assets/view/`) is static
//! and built into the binary; its data comes from a [`Timeline`](crate::view::timeline::Timeline)
//! fed with the step log's records — live by the launcher as it writes them, in a replay from
//! `steps.log`.
//!
//! Routes: `GET /` (and `/app.js`, `/style.css`), `GET /api/info`, `GET /api/truth.png`, `GET
//! /api/series`, `GET /api/frame/{step|latest}` (with every trajectory up to the step), `GET
//! /api/robot/{id}` and `GET /api/robot/{id}/grid.png` (`?step=N`; `404` for a robot the run does
//! not have or that has not reported yet), and in a live run `GET /ws` (a WebSocket: one JSON
//! [`Frame`](crate::view::timeline::Frame) per step), `GET /api/robot/{id}/polygons` (the robot's
//! own polygonal approximation and its peers' as it holds them, asked of the robot on the sim
//! plane), `POST /api/link/{name}` (cut, restore, bandwidth, latency: forwarded to netem's API with
//! the run's token — netem itself refuses browsers) and `POST /api/clock/{pause|resume|step}`.
//!
//! The viewer never slows the run: the launcher hands it each record under a short lock, and
//! a page that reads frames slower than they come misses some (a bounded broadcast queue
//! drops the oldest), never a step.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex, MutexGuard};

use anyhow::Context;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{Path, Query, State};
use axum::http::header::CONTENT_TYPE;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::Router;
use proto::grid::{Grid, Occ};
use proto::keys;
use proto::msg::{encode, Control, RobotId, Step};
use tokio::net::TcpListener;
use tokio::sync::broadcast;
use zenoh::qos::CongestionControl;

use crate::rundir::render::Picture;
use crate::rundir::steplog::{Header, Record};
use crate::score::fidelity::false_free_cells;
use crate::view::timeline::{frontiers, Timeline};

const INDEX: &str = include_str!("../../assets/view/index.html");
const APP: &str = include_str!("../../assets/view/app.js");
const STYLE: &str = include_str!("../../assets/view/style.css");

/// Frames a live page may fall behind by before it misses some.
const FRAMES_QUEUED: usize = 16;

/// Flags of `swarm view`.
#[derive(clap::Args, Debug, Clone)]
pub struct ViewArgs {
    /// A finished run's directory (it holds steps.log).
    pub run_dir: PathBuf,
    /// Where to serve the page (port 0: any free port; the address is printed).
    #[arg(long, default_value = "127.0.0.1:0")]
    pub addr: SocketAddr,
    /// Also replay the run over the Foxglove WebSocket protocol at ADDR (default
    /// 127.0.0.1:8765; port 0: a free port), from the first client's connect, and again from
    /// the start after the end while a client is connected.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, require_equals = true, default_missing_value = "127.0.0.1:8765")]
    pub foxglove: Option<SocketAddr>,
    /// Steps per second of the Foxglove replay.
    #[arg(long, default_value_t = 10.0, value_name = "N")]
    pub rate: f64,
}

/// How the live viewer reaches netem's API.
#[derive(Clone, Debug)]
pub struct NetemApi {
    pub addr: SocketAddr,
    pub token: Option<String>,
}

/// What the page's server shares.
struct App {
    timeline: Mutex<Timeline>,
    truth_png: Vec<u8>,
    /// A live run: frames as they come, netem's API, the step clock.
    live: Option<Live>,
}

/// What a live run's page reaches besides the timeline.
struct Live {
    frames: broadcast::Sender<Arc<String>>,
    netem: NetemApi,
    /// The launcher's sim-plane session: the page's pause / resume / step go out on it as
    /// [`Control`] orders to the world-server (and the robots, which then do not time out).
    sim: zenoh::Session,
    /// The last clock order sent from the page (what the page shows).
    paused: std::sync::atomic::AtomicBool,
    /// What the pages were sent.
    stats: Mutex<FrameStats>,
    /// The last step whose frame went out.
    framed: Mutex<Option<Step>>,
}

impl Live {
    fn stats(&self) -> MutexGuard<'_, FrameStats> {
        self.stats
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    fn framed(&self) -> MutexGuard<'_, Option<Step>> {
        self.framed
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}

/// Frames sent to the live pages over a run.
#[derive(Clone, Copy, Debug, Default)]
pub struct FrameStats {
    /// Frames sent, to every page.
    pub sent: u64,
    /// Frames a page that fell behind skipped.
    pub skipped: u64,
    /// From the first frame sent to the last (any page).
    pub span: Option<(std::time::Instant, std::time::Instant)>,
}

impl FrameStats {
    /// Frames per second while pages were sent frames.
    pub fn per_second(&self) -> Option<f64> {
        let (a, b) = self.span?;
        let s = b.duration_since(a).as_secs_f64();
        (s > 0.0).then(|| self.sent as f64 / s)
    }

    fn sent_one(&mut self) {
        let now = std::time::Instant::now();
        self.sent += 1;
        self.span = Some((self.span.map_or(now, |(a, _)| a), now));
    }
}

fn lock(m: &Mutex<Timeline>) -> MutexGuard<'_, Timeline> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// The live viewer's side in the launcher: hand it every step-log record.
#[derive(Clone)]
pub struct Feed {
    app: Arc<App>,
}

impl Feed {
    /// Takes a record. A step's frame goes to the pages once every robot alive in it has
    /// reported it — or, if some never does, when the next step's first report comes (every
    /// report of a step is taken before the next step's). So a paused run shows its last step.
    pub fn push(&self, r: Record) {
        let Some(live) = &self.app.live else {
            lock(&self.app.timeline).push(r);
            return;
        };
        let mut t = lock(&self.app.timeline);
        let before = t.latest();
        let reported = match &r {
            Record::Robot(rs, _) => Some(rs.step),
            _ => None,
        };
        t.push(r);
        let due = match reported {
            Some(s) if t.complete(s) => Some(s),
            Some(s) if Some(s) != before => before,
            _ => None,
        };
        let mut framed = live.framed();
        if let Some(step) = due.filter(|&s| framed.is_none_or(|f| s > f)) {
            *framed = Some(step);
            if live.frames.receiver_count() > 0 {
                if let Ok(json) = serde_json::to_string(&t.frame(step, false)) {
                    let _ = live.frames.send(Arc::new(json));
                }
            }
        }
    }

    /// What the live pages were sent so far.
    pub fn stats(&self) -> FrameStats {
        self.app
            .live
            .as_ref()
            .map_or_else(FrameStats::default, |l| *l.stats())
    }

    /// The last step's frame, once the run has ended.
    pub fn finish(&self) {
        let t = lock(&self.app.timeline);
        if let (Some(step), Some(live)) = (t.latest(), &self.app.live) {
            let mut framed = live.framed();
            if *framed == Some(step) {
                return;
            }
            *framed = Some(step);
            if let Ok(json) = serde_json::to_string(&t.frame(step, false)) {
                let _ = live.frames.send(Arc::new(json));
            }
        }
    }
}

/// A viewer being served.
pub struct Viewer {
    pub addr: SocketAddr,
    task: tokio::task::JoinHandle<()>,
}

impl Viewer {
    pub fn stop(self) {
        self.task.abort();
    }
}

/// A planning grid with its frontier cells in red and the cells it believes free that are not
/// free in the world in magenta.
fn png_of(
    g: &Grid,
    header: &Header,
    frontiers: &[proto::grid::Cell],
    false_free: &[proto::grid::Cell],
) -> anyhow::Result<Vec<u8>> {
    let mut p = Picture::of_grid(g, header.map);
    for &c in false_free {
        p.cell(c, [200, 0, 200]);
    }
    for &c in frontiers {
        p.cell(c, [220, 30, 30]);
    }
    p.png()
}

async fn start(app: Arc<App>, addr: SocketAddr) -> anyhow::Result<Viewer> {
    let listener = TcpListener::bind(addr)
        .await
        .with_context(|| format!("the viewer cannot listen on {addr}"))?;
    let addr = listener.local_addr()?;
    let router = Router::new()
        .route(
            "/",
            get(|| async { ([(CONTENT_TYPE, "text/html; charset=utf-8")], INDEX) }),
        )
        .route(
            "/app.js",
            get(|| async { ([(CONTENT_TYPE, "text/javascript")], APP) }),
        )
        .route(
            "/style.css",
            get(|| async { ([(CONTENT_TYPE, "text/css")], STYLE) }),
        )
        .route("/api/info", get(info))
        .route("/api/truth.png", get(truth))
        .route("/api/series", get(series))
        .route("/api/frame/{step}", get(frame))
        .route("/api/robot/{id}", get(robot))
        .route("/api/robot/{id}/grid.png", get(robot_grid))
        .route("/api/robot/{id}/polygons", get(robot_polygons))
        .route("/api/link/{name}", post(link))
        .route("/api/clock/{order}", post(clock))
        .route("/ws", get(ws))
        .fallback(|| async { (StatusCode::NOT_FOUND, "not found") })
        .with_state(app);
    let task = tokio::spawn(async move {
        if let Err(e) = axum::serve(listener, router).await {
            tracing::warn!("the viewer stopped: {e}");
        }
    });
    Ok(Viewer { addr, task })
}

/// The live viewer of a run that is starting: serve on `addr`; the launcher feeds it.
pub async fn live(
    addr: SocketAddr,
    header: Header,
    netem: NetemApi,
    sim: zenoh::Session,
) -> anyhow::Result<(Viewer, Feed)> {
    let (frames, _) = broadcast::channel(FRAMES_QUEUED);
    let app = Arc::new(App {
        truth_png: truth_png(&header)?,
        timeline: Mutex::new(Timeline::new(header)),
        live: Some(Live {
            frames,
            netem,
            sim,
            paused: false.into(),
            stats: Mutex::default(),
            framed: Mutex::default(),
        }),
    });
    let viewer = start(Arc::clone(&app), addr).await?;
    Ok((viewer, Feed { app }))
}

/// `swarm view RUN_DIR`: serves the replay until interrupted.
pub async fn replay(args: &ViewArgs) -> anyhow::Result<()> {
    let log = crate::rundir::steplog::read(&args.run_dir)?;
    if let Some(w) = log.cut_warning(&args.run_dir) {
        eprintln!("swarm: {w}");
    }
    if !(args.rate.is_finite() && args.rate > 0.0) {
        anyhow::bail!("--rate {}: steps per second must be above 0", args.rate);
    }
    let foxglove = match args.foxglove {
        Some(addr) => {
            let (tx, rx) = tokio::sync::oneshot::channel();
            let (log, rate) = (log.clone(), args.rate);
            let name = format!("swarm-explore replay: {}", args.run_dir.display());
            let task = tokio::spawn(async move {
                crate::view::foxglove::Server::replay(addr, &log, rate, &name, |a| {
                    let _ = tx.send(a);
                })
                .await
            });
            match rx.await {
                Ok(a) => println!("Foxglove WebSocket replay at ws://{a}"),
                Err(_) => return task.await?,
            }
            Some(task)
        }
        None => None,
    };
    let app = Arc::new(App {
        truth_png: truth_png(&log.header)?,
        timeline: Mutex::new(Timeline::of(log.header, log.records)),
        live: None,
    });
    let viewer = start(app, args.addr).await?;
    println!(
        "replay of {} at http://{}/",
        args.run_dir.display(),
        viewer.addr
    );
    tokio::signal::ctrl_c().await?;
    viewer.stop();
    if let Some(t) = foxglove {
        t.abort();
    }
    Ok(())
}

/// `swarm view`: serves the replay until Ctrl-C.
pub async fn command(args: ViewArgs) -> anyhow::Result<std::process::ExitCode> {
    replay(&args).await?;
    Ok(std::process::ExitCode::SUCCESS)
}

fn truth_png(h: &Header) -> anyhow::Result<Vec<u8>> {
    png_of(&h.truth(), h, &[], &[])
}

type Shared = State<Arc<App>>;

fn json<T: serde::Serialize>(v: &T) -> Response {
    match serde_json::to_vec(v) {
        Ok(b) => ([(CONTENT_TYPE, "application/json")], b).into_response(),
        Err(e) => (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()).into_response(),
    }
}

fn not_found(what: String) -> Response {
    (StatusCode::NOT_FOUND, what).into_response()
}

async fn info(State(app): Shared) -> Response {
    let t = lock(&app.timeline);
    let (first, last) = t.span().unwrap_or((0, 0));
    json(&serde_json::json!({
        "live": app.live.is_some(),
        "paused": app.live.as_ref().is_some_and(|l| l.paused.load(Ordering::Relaxed)),
        "robots": t.header.robots,
        "map": t.header.map,
        "step_seconds": t.header.step_seconds,
        "first_step": first,
        "last_step": last,
        "palette": crate::rundir::render::palette_css(),
    }))
}

async fn truth(State(app): Shared) -> Response {
    ([(CONTENT_TYPE, "image/png")], app.truth_png.clone()).into_response()
}

async fn series(State(app): Shared) -> Response {
    json(lock(&app.timeline).series())
}

async fn frame(State(app): Shared, Path(step): Path<String>) -> Response {
    let t = lock(&app.timeline);
    let step = match step.as_str() {
        "latest" => t.latest(),
        s => s.parse::<Step>().ok(),
    };
    match step {
        Some(s) => json(&t.frame(s, true)),
        None => not_found("no such step (a number, or latest once the run has reported)".into()),
    }
}

#[derive(serde::Deserialize)]
struct AtStep {
    step: Option<Step>,
}

/// The robot `id` names in this run (the base station included); else why not (a 404).
fn robot_id(t: &Timeline, id: &str) -> Result<RobotId, String> {
    id.parse()
        .ok()
        .filter(|&i| i <= t.header.robots)
        .ok_or_else(|| format!("no robot {id:?} in this run"))
}

/// The robot `id` names in this run, and the step asked for (default: the latest); else why
/// not (a 404).
fn robot_at(t: &Timeline, id: &str, q: &AtStep) -> Result<(RobotId, Step), String> {
    let id = robot_id(t, id)?;
    let step = q.step.or(t.latest()).ok_or("no step yet")?;
    Ok((id, step))
}

async fn robot(State(app): Shared, Path(id): Path<String>, Query(q): Query<AtStep>) -> Response {
    let t = lock(&app.timeline);
    let (id, step) = match robot_at(&t, &id, &q) {
        Ok(x) => x,
        Err(why) => return not_found(why),
    };
    match t.robot(id, step) {
        Some(d) => json(&d),
        None => not_found(format!("robot {id} has not reported by step {step}")),
    }
}

async fn robot_grid(
    State(app): Shared,
    Path(id): Path<String>,
    Query(q): Query<AtStep>,
) -> Response {
    let (grid, header) = {
        let t = lock(&app.timeline);
        let (id, step) = match robot_at(&t, &id, &q) {
            Ok(x) => x,
            Err(why) => return not_found(why),
        };
        match t.grid(id, step) {
            Some(g) => (g, t.header.clone()),
            None => return not_found(format!("robot {id} has not reported by step {step}")),
        }
    };
    let false_free = false_free_cells(&grid, &header.truth());
    match png_of(&grid, &header, &frontiers(&grid), &false_free) {
        Ok(png) => ([(CONTENT_TYPE, "image/png")], png).into_response(),
        Err(e) => (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()).into_response(),
    }
}

/// `GET /api/robot/{id}/polygons` (live only): what the robot holds of every owner's polygonal
/// approximation, asked of the robot itself ([`keys::held`]), its vertices in metres. Only the
/// robot has it — the step log keeps digests, not polygons — so a replay answers 409.
async fn robot_polygons(State(app): Shared, Path(id): Path<String>) -> Response {
    let Some(live) = &app.live else {
        return (
            StatusCode::CONFLICT,
            "polygons are asked of the live robots; a replay has only their digests",
        )
            .into_response();
    };
    let (id, map) = {
        let t = lock(&app.timeline);
        match robot_id(&t, &id) {
            Ok(id) => (id, t.header.map),
            Err(why) => return not_found(why),
        }
    };
    match proto::node::query_once::<proto::msg::Held>(&live.sim, &keys::held(id)).await {
        Ok(Some(held)) if held.robot == id => json(&held_json(&held, &map)),
        Ok(Some(held)) => (
            StatusCode::BAD_GATEWAY,
            format!("robot {id}'s key was answered for robot {}", held.robot),
        )
            .into_response(),
        Ok(None) => (
            StatusCode::GATEWAY_TIMEOUT,
            format!("robot {id} did not answer (its process is down, or busy with a step)"),
        )
            .into_response(),
        Err(e) => (StatusCode::BAD_GATEWAY, e.to_string()).into_response(),
    }
}

/// What a robot holds, for the page: per owner (the robot and its life), ops held and shown,
/// and each polygon's vertices in metres with f_occ of the edge from each (`o`ccupied,
/// `f`ree, `u`nknown).
fn held_json(h: &proto::msg::Held, map: &proto::geom::MapInfo) -> serde_json::Value {
    let metres = |q: i32, origin: f64| origin + f64::from(q) / 4.0 * map.resolution_m;
    let owners: Vec<serde_json::Value> = h
        .owners
        .iter()
        .map(|o| {
            let (robot, life) = proto::msg::owner_life(o.owner);
            let polygons: Vec<serde_json::Value> = o
                .polygons
                .iter()
                .map(|p| {
                    let points: Vec<[f64; 2]> = p
                        .vertices
                        .iter()
                        .map(|&(x, y, _)| [metres(x, map.origin_x_m), metres(y, map.origin_y_m)])
                        .collect();
                    let occ: String = p
                        .vertices
                        .iter()
                        .map(|&(_, _, o)| match o {
                            Occ::Occupied => 'o',
                            Occ::Free => 'f',
                            Occ::Unknown => 'u',
                        })
                        .collect();
                    serde_json::json!({ "outside": p.outside, "points": points, "occ": occ })
                })
                .collect();
            serde_json::json!({
                "owner": o.owner, "robot": robot, "life": life,
                "held": o.held, "shown": o.shown, "polygons": polygons,
            })
        })
        .collect();
    serde_json::json!({ "robot": h.robot, "step": h.step, "owners": owners })
}

/// What a click on a link asks for.
#[derive(serde::Deserialize)]
struct LinkAction {
    enabled: Option<bool>,
    bandwidth_bytes_per_s: Option<u64>,
    latency_ms: Option<u64>,
}

/// Forwards a link action to netem's API: `enabled` as a proxy update, a bandwidth or latency
/// as the viewer's own toxic on the link (created, or updated if it is there).
/// `POST /api/clock/{pause|resume|step}`: the order goes to the world-server on the sim plane;
/// a pause holds the step after the one under way.
async fn clock(State(app): Shared, Path(order): Path<String>) -> Response {
    let Some(live) = &app.live else {
        return (StatusCode::CONFLICT, "a replay has no clock to hold").into_response();
    };
    let (c, paused) = match order.as_str() {
        "pause" => (Control::Pause, true),
        "resume" => (Control::Resume, false),
        "step" => (Control::Step, true),
        _ => return not_found(format!("no clock order {order:?} (pause, resume, step)")),
    };
    if let Err(e) = live
        .sim
        .put(keys::CONTROL, encode(&c))
        .congestion_control(CongestionControl::Block)
        .await
    {
        return (
            StatusCode::SERVICE_UNAVAILABLE,
            format!("the sim plane did not take the order: {e}"),
        )
            .into_response();
    }
    live.paused.store(paused, Ordering::Relaxed);
    json(&serde_json::json!({ "paused": paused }))
}

async fn link(State(app): Shared, Path(name): Path<String>, body: axum::body::Bytes) -> Response {
    let Some(Live { netem: api, .. }) = &app.live else {
        return (StatusCode::CONFLICT, "a replay has no links to change").into_response();
    };
    let a: LinkAction = match serde_json::from_slice(&body) {
        Ok(a) => a,
        Err(e) => {
            return (StatusCode::BAD_REQUEST, format!("bad request body: {e}")).into_response()
        }
    };
    if !name.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'-') {
        return not_found(format!("no link {name:?}"));
    }
    let (path, body, update): NetemCall = match a {
        LinkAction {
            enabled: Some(on), ..
        } => (
            format!("/proxies/{name}"),
            serde_json::json!({ "enabled": on }).to_string(),
            None,
        ),
        LinkAction {
            bandwidth_bytes_per_s: Some(rate),
            ..
        } => toxic(
            &name,
            "viewer_bandwidth",
            "bandwidth",
            serde_json::json!({ "rate_bytes_per_s": rate }),
        ),
        LinkAction {
            latency_ms: Some(ms),
            ..
        } => toxic(
            &name,
            "viewer_latency",
            "latency",
            serde_json::json!({ "latency": ms }),
        ),
        _ => {
            return (
                StatusCode::BAD_REQUEST,
                "say enabled, bandwidth_bytes_per_s or latency_ms",
            )
                .into_response()
        }
    };
    let api = api.clone();
    let answer = tokio::task::spawn_blocking(move || -> anyhow::Result<(u16, String)> {
        let answer =
            crate::cmd::netemctl::http(api.addr, api.token.as_deref(), "POST", &path, &body)?;
        match (answer.0, update) {
            // The toxic is there already: update it.
            (409, Some((path, body))) => {
                crate::cmd::netemctl::http(api.addr, api.token.as_deref(), "PATCH", &path, &body)
            }
            _ => Ok(answer),
        }
    })
    .await;
    match answer {
        Ok(Ok((status, text))) => (
            StatusCode::from_u16(status).unwrap_or(StatusCode::BAD_GATEWAY),
            [(CONTENT_TYPE, "application/json")],
            text,
        )
            .into_response(),
        Ok(Err(e)) => (StatusCode::BAD_GATEWAY, format!("{e:#}")).into_response(),
        Err(e) => (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()).into_response(),
    }
}

/// A POST to netem's API (path, body), and the PATCH (path, body) to send instead if it
/// answers `409` (the toxic is there already).
type NetemCall = (String, String, Option<(String, String)>);

/// A toxic POST for link `link`, and the PATCH that updates it if it exists.
fn toxic(link: &str, name: &str, kind: &str, attributes: serde_json::Value) -> NetemCall {
    (
        format!("/proxies/{link}/toxics"),
        serde_json::json!({ "name": name, "type": kind, "attributes": attributes }).to_string(),
        Some((
            format!("/proxies/{link}/toxics/{name}"),
            serde_json::json!({ "attributes": attributes }).to_string(),
        )),
    )
}

async fn ws(State(app): Shared, upgrade: WebSocketUpgrade) -> Response {
    let Some(Live { frames, .. }) = &app.live else {
        return (StatusCode::CONFLICT, "a replay has no live frames").into_response();
    };
    let rx = frames.subscribe();
    let app = Arc::clone(&app);
    upgrade.on_upgrade(move |socket| send_frames(socket, rx, app))
}

/// Sends every frame it gets; a lagging page skips what it missed.
async fn send_frames(
    mut socket: WebSocket,
    mut rx: broadcast::Receiver<Arc<String>>,
    app: Arc<App>,
) {
    let Some(live) = &app.live else { return };
    loop {
        match rx.recv().await {
            Ok(f) => {
                if socket.send(Message::Text(f.as_str().into())).await.is_err() {
                    return;
                }
                live.stats().sent_one();
            }
            Err(broadcast::error::RecvError::Lagged(n)) => live.stats().skipped += n,
            Err(broadcast::error::RecvError::Closed) => {
                let _ = socket.send(Message::Close(None)).await;
                return;
            }
        }
    }
}
