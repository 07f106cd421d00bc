//! Faults: the runtime and scheduled control vocabulary of netem (docs/design.md §5 "Faults": cut /
//! restore a pair, partition groups, blackhole, reset, bandwidth change, latency, corrupt bytes;
//! "the names and semantics follow toxiproxy / tc netem, which users know").
//!
//! Link-level faults (`Fault::Cut`, `Fault::Partition`, …) switch a pair's administrative
//! state; everything that shapes bytes is a *toxic* in toxiproxy's model: a named effect on one
//! stream of a link (`upstream` = a → b, the connecting side to the listening side; `downstream`
//! = b → a), with a `toxicity` (the probability that it applies to a given connection). Toxic
//! types keep toxiproxy's names and attributes where they exist — `latency {latency, jitter}`
//! (ms), `bandwidth {rate}` (KB/s; we also accept `rate_bytes_per_s`), `timeout {timeout}` (ms;
//! 0 = blackhole: stall without closing), `reset_peer {timeout}`, `limit_data {bytes}`,
//! `slicer {average_size, size_variation, delay}` (bytes; the delay between slices in µs),
//! `slow_close {delay}` (ms) — plus our `corrupt {probability}`. A toxic's times are simulated
//! (milliseconds, a slicer's microseconds), its rates bytes per simulated second (`clock.rs`).
//!
//! Deviations from toxiproxy, on purpose: `timeout` *stalls* (bytes stay buffered and flow again
//! when the toxic goes) instead of discarding them, because discarding bytes from the middle of a
//! TCP stream breaks its framing rather than simulating a dead radio; a `bandwidth` toxic
//! *replaces* the link's own rate (it may raise it), while a shared medium always applies on top;
//! a toxic may also name `stream = "both"`; a `slicer` draws each slice's size uniformly in
//! `average_size ± size_variation` (toxiproxy halves a write recursively around the average; the
//! sizes spread alike) and refuses `average_size = 0` (which never terminates in toxiproxy); and
//! with step markers a slicer's delay is dropped like the link's latency is (`link.rs`).
//!
//! `fold` turns a link's base parameters and its toxics into the `DirShape` of one connection
//! direction; the pipeline reads it from a `watch`, so changes reach live connections at once.

use std::sync::Arc;

use proto::msg::{RobotId, Step};
use serde::{Deserialize, Serialize};

use crate::accounting::Dir;
use crate::shaping::{Budget, DirShape, Limit, Rng, Slicing};

/// An unordered robot pair, written `(lower, higher)`.
pub type Pair = (RobotId, RobotId);

/// The name of a pair's proxy: `r{a}-r{b}` with `a < b`.
pub fn link_name(a: RobotId, b: RobotId) -> String {
    format!("r{}-r{}", a.min(b), a.max(b))
}

/// Parses `r{a}-r{b}` (either order) into a pair.
pub fn parse_link_name(name: &str) -> Option<Pair> {
    let (x, y) = name.split_once('-')?;
    let x: RobotId = x.strip_prefix('r')?.parse().ok()?;
    let y: RobotId = y.strip_prefix('r')?.parse().ok()?;
    (x != y).then_some((x.min(y), x.max(y)))
}

/// Which direction(s) of a link a toxic acts on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Stream {
    /// a → b (toxiproxy: client → upstream server).
    Upstream,
    /// b → a (toxiproxy's default).
    Downstream,
    Both,
}

impl Stream {
    pub fn applies(self, dir: Dir) -> bool {
        matches!(
            (self, dir),
            (Stream::Both, _) | (Stream::Upstream, Dir::AtoB) | (Stream::Downstream, Dir::BtoA)
        )
    }

    pub fn name(self) -> &'static str {
        match self {
            Stream::Upstream => "upstream",
            Stream::Downstream => "downstream",
            Stream::Both => "both",
        }
    }
}

/// What a toxic does.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ToxicKind {
    /// Delay every byte by `latency_ms` ± `jitter_ms` (simulated).
    Latency { latency_ms: u64, jitter_ms: u64 },
    /// Limit the rate (bytes per simulated second; 0 = unlimited).
    Bandwidth { rate_bytes_per_s: u64 },
    /// Stop all data; close the connection after `timeout_ms` (0: never — a blackhole).
    Timeout { timeout_ms: u64 },
    /// Reset (TCP RST) every connection `timeout_ms` after it starts or the toxic appears.
    ResetPeer { timeout_ms: u64 },
    /// Close the connection once `bytes` more bytes have passed.
    LimitData { bytes: u64 },
    /// Flip one bit in a byte with this probability.
    Corrupt { probability: f64 },
    /// Write what arrives in slices of `average_size ± size_variation` bytes, `delay_us`
    /// (simulated) apart.
    Slicer {
        average_size: u64,
        size_variation: u64,
        delay_us: u64,
    },
    /// Pass the sender's close (FIN) on `delay_ms` (simulated) after it came.
    SlowClose { delay_ms: u64 },
}

