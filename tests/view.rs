//! The run viewer over HTTP: `swarm run --view` serves the page and its data while the run goes
//! on; a link cut from the viewer reaches netem (its `/proxies` shows it disabled, `links.csv`
//! shows it down from then on); a robot the run does not have is a 404; `swarm view` of a
//! finished run serves the same page, and of a foreign directory fails naming `steps.log`.

use std::net::SocketAddr;
use std::process::Command;
use std::time::{Duration, Instant};

use swarm::netemctl::http;

use crate::support::{csv, fails_naming, run_args, stderr, wait_file, Launcher, TempDir, SWARM};

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
    let run = dir.path().join("run");
    let mut cmd = Command::new(SWARM);
    run_args(
        &mut cmd,
        &run,
        &[
            "world.map=office",
            "world.width_m=14",
            "world.height_m=10",
            "robots.count=3",
            "radio.model=always",
            // Realtime, 10 steps a second: time to act on the page while the run goes on.
            "clock.mode=realtime",
            "clock.step_seconds=0.1",
            "max_steps=150",
            "done_pct=100",
        ],
    );
    cmd.arg("--view");
    let launcher = Launcher::spawn(cmd);
    let view: SocketAddr = wait_file(&run.join("view.addr"), Duration::from_secs(60))
        .parse()
        .expect("view.addr holds an address");
    let netem: SocketAddr = wait_file(&run.join("netem.addr"), Duration::from_secs(60))
        .parse()
        .expect("netem.addr holds an address");

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
    assert_eq!(robot["id"], 1, "{robot}");
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

    let out = launcher.wait_output(Duration::from_secs(120));
    assert!(
        out.status.code().is_some_and(|c| c == 0 || c == 2),
        "{}",
        stderr(&out)
    );
    // From a step after the cut on, links.csv has r0-r1 down.
    let rows: Vec<_> = csv(&run.join("links.csv"))
        .into_iter()
        .filter(|r| r["a"] == "0" && r["b"] == "1")
        .filter(|r| r["step"].parse::<u64>().is_ok_and(|s| s > step + 3))
        .collect();
    assert!(!rows.is_empty(), "links.csv goes on after the cut");
    let up: Vec<&String> = rows
        .iter()
        .filter(|r| r["up"] != "0")
        .map(|r| &r["step"])
        .collect();
    assert!(
        up.is_empty(),
        "r0-r1 up after the cut at step {step}: steps {up:?}"
    );

    // The replay of the finished run; a foreign directory fails naming the file.
    fails_naming(&["view", "--addr", "127.0.0.1:0"], dir.path(), "steps.log");
}
