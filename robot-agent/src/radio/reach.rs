//! What a robot can tell of the radio from what it knows: its own map and the radio model's
//! parameters — never the truth (netem alone judges links on the truth map). Both use
//! [`proto::pathloss`], the one implementation of the path loss model and its wall count; a robot
//! counts as walls only the cells it knows occupied.
//!
//! * [`Reach::estimate`](crate::radio::reach::Reach::estimate): how far a robot at a place could be
//!   heard (de Hoog et al.'s rendezvous points prefer the best reach).
//! * [`Reach::linked`](crate::radio::reach::Reach::linked): whether robots at two places could talk
//!   (Rooker and Birk's pack judges its configurations with it).

use proto::geom::{MapInfo, Metres};
use proto::grid::{Cell, Grid, Occ};
use proto::pathloss::{count_walls, walls_along, PathLoss};
use proto::scenario::{RadioModel, Scenario};

/// Directions [`Reach::estimate`] casts.
const REACH_RAYS: usize = 16;

/// How far a robot at a place could be heard, estimated from what it knows: its own map and the
/// radio model's parameters — never the truth.
#[derive(Clone, Debug)]
pub enum Reach {
    /// `always`: everywhere; every place is as good.
    Unlimited,
    /// `disk`: the range, whatever the walls (cells).
    Disk { range_cells: f64 },
    /// `pathloss`: the model, with walls counted on the robot's map (occupied cells; unknown
    /// space is not counted) and distances converted at `res_m` metres per cell.
    PathLoss {
        model: PathLoss,
        range_cells: f64,
        res_m: f64,
    },
}

impl Reach {
    pub fn new(s: &Scenario, res_m: f64) -> Reach {
        let range_cells = s.radio.range_m / res_m;
        match (s.radio.model, PathLoss::of(&s.radio)) {
            (RadioModel::Always, _) => Reach::Unlimited,
            (RadioModel::Pathloss, Some(model)) => Reach::PathLoss {
                model,
                range_cells,
                res_m,
            },
            _ => Reach::Disk { range_cells },
        }
    }

    /// The mean, over [`REACH_RAYS`] directions from the centre of `p`, of the farthest distance
    /// (cells) at which a robot there would still be heard: the free-space range for `disk`; for
    /// `pathloss` the farthest point of each ray whose signal, through the walls the ray has
    /// crossed so far, is at least the threshold.
    pub fn estimate(&self, g: &Grid, p: Cell) -> f64 {
        let (model, range_cells, res_m) = match self {
            Reach::Unlimited => return f64::INFINITY,
            Reach::Disk { range_cells } => return *range_cells,
            Reach::PathLoss {
                model,
                range_cells,
                res_m,
            } => (model, *range_cells, *res_m),
        };
        // A frame of 1 m cells at the origin: its metres are `g`'s cell units.
        let cells = MapInfo::at_origin(g.width(), g.height(), 1.0);
        let from = cells.centre_of(p);
        let mut total = 0.0;
        for k in 0..REACH_RAYS {
            let a = std::f64::consts::TAU * k as f64 / REACH_RAYS as f64;
            let to = Metres::new(
                from.x + range_cells * a.cos(),
                from.y + range_cells * a.sin(),
            );
            // The walls counted as [`Reach::linked`] and netem count them.
            let mut heard = 0.0f64;
            for (c, walls) in walls_along(&cells, g, from, to, |o| o == Occ::Occupied) {
                let d = c.dist(p);
                if model.signal_dbm(d * res_m, walls) >= model.threshold_dbm {
                    heard = heard.max(d);
                }
            }
            total += heard;
        }
        total / REACH_RAYS as f64
    }

