//! Airtime on one shared radio channel: who may send how much in a step (docs/guide/radio.md).
//!
//! The channel carries `capacity` bytes a step. A sender's bytes occupy it for every node within
//! its interference range, itself included: the nodes `u` with `hears[w]` containing `u`, or
//! `w == u`, form w's closed neighbourhood N\[w\], and the channel as node w hears it is busy for
//! the airtime of every sender in N\[w\]. The one constraint of the model is that no node's channel
//! is busy beyond its capacity:
//!
//!   for every node w:  Σ_{u ∈ N\[w\]} (x_u + pre_u) ≤ capacity
//!
//! with x_u the airtime sender u is given and pre_u what it already has in the air (a frame it
//! sends again, bytes it ran over its last share). Senders that no node hears together share
//! nothing (spatial reuse); n senders that all hear each other share one capacity. Among the
//! allocations that meet the constraint, [`allocate`](crate::airtime::allocate) gives the max-min
//! fair one (progressive filling, Bertsekas & Gallager's water-filling over the neighbourhoods):
//! every sender's share grows at the same pace until its demand is met or a neighbourhood it is in
//! is full. It fills twice: first up to each sender's demand, then what is left of the channel to
//! every sender that has a link (the demand is an estimate from the step before; a sender that
//! suddenly has more to say finds room at once when the channel has room).
//!
//! This is a fluid model of a perfect MAC: it has no collisions, no back-off, and no hidden
//! terminals: in a chain A – B – C where A and C do not hear each other, B hears both, so its
//! neighbourhood holds A's and C's airtime together and they get half each — what a MAC that
//! schedules them perfectly (RTS/CTS with no losses) would reach, an upper bound on 802.11's.
//! Pure and deterministic: the same inputs give the same shares, bit for bit.

/// What one sender asks of the channel in a step, in bytes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Claim {
    /// What it will send at the most (`f64::INFINITY`: all it gets); 0 if it has no link.
    pub demand: f64,
    /// What it has in the air already this step, outside its share (retransmissions, overrun).
    pub preload: f64,
    /// Whether it has a link to send on: only those take the channel's spare room.
    pub linked: bool,
}

/// Each sender's airtime in bytes for one step: `claims[u]` is sender u's, `hears[w]` the nodes
/// (other than w) whose transmissions w hears. `hears` must be symmetric; a node out of range
/// of everyone has an empty list. Meets the neighbourhood constraint (up to float rounding) and
/// gives no sender more than it may take.
pub fn allocate(capacity: f64, hears: &[Vec<usize>], claims: &[Claim]) -> Vec<f64> {
    let n = claims.len();
    debug_assert_eq!(hears.len(), n);
    let mut x = vec![0.0; n];
    if capacity <= 0.0 || n == 0 {
        return x;
    }
    // The load of each node's neighbourhood.
    let mut load: Vec<f64> = (0..n)
        .map(|w| claims[w].preload + hears[w].iter().map(|&u| claims[u].preload).sum::<f64>())
        .collect();
    let demand: Vec<f64> = claims.iter().map(|c| c.demand.max(0.0)).collect();
    fill(capacity, hears, &demand, &mut x, &mut load);
    let spare: Vec<f64> = (claims.iter())
        .map(|c| if c.linked { f64::INFINITY } else { 0.0 })
        .collect();
    fill(capacity, hears, &spare, &mut x, &mut load);
    x
}

/// Progressive filling from `x` up to `limit`: every sender not yet at its limit, and in no full
/// neighbourhood, gets the same increment, as large as the tightest neighbourhood or limit
/// allows; those that reach a limit or a full neighbourhood stop. Each round stops at least one
/// sender or fills at least one neighbourhood, so it ends within 2n rounds.
fn fill(capacity: f64, hears: &[Vec<usize>], limit: &[f64], x: &mut [f64], load: &mut [f64]) {
    let n = x.len();
    let eps = capacity * 1e-9;
    let closed = |w: usize| std::iter::once(w).chain(hears[w].iter().copied());
    let mut active: Vec<bool> = (0..n).map(|u| limit[u] - x[u] > eps).collect();
    loop {
        for (w, &l) in load.iter().enumerate() {
            if capacity - l <= eps {
                for u in closed(w) {
                    active[u] = false;
                }
            }
        }
        let mut step = f64::INFINITY;
        for (w, &l) in load.iter().enumerate() {
            let k = closed(w).filter(|&u| active[u]).count();
            if k > 0 {
                step = step.min((capacity - l) / k as f64);
            }
        }
        for u in (0..n).filter(|&u| active[u]) {
            step = step.min(limit[u] - x[u]);
        }
        if !step.is_finite() {
            return;
        }
        for u in 0..n {
            if !active[u] {
                continue;
            }
            x[u] += step;
            for w in closed(u) {
                load[w] += step;
            }
            if limit[u] - x[u] <= eps {
                active[u] = false;
            }
        }
    }
}

