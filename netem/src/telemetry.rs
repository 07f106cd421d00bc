//! One link's row of links.csv: its state and counters at the end of a step, as
//! [`Netem::telemetry`](crate::Netem::telemetry) gives it and the HTTP API's `GET /links` shows it.

use proto::msg::{RobotId, Step};
use serde::Serialize;

use crate::link::{DownReason, LinkSnapshot};

/// One link at the end of one step (a row of links.csv).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LinkTelemetry {
    /// The last step given to [`Netem::on_step`](crate::Netem::on_step) (`None` before the first).
    pub step: Option<Step>,
    pub a: RobotId,
    pub b: RobotId,
    pub up: bool,
    /// `disabled`, `dead`, `out_of_range` or `no_pose` when down.
    pub down_reason: Option<DownReason>,
    /// `None` until both poses are known.
    pub distance_m: Option<f64>,
    pub signal_dbm: Option<f64>,
    pub walls: Option<u32>,
    /// Bytes delivered since the previous [`Netem::telemetry`](crate::Netem::telemetry) call.
    pub bytes_a_to_b: u64,
    pub bytes_b_to_a: u64,
    pub bytes_a_to_b_total: u64,
    pub bytes_b_to_a_total: u64,
    pub chunks_a_to_b_total: u64,
    pub chunks_b_to_a_total: u64,
    /// Bytes held inside netem now, both directions.
    pub queued_bytes: u64,
    pub queued_a_to_b: u64,
    pub queued_b_to_a: u64,
    /// Bytes read and then dropped by cuts, resets and limit_data, both directions.
    pub lost_bytes_total: u64,
    pub connections: usize,
    pub connects_total: u64,
    /// Connections that reached robot b's radio listener.
    pub established_total: u64,
    pub refused_total: u64,
    pub toxics: usize,
    /// Up but held (a blackhole).
    pub held: bool,
    /// Its use of the shared or lossy channel in the step (`None`: neither, or not usable).
    pub air: Option<proto::msg::LinkAir>,
}

/// The row of link snapshot `s` at `step`, with `step_bytes` as the step's bytes (a→b, b→a).
pub(crate) fn telemetry_row(
    step: Option<Step>,
    s: &LinkSnapshot,
    step_bytes: [u64; 2],
) -> LinkTelemetry {
    let [ab, ba] = s.dirs;
    LinkTelemetry {
        step,
        a: s.a,
        b: s.b,
        up: s.up,
        down_reason: s.down_reason,
        distance_m: s.verdict.map(|v| v.distance_m),
        signal_dbm: s.verdict.and_then(|v| v.signal_dbm),
        walls: s.verdict.and_then(|v| v.walls),
        bytes_a_to_b: step_bytes[0],
        bytes_b_to_a: step_bytes[1],
        bytes_a_to_b_total: ab.bytes_total,
        bytes_b_to_a_total: ba.bytes_total,
        chunks_a_to_b_total: ab.chunks_total,
        chunks_b_to_a_total: ba.chunks_total,
        queued_bytes: ab.queued_bytes + ba.queued_bytes,
        queued_a_to_b: ab.queued_bytes,
        queued_b_to_a: ba.queued_bytes,
        lost_bytes_total: ab.lost_bytes_total + ba.lost_bytes_total,
        connections: s.connections,
        connects_total: s.connects_total,
        established_total: s.established_total,
        refused_total: s.refused_total,
        toxics: s.toxics.len(),
        held: s.held,
        air: None,
    }
}