impl ToxicKind {
    /// toxiproxy's type name.
    pub fn type_name(&self) -> &'static str {
        match self {
            ToxicKind::Latency { .. } => "latency",
            ToxicKind::Bandwidth { .. } => "bandwidth",
            ToxicKind::Timeout { .. } => "timeout",
            ToxicKind::ResetPeer { .. } => "reset_peer",
            ToxicKind::LimitData { .. } => "limit_data",
            ToxicKind::Corrupt { .. } => "corrupt",
            ToxicKind::Slicer { .. } => "slicer",
            ToxicKind::SlowClose { .. } => "slow_close",
        }
    }
}

/// A named effect on one stream of a link. (De)serializes as toxiproxy's JSON:
/// `{"name", "type", "stream", "toxicity", "attributes": {…}}`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "ToxicWire", into = "ToxicWire")]
pub struct Toxic {
    pub name: String,
    pub kind: ToxicKind,
    pub stream: Stream,
    pub toxicity: f64,
}

/// toxiproxy's wire form of a toxic, every field optional (for creation and partial updates).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ToxicWire {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    #[serde(rename = "type", default, skip_serializing_if = "Option::is_none")]
    pub kind: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stream: Option<Stream>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub toxicity: Option<f64>,
    #[serde(default)]
    pub attributes: Attributes,
}

/// The union of every toxic type's attributes; absent ones read as 0, as in toxiproxy.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Attributes {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub latency: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub jitter: Option<u64>,
    /// toxiproxy's bandwidth unit: KB/s (1000 bytes per second).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rate: Option<u64>,
    /// Ours: bytes per (simulated) second; wins over `rate` when both are given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rate_bytes_per_s: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub timeout: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bytes: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub probability: Option<f64>,
    /// `slicer`: the mean slice, bytes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub average_size: Option<u64>,
    /// `slicer`: how far a slice's size may be from the mean, bytes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub size_variation: Option<u64>,
    /// `slicer`: µs between slices; `slow_close`: ms before the close is passed on.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub delay: Option<u64>,
}

/// Longest latency, jitter or timeout a toxic may ask for: one simulated day.
pub const MAX_TOXIC_MS: u64 = proto::scenario::MAX_DELAY_MS;
const MAX_NAME_LEN: usize = 64;

impl TryFrom<ToxicWire> for Toxic {
    type Error = String;

    fn try_from(w: ToxicWire) -> Result<Toxic, String> {
        let kind = toxic_kind(w.kind.as_deref(), &w.attributes)?;
        let stream = w.stream.unwrap_or(Stream::Downstream);
        let toxicity = w.toxicity.unwrap_or(1.0);
        if !(0.0..=1.0).contains(&toxicity) {
            return Err(format!("toxicity = {toxicity} is not in [0, 1]"));
        }
        let name = match w.name {
            Some(n) if !n.is_empty() => n,
            _ => format!("{}_{}", kind.type_name(), stream.name()),
        };
        if name.len() > MAX_NAME_LEN || !name.chars().all(|c| c.is_ascii_graphic() && c != '/') {
            return Err(format!(
                "toxic name {name:?} must be 1..={MAX_NAME_LEN} printable ASCII characters without '/'"
            ));
        }
        Ok(Toxic {
            name,
            kind,
            stream,
            toxicity,
        })
    }
}

/// A toxic's kind from its `type` and attributes, each attribute checked.
fn toxic_kind(kind: Option<&str>, a: &Attributes) -> Result<ToxicKind, String> {
    let ms = |key: &str, v: Option<u64>| -> Result<u64, String> {
        let v = v.unwrap_or(0);
        if v > MAX_TOXIC_MS {
            Err(format!(
                "attribute {key} = {v} ms is more than {MAX_TOXIC_MS} ms"
            ))
        } else {
            Ok(v)
        }
    };
    Ok(match kind {
        Some("latency") => ToxicKind::Latency {
            latency_ms: ms("latency", a.latency)?,
            jitter_ms: ms("jitter", a.jitter)?,
        },
        Some("bandwidth") => ToxicKind::Bandwidth {
            rate_bytes_per_s: match (a.rate_bytes_per_s, a.rate) {
                (Some(r), _) => r,
                (None, Some(kb)) => kb.saturating_mul(1000),
                (None, None) => 0,
            },
        },
        Some("timeout") => ToxicKind::Timeout {
            timeout_ms: ms("timeout", a.timeout)?,
        },
        Some("reset_peer") => ToxicKind::ResetPeer {
            timeout_ms: ms("timeout", a.timeout)?,
        },
        Some("limit_data") => ToxicKind::LimitData {
            bytes: a.bytes.unwrap_or(0),
        },
        Some("corrupt") => {
            let p = a.probability.unwrap_or(0.0);
            if !(0.0..=1.0).contains(&p) {
                return Err(format!("attribute probability = {p} is not in [0, 1]"));
            }
            ToxicKind::Corrupt { probability: p }
        }
        Some("slicer") => {
            let average_size = a.average_size.unwrap_or(0);
            if average_size == 0 {
                return Err("attribute average_size must be at least 1 (bytes)".into());
            }
            let delay_us = a.delay.unwrap_or(0);
            if delay_us > MAX_TOXIC_MS.saturating_mul(1000) {
                return Err(format!(
                    "attribute delay = {delay_us} µs is more than {MAX_TOXIC_MS} ms"
                ));
            }
            ToxicKind::Slicer {
                average_size,
                size_variation: a.size_variation.unwrap_or(0),
                delay_us,
            }
        }
        Some("slow_close") => ToxicKind::SlowClose {
            delay_ms: ms("delay", a.delay)?,
        },
        Some(other) => {
            return Err(format!(
                "invalid toxic type {other:?} (supported: latency, bandwidth, timeout, \
                 reset_peer, limit_data, slicer, slow_close, corrupt)"
            ))
        }
        None => return Err("missing required field: type".into()),
    })
}

