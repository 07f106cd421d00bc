//! netem on the sim plane: follows the world-server's per-step status (robot poses) to drive the
//! simulated clock and every link's radio verdict, and publishes a
//! [`LinkReport`](proto::msg::LinkReport) per step for the launcher's `links.csv`; hands the
//! process faults its API is asked for on to the launcher. Thin adapter over
//! [`crate::netem::Netem`]; no link logic here.

use std::time::Duration;

use proto::grid::Grid;
use proto::keys;
use proto::msg::{
    decode, encode, Control, LinkCut, LinkReport, LinkState, ProcessOrder, Status, Step, TruthMap,
};
use proto::node::{zerr, ZenohError};
use proto::scenario::{RadioModel, Scenario};
use tokio::sync::mpsc;
use zenoh::qos::CongestionControl;
use zenoh::sample::SampleKind;
use zenoh::Session;

use crate::link::DownReason;
use crate::netem::Netem;
use crate::telemetry::LinkTelemetry;

/// The truth map (for path-loss wall counts), asked of the world-server.
pub async fn fetch_truth(
    sim: &Session,
    wait: Duration,
) -> Result<(proto::geom::MapInfo, Grid), ZenohError> {
    let t: TruthMap = proto::node::query_retry(sim, keys::WORLD_TRUTH, wait).await?;
    let g = Grid::from_rle(&t.grid_rle).map_err(|e| ZenohError(format!("truth map: {e}")))?;
    Ok((t.map, g))
}

/// Whether the scenario's radio model needs the truth map.
pub fn needs_truth(s: &Scenario) -> bool {
    s.radio.model == RadioModel::Pathloss
}

fn state(t: &LinkTelemetry) -> LinkState {
    LinkState {
        a: t.a,
        b: t.b,
        up: t.up,
        distance_m: t.distance_m,
        bytes_a_to_b: t.bytes_a_to_b,
        bytes_b_to_a: t.bytes_b_to_a,
        bytes_total: t.bytes_a_to_b_total + t.bytes_b_to_a_total,
        queued_bytes: t.queued_bytes,
        connected: t.connections > 0,
        cut: cut(t),
        air: t.air,
    }
}

/// Why the link carries nothing, for the launcher (and the viewer).
fn cut(t: &LinkTelemetry) -> Option<LinkCut> {
    match t.down_reason {
        _ if t.up && t.held => Some(LinkCut::Blackhole),
        _ if t.up => None,
        Some(DownReason::Disabled) => Some(LinkCut::Fault),
        Some(DownReason::Dead) => Some(LinkCut::Dead),
        Some(DownReason::OutOfRange | DownReason::NoPose) | None => Some(LinkCut::Range),
    }
}

/// Follows the run until the world-server or the launcher ends it; hands the process faults
/// the API was asked for (`orders`) on to the launcher.
pub async fn follow(
    sim: &Session,
    netem: &Netem,
    mut orders: mpsc::Receiver<ProcessOrder>,
) -> Result<(), ZenohError> {
    let statuses = sim.declare_subscriber(keys::STATUS).await.map_err(zerr)?;
    let ctl = sim.declare_subscriber(keys::CONTROL).await.map_err(zerr)?;
    let world = sim
        .liveliness()
        .declare_subscriber(keys::WORLD_ALIVE)
        .history(true)
        .await
        .map_err(zerr)?;
    // Declared after the subscriptions: a robot that sees it knows netem will see the world's
    // first status (and publish the first step's links).
    let _alive = sim
        .liveliness()
        .declare_token(keys::NETEM_ALIVE)
        .await
        .map_err(zerr)?;
    let mut last: Option<Step> = None;
    loop {
        tokio::select! {
            // Statuses first: the world's last status (at its step limit) closes the last step
            // and is followed at once by the world's exit; taken in random order, netem would
            // sometimes leave before reporting that step's links.
            biased;
            s = statuses.recv_async() => {
                let Ok(s) = s else { return Ok(()) };
                let st = match decode::<Status>(&s.payload().to_bytes()) {
                    Ok(st) => st,
                    Err(e) => { tracing::warn!("bad status: {e}"); continue; }
                };
                // Opening this step closes the previous one: its links' state and bytes.
                // The base station is a node like a robot (it only never moves).
                let poses: Vec<_> = st.robots.iter().chain(&st.base).map(|r| (r.id, r.pose, r.alive)).collect();
                let rows = netem.advance(st.step, &poses);
                // The step's links first: lockstep robots wait for them before they act. Each
                // node gets its own (the whole plan to every robot was n³ bytes a step).
                for (id, plan) in netem.plan().split(poses.iter().map(|p| p.0)) {
                    sim.put(keys::plan(id), encode(&plan)).congestion_control(CongestionControl::Block).await.map_err(zerr)?;
                }
                if let (Some(prev), false) = (last, rows.is_empty()) {
                    let report = LinkReport { step: prev, links: rows.iter().map(state).collect(), nodes: netem.nodes_air() };
                    sim.put(keys::NETEM_LINKS, encode(&report)).congestion_control(CongestionControl::Block).await.map_err(zerr)?;
                }
                last = Some(st.step);
            }
            Some(o) = orders.recv() => {
                tracing::info!(process = %o.process, order = ?o.order, "process fault asked for through the API");
                sim.put(keys::PROCESS_ORDERS, encode(&o)).congestion_control(CongestionControl::Block).await.map_err(zerr)?;
            }
            c = ctl.recv_async() => {
                if matches!(c.map(|c| decode::<Control>(&c.payload().to_bytes())), Ok(Ok(Control::Stop)) | Err(_)) {
                    return Ok(());
                }
            }
            w = world.recv_async() => {
                if w.map_or(true, |w| w.kind() == SampleKind::Delete) {
                    return Ok(());
                }
            }
        }
    }
}
