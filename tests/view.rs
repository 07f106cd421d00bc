//! The run viewer over HTTP: `swarm run --view` serves the page and its data while the run goes
//! on; a link cut from the viewer reaches netem (its `/proxies` shows it disabled, `links.csv`
//! shows it down from then on); the page's pause holds the step clock, a single step lets one
//! step through, resume lets the run go on; a robot's polygons are asked of the robot; a robot
//! the run does not have is a 404; `swarm view`
//! of a finished run serves the same page, and of a foreign directory fails naming `steps.log`.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use swarm::cmd::netemctl::http;

use crate::support::{ended_with_link_down, fails_naming, viewed_run, TempDir};

fn get(addr: SocketAddr, path: &str) -> (u16, String) {
    http(addr, None, "GET", path, "").unwrap_or_else(|e| panic!("GET {path}: {e:#}"))
}

/// A GET's whole answer, head and body, as bytes.
fn get_bytes(addr: SocketAddr, path: &str) -> Vec<u8> {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(addr).expect("connect");
    s.set_read_timeout(Some(Duration::from_secs(10)))
        .expect("timeout");
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"
    )
    .expect("write");
    let mut out = Vec::new();
    s.read_to_end(&mut out).expect("read");
    out
}

#[test]
fn the_live_viewer_serves_the_run_and_cuts_a_link_through_netem() {
    let dir = TempDir::new("view");
    // 10 steps a second: time to act on the page while the run goes on.
    let (launcher, run, view, netem) = viewed_run(
        &dir,
        &[
            "world.width_m=14",
            "world.height_m=10",
            "clock.step_seconds=0.1",
            "max_steps=150",
        ],
    );

    let (st, page) = get(view, "/");
    assert_eq!(st, 200);
    assert!(
        page.contains("swarm-explore") && page.contains("/app.js"),
        "{page}"
    );
    let (st, info) = get(view, "/api/info");
    assert_eq!(st, 200);
    let info: serde_json::Value = serde_json::from_str(&info).expect("JSON");
    assert_eq!(
        (info["live"].as_bool(), info["robots"].as_u64()),
        (Some(true), Some(3))
    );
    // The page draws robots in the colours of every picture, plot and MCAP file (it once had
    // a palette of its own: robot 1 was blue in truth.png and green on the page).
    let palette: Vec<String> = swarm::rundir::render::palette_css();
    assert_eq!(info["palette"], serde_json::json!(palette));
    for path in [
        "/api/robot/9",
        "/api/robot/x",
        "/api/robot/9/grid.png",
        "/nothing",
    ] {
        assert_eq!(get(view, path).0, 404, "{path}");
    }

    // Once a step is in: the frame, a robot's grid, then the cut.
    let deadline = Instant::now() + Duration::from_secs(60);
    let step = loop {
        let (st, body) = get(view, "/api/frame/latest");
        if st == 200 {
            let f: serde_json::Value = serde_json::from_str(&body).expect("JSON");
            if f["step"].as_u64().is_some_and(|s| s >= 5) {
                assert_eq!(f["robots"].as_array().map(Vec::len), Some(3), "{f}");
                break f["step"].as_u64().expect("a step");
            }
        }
        assert!(Instant::now() < deadline, "no frame from the viewer");
        std::thread::sleep(Duration::from_millis(100));
    };
    let png = get_bytes(view, "/api/robot/1/grid.png");
    assert!(
        png.starts_with(b"HTTP/1.1 200"),
        "{:?}",
        String::from_utf8_lossy(&png[..png.len().min(200)])
    );
    assert!(png.windows(4).any(|w| w == b"\x89PNG"), "a PNG");
    let (st, robot) = get(view, "/api/robot/1");
    assert_eq!(st, 200);
    let robot: serde_json::Value = serde_json::from_str(&robot).expect("JSON");
    assert_eq!(robot["robot"], 1, "{robot}");
    let (st, _) = http(
        view,
        None,
        "POST",
        "/api/link/r0-r1",
        r#"{"enabled":false}"#,
    )
    .expect("POST");
    assert_eq!(st, 200);
    let (_, proxy) = get(netem, "/proxies/r0-r1");
    let proxy: serde_json::Value = serde_json::from_str(&proxy).expect("JSON");
    assert_eq!(proxy["enabled"], false, "{proxy}");
    assert_eq!(
        http(view, None, "POST", "/api/link/r0-r1", r#"{"nothing":1}"#)
            .expect("POST")
            .0,
        400
    );

    // The page's clock: a pause holds the next step, a single step lets one through, resume
    // lets the run go on; an order the clock does not know is a 404.
    let post = |path: &str| http(view, None, "POST", path, "").expect("POST").0;
    let latest = || -> u64 {
        let (_, body) = get(view, "/api/frame/latest");
        let f: serde_json::Value = serde_json::from_str(&body).expect("JSON");
        f["step"].as_u64().expect("a step")
    };
    let wait_for = |want: &dyn Fn(u64) -> bool, what: &str| {
        let deadline = Instant::now() + Duration::from_secs(20);
        while !want(latest()) {
            assert!(
                Instant::now() < deadline,
                "{what}: still at step {}",
                latest()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    };
    assert_eq!(post("/api/clock/pause"), 200);
    std::thread::sleep(Duration::from_millis(800));
    let held = latest();
    std::thread::sleep(Duration::from_millis(1500));
    assert_eq!(latest(), held, "paused at step {held}");
    // What a robot holds, asked of the robot: its own polygons first, every vertex on the map.
    let (st, body) = get(view, "/api/robot/0/polygons");
    assert_eq!(st, 200, "{body}");
    let polygons: serde_json::Value = serde_json::from_str(&body).expect("JSON");
    assert_eq!(polygons["robot"], 0, "{polygons}");
    let owners = polygons["owners"].as_array().expect("owners");
    assert_eq!(
        owners[0]["robot"], 0,
        "its own approximation first: {polygons}"
    );
    assert!(owners[0]["held"].as_u64() > Some(0), "{polygons}");
    let own = owners[0]["polygons"].as_array().expect("polygons");
    assert!(
        !own.is_empty(),
        "robot 0 has no polygons after {held} steps"
    );
    for p in owners
        .iter()
        .flat_map(|o| o["polygons"].as_array().expect("polygons"))
    {
        let points = p["points"].as_array().expect("points");
        assert_eq!(Some(points.len()), p["occ"].as_str().map(str::len), "{p}");
        for xy in points {
            let (x, y) = (xy[0].as_f64().expect("x"), xy[1].as_f64().expect("y"));
            assert!(
                (0.0..=14.0).contains(&x) && (0.0..=10.0).contains(&y),
                "{xy} off the map"
            );
        }
    }
    for o in owners {
        assert!(o["shown"].as_u64() <= o["held"].as_u64(), "{o}");
    }
    assert_eq!(get(view, "/api/robot/9/polygons").0, 404);
    assert_eq!(post("/api/clock/step"), 200);
    wait_for(&|s| s > held, "one step");
    std::thread::sleep(Duration::from_millis(1000));
    assert_eq!(
        latest(),
        held + 1,
        "one step after step {held}, then paused"
    );
    assert_eq!(post("/api/clock/resume"), 200);
    wait_for(&|s| s > held + 3, "resumed");
    assert_eq!(post("/api/clock/rewind"), 404);

    // From a step after the cut on, links.csv has r0-r1 down.
    ended_with_link_down(launcher, &run, (0, 1), step);

    // The replay of the finished run; a foreign directory fails naming the file.
    fails_naming(&["view", "--addr", "127.0.0.1:0"], dir.path(), "steps.log");
}