impl From<Toxic> for ToxicWire {
    fn from(t: Toxic) -> ToxicWire {
        let mut a = Attributes::default();
        match t.kind {
            ToxicKind::Latency {
                latency_ms,
                jitter_ms,
            } => {
                a.latency = Some(latency_ms);
                a.jitter = Some(jitter_ms);
            }
            ToxicKind::Bandwidth { rate_bytes_per_s } => {
                a.rate = Some(rate_bytes_per_s / 1000);
                a.rate_bytes_per_s = Some(rate_bytes_per_s);
            }
            ToxicKind::Timeout { timeout_ms } | ToxicKind::ResetPeer { timeout_ms } => {
                a.timeout = Some(timeout_ms);
            }
            ToxicKind::LimitData { bytes } => a.bytes = Some(bytes),
            ToxicKind::Corrupt { probability } => a.probability = Some(probability),
            ToxicKind::Slicer {
                average_size,
                size_variation,
                delay_us,
            } => {
                a.average_size = Some(average_size);
                a.size_variation = Some(size_variation);
                a.delay = Some(delay_us);
            }
            ToxicKind::SlowClose { delay_ms } => a.delay = Some(delay_ms),
        }
        ToxicWire {
            name: Some(t.name),
            kind: Some(t.kind.type_name().into()),
            stream: Some(t.stream),
            toxicity: Some(t.toxicity),
            attributes: a,
        }
    }
}

impl Toxic {
    /// A toxic on both streams, named after its type.
    pub fn both(kind: ToxicKind) -> Toxic {
        Toxic {
            name: kind.type_name().into(),
            kind,
            stream: Stream::Both,
            toxicity: 1.0,
        }
    }

    /// This toxic with the fields present in `patch` replaced (toxiproxy's update: attributes
    /// merge one by one; the type cannot change).
    pub fn patched(&self, patch: ToxicWire) -> Result<Toxic, String> {
        let mut w = ToxicWire::from(self.clone());
        if let Some(k) = patch.kind {
            if Some(&k) != w.kind.as_ref() {
                return Err(format!(
                    "cannot change the type of toxic {} to {k:?}",
                    self.name
                ));
            }
        }
        if let Some(n) = patch.name {
            if n != self.name {
                return Err(format!("cannot rename toxic {} to {n:?}", self.name));
            }
        }
        w.stream = patch.stream.or(w.stream);
        w.toxicity = patch.toxicity.or(w.toxicity);
        let (a, p) = (&mut w.attributes, patch.attributes);
        a.latency = p.latency.or(a.latency);
        a.jitter = p.jitter.or(a.jitter);
        if p.rate_bytes_per_s.is_some() || p.rate.is_some() {
            a.rate_bytes_per_s = p.rate_bytes_per_s;
            a.rate = p.rate;
        }
        a.timeout = p.timeout.or(a.timeout);
        a.bytes = p.bytes.or(a.bytes);
        a.probability = p.probability.or(a.probability);
        a.average_size = p.average_size.or(a.average_size);
        a.size_variation = p.size_variation.or(a.size_variation);
        a.delay = p.delay.or(a.delay);
        Toxic::try_from(w)
    }
}