    /// Whether robots at the centres of `a` and `b` could talk: within range for `disk`; for
    /// `pathloss`, a signal at least the threshold through the walls the straight line crosses on
    /// `g` (cells known occupied; unknown space is not counted). The distance counts `slack`
    /// cells more than between the centres (robots stand anywhere in their cells).
    pub fn linked(&self, g: &Grid, a: Cell, b: Cell, slack: f64) -> bool {
        let d = a.dist(b) + slack.max(0.0);
        match self {
            Reach::Unlimited => true,
            Reach::Disk { range_cells } => d <= *range_cells,
            Reach::PathLoss { model, res_m, .. } => {
                // A frame of 1 m cells at the origin: its metres are `g`'s cell units.
                let cells = MapInfo::at_origin(g.width(), g.height(), 1.0);
                let centre = |c| cells.centre_of(c);
                let walls = count_walls(&cells, g, centre(a), centre(b), |o| o == Occ::Occupied);
                model.signal_dbm(d * res_m, walls) >= model.threshold_dbm
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pathloss(range_m: f64) -> Reach {
        let s = Scenario::from_toml(
            "",
            &[
                "radio.model=\"pathloss\"".into(),
                format!("radio.range_m={range_m}"),
            ],
        )
        .expect("scenario");
        Reach::new(&s, 1.0)
    }

    #[test]
    fn walls_on_the_robots_own_map_shorten_the_estimated_reach() {
        let free = Grid::new(41, 41, Occ::Free);
        let mut walled = free.clone();
        for y in 0..41 {
            walled.set(Cell::new(23, y), Occ::Occupied);
        }
        let mut unknown = free.clone();
        for y in 0..41 {
            unknown.set(Cell::new(23, y), Occ::Unknown);
        }
        let r = pathloss(10.0);
        let p = Cell::new(20, 20);
        let open_reach = r.estimate(&free, p);
        assert!((open_reach - 10.0).abs() < 1.0, "{open_reach}");
        assert!(r.estimate(&walled, p) < open_reach);
        // Unknown space is not a wall.
        assert_eq!(r.estimate(&unknown, p), open_reach);
        assert_eq!(Reach::Disk { range_cells: 7.0 }.estimate(&walled, p), 7.0);
    }

    #[test]
    fn links_are_judged_on_the_robots_own_map() {
        let free = Grid::new(41, 41, Occ::Free);
        let mut walled = free.clone();
        for y in 0..41 {
            walled.set(Cell::new(23, y), Occ::Occupied);
        }
        let r = pathloss(10.0);
        let (a, b, far) = (Cell::new(20, 20), Cell::new(29, 20), Cell::new(32, 20));
        assert!(r.linked(&free, a, b, 0.0));
        assert!(!r.linked(&free, a, far, 0.0), "beyond the free-space range");
        let mut thick = walled.clone();
        for x in 24..26 {
            for y in 0..41 {
                thick.set(Cell::new(x, y), Occ::Occupied);
            }
        }
        // One wall (3.1 dB) shortens the 10 m free-space range to 10 × 10^(−3.1/20) ≈ 7 m.
        assert!(!r.linked(&walled, a, b, 0.0), "9 m through one wall");
        assert!(
            r.linked(&walled, a, Cell::new(26, 20), 0.0),
            "6 m through one wall"
        );
        // A wall three cells thick counts once (three would leave about 3.4 m).
        assert!(r.linked(&thick, a, Cell::new(26, 20), 0.0));
        let mut unknown = free.clone();
        for y in 0..41 {
            unknown.set(Cell::new(23, y), Occ::Unknown);
        }
        assert!(r.linked(&unknown, a, b, 0.0), "unknown space is not a wall");
        let disk = Reach::Disk { range_cells: 9.0 };
        assert!(disk.linked(&walled, a, b, 0.0) && !disk.linked(&walled, a, far, 0.0));
        assert!(
            !disk.linked(&walled, a, b, 0.5),
            "9 cells and half a cell of slack"
        );
        assert!(Reach::Unlimited.linked(&walled, a, Cell::new(0, 40), 0.0));
    }
}
