//! The viewer's page in a real browser: headless Chromium driven over WebDriver (Debian's
//! `chromium` and `chromium-driver`, through the fantoccini client).
//!
//! A live run (`swarm run --view`): the page loads; a robot moves between two screenshots (its
//! colour is drawn where the viewer's frame of each screenshot's step puts it, and gone from the
//! first place in the second); "pause" holds the run (the page's step stays); a click on a link
//! and on its panel's "cut" button cuts it (netem's `/proxies` shows it disabled, `links.csv`
//! shows it down from then on); a click on a robot shows its planning grid and lists the polygons
//! it holds (asked of the robot); "step" lets one step through, "resume" lets the run go on. The
//! replay of the finished run (`swarm view`): moving the slider seeks to a step, and every robot
//! is drawn where `metrics.csv` says it was at that step (polygons are a live run's: 409).
//!
//! Chromium is started with its networking limited to this machine: no host name resolves
//! (`--host-resolver-rules`), background services, updates and sync are off; the page is on a
//! loopback address.

use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use fantoccini::actions::{InputSource, MouseActions, PointerAction, MOUSE_BUTTON_LEFT};
use fantoccini::{Client, ClientBuilder, Locator};
use serde_json::{json, Value};
use swarm::cmd::netemctl::http;

use crate::support::{
    csv, ended_with_link_down, free_ports, num, viewed_run, Launcher, TempDir, SWARM,
};

/// A robot's disc on the page has a radius of 6 px: within 8 px of where it is drawn, at least
/// this many pixels have its colour (a disc's ~110 less its heading line and anti-aliased rim);
/// its target's square and dashed line, also in its colour, have fewer.
const DRAWN: usize = 50;
/// Fewer than this: the robot is not drawn there.
const NOT_DRAWN: usize = 20;

fn on_path(names: &[&str]) -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .flat_map(|d| names.iter().map(move |n| d.join(n)))
        .find(|p| p.is_file())
}

fn get_json(addr: SocketAddr, path: &str) -> Value {
    let (st, body) =
        http(addr, None, "GET", path, "").unwrap_or_else(|e| panic!("GET {path}: {e:#}"));
    assert_eq!(st, 200, "GET {path}: {body}");
    serde_json::from_str(&body).unwrap_or_else(|e| panic!("GET {path}: {e}: {body}"))
}

/// A screenshot, decoded.
struct Shot {
    width: usize,
    height: usize,
    rgb: Vec<[u8; 3]>,
}

impl Shot {
    fn decode(bytes: &[u8]) -> Shot {
        let mut d = png::Decoder::new(std::io::Cursor::new(bytes));
        d.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
        let mut r = d.read_info().expect("a PNG screenshot");
        let mut buf = vec![0; r.output_buffer_size()];
        let info = r.next_frame(&mut buf).expect("a PNG frame");
        let samples = info.color_type.samples();
        assert!(samples >= 3, "a colour screenshot: {:?}", info.color_type);
        let rgb = buf[..info.buffer_size()]
            .chunks_exact(samples)
            .map(|p| [p[0], p[1], p[2]])
            .collect();
        Shot {
            width: info.width as usize,
            height: info.height as usize,
            rgb,
        }
    }

    /// Pixels of colour `c` (each channel within 24) within `r` px of page point `(x, y)`.
    fn colour_near(&self, (x, y): (f64, f64), r: f64, c: [u8; 3]) -> usize {
        let mut n = 0;
        let (x0, x1) = ((x - r).floor().max(0.0) as usize, (x + r).ceil() as usize);
        let (y0, y1) = ((y - r).floor().max(0.0) as usize, (y + r).ceil() as usize);
        for py in y0..=y1.min(self.height.saturating_sub(1)) {
            for px in x0..=x1.min(self.width.saturating_sub(1)) {
                let d = (px as f64 + 0.5 - x).hypot(py as f64 + 0.5 - y);
                let p = self.rgb[py * self.width + px];
                let close = p.iter().zip(c).all(|(a, b)| a.abs_diff(b) <= 24);
                if d <= r && close {
                    n += 1;
                }
            }
        }
        n
    }
}

/// Where the page draws a point of the map: the map canvas's place on the page (its 1 px border
/// inside) and the page's scale (metres to pixels, the whole map fitted, y up).
struct Geometry {
    left: f64,
    top: f64,
    scale: f64,
    map_h_m: f64,
    origin: (f64, f64),
}