/// A control action on the links. Serialized internally tagged by `kind` (TOML-friendly, for
/// the scenario's scheduled faults).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Fault {
    /// Take a pair down administratively (toxiproxy: `enabled = false`): connections are reset
    /// and reconnects held until [`Fault::Restore`].
    Cut {
        pair: Pair,
    },
    Restore {
        pair: Pair,
    },
    /// Cut every pair whose robots are in different groups; pairs with a robot in no group are
    /// left as they are.
    Partition {
        groups: Vec<Vec<RobotId>>,
    },
    /// Restore every pair.
    Heal,
    /// Reset (TCP RST) the current connections of a pair (`None`: every pair) once; the link
    /// stays up, so the robots reconnect.
    Reset {
        #[serde(default)]
        pair: Option<Pair>,
    },
    /// Add a toxic; an existing toxic of that name is an error.
    AddToxic {
        #[serde(default)]
        pair: Option<Pair>,
        toxic: Toxic,
    },
    /// Add a toxic or replace the one of that name.
    SetToxic {
        #[serde(default)]
        pair: Option<Pair>,
        toxic: Toxic,
    },
    RemoveToxic {
        #[serde(default)]
        pair: Option<Pair>,
        name: String,
    },
    /// toxiproxy's `POST /reset`: every pair enabled, every toxic removed.
    ResetAll,
}

impl Fault {
    /// Stall a pair both ways without closing (toxiproxy `timeout` 0).
    pub fn blackhole(pair: Option<Pair>) -> Fault {
        Fault::SetToxic {
            pair,
            toxic: Toxic {
                name: "blackhole".into(),
                ..Toxic::both(ToxicKind::Timeout { timeout_ms: 0 })
            },
        }
    }

    /// Close a pair's connections after `bytes` more bytes each way.
    pub fn limit_data(pair: Option<Pair>, bytes: u64) -> Fault {
        Fault::SetToxic {
            pair,
            toxic: Toxic::both(ToxicKind::LimitData { bytes }),
        }
    }

    /// Change a pair's rate both ways (bytes per simulated second).
    pub fn bandwidth(pair: Option<Pair>, rate_bytes_per_s: u64) -> Fault {
        Fault::SetToxic {
            pair,
            toxic: Toxic::both(ToxicKind::Bandwidth { rate_bytes_per_s }),
        }
    }

    /// Add latency ± jitter (simulated ms) both ways.
    pub fn latency(pair: Option<Pair>, latency_ms: u64, jitter_ms: u64) -> Fault {
        Fault::SetToxic {
            pair,
            toxic: Toxic::both(ToxicKind::Latency {
                latency_ms,
                jitter_ms,
            }),
        }
    }

    /// Flip bits both ways with probability `p` per byte.
    pub fn corrupt(pair: Option<Pair>, probability: f64) -> Fault {
        Fault::SetToxic {
            pair,
            toxic: Toxic::both(ToxicKind::Corrupt { probability }),
        }
    }
}

impl Fault {
    /// Why this fault's effect on the robots is not in the step plans of a lockstep run with
    /// markers (so it depends on timing); `None` if it is. The plan carries which links are up,
    /// their rate, latency and jitter, and stalls; a reset, a toxic that closes connections
    /// after some time or bytes, a delayed close, corruption, and a toxic that hits only some
    /// connections (toxicity below 1) are not. A `slicer` is inside: with markers it only cuts
    /// writes smaller (its delay is dropped, `link.rs`), and a step's frames still all arrive
    /// within the step.
    pub fn outside_plan(&self) -> Option<&'static str> {
        match self {
            Fault::Reset { .. } => Some("a reset closes sessions the plan keeps up"),
            Fault::AddToxic { toxic, .. } | Fault::SetToxic { toxic, .. } => {
                if toxic.toxicity < 1.0 {
                    return Some("a toxic with toxicity below 1 hits connections by their number");
                }
                match toxic.kind {
                    ToxicKind::Timeout { timeout_ms } if timeout_ms > 0 => {
                        Some("a timeout toxic closes connections after a while")
                    }
                    ToxicKind::ResetPeer { .. } => Some("reset_peer closes connections"),
                    ToxicKind::LimitData { .. } => Some("limit_data closes connections"),
                    ToxicKind::Corrupt { .. } => Some("corrupt bytes break messages and sessions"),
                    ToxicKind::SlowClose { .. } => {
                        Some("slow_close holds a closing connection open on the clock")
                    }
                    _ => None,
                }
            }
            _ => None,
        }
    }
}

/// A fault applied when the simulation reaches `step`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ScheduledFault {
    pub step: Step,
    #[serde(flatten)]
    pub fault: Fault,
}

/// Reads the scenario's link faults among its `[[faults]]` tables (`step`, `kind` and the kind's
/// fields; process faults are the launcher's and skipped), naming the index of the first bad one.
pub fn parse_faults(tables: &[toml::Table]) -> Result<Vec<ScheduledFault>, (usize, String)> {
    tables
        .iter()
        .enumerate()
        .filter(|(_, t)| !proto::scenario::is_process_fault(t))
        .map(|(i, t)| {
            toml::Value::Table(t.clone())
                .try_into::<ScheduledFault>()
                .map_err(|e| (i, e.message().trim().replace('\n', " ")))
        })
        .collect()
}

