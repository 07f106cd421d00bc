//! Who can talk to whom over a step's links (netem's `up`, from `links.csv`): Rooker and Birk's
//! communication level (RoboCup 2005, Fig. 6), for every strategy, and the `pack` leaders'
//! judgements of their links set against what netem then did.

use std::collections::{BTreeMap, BTreeSet};

use proto::graph::components;
use proto::msg::{Judged, RobotId, Step};
use serde::{Deserialize, Serialize};

/// The links up at each step, as node pairs (from `links.csv`'s `up`).
pub type UpLinks = BTreeMap<Step, Vec<(RobotId, RobotId)>>;

/// The communication level: the percentage of pairs of robots `0..robots` that can reach each
/// other over `links`, directly or through others (any of `nodes` nodes: the base station may
/// relay). One robot alone is fully in touch with itself: 100.
pub fn comm_level_pct(robots: usize, nodes: usize, links: &[(RobotId, RobotId)]) -> f64 {
    let pairs = robots * robots.saturating_sub(1) / 2;
    if pairs == 0 {
        return 100.0;
    }
    let roots = components(nodes.max(robots), links);
    let mut together = 0usize;
    for a in 0..robots {
        for b in a + 1..robots {
            together += usize::from(roots[a] == roots[b]);
        }
    }
    100.0 * together as f64 / pairs as f64
}

/// `link_judgement` in `summary.json`: how the `pack` leaders' expectations of their links
/// compared with netem's verdicts at the steps they were made for.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LinkJudgement {
    /// Robot pairs judged (each judgement: every pair of its group).
    pub pairs: u64,
    /// Judged up, but netem had them down.
    pub wrong_up: u64,
    /// Judged down, but netem had them up.
    pub wrong_down: u64,
    /// (wrong_up + wrong_down) / pairs, in percent.
    pub wrong_pct: f64,
    /// Judgements whose group, connected by the leader's estimate, was split in netem's truth.
    pub split_unforeseen: u64,
    pub judgements: u64,
}

/// Checks every judgement made for a step up to `last` against the links up at that step;
/// `None` without judgements.
pub fn check_judgements(judged: &[Judged], up: &UpLinks, last: Step) -> Option<LinkJudgement> {
    let mut out = LinkJudgement::default();
    for j in judged.iter().filter(|j| j.step <= last) {
        let actual: BTreeSet<(RobotId, RobotId)> = up
            .get(&j.step)
            .map(|l| l.iter().map(|&(a, b)| (a.min(b), a.max(b))).collect())
            .unwrap_or_default();
        let expected: BTreeSet<(RobotId, RobotId)> =
            j.up.iter().map(|&(a, b)| (a.min(b), a.max(b))).collect();
        for (i, &a) in j.group.iter().enumerate() {
            for &b in &j.group[i + 1..] {
                let pair = (a.min(b), a.max(b));
                out.pairs += 1;
                match (expected.contains(&pair), actual.contains(&pair)) {
                    (true, false) => out.wrong_up += 1,
                    (false, true) => out.wrong_down += 1,
                    _ => {}
                }
            }
        }
        let connected = |links: &BTreeSet<(RobotId, RobotId)>| {
            let index: BTreeMap<RobotId, usize> =
                j.group.iter().enumerate().map(|(i, &r)| (r, i)).collect();
            let local: Vec<(RobotId, RobotId)> = links
                .iter()
                .filter_map(|(a, b)| {
                    let (ia, ib) = (*index.get(a)?, *index.get(b)?);
                    Some((ia as RobotId, ib as RobotId))
                })
                .collect();
            proto::graph::connected(j.group.len(), &local)
        };
        if !j.group.is_empty() && connected(&expected) && !connected(&actual) {
            out.split_unforeseen += 1;
        }
        out.judgements += 1;
    }
    if out.judgements == 0 {
        return None;
    }
    out.wrong_pct = if out.pairs == 0 {
        0.0
    } else {
        100.0 * (out.wrong_up + out.wrong_down) as f64 / out.pairs as f64
    };
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_level_counts_pairs_in_touch_directly_or_through_others() {
        // 0–1–2 in a chain, 3 alone: pairs (0,1), (0,2), (1,2) of 6.
        assert_eq!(comm_level_pct(4, 4, &[(0, 1), (1, 2)]), 50.0);
        assert_eq!(comm_level_pct(4, 4, &[(0, 1), (1, 2), (2, 3)]), 100.0);
        assert_eq!(comm_level_pct(4, 4, &[]), 0.0);
        assert_eq!(comm_level_pct(1, 1, &[]), 100.0);
        // The base station (node 4) relays, but is no pair of its own.
        assert_eq!(
            comm_level_pct(4, 5, &[(0, 4), (1, 4), (2, 4), (3, 4)]),
            100.0
        );
        // Links to nodes beyond the team are ignored.
        assert_eq!(comm_level_pct(2, 2, &[(0, 7), (1, 7)]), 0.0);
    }

    #[test]
    fn judgements_are_checked_against_the_links_of_their_step() {
        let up: UpLinks = BTreeMap::from([(5, vec![(0, 1)]), (6, vec![(0, 1), (1, 2)])]);
        let j = |step, up: &[(RobotId, RobotId)]| Judged {
            step,
            group: vec![0, 1, 2],
            up: up.to_vec(),
        };
        // At 5: (0,1) right, (1,2) judged up but down, (0,2) right (down).
        let r = check_judgements(&[j(5, &[(0, 1), (2, 1)])], &up, 10).expect("judged");
        assert_eq!((r.pairs, r.wrong_up, r.wrong_down), (3, 1, 0));
        assert_eq!(r.split_unforeseen, 1, "2 was cut off");
        // At 6 it was all right; a judgement past the run's end is not counted.
        let r = check_judgements(&[j(6, &[(0, 1), (1, 2)]), j(11, &[])], &up, 10).expect("judged");
        assert_eq!(
            (r.pairs, r.wrong_up, r.wrong_down, r.judgements),
            (3, 0, 0, 1)
        );
        assert_eq!(r.wrong_pct, 0.0);
        // Judged down, was up.
        let r = check_judgements(&[j(6, &[(0, 1)])], &up, 10).expect("judged");
        assert_eq!((r.wrong_up, r.wrong_down, r.split_unforeseen), (0, 1, 0));
        assert!(check_judgements(&[], &up, 10).is_none());
    }
}
