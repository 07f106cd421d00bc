//! The log-distance path loss model with a wall attenuation factor (de Hoog, Cameron & Visser 2010,
//! §VI-A, after Bahl & Padmanabhan's RADAR, 2000): the signal at distance d through nW walls is
//!
//!   S = P(d₀) − 10·N·log₁₀(d / d₀) − min(nW, C)·WAF
//!
//! netem decides links with it on the truth map; a robot estimates with the same formula, on its
//! own map, how far it could be heard from a place (the `roles` strategy's rendezvous points).

use crate::scenario::{Radio, RadioModel};

/// Parameters of the path loss model (defaults: free space, RADAR's wall factor and cap).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathLoss {
    /// P(d₀), dBm.
    pub ref_dbm: f64,
    /// d₀, metres.
    pub ref_distance_m: f64,
    /// N.
    pub exponent: f64,
    /// WAF, dB per wall.
    pub wall_attenuation_db: f64,
    /// C.
    pub max_walls: u32,
    /// Link up iff the signal is at least this, dBm.
    pub threshold_dbm: f64,
}

impl PathLoss {
    /// The threshold at which the free-space range is `range_m`.
    pub fn threshold_for_range(
        ref_dbm: f64,
        ref_distance_m: f64,
        exponent: f64,
        range_m: f64,
    ) -> f64 {
        ref_dbm - 10.0 * exponent * (range_m.max(1e-9) / ref_distance_m.max(1e-9)).log10()
    }

    /// S for a distance and a wall count, dBm. Distances below d₀ read as d₀.
    pub fn signal_dbm(&self, distance_m: f64, walls: u32) -> f64 {
        let d0 = self.ref_distance_m.max(1e-9);
        let d = distance_m.max(d0);
        self.ref_dbm
            - 10.0 * self.exponent * (d / d0).log10()
            - f64::from(walls.min(self.max_walls)) * self.wall_attenuation_db
    }
}

impl PathLoss {
    /// The scenario's path loss model (`None` unless `radio.model = "pathloss"`); the threshold
    /// defaults to the one at which the free-space range is `radio.range_m`.
    pub fn of(r: &Radio) -> Option<PathLoss> {
        (r.model == RadioModel::Pathloss).then(|| PathLoss {
            ref_dbm: r.pathloss_ref_dbm,
            ref_distance_m: r.pathloss_ref_distance_m,
            exponent: r.pathloss_exponent,
            wall_attenuation_db: r.pathloss_wall_attenuation_db,
            max_walls: r.pathloss_max_walls,
            threshold_dbm: r.pathloss_threshold_dbm.unwrap_or_else(|| {
                PathLoss::threshold_for_range(
                    r.pathloss_ref_dbm,
                    r.pathloss_ref_distance_m,
                    r.pathloss_exponent,
                    r.range_m,
                )
            }),
        })
    }
}