impl Geometry {
    async fn of(client: &Client, info: &Value) -> Geometry {
        let (x, y, w, h) = client
            .find(Locator::Id("map"))
            .await
            .expect("the map canvas")
            .rectangle()
            .await
            .expect("its rectangle");
        let m = &info["map"];
        let f = |k: &str| m[k].as_f64().unwrap_or_else(|| panic!("map.{k} in {info}"));
        let (map_w_m, map_h_m) = (
            f("width") * f("resolution_m"),
            f("height") * f("resolution_m"),
        );
        Geometry {
            left: x + 1.0,
            top: y + 1.0,
            scale: ((w - 2.0) / map_w_m).min((h - 2.0) / map_h_m),
            map_h_m,
            origin: (f("origin_x_m"), f("origin_y_m")),
        }
    }

    fn page(&self, (x, y): (f64, f64)) -> (f64, f64) {
        (
            self.left + (x - self.origin.0) * self.scale,
            self.top + (self.map_h_m - (y - self.origin.1)) * self.scale,
        )
    }
}

fn dist((ax, ay): (f64, f64), (bx, by): (f64, f64)) -> f64 {
    (ax - bx).hypot(ay - by)
}

/// Robot id → its place in a frame of the viewer.
fn robots_of(frame: &Value) -> Vec<(u64, (f64, f64))> {
    frame["robots"]
        .as_array()
        .unwrap_or_else(|| panic!("robots in {frame}"))
        .iter()
        .map(|r| {
            let f = |k: &str| r[k].as_f64().unwrap_or_else(|| panic!("{k} in {r}"));
            (r["id"].as_u64().expect("an id"), (f("x"), f("y")))
        })
        .collect()
}

/// The robots' colours, as the page draws them (`#rrggbb`, by id modulo their number).
async fn palette(client: &Client) -> Vec<[u8; 3]> {
    let v = client
        .execute("return COLOURS;", vec![])
        .await
        .expect("the page's palette");
    v.as_array()
        .expect("a list of colours")
        .iter()
        .map(|c| {
            let c = c.as_str().expect("a colour");
            let h = |i: usize| u8::from_str_radix(&c[i..i + 2], 16).expect("hex");
            [h(1), h(3), h(5)]
        })
        .collect()
}

async fn text(client: &Client, css: &str) -> Option<String> {
    client.find(Locator::Css(css)).await.ok()?.text().await.ok()
}

/// The step the page shows (`step N` in its header).
async fn shown_step(client: &Client) -> Option<u64> {
    text(client, "#step")
        .await?
        .strip_prefix("step ")?
        .parse()
        .ok()
}

/// Waits (at most `limit`) until the page shows a step `want` takes; that step.
async fn shown_step_until(
    client: &Client,
    limit: Duration,
    what: &str,
    want: impl Fn(u64) -> bool,
) -> u64 {
    let want = &want;
    until(limit, what, move || async move {
        shown_step(client).await.filter(|&s| want(s))
    })
    .await
}

