//! The robot on its two zenoh planes (docs/design.md §1): the sim plane (a client of the
//! world-server's router: scans in, commands and telemetry out) and the radio plane (a peer with
//! scouting off, linked only to the endpoints it was given: handshakes and log deltas). All
//! decisions are [`crate::agent::Agent`]'s; this module only moves bytes between zenoh and the agent
//! (the agent's radio encodes, decodes and counts them).

use std::time::Duration;

use proto::keys;
use proto::msg::{decode, encode, Control, RobotId, Scan, WorldInfo};
use proto::node::{zerr, ZenohError};
use proto::scenario::Scenario;
use zenoh::qos::CongestionControl;
use zenoh::sample::SampleKind;
use zenoh::Session;

use crate::agent::Agent;
use crate::radio::Outgoing;

/// Why the robot stopped.
#[derive(Debug, PartialEq, Eq)]
pub enum End {
    Stopped,
    /// No scan arrived for this long: the world is gone.
    WorldSilent,
    /// The world-server's liveliness token vanished.
    WorldGone,
}

/// Asks the world-server for [`WorldInfo`], retrying until `wait` has passed.
pub async fn world_info(sim: &Session, wait: Duration) -> Result<WorldInfo, ZenohError> {
    proto::node::query_retry(sim, keys::WORLD_INFO, wait).await
}

/// Puts encoded radio messages on the radio plane. A radio link may be gone at any moment:
/// messages are dropped rather than queued (`CongestionControl::Drop`); the exchange's
/// handshakes make losses harmless.
async fn send_radio(radio: &Session, out: Vec<Outgoing>) {
    for Outgoing { key, bytes, .. } in out {
        if let Err(e) = radio
            .put(&key, bytes)
            .congestion_control(CongestionControl::Drop)
            .await
        {
            tracing::debug!("radio put to {key} failed: {e}");
        }
    }
}

/// One step: the scan in, the motion command out to the world-server, then this step's radio
/// traffic, then the step's telemetry.
async fn step(
    agent: &mut Agent,
    id: RobotId,
    scan: &Scan,
    sim: &Session,
    radio: &Session,
) -> Result<(), ZenohError> {
    let cmd = agent.on_scan(scan);
    sim.put(keys::cmd(id), encode(&cmd))
        .congestion_control(CongestionControl::Block)
        .await
        .map_err(zerr)?;
    send_radio(radio, agent.radio_step()).await;
    sim.put(keys::telemetry(id), encode(&agent.telemetry()))
        .congestion_control(CongestionControl::Block)
        .await
        .map_err(zerr)
}

/// Runs one robot until the launcher stops it or the world falls silent.
pub async fn run_robot(
    id: RobotId,
    s: &Scenario,
    sim: Session,
    radio: Session,
    world: WorldInfo,
    idle_timeout: Duration,
) -> Result<End, ZenohError> {
    let mut agent = Agent::new(id, world, s);
    let scans = sim.declare_subscriber(keys::scan(id)).await.map_err(zerr)?;
    let ctl = sim.declare_subscriber(keys::CONTROL).await.map_err(zerr)?;
    let world_alive = sim
        .liveliness()
        .declare_subscriber(keys::WORLD_ALIVE)
        .history(true)
        .await
        .map_err(zerr)?;
    // Everything addressed to this robot on the radio, told apart by the key's last segment.
    let inbox = radio
        .declare_subscriber(keys::radio_inbox(id))
        .await
        .map_err(zerr)?;
    let peers = radio
        .liveliness()
        .declare_subscriber(keys::RADIO_ALIVE_ALL)
        .history(true)
        .await
        .map_err(zerr)?;
    let _radio_token = radio
        .liveliness()
        .declare_token(keys::radio_alive(id))
        .await
        .map_err(zerr)?;
    // Declared last: the world-server starts the clock once every robot's token is there, and by
    // then this robot's subscribers exist.
    let _sim_token = sim
        .liveliness()
        .declare_token(keys::sim_alive(id))
        .await
        .map_err(zerr)?;
    loop {
        tokio::select! {
            sample = scans.recv_async() => {
                let Ok(sample) = sample else { return Ok(End::Stopped) };
                match decode::<Scan>(&sample.payload().to_bytes()) {
                    Ok(scan) => step(&mut agent, id, &scan, &sim, &radio).await?,
                    Err(e) => tracing::warn!("bad scan: {e}"),
                }
            }
            sample = inbox.recv_async() => {
                let Ok(sample) = sample else { return Ok(End::Stopped) };
                let kind = keys::radio_kind(sample.key_expr().as_str()).unwrap_or_default();
                let out = agent.on_radio(kind, &sample.payload().to_bytes());
                send_radio(&radio, out).await;
            }
            sample = peers.recv_async() => {
                let Ok(sample) = sample else { return Ok(End::Stopped) };
                let Some(peer) = keys::robot_of(sample.key_expr().as_str()) else { continue };
                if sample.kind() == SampleKind::Put {
                    let out = agent.link_up(peer);
                    send_radio(&radio, out).await;
                } else {
                    agent.link_down(peer);
                }
            }
            c = ctl.recv_async() => {
                match c.map(|c| decode::<Control>(&c.payload().to_bytes())) {
                    Ok(Ok(Control::Stop)) | Err(_) => return Ok(End::Stopped),
                    Ok(Err(e)) => tracing::warn!("bad control message: {e}"),
                }
            }
            w = world_alive.recv_async() => {
                if w.map_or(true, |w| w.kind() == SampleKind::Delete) {
                    return Ok(End::WorldGone);
                }
            }
            _ = tokio::time::sleep(idle_timeout) => return Ok(End::WorldSilent),
        }
    }
}