/// A sender's airtime split among its links: each link up to its `demand` (`f64::INFINITY`: all
/// it gets), max-min fairly; what the demands leave goes to every link alike.
pub fn split(total: f64, demand: &[f64]) -> Vec<f64> {
    let k = demand.len();
    let mut give = vec![0.0; k];
    if k == 0 || total <= 0.0 {
        return give;
    }
    let eps = total * 1e-12;
    let mut left = total;
    let mut open: Vec<usize> = (0..k).filter(|&i| demand[i] > 0.0).collect();
    while left > eps && !open.is_empty() {
        let each = open
            .iter()
            .map(|&i| demand[i] - give[i])
            .fold(left / open.len() as f64, f64::min);
        for &i in &open {
            give[i] += each;
        }
        left -= each * open.len() as f64;
        open.retain(|&i| demand[i] - give[i] > eps);
    }
    if left > eps {
        for g in &mut give {
            *g += left / k as f64;
        }
    }
    give
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn saturated(n: usize) -> Vec<Claim> {
        vec![
            Claim {
                demand: f64::INFINITY,
                preload: 0.0,
                linked: true,
            };
            n
        ]
    }

    /// Everybody hears everybody.
    fn clique(n: usize) -> Vec<Vec<usize>> {
        (0..n)
            .map(|w| (0..n).filter(|&u| u != w).collect())
            .collect()
    }

    fn graph(n: usize, edges: &[(usize, usize)]) -> Vec<Vec<usize>> {
        let mut g = vec![Vec::new(); n];
        for &(a, b) in edges {
            g[a].push(b);
            g[b].push(a);
        }
        g
    }

    #[test]
    fn n_saturated_senders_in_one_collision_domain_get_one_nth_each() {
        for n in 1..=12 {
            let x = allocate(1000.0, &clique(n), &saturated(n));
            for share in x {
                assert!((share - 1000.0 / n as f64).abs() < 1e-6, "n = {n}: {share}");
            }
        }
    }

    #[test]
    fn pairs_out_of_each_others_range_each_get_the_whole_channel() {
        // Two pairs, 0–1 and 2–3; one sender in each.
        let g = graph(4, &[(0, 1), (2, 3)]);
        let mut c = saturated(4);
        c[1].demand = 0.0;
        c[3].demand = 0.0;
        c[1].linked = false;
        c[3].linked = false;
        let x = allocate(1000.0, &g, &c);
        assert_eq!(x, vec![1000.0, 0.0, 1000.0, 0.0]);
        // Both ends of each pair sending: half each, in each pair.
        let x = allocate(1000.0, &g, &saturated(4));
        assert!(x.iter().all(|&s| (s - 500.0).abs() < 1e-6), "{x:?}");
    }

    #[test]
    fn a_chain_whose_ends_do_not_hear_each_other_shares_at_the_middle() {
        // A – B – C: B hears both ends, A and C do not hear each other.
        let g = graph(3, &[(0, 1), (1, 2)]);
        let x = allocate(900.0, &g, &saturated(3));
        assert!(x.iter().all(|&s| (s - 300.0).abs() < 1e-6), "{x:?}");
        // B silent: A and C still share B's channel, half each (no hidden-terminal collisions).
        let mut c = saturated(3);
        c[1] = Claim {
            demand: 0.0,
            preload: 0.0,
            linked: false,
        };
        let x = allocate(900.0, &g, &c);
        assert_eq!(x, vec![450.0, 0.0, 450.0]);
    }

    #[test]
    fn a_small_demand_is_met_and_the_rest_goes_to_the_others() {
        let mut c = saturated(3);
        c[0].demand = 100.0;
        let x = allocate(1000.0, &clique(3), &c);
        // Demands first: 100 to sender 0, 450 to each other; nothing left for the spare round.
        assert!(
            (x[0] - 100.0).abs() < 1e-6 && (x[1] - 450.0).abs() < 1e-6,
            "{x:?}"
        );
        // All demands small: each gets its demand, then the spare room alike.
        let c = vec![
            Claim {
                demand: 100.0,
                preload: 0.0,
                linked: true,
            };
            2
        ];
        let x = allocate(1000.0, &clique(2), &c);
        assert!(x.iter().all(|&s| (s - 500.0).abs() < 1e-6), "{x:?}");
    }

    #[test]
    fn what_is_in_the_air_already_comes_off_the_neighbourhood() {
        let mut c = saturated(2);
        c[0].preload = 400.0;
        let x = allocate(1000.0, &clique(2), &c);
        assert!(
            (x[0] - 300.0).abs() < 1e-6 && (x[1] - 300.0).abs() < 1e-6,
            "{x:?}"
        );
        // More in the air than the channel holds: nobody gets anything.
        c[0].preload = 5000.0;
        assert_eq!(allocate(1000.0, &clique(2), &c), vec![0.0, 0.0]);
    }

    #[test]
    fn a_senders_share_splits_among_its_links_by_demand() {
        let s = split(900.0, &[100.0, f64::INFINITY, f64::INFINITY]);
        assert!(
            (s[0] - 100.0).abs() < 1e-9 && (s[1] - 400.0).abs() < 1e-9,
            "{s:?}"
        );
        let s = split(900.0, &[100.0, 200.0, 0.0]);
        // Demands met (300), the 600 left alike to all three.
        assert!(
            (s[0] - 300.0).abs() < 1e-9 && (s[2] - 200.0).abs() < 1e-9,
            "{s:?}"
        );
        assert!(split(900.0, &[]).is_empty());
    }

    fn arb_case() -> impl Strategy<Value = (Vec<Vec<usize>>, Vec<Claim>)> {
        (1usize..14).prop_flat_map(|n| {
            let edges = proptest::collection::vec((0..n, 0..n), 0..n * 3);
            let claims = proptest::collection::vec(
                (
                    prop_oneof![Just(f64::INFINITY), 0.0..1500.0f64],
                    prop_oneof![Just(0.0), 0.0..600.0f64],
                    any::<bool>(),
                ),
                n,
            );
            (Just(n), edges, claims).prop_map(|(n, edges, claims)| {
                let mut g = vec![Vec::new(); n];
                for (a, b) in edges {
                    if a != b && !g[a].contains(&b) {
                        g[a].push(b);
                        g[b].push(a);
                    }
                }
                let claims = claims
                    .into_iter()
                    .map(|(demand, preload, linked)| Claim {
                        demand: if linked { demand } else { 0.0 },
                        preload,
                        linked,
                    })
                    .collect();
                (g, claims)
            })
        })
    }

    proptest! {
        /// Invariant: no node's neighbourhood is busy beyond the capacity (unless what was in the
        /// air already is), no share is negative, a sender without a link gets nothing; the
        /// channel is used up (every sender with a link is in a full neighbourhood); and it is
        /// max-min fair: a sender short of its demand is in a full neighbourhood where nobody
        /// got more than it did.
        #[test]
        fn shares_fit_every_neighbourhood_and_are_max_min_fair((g, c) in arb_case()) {
            let cap = 1000.0;
            let x = allocate(cap, &g, &c);
            let closed = |w: usize| std::iter::once(w).chain(g[w].iter().copied()).collect::<Vec<_>>();
            let load = |w: usize| closed(w).iter().map(|&u| x[u] + c[u].preload).sum::<f64>();
            let pre = |w: usize| closed(w).iter().map(|&u| c[u].preload).sum::<f64>();
            let full = |w: usize| load(w) >= cap - 1e-6;
            for w in 0..x.len() {
                prop_assert!(x[w] >= 0.0);
                if !c[w].linked {
                    prop_assert_eq!(x[w], 0.0);
                }
                prop_assert!(load(w) <= cap.max(pre(w)) + 1e-6, "node {}: {} > {}", w, load(w), cap);
            }
            for u in (0..x.len()).filter(|&u| c[u].linked) {
                prop_assert!(closed(u).into_iter().any(full), "sender {} left room: {:?}", u, x);
                if x[u] + 1e-6 < c[u].demand {
                    let fair = closed(u).into_iter().any(|w| {
                        full(w) && closed(w).iter().all(|&v| x[v] <= x[u] + 1e-6)
                    });
                    prop_assert!(fair, "sender {} (share {}) could have had more: {:?}", u, x[u], x);
                }
            }
        }

        /// Invariant: a split gives out exactly the total, and no link less than another that is
        /// short of its demand.
        #[test]
        fn a_split_gives_out_the_whole_share(total in 0.0..5000.0f64,
                demand in proptest::collection::vec(prop_oneof![Just(f64::INFINITY), 0.0..2000.0f64], 1..8)) {
            let s = split(total, &demand);
            prop_assert!((s.iter().sum::<f64>() - total).abs() < 1e-6 * total.max(1.0));
            for i in 0..s.len() {
                if s[i] + 1e-6 < demand[i] {
                    prop_assert!(s.iter().all(|&o| o <= s[i] + 1e-6), "{:?} for {:?}", s, demand);
                }
            }
        }
    }
}