/// A toxic installed on a link: a unique id (a new one on every add or update, so that
/// `limit_data` and timers start afresh) and, for `bandwidth`, one budget per direction it acts
/// on (so `stream = both` limits each direction separately, like the link's own rate).
#[derive(Clone, Debug)]
pub struct ActiveToxic {
    pub toxic: Toxic,
    pub id: u64,
    pub budgets: [Option<Arc<Budget>>; 2],
}

/// The link-wide parameters of one direction before toxics.
#[derive(Clone, Debug, Default)]
pub struct BaseShape {
    /// The pair's own rate in this direction (per-link medium); `None`: unlimited or shared.
    pub budget: Option<Arc<Budget>>,
    /// The one budget of a shared medium.
    pub medium: Option<Arc<Budget>>,
    pub latency_ns: u64,
    pub jitter_ns: u64,
}

/// Whether a toxic of this `toxicity` applies to connection `conn` (deterministic per pair of
/// ids, so a connection keeps its draw for as long as the toxic exists).
pub fn hits(toxicity: f64, toxic_id: u64, conn: u64) -> bool {
    if toxicity >= 1.0 {
        return true;
    }
    if toxicity.is_nan() || toxicity <= 0.0 {
        return false;
    }
    Rng::new(toxic_id.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ conn).unit() < toxicity
}

/// The effective shape of direction `dir` of connection `conn`.
pub fn fold(base: &BaseShape, toxics: &[ActiveToxic], conn: u64, dir: Dir) -> DirShape {
    fold_with(base, toxics, dir, |t| hits(t.toxic.toxicity, t.id, conn))
}

/// The shape of direction `dir` with every toxic applied, whatever its toxicity: what a step's
/// plan announces (lockstep with markers).
pub fn planned(base: &BaseShape, toxics: &[ActiveToxic], dir: Dir) -> DirShape {
    fold_with(base, toxics, dir, |_| true)
}

fn fold_with(
    base: &BaseShape,
    toxics: &[ActiveToxic],
    dir: Dir,
    applies: impl Fn(&ActiveToxic) -> bool,
) -> DirShape {
    let mut s = DirShape {
        latency_ns: base.latency_ns,
        jitter_ns: base.jitter_ns,
        ..DirShape::default()
    };
    let mut rate_toxic = false;
    let mut budgets = Vec::new();
    for t in toxics {
        if !t.toxic.stream.applies(dir) || !applies(t) {
            continue;
        }
        match t.toxic.kind {
            ToxicKind::Latency {
                latency_ms,
                jitter_ms,
            } => {
                s.latency_ns = s
                    .latency_ns
                    .saturating_add(latency_ms.saturating_mul(1_000_000));
                s.jitter_ns = s
                    .jitter_ns
                    .saturating_add(jitter_ms.saturating_mul(1_000_000));
            }
            ToxicKind::Bandwidth { .. } => {
                rate_toxic = true;
                budgets.extend(t.budgets[dir.index()].iter().cloned());
            }
            ToxicKind::Timeout { .. } => s.stalled = true,
            ToxicKind::ResetPeer { .. } => {}
            ToxicKind::LimitData { bytes } => {
                if s.limit.is_none_or(|l| bytes < l.bytes) {
                    s.limit = Some(Limit { id: t.id, bytes });
                }
            }
            ToxicKind::Corrupt { probability } => {
                s.corrupt_probability = 1.0 - (1.0 - s.corrupt_probability) * (1.0 - probability);
            }
            ToxicKind::Slicer {
                average_size,
                size_variation,
                delay_us,
            } => {
                // Slices of slices are as small as the finer slicer makes them.
                if s.slicer.is_none_or(|x| average_size < x.average_size) {
                    s.slicer = Some(Slicing {
                        average_size,
                        size_variation,
                        delay_ns: delay_us.saturating_mul(1000),
                    });
                }
            }
            ToxicKind::SlowClose { delay_ms } => {
                s.close_delay_ns = s
                    .close_delay_ns
                    .saturating_add(delay_ms.saturating_mul(1_000_000));
            }
        }
    }
    if !rate_toxic {
        budgets.extend(base.budget.iter().cloned());
    }
    budgets.extend(base.medium.iter().cloned());
    s.budgets = budgets;
    s
}

/// What a connection timer does when it fires.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kill {
    /// FIN both ways (toxiproxy `timeout`, `limit_data`).
    Close,
    /// RST both ways, dropping what is buffered (a cut, `reset_peer`).
    Reset,
}

