//! Pacing (docs/design.md §4.4): a robot never offers a link more than its budget. Per neighbour, a
//! byte budget on the **simulated** clock ([`proto::budget`], the one netem shapes links with too)
//! meters the bytes the robot sends: the rate is the link's bandwidth, the burst a few steps of it
//! (and at least one whole log entry, so an entry larger than one step's budget still goes every
//! few steps instead of blocking the log forever). What does not fit waits in the logs;
//! [`crate::exchange::sharing`] reports how much.
//!
//! The budget answers "may these n bytes pass now?", while the exchange needs "how many bytes may
//! pass now?" to fill a message. So [`Pacer::available`](crate::radio::pacing::Pacer::available)
//! takes one byte as a probe, which tells the remaining burst capacity, and holds that byte for the
//! next [`Pacer::spend`](crate::radio::pacing::Pacer::spend): nothing is lost or granted twice.

use std::collections::HashMap;

use proto::budget::{ByteBudget, ByteRate, Take};
use proto::clock::{SimClock, SimTime};
use proto::msg::{RobotId, Step};

/// A link's metering: its rate, burst and how much a fresh budget is drained by at once (so
/// that it starts with one step's budget rather than a whole burst: a fresh connection is not
/// flooded).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Quota {
    rate: ByteRate,
    burst_cells: u32,
    burst_bytes: u64,
    start_drain: u32,
}

impl Quota {
    /// `None` for an unlimited rate.
    fn new(rate_bytes_per_s: Option<u64>, burst_bytes: u64, step_seconds: f64) -> Option<Quota> {
        rate_bytes_per_s.filter(|&r| r > 0).map(|rate| {
            let rate = ByteRate::new(rate);
            let burst_cells = rate.cells_up(burst_bytes).max(1);
            let step_cells =
                ((rate.bytes_per_s as f64 * step_seconds.max(0.0)) / rate.cell_bytes as f64) as u64;
            Quota {
                rate,
                burst_cells,
                burst_bytes,
                start_drain: u64::from(burst_cells).saturating_sub(step_cells.max(1)) as u32,
            }
        })
    }
}

/// One neighbour's budget and the probe bytes held for the next spend.
struct LinkBudget {
    quota: Quota,
    budget: ByteBudget<SimClock>,
    held: u64,
}

/// Per-neighbour byte budgets on the simulated clock.
pub struct Pacer {
    /// The links' rate unless told otherwise ([`Pacer::set_rate`]); `None`: unlimited.
    rate: Option<u64>,
    /// The burst at `rate`; a link of another rate gets the same burst in steps.
    burst_bytes: u64,
    step_seconds: f64,
    step_ns: u64,
    clock: SimClock,
    /// Links whose rate is not `rate`.
    rates: HashMap<RobotId, Option<u64>>,
    links: HashMap<RobotId, LinkBudget>,
}

impl Pacer {
    /// Budgets of `rate_bytes_per_s` (`None`: unlimited) per link with bursts of `burst_bytes`,
    /// for steps of `step_seconds` simulated seconds. A link starts with one step's budget.
    pub fn new(rate_bytes_per_s: Option<u64>, burst_bytes: u64, step_seconds: f64) -> Pacer {
        Pacer {
            rate: rate_bytes_per_s.filter(|&r| r > 0),
            burst_bytes,
            step_seconds,
            step_ns: (step_seconds.max(0.0) * 1e9).round() as u64,
            clock: SimClock::lockstep(),
            rates: HashMap::new(),
            links: HashMap::new(),
        }
    }

    /// Simulated time moves on to `step`.
    pub fn at_step(&self, step: Step) {
        self.clock
            .advance_to(SimTime(u64::from(step).saturating_mul(self.step_ns)));
    }

    /// `peer`'s link now has `rate_bytes_per_s` (`None`: unlimited), with a burst of as many
    /// steps as the default's. A change starts the link's budget afresh.
    pub fn set_rate(&mut self, peer: RobotId, rate_bytes_per_s: Option<u64>) {
        let rate = rate_bytes_per_s.filter(|&r| r > 0);
        if self.rate_of(peer) != rate {
            self.links.remove(&peer);
            self.rates.insert(peer, rate);
        }
    }

    /// `peer`'s link has the default rate again.
    pub fn default_rate(&mut self, peer: RobotId) {
        if self.rates.remove(&peer).is_some_and(|r| r != self.rate) {
            self.links.remove(&peer);
        }
    }

    fn rate_of(&self, peer: RobotId) -> Option<u64> {
        self.rates.get(&peer).copied().unwrap_or(self.rate)
    }

    fn quota(&self, peer: RobotId) -> Option<Quota> {
        let rate = self.rate_of(peer)?;
        let burst = match self.rate {
            Some(r) if r != rate => {
                ((self.burst_bytes as f64) * rate as f64 / r as f64).round() as u64
            }
            _ => self.burst_bytes,
        };
        Quota::new(Some(rate), burst, self.step_seconds)
    }

