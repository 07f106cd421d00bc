//! Graph components: which nodes can reach each other over undirected links, directly or
//! through others. The one implementation the launcher's communication level and contact
//! tracking, and the `pack` strategy's connectivity check, use.

/// The connected components of nodes `0..nodes` under `links` (union–find): each node's
/// component's representative, the lowest node of the component. Links naming a node outside
/// `0..nodes` are ignored.
pub fn components<N: Copy + Into<usize>>(nodes: usize, links: &[(N, N)]) -> Vec<usize> {
    fn find(parent: &mut [usize], mut x: usize) -> usize {
        while parent[x] != x {
            parent[x] = parent[parent[x]];
            x = parent[x];
        }
        x
    }
    let mut parent: Vec<usize> = (0..nodes).collect();
    for &(a, b) in links {
        let (a, b) = (a.into(), b.into());
        if a >= nodes || b >= nodes {
            continue;
        }
        let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
        parent[ra.max(rb)] = ra.min(rb);
    }
    (0..nodes).map(|x| find(&mut parent, x)).collect()
}

/// Whether nodes `0..nodes` form one component under `links` (no nodes: true).
pub fn connected<N: Copy + Into<usize>>(nodes: usize, links: &[(N, N)]) -> bool {
    let roots = components(nodes, links);
    roots.iter().all(|&r| r == 0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The nodes reachable from `from` by breadth-first search, the plain definition.
    fn reached(nodes: usize, links: &[(usize, usize)], from: usize) -> Vec<bool> {
        let mut seen = vec![false; nodes];
        seen[from] = true;
        let mut queue = vec![from];
        while let Some(n) = queue.pop() {
            for &(a, b) in links {
                for (x, y) in [(a, b), (b, a)] {
                    if x == n && y < nodes && !seen[y] {
                        seen[y] = true;
                        queue.push(y);
                    }
                }
            }
        }
        seen
    }

    #[test]
    fn two_islands_and_a_stranger() {
        let links: &[(u16, u16)] = &[(0, 1), (2, 3), (3, 4), (1, 9)];
        assert_eq!(components(6, links), vec![0, 0, 2, 2, 2, 5]);
        assert!(!connected(6, links));
        assert!(connected(2, links));
        assert!(connected::<u16>(0, &[]));
    }

    proptest! {
        #[test]
        fn same_representative_iff_reachable(
            nodes in 1usize..12,
            links in prop::collection::vec((0usize..14, 0usize..14), 0..20),
        ) {
            let roots = components(nodes, &links);
            for a in 0..nodes {
                prop_assert!(roots[a] <= a, "the representative is the lowest node");
                let from_a = reached(nodes, &links, a);
                for b in 0..nodes {
                    prop_assert_eq!(roots[a] == roots[b], from_a[b]);
                }
            }
            prop_assert_eq!(connected(nodes, &links), reached(nodes, &links, 0).iter().all(|&r| r));
        }
    }
}