/// Polls `f` every 100 ms until it gives something, at most `limit`.
async fn poll<T, F, Fut>(limit: Duration, mut f: F) -> Option<T>
where
    F: FnMut() -> Fut,
    Fut: std::future::Future<Output = Option<T>>,
{
    let deadline = Instant::now() + limit;
    loop {
        if let Some(t) = f().await {
            return Some(t);
        }
        if Instant::now() >= deadline {
            return None;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// [`poll`], failing the test when nothing came.
async fn until<T, F, Fut>(limit: Duration, what: &str, f: F) -> T
where
    F: FnMut() -> Fut,
    Fut: std::future::Future<Output = Option<T>>,
{
    poll(limit, f)
        .await
        .unwrap_or_else(|| panic!("no {what} within {limit:?}"))
}

/// Whether the side panel's title becomes `want` within 3 s.
async fn panel_shows(client: &Client, want: &str) -> bool {
    poll(Duration::from_secs(3), || async {
        (text(client, "#detail h3").await? == want).then_some(())
    })
    .await
    .is_some()
}

/// A screenshot of the page and the step it shows (the same before and after it was taken).
async fn shot(client: &Client) -> (u64, Shot) {
    until(
        Duration::from_secs(20),
        "a screenshot of one step",
        || async {
            let before = shown_step(client).await?;
            let png = client.screenshot().await.ok()?;
            (shown_step(client).await? == before).then(|| (before, Shot::decode(&png)))
        },
    )
    .await
}

/// With `SWARM_SCREENSHOTS=DIR` set, keeps a screenshot of the page as `DIR/NAME` (how the
/// pictures in docs/ were taken).
async fn keep(client: &Client, name: &str) {
    if let Some(dir) = std::env::var_os("SWARM_SCREENSHOTS") {
        let png = client.screenshot().await.expect("a screenshot");
        let path = Path::new(&dir).join(name);
        std::fs::write(&path, png).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    }
}

/// The viewer's frame of the step the page shows.
async fn shown_frame(client: &Client, view: SocketAddr) -> Value {
    let step = shown_step(client).await.expect("the page shows a step");
    get_json(view, &format!("/api/frame/{step}"))
}

/// A click on the element with id `id`.
async fn click_id(client: &Client, id: &str) {
    client
        .find(Locator::Id(id))
        .await
        .unwrap_or_else(|e| panic!("#{id}: {e}"))
        .click()
        .await
        .unwrap_or_else(|e| panic!("a click on #{id}: {e}"));
}

async fn click_at(client: &Client, (x, y): (f64, f64)) {
    let mouse = MouseActions::new("mouse".into())
        .then(PointerAction::MoveTo {
            duration: None,
            x: x.round(),
            y: y.round(),
        })
        .then(PointerAction::Down {
            button: MOUSE_BUTTON_LEFT,
        })
        .then(PointerAction::Up {
            button: MOUSE_BUTTON_LEFT,
        });
    client.perform_actions(mouse).await.expect("a click");
    client.release_actions().await.expect("release");
}

/// Chromium under chromedriver on a free port; the driver (and its browser) go with the guard.
async fn browser(dir: &Path) -> (Client, Launcher) {
    let missing = "the browser test needs Chromium and its WebDriver (Debian: apt install \
                   chromium chromium-driver)";
    let chromium = on_path(&["chromium", "chromium-browser"]).expect(missing);
    let driver = on_path(&["chromedriver"]).expect(missing);
    let port = free_ports(1)[0];
    let mut cmd = Command::new(driver);
    cmd.arg(format!("--port={port}"));
    let guard = Launcher::spawn(cmd);
    let url = format!("http://127.0.0.1:{port}");
    let profile = dir.join("chromium");
    let mut caps = serde_json::Map::new();
    caps.insert(
        "goog:chromeOptions".into(),
        json!({
            "binary": chromium,
            "args": [
                "--headless=new",
                "--no-sandbox",
                "--disable-gpu",
                "--disable-dev-shm-usage",
                "--window-size=1400,1100",
                "--force-device-scale-factor=1",
                "--hide-scrollbars",
                "--no-first-run",
                "--no-default-browser-check",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--disable-extensions",
                "--disable-default-apps",
                "--host-resolver-rules=MAP * ~NOTFOUND , EXCLUDE 127.0.0.1",
                format!("--user-data-dir={}", profile.display()),
            ],
        }),
    );
    let connector = hyper_util::client::legacy::connect::HttpConnector::new();
    let deadline = Instant::now() + Duration::from_secs(30);
    let client = loop {
        match ClientBuilder::new(connector.clone())
            .capabilities(caps.clone())
            .connect(&url)
            .await
        {
            Ok(c) => break c,
            Err(e) if Instant::now() < deadline => {
                let _ = e;
                tokio::time::sleep(Duration::from_millis(200)).await;
            }
            Err(e) => panic!("no WebDriver session at {url}: {e}"),
        }
    };
    (client, guard)
}

#[test]
#[ignore = "needs Chromium and chromedriver: apt install chromium chromium-driver"]
fn the_page_in_chromium_follows_the_run_cuts_a_link_and_replays() {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("a runtime");
    rt.block_on(page_test());
}

async fn page_test() {
    let dir = TempDir::new("browser");
    // 4 steps a second: a page to look at while the run goes on.
    let (launcher, run, view, netem) = viewed_run(
        &dir,
        &[
            "world.width_m=20",
            "world.height_m=14",
            "clock.speedup=4",
            "max_steps=400",
        ],
    );
    let (client, _driver) = browser(dir.path()).await;

    // The page loads and follows the run.
    client
        .goto(&format!("http://{view}/"))
        .await
        .expect("the page");
    let mode = until(Duration::from_secs(20), "the page's mode", || {
        text(&client, "#mode")
    })
    .await;
    assert!(mode.starts_with("live"), "{mode}");
    shown_step_until(
        &client,
        Duration::from_secs(60),
        "the page showing step 3",
        |s| s >= 3,
    )
    .await;
    let info = get_json(view, "/api/info");
    let geo = Geometry::of(&client, &info).await;
    // Robots only: links and trajectories are drawn in colours close to some robots'.
    click_id(&client, "links").await;
    click_id(&client, "trails").await;
    let colours = palette(&client).await;
    let colour = |id: u64| colours[id as usize % colours.len()];

    // A robot moves between two screenshots.
    let (s1, shot1) = shot(&client).await;
    let at1 = robots_of(&get_json(view, &format!("/api/frame/{s1}")));
    let deadline = Instant::now() + Duration::from_secs(40);
    let (s2, shot2, id, p1, p2) = loop {
        let (s2, shot2) = shot(&client).await;
        let at2 = robots_of(&get_json(view, &format!("/api/frame/{s2}")));
        let moved = at1.iter().find_map(|&(id, a)| {
            let (_, b) = at2.iter().find(|(j, _)| *j == id)?;
            let (pa, pb) = (geo.page(a), geo.page(*b));
            (dist(pa, pb) >= 20.0).then_some((id, pa, pb))
        });
        if let Some((id, p1, p2)) = moved {
            break (s2, shot2, id, p1, p2);
        }
        assert!(
            Instant::now() < deadline,
            "no robot moved 20 px from step {s1}"
        );
        tokio::time::sleep(Duration::from_millis(300)).await;
    };
    let c = colour(id);
    let (drawn1, drawn2, left) = (
        shot1.colour_near(p1, 8.0, c),
        shot2.colour_near(p2, 8.0, c),
        shot2.colour_near(p1, 8.0, c),
    );
    assert!(
        drawn1 >= DRAWN && drawn2 >= DRAWN && left < NOT_DRAWN,
        "robot {id}: at step {s1} {drawn1} px of its colour at {p1:?}, at step {s2} {drawn2} px \
         at {p2:?} and {left} px at the first place"
    );

    // The page's pause holds the run: the step it shows stays.
    click_id(&client, "pause").await;
    until(Duration::from_secs(10), "the page paused", || async {
        (text(&client, "#mode").await? == "live (paused)").then_some(())
    })
    .await;
    tokio::time::sleep(Duration::from_millis(1000)).await;
    let held = shown_step(&client).await.expect("a step");
    tokio::time::sleep(Duration::from_millis(1500)).await;
    assert_eq!(
        shown_step(&client).await,
        Some(held),
        "paused at step {held}"
    );

    // A click on a link (where no robot is), then on "cut".
    click_id(&client, "links").await;
    click_id(&client, "trails").await;
    let deadline = Instant::now() + Duration::from_secs(30);
    let (a, b, cut_step) = loop {
        let frame = shown_frame(&client, view).await;
        let at = robots_of(&frame);
        let place = |id: u64| at.iter().find(|(j, _)| *j == id).map(|(_, p)| geo.page(*p));
        let pick = frame["links"]
            .as_array()
            .into_iter()
            .flatten()
            .find_map(|l| {
                let (a, b) = (l["a"].as_u64()?, l["b"].as_u64()?);
                let (pa, pb) = (place(a)?, place(b)?);
                let mid = ((pa.0 + pb.0) / 2.0, (pa.1 + pb.1) / 2.0);
                let clear = at.iter().all(|(_, p)| dist(geo.page(*p), mid) > 16.0);
                (l["state"] == "up" && clear).then_some((a, b, mid))
            });
        if let Some((a, b, mid)) = pick {
            click_at(&client, mid).await;
            if panel_shows(&client, &format!("link r{a}-r{b}")).await {
                click_id(&client, "cut").await;
                break (a, b, shown_step(&client).await.expect("a step"));
            }
        }
        assert!(Instant::now() < deadline, "no link picked on the page");
        tokio::time::sleep(Duration::from_millis(300)).await;
    };
    let name = format!("r{a}-r{b}");
    until(
        Duration::from_secs(10),
        "netem's proxy disabled",
        || async {
            let p = get_json(netem, &format!("/proxies/{name}"));
            (p["enabled"] == false).then_some(())
        },
    )
    .await;

    // A click on a robot (away from the others) shows its planning grid.
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let at = robots_of(&shown_frame(&client, view).await);
        let pick = at.iter().find(|(id, p)| {
            at.iter()
                .all(|(j, q)| j == id || dist(geo.page(*p), geo.page(*q)) > 20.0)
        });
        if let Some(&(id, p)) = pick {
            click_at(&client, geo.page(p)).await;
            if panel_shows(&client, &format!("robot {id}")).await {
                let loaded = "const i = document.getElementById('grid'); \
                              return !!i && i.complete && i.naturalWidth > 0;";
                until(
                    Duration::from_secs(10),
                    "the planning grid's image",
                    || async { (client.execute(loaded, vec![]).await.ok()? == true).then_some(()) },
                )
                .await;
                // Its polygons, asked of the robot, listed in the panel (and drawn on the map).
                let listed = "const t = document.getElementById('held-table'); \
                              return t ? t.rows.length - 1 : 0;";
                until(
                    Duration::from_secs(20),
                    "the polygons the robot holds in its panel",
                    || async {
                        (client.execute(listed, vec![]).await.ok()?.as_u64()? >= 1).then_some(())
                    },
                )
                .await;
                keep(&client, "view-live.png").await;
                break;
            }
        }
        assert!(Instant::now() < deadline, "no robot picked on the page");
        tokio::time::sleep(Duration::from_millis(300)).await;
    }

    // One step, then the run goes on.
    assert_eq!(
        shown_step(&client).await,
        Some(held),
        "still paused at step {held}"
    );
    click_id(&client, "stepone").await;
    shown_step_until(&client, Duration::from_secs(10), "one step", |s| s > held).await;
    tokio::time::sleep(Duration::from_millis(1000)).await;
    assert_eq!(
        shown_step(&client).await,
        Some(held + 1),
        "one step from {held}"
    );
    click_id(&client, "pause").await;
    shown_step_until(&client, Duration::from_secs(20), "the run going on", |s| {
        s > held + 5
    })
    .await;

    // From a step after the cut on, links.csv has the pair down.
    ended_with_link_down(launcher, &run, (a, b), cut_step);

    // The replay: the slider seeks to a step with every robot in metrics.csv, apart on the page.
    let mut cmd = Command::new(SWARM);
    cmd.args(["view", "--addr", "127.0.0.1:0"]).arg(&run);
    let mut replay = Launcher::spawn(cmd);
    let stdout = replay
        .child
        .as_mut()
        .and_then(|c| c.stdout.take())
        .expect("swarm view's output");
    let mut line = String::new();
    BufReader::new(stdout)
        .read_line(&mut line)
        .expect("swarm view prints its address");
    let url = line
        .split_whitespace()
        .find(|w| w.starts_with("http://"))
        .unwrap_or_else(|| panic!("an address in {line:?}"))
        .to_string();
    // Polygons are the live robots' own: a replay has none to ask for.
    let addr: SocketAddr = url
        .trim_start_matches("http://")
        .trim_end_matches('/')
        .parse()
        .unwrap_or_else(|e| panic!("{url}: {e}"));
    let (st, why) = http(addr, None, "GET", "/api/robot/0/polygons", "").expect("GET polygons");
    assert_eq!(st, 409, "{why}");
    client.goto(&url).await.expect("the replay page");
    until(Duration::from_secs(20), "the replay's mode", || async {
        (text(&client, "#mode").await? == "replay").then_some(())
    })
    .await;
    // The replay's header has the slider: the map may sit elsewhere on the page.
    let geo = Geometry::of(&client, &info).await;
    click_id(&client, "links").await;
    click_id(&client, "trails").await;
    let metrics = csv(&run.join("metrics.csv"));
    let robots = 3;
    let mut steps: Vec<u64> = metrics.iter().map(|r| num(r, "step") as u64).collect();
    steps.dedup();
    let places = |step: u64| -> Vec<(u64, (f64, f64))> {
        metrics
            .iter()
            .filter(|r| num(r, "step") as u64 == step)
            .map(|r| (num(r, "robot") as u64, (num(r, "x"), num(r, "y"))))
            .collect()
    };
    let target = steps
        .iter()
        .rev()
        .copied()
        .find(|&s| {
            let at = places(s);
            at.len() == robots
                && at.iter().all(|(i, p)| {
                    at.iter()
                        .all(|(j, q)| i == j || dist(geo.page(*p), geo.page(*q)) > 20.0)
                })
        })
        .expect("a step with every robot apart");
    let seek = "const s = document.getElementById('slider'); s.value = arguments[0]; \
                s.dispatchEvent(new Event('input')); return Number(s.value);";
    let v = client
        .execute(seek, vec![json!(target)])
        .await
        .expect("moving the slider");
    assert_eq!(v, json!(target), "the slider takes step {target}");
    shown_step_until(
        &client,
        Duration::from_secs(20),
        "the replay at the step",
        |s| s == target,
    )
    .await;
    let (shown, replayed) = shot(&client).await;
    assert_eq!(shown, target);
    for (id, p) in places(target) {
        let n = replayed.colour_near(geo.page(p), 8.0, colour(id));
        assert!(
            n >= DRAWN,
            "replay at step {target}: robot {id} at {p:?} (metrics.csv) has {n} px of its colour"
        );
    }
    click_id(&client, "links").await;
    click_id(&client, "trails").await;
    keep(&client, "view-replay.png").await;
    client.close().await.expect("closing the browser");
}