/// The connection timers the toxics of a link ask for: (toxic id, action, delay in simulated ns).
pub fn timers(toxics: &[ActiveToxic], conn: u64) -> Vec<(u64, Kill, u64)> {
    toxics
        .iter()
        .filter(|t| hits(t.toxic.toxicity, t.id, conn))
        .filter_map(|t| match t.toxic.kind {
            ToxicKind::Timeout { timeout_ms } if timeout_ms > 0 => {
                Some((t.id, Kill::Close, timeout_ms.saturating_mul(1_000_000)))
            }
            ToxicKind::ResetPeer { timeout_ms } => {
                Some((t.id, Kill::Reset, timeout_ms.saturating_mul(1_000_000)))
            }
            _ => None,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proto::clock::SimClock;

    fn parse(json: &str) -> Result<Toxic, String> {
        serde_json::from_str::<Toxic>(json).map_err(|e| e.to_string())
    }

    #[test]
    fn toxiproxy_json_round_trips_with_toxiproxy_defaults() {
        let t = parse(r#"{"type":"latency","attributes":{"latency":100,"jitter":10}}"#).unwrap();
        assert_eq!(t.name, "latency_downstream");
        assert_eq!(t.stream, Stream::Downstream);
        assert_eq!(t.toxicity, 1.0);
        assert_eq!(
            t.kind,
            ToxicKind::Latency {
                latency_ms: 100,
                jitter_ms: 10
            }
        );
        let json = serde_json::to_string(&t).unwrap();
        assert_eq!(parse(&json).unwrap(), t);
        let v: serde_json::Value = serde_json::from_str(&json).unwrap();
        assert_eq!(v["type"], "latency");
        assert_eq!(v["attributes"]["latency"], 100);
    }

    #[test]
    fn bandwidth_accepts_kb_per_s_and_bytes_per_s() {
        let kb =
            parse(r#"{"type":"bandwidth","stream":"upstream","attributes":{"rate":2}}"#).unwrap();
        assert_eq!(
            kb.kind,
            ToxicKind::Bandwidth {
                rate_bytes_per_s: 2000
            }
        );
        let b = parse(r#"{"type":"bandwidth","attributes":{"rate_bytes_per_s":1500}}"#).unwrap();
        assert_eq!(
            b.kind,
            ToxicKind::Bandwidth {
                rate_bytes_per_s: 1500
            }
        );
    }

    #[test]
    fn bad_toxics_are_refused_with_a_reason() {
        for (json, needle) in [
            (r#"{"type":"explode"}"#, "invalid toxic type"),
            (r#"{"type":"slicer"}"#, "average_size"),
            (
                r#"{"type":"slicer","attributes":{"average_size":1,"delay":999999999999}}"#,
                "delay",
            ),
            (
                r#"{"type":"slow_close","attributes":{"delay":999999999999}}"#,
                "delay",
            ),
            (r#"{"attributes":{}}"#, "type"),
            (
                r#"{"type":"corrupt","attributes":{"probability":2}}"#,
                "probability",
            ),
            (r#"{"type":"latency","toxicity":-1}"#, "toxicity"),
            (r#"{"type":"latency","name":"a/b"}"#, "name"),
            (
                r#"{"type":"latency","attributes":{"latency":999999999999}}"#,
                "latency",
            ),
            (r#"{"type":"latency","stream":"sideways"}"#, "sideways"),
        ] {
            let e = parse(json).unwrap_err();
            assert!(e.contains(needle), "{json}: {e}");
        }
    }

    #[test]
    fn slicer_and_slow_close_take_toxiproxys_attributes_and_units() {
        let t = parse(
            r#"{"name":"s","type":"slicer","stream":"upstream",
                "attributes":{"average_size":64,"size_variation":16,"delay":250}}"#,
        )
        .unwrap();
        assert_eq!(
            t.kind,
            ToxicKind::Slicer {
                average_size: 64,
                size_variation: 16,
                delay_us: 250
            }
        );
        let v = serde_json::to_value(&t).unwrap();
        assert_eq!(
            v["attributes"],
            serde_json::json!({"average_size": 64, "size_variation": 16, "delay": 250})
        );
        assert_eq!(parse(&v.to_string()).unwrap(), t);
        // toxiproxy's default variation and delay are 0.
        let plain = parse(r#"{"type":"slicer","attributes":{"average_size":8}}"#).unwrap();
        assert_eq!(plain.name, "slicer_downstream");
        let p: ToxicWire = serde_json::from_str(r#"{"attributes":{"delay":5}}"#).unwrap();
        assert_eq!(
            t.patched(p).unwrap().kind,
            ToxicKind::Slicer {
                average_size: 64,
                size_variation: 16,
                delay_us: 5
            }
        );
        let c = parse(r#"{"type":"slow_close","attributes":{"delay":1500}}"#).unwrap();
        assert_eq!(c.kind, ToxicKind::SlowClose { delay_ms: 1500 });
        assert_eq!(c.name, "slow_close_downstream");
        assert_eq!(
            serde_json::to_value(&c).unwrap()["attributes"],
            serde_json::json!({"delay": 1500})
        );
        // Folded: the finer slicer wins, in µs turned ns; slow closes add up.
        let mk = |kind, id| ActiveToxic {
            toxic: Toxic::both(kind),
            id,
            budgets: [None, None],
        };
        let toxics = [
            mk(
                ToxicKind::Slicer {
                    average_size: 100,
                    size_variation: 0,
                    delay_us: 1,
                },
                1,
            ),
            mk(
                ToxicKind::Slicer {
                    average_size: 10,
                    size_variation: 2,
                    delay_us: 3,
                },
                2,
            ),
            mk(ToxicKind::SlowClose { delay_ms: 2 }, 3),
            mk(ToxicKind::SlowClose { delay_ms: 5 }, 4),
        ];
        let s = fold(&BaseShape::default(), &toxics, 0, Dir::AtoB);
        assert_eq!(
            s.slicer,
            Some(Slicing {
                average_size: 10,
                size_variation: 2,
                delay_ns: 3000
            })
        );
        assert_eq!(s.close_delay_ns, 7_000_000);
        let none = fold(&BaseShape::default(), &[], 0, Dir::AtoB);
        assert_eq!((none.slicer, none.close_delay_ns), (None, 0));
    }

    #[test]
    fn patch_merges_attributes_and_keeps_the_type() {
        let t = parse(r#"{"type":"latency","attributes":{"latency":100,"jitter":10}}"#).unwrap();
        let p: ToxicWire = serde_json::from_str(r#"{"attributes":{"jitter":5}}"#).unwrap();
        let t2 = t.patched(p).unwrap();
        assert_eq!(
            t2.kind,
            ToxicKind::Latency {
                latency_ms: 100,
                jitter_ms: 5
            }
        );
        let p: ToxicWire = serde_json::from_str(r#"{"type":"bandwidth"}"#).unwrap();
        assert!(t.patched(p).is_err());
    }

    #[test]
    fn scheduled_faults_read_from_toml_like_data() {
        let json = r#"[
            {"step": 10, "kind": "cut", "pair": [0, 1]},
            {"step": 20, "kind": "partition", "groups": [[0, 1], [2]]},
            {"step": 30, "kind": "set_toxic", "toxic": {"type": "bandwidth", "stream": "both",
                                                        "attributes": {"rate_bytes_per_s": 500}}},
            {"step": 40, "kind": "heal"}
        ]"#;
        let f: Vec<ScheduledFault> = serde_json::from_str(json).unwrap();
        assert_eq!(f[0].fault, Fault::Cut { pair: (0, 1) });
        assert_eq!(
            f[3],
            ScheduledFault {
                step: 40,
                fault: Fault::Heal
            }
        );
        match &f[2].fault {
            Fault::SetToxic { pair: None, toxic } => assert_eq!(toxic.stream, Stream::Both),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn scenario_fault_tables_parse_and_errors_name_the_index() {
        let text = r#"
            [[faults]]
            step = 100
            kind = "cut"
            pair = [0, 1]

            [[faults]]
            step = 120
            kind = "set_toxic"
            pair = [1, 2]
            toxic = { type = "latency", stream = "both", attributes = { latency = 250, jitter = 50 } }

            [[faults]]
            step = 130
            kind = "reset"
        "#;
        let doc: toml::Table = text.parse().unwrap();
        let tables: Vec<toml::Table> = doc["faults"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_table().unwrap().clone())
            .collect();
        let f = parse_faults(&tables).unwrap();
        assert_eq!(
            f[0],
            ScheduledFault {
                step: 100,
                fault: Fault::Cut { pair: (0, 1) }
            }
        );
        assert_eq!(f[2].fault, Fault::Reset { pair: None });
        // Process faults are the launcher's: skipped, and the indices still name the tables.
        let mut with_kill = tables.clone();
        with_kill.insert(
            0,
            "step = 5\nkind = \"kill\"\nprocess = \"robot-1\""
                .parse()
                .unwrap(),
        );
        assert_eq!(parse_faults(&with_kill).unwrap(), f);
        with_kill[2].insert("kind".into(), toml::Value::String("explode".into()));
        assert_eq!(parse_faults(&with_kill).unwrap_err().0, 2);
        match &f[1].fault {
            Fault::SetToxic {
                pair: Some((1, 2)),
                toxic,
            } => {
                assert_eq!(
                    toxic.kind,
                    ToxicKind::Latency {
                        latency_ms: 250,
                        jitter_ms: 50
                    }
                )
            }
            other => panic!("{other:?}"),
        }
        let mut bad = tables.clone();
        bad[1].insert("kind".into(), toml::Value::String("explode".into()));
        let (i, msg) = parse_faults(&bad).unwrap_err();
        assert_eq!(i, 1);
        assert!(msg.contains("explode"), "{msg}");
        bad[1] = tables[1].clone();
        bad[1].insert("toxic".into(), "not a table".into());
        assert_eq!(parse_faults(&bad).unwrap_err().0, 1);
    }

    #[test]
    fn link_names_parse_both_orders_and_reject_garbage() {
        assert_eq!(link_name(3, 1), "r1-r3");
        assert_eq!(parse_link_name("r1-r3"), Some((1, 3)));
        assert_eq!(parse_link_name("r3-r1"), Some((1, 3)));
        for bad in ["r1-r1", "x1-r2", "r1r2", "r-r2", "r1-r99999999", ""] {
            assert_eq!(parse_link_name(bad), None, "{bad}");
        }
    }

    #[test]
    fn fold_combines_base_and_toxics_per_direction() {
        let clock = SimClock::lockstep();
        let base_budget = Budget::new(1000, 1.0, false, clock.clone());
        let medium = Budget::new(5000, 1.0, true, clock.clone());
        let toxic_budget = Budget::new(300, 1.0, false, clock);
        let base = BaseShape {
            budget: Some(Arc::clone(&base_budget)),
            medium: Some(Arc::clone(&medium)),
            latency_ns: 1_000_000,
            jitter_ns: 0,
        };
        let toxics = vec![
            ActiveToxic {
                toxic: Toxic {
                    name: "slow".into(),
                    kind: ToxicKind::Bandwidth {
                        rate_bytes_per_s: 300,
                    },
                    stream: Stream::Upstream,
                    toxicity: 1.0,
                },
                id: 1,
                budgets: [Some(Arc::clone(&toxic_budget)), None],
            },
            ActiveToxic {
                toxic: Toxic::both(ToxicKind::Latency {
                    latency_ms: 5,
                    jitter_ms: 2,
                }),
                id: 2,
                budgets: [None, None],
            },
            ActiveToxic {
                toxic: Toxic {
                    name: "bh".into(),
                    kind: ToxicKind::Timeout { timeout_ms: 0 },
                    stream: Stream::Downstream,
                    toxicity: 1.0,
                },
                id: 3,
                budgets: [None, None],
            },
        ];
        let up = fold(&base, &toxics, 7, Dir::AtoB);
        assert_eq!(up.budgets.len(), 2);
        assert!(
            Arc::ptr_eq(&up.budgets[0], &toxic_budget),
            "the toxic replaces the base rate"
        );
        assert!(
            Arc::ptr_eq(&up.budgets[1], &medium),
            "the medium always applies"
        );
        assert_eq!(up.latency_ns, 6_000_000);
        assert_eq!(up.jitter_ns, 2_000_000);
        assert!(!up.stalled);
        let down = fold(&base, &toxics, 7, Dir::BtoA);
        assert!(Arc::ptr_eq(&down.budgets[0], &base_budget));
        assert!(down.stalled);
    }

    #[test]
    fn toxicity_selects_about_that_share_of_connections() {
        let n = (0..10_000u64).filter(|&c| hits(0.3, 17, c)).count();
        assert!((2700..3300).contains(&n), "{n}");
        assert!((0..100u64).all(|c| hits(1.0, 1, c) && !hits(0.0, 1, c)));
    }

    #[test]
    fn what_a_step_plan_carries_and_what_it_cannot() {
        let pair = Some((0, 1));
        for inside in [
            Fault::Cut { pair: (0, 1) },
            Fault::Partition {
                groups: vec![vec![0], vec![1]],
            },
            Fault::Heal,
            Fault::ResetAll,
            Fault::blackhole(pair),
            Fault::bandwidth(pair, 300),
            Fault::latency(None, 2500, 400),
            Fault::SetToxic {
                pair,
                toxic: Toxic::both(ToxicKind::Slicer {
                    average_size: 10,
                    size_variation: 5,
                    delay_us: 100,
                }),
            },
        ] {
            assert_eq!(inside.outside_plan(), None, "{inside:?}");
        }
        let mut partial = Toxic::both(ToxicKind::Latency {
            latency_ms: 10,
            jitter_ms: 0,
        });
        partial.toxicity = 0.5;
        for outside in [
            Fault::Reset { pair: None },
            Fault::limit_data(pair, 100),
            Fault::corrupt(pair, 0.01),
            Fault::SetToxic {
                pair,
                toxic: Toxic::both(ToxicKind::Timeout { timeout_ms: 5 }),
            },
            Fault::AddToxic {
                pair,
                toxic: Toxic::both(ToxicKind::ResetPeer { timeout_ms: 5 }),
            },
            Fault::SetToxic {
                pair,
                toxic: partial,
            },
            Fault::SetToxic {
                pair,
                toxic: Toxic::both(ToxicKind::SlowClose { delay_ms: 100 }),
            },
        ] {
            assert!(outside.outside_plan().is_some(), "{outside:?}");
        }
    }
}