    /// Bytes `peer`'s link may carry now (`usize::MAX` if unlimited).
    pub fn available(&mut self, peer: RobotId) -> usize {
        let Some(quota) = self.quota(peer) else {
            return usize::MAX;
        };
        let cell = quota.rate.cell_bytes;
        let clock = &self.clock;
        let link = self.links.entry(peer).or_insert_with(|| {
            let budget = ByteBudget::new(quota.rate, quota.burst_cells, clock.clone());
            if quota.start_drain > 0 {
                let _ = budget.take(quota.start_drain);
            }
            LinkBudget {
                quota,
                budget,
                held: 0,
            }
        });
        match link.budget.take(1) {
            Take::Taken { remaining } => {
                // Probe bytes held from calls that sent nothing are the link's all the same, but
                // never lift what one step may send above the burst.
                link.held += cell;
                let avail = link.held + u64::from(remaining) * cell;
                usize::try_from(avail.min(link.quota.burst_bytes.max(cell))).unwrap_or(usize::MAX)
            }
            Take::NotYet { .. } | Take::OverBurst => {
                usize::try_from(link.held).unwrap_or(usize::MAX)
            }
        }
    }

    /// `bytes` were sent to `peer`: they are taken off its budget, as far as it reaches (a
    /// handshake is sent even when the budget is spent). Call after [`Pacer::available`].
    pub fn spend(&mut self, peer: RobotId, bytes: usize) {
        let Some(link) = self.links.get_mut(&peer) else {
            return;
        };
        let bytes = bytes as u64;
        let from_held = bytes.min(link.held);
        link.held -= from_held;
        let mut cells = (bytes - from_held).div_ceil(link.quota.rate.cell_bytes);
        while cells > 0 {
            let n = u32::try_from(cells).unwrap_or(u32::MAX);
            match link.budget.take(n) {
                Take::Taken { .. } => cells -= u64::from(n),
                // Over the budget: take what is left, one probe at a time tells how much.
                Take::NotYet { .. } | Take::OverBurst => {
                    if let Take::Taken { remaining } = link.budget.take(1) {
                        let rest = remaining.min(n.saturating_sub(1));
                        if rest > 0 {
                            let _ = link.budget.take(rest);
                        }
                    }
                    break;
                }
            }
        }
    }

    /// The link to `peer` went down: its budget starts afresh at the next contact.
    pub fn forget(&mut self, peer: RobotId) {
        self.links.remove(&peer);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_link_gets_its_rate_per_simulated_second_and_no_more() {
        // 1000 B/s, bursts of 4 steps of 1 s.
        let mut p = Pacer::new(Some(1000), 4000, 1.0);
        p.at_step(0);
        assert_eq!(
            p.available(1),
            1000,
            "a new link starts with one step's budget"
        );
        p.spend(1, 1000);
        assert_eq!(p.available(1), 0);
        p.at_step(1);
        let a = p.available(1);
        assert_eq!(a, 1000);
        p.spend(1, 300);
        assert_eq!(p.available(1), 700, "the probe byte is not lost");
        // Over 100 steps of sending all it may, a link carries 100 × rate (plus the start burst).
        let mut sent = 0;
        for step in 2..102 {
            p.at_step(step);
            let n = p.available(1);
            p.spend(1, n);
            sent += n;
        }
        assert_eq!(sent, 100 * 1000 + 700);
        // Idle steps save up at most the burst.
        p.at_step(200);
        assert_eq!(p.available(1), 4000);
    }

    #[test]
    fn spending_beyond_the_budget_empties_it_and_links_are_independent() {
        let mut p = Pacer::new(Some(500), 1000, 1.0);
        p.at_step(3);
        assert_eq!(p.available(2), 500);
        p.spend(2, 5000);
        assert_eq!(p.available(2), 0);
        assert_eq!(p.available(3), 500);
        p.forget(2);
        assert_eq!(p.available(2), 500);
        p.at_step(10);
        assert_eq!(p.available(2), 1000, "idle steps fill up to the burst");
    }

    #[test]
    fn a_link_told_another_rate_starts_afresh_at_that_rate() {
        // 1000 B/s, bursts of 4 steps of 1 s; link 1 drops to 250 B/s.
        let mut p = Pacer::new(Some(1000), 4000, 1.0);
        p.at_step(0);
        assert_eq!(p.available(1), 1000);
        p.spend(1, 1000);
        p.set_rate(1, Some(250));
        assert_eq!(p.available(1), 250, "one step's budget at the new rate");
        p.spend(1, 250);
        p.at_step(40);
        assert_eq!(p.available(1), 1000, "its burst is four steps of its rate");
        assert_eq!(p.available(2), 1000, "other links keep the default");
        // Told the rate it has: nothing changes.
        p.spend(1, 500);
        p.set_rate(1, Some(250));
        assert_eq!(p.available(1), 500);
        p.default_rate(1);
        assert_eq!(p.available(1), 1000, "back to the default, afresh");
        p.set_rate(1, None);
        assert_eq!(p.available(1), usize::MAX);
    }

    #[test]
    fn unlimited_meters_nothing() {
        let mut p = Pacer::new(None, 0, 1.0);
        assert_eq!(p.available(1), usize::MAX);
        p.spend(1, 1 << 30);
        assert_eq!(p.available(1), usize::MAX);
    }

    #[test]
    fn fast_links_use_multi_byte_cells_and_keep_their_rate() {
        let mut p = Pacer::new(Some(10_000_000), 40_000_000, 1.0);
        p.at_step(0);
        let a = p.available(1);
        assert!((a as f64 - 1e7).abs() < 1e7 * 0.001, "{a}");
        p.spend(1, a);
        p.at_step(1);
        let b = p.available(1);
        assert!((b as f64 - 1e7).abs() < 1e7 * 0.001, "{b}");
    }
}
