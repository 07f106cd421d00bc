//! Deltas between approximations and the op log with save points (thesis §4.2.3,
//! Algorithms 4–5, §6.4 Table 6.1; docs/design.md §4.3).
//!
//! One step's change A_{t−1} → A_t is a list of [`Op`](crate::exchange::delta::Op)s: per object
//! whose vertices or kind changed a `chg` (or `em` for a new object, `rm` for a vanished one) that
//! selects it, then the minimum edit script of its vertex array — Levenshtein DP with substitution
//! cost 0 for equal vertices (the extracted Algorithm 4 prints this test inverted), backtraced from
//! the end so that positions always refer to the array as the receiver holds it — and a closing
//! `save`. A vertex is its point *and* its edge occupancy, so an edge turning occupied is a `rep`.
//!
//! `em`/`chg` carry the object's vertex count after its edits, so a receiver
//! ([`crate::exchange::oplog::Replica`]) catches a corrupt or misordered stream at the next object
//! op or save instead of silently producing a wrong map.
//!
//! For huge objects the DP is bounded: after trimming the common prefix and suffix, a middle larger
//! than [`DP_LIMIT`](crate::exchange::delta::DP_LIMIT) cells is cut at anchors (points unique in
//! both arrays, in the same order) and each gap gets its own DP — near-minimal, and linear-ish
//! instead of quadratic.

use std::collections::HashMap;

use proto::msg::Traffic;

use crate::mapping::approx::{Approximation, ObjectId, Vertex};
use crate::mapping::contour::Kind;

/// Largest Levenshtein table (cells) computed in one piece.
pub const DP_LIMIT: usize = 1 << 20;

/// One package of the delta stream (the six change types and `save` of thesis Table 6.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Op {
    /// Insert `v` at `pos` of the selected object (`pos` ≤ length).
    Insert { pos: u32, v: Vertex },
    /// Replace the vertex at `pos` of the selected object.
    Replace { pos: u32, v: Vertex },
    /// Delete the vertex at `pos` of the selected object.
    Delete { pos: u32 },
    /// A new, empty object; selected; will have `len` vertices after its edits.
    Emerge { id: ObjectId, kind: Kind, len: u32 },
    /// Selects an existing object, sets its kind; it will have `len` vertices after its edits.
    Change { id: ObjectId, kind: Kind, len: u32 },
    /// The object vanished.
    Remove { id: ObjectId },
    /// Everything since the last save point is one consistent step.
    Save,
}

impl Op {
    /// Its package type, for accounting bytes by type.
    pub fn kind(&self) -> Traffic {
        match self {
            Op::Insert { .. } => Traffic::Ins,
            Op::Replace { .. } => Traffic::Rep,
            Op::Delete { .. } => Traffic::Del,
            Op::Emerge { .. } => Traffic::Em,
            Op::Change { .. } => Traffic::Chg,
            Op::Remove { .. } => Traffic::Rm,
            Op::Save => Traffic::Save,
        }
    }
}

/// The ops turning `old` into `new`, ending with a save point; empty if they are equal.
pub fn diff(old: &Approximation, new: &Approximation) -> Vec<Op> {
    let mut ops = Vec::new();
    let mut ids: Vec<ObjectId> = old
        .objects
        .keys()
        .chain(new.objects.keys())
        .copied()
        .collect();
    ids.sort_unstable();
    ids.dedup();
    for id in ids {
        match (old.objects.get(&id), new.objects.get(&id)) {
            (Some(_), None) => ops.push(Op::Remove { id }),
            (None, Some(n)) => {
                ops.push(Op::Emerge {
                    id,
                    kind: n.kind,
                    len: n.vertices.len() as u32,
                });
                ops.extend(script(&[], &n.vertices));
            }
            (Some(o), Some(n)) if o != n => {
                ops.push(Op::Change {
                    id,
                    kind: n.kind,
                    len: n.vertices.len() as u32,
                });
                ops.extend(script(&o.vertices, &n.vertices));
            }
            _ => {}
        }
    }
    if !ops.is_empty() {
        ops.push(Op::Save);
    }
    ops
}

/// Vertex ops turning `old` into `new`, in application order.
pub fn script(old: &[Vertex], new: &[Vertex]) -> Vec<Op> {
    let pre = old.iter().zip(new).take_while(|(a, b)| a == b).count();
    let max_suf = old.len().min(new.len()) - pre;
    let suf = old
        .iter()
        .rev()
        .zip(new.iter().rev())
        .take(max_suf)
        .take_while(|(a, b)| a == b)
        .count();
    let (o, n) = (&old[pre..old.len() - suf], &new[pre..new.len() - suf]);
    let mut ops = Vec::new();
    if (o.len() + 1) * (n.len() + 1) <= DP_LIMIT {
        levenshtein(o, n, pre, &mut ops);
    } else {
        anchored(o, n, pre, &mut ops);
    }
    ops
}

/// Algorithms 4–5: the minimum edit script of `o` → `n`, whose first vertex sits at `base`.
fn levenshtein(o: &[Vertex], n: &[Vertex], base: usize, ops: &mut Vec<Op>) {
    let (m, w) = (o.len(), n.len() + 1);
    let mut eda = vec![0u32; (m + 1) * w];
    (0..=m).for_each(|i| eda[i * w] = i as u32);
    (0..w).for_each(|j| eda[j] = j as u32);
    for i in 1..=m {
        for j in 1..w {
            let cost = u32::from(o[i - 1] != n[j - 1]);
            let best = (eda[(i - 1) * w + j] + 1).min(eda[i * w + j - 1] + 1);
            eda[i * w + j] = best.min(eda[(i - 1) * w + j - 1] + cost);
        }
    }
    let (mut i, mut j) = (m, n.len());
    while i > 0 || j > 0 {
        let here = eda[i * w + j];
        let diagonal =
            i > 0 && j > 0 && here == eda[(i - 1) * w + j - 1] + u32::from(o[i - 1] != n[j - 1]);
        let pos = (base + i) as u32;
        if diagonal {
            if o[i - 1] != n[j - 1] {
                ops.push(Op::Replace {
                    pos: pos - 1,
                    v: n[j - 1],
                });
            }
            (i, j) = (i - 1, j - 1);
        } else if i > 0 && here == eda[(i - 1) * w + j] + 1 {
            ops.push(Op::Delete { pos: pos - 1 });
            i -= 1;
        } else {
            ops.push(Op::Insert { pos, v: n[j - 1] });
            j -= 1;
        }
    }
}

/// Splits a large problem at anchors and runs the DP per gap, last gap first.
fn anchored(o: &[Vertex], n: &[Vertex], base: usize, ops: &mut Vec<Op>) {
    let pairs = anchors(o, n);
    let mut ends: Vec<(usize, usize)> = pairs.clone();
    ends.push((o.len(), n.len()));
    let mut starts = vec![(0, 0)];
    starts.extend(pairs.iter().map(|&(i, j)| (i + 1, j + 1)));
    for (k, (&(i0, j0), &(i1, j1))) in starts.iter().zip(&ends).enumerate().rev() {
        let (go, gn) = (&o[i0..i1], &n[j0..j1]);
        if (go.len() + 1) * (gn.len() + 1) <= DP_LIMIT {
            levenshtein(go, gn, base + i0, ops);
        } else {
            // No anchor inside a huge gap: replace what overlaps, then delete or insert.
            plain(go, gn, base + i0, ops);
        }
        if k > 0 {
            let (ai, aj) = pairs[k - 1];
            if o[ai] != n[aj] {
                ops.push(Op::Replace {
                    pos: (base + ai) as u32,
                    v: n[aj],
                });
            }
        }
    }
}

/// A valid (not minimal) script for a gap without anchors.
fn plain(o: &[Vertex], n: &[Vertex], base: usize, ops: &mut Vec<Op>) {
    let common = o.len().min(n.len());
    for i in (common..o.len()).rev() {
        ops.push(Op::Delete {
            pos: (base + i) as u32,
        });
    }
    for j in (common..n.len()).rev() {
        ops.push(Op::Insert {
            pos: (base + common) as u32,
            v: n[j],
        });
    }
    for i in (0..common).rev().filter(|&i| o[i] != n[i]) {
        ops.push(Op::Replace {
            pos: (base + i) as u32,
            v: n[i],
        });
    }
}

/// Index pairs of points unique in both arrays, forming the longest chain increasing in both.
fn anchors(o: &[Vertex], n: &[Vertex]) -> Vec<(usize, usize)> {
    let count = |vs: &[Vertex]| {
        let mut m: HashMap<crate::mapping::qpoint::QPoint, (usize, usize)> = HashMap::new();
        for (i, v) in vs.iter().enumerate() {
            m.entry(v.p).and_modify(|e| e.1 += 1).or_insert((i, 1));
        }
        m
    };
    let (co, cn) = (count(o), count(n));
    let mut pairs: Vec<(usize, usize)> = co
        .iter()
        .filter(|(_, &(_, k))| k == 1)
        .filter_map(|(p, &(i, _))| cn.get(p).filter(|&&(_, k)| k == 1).map(|&(j, _)| (i, j)))
        .collect();
    pairs.sort_unstable();
    longest_increasing(&pairs)
}

/// The longest subsequence of `pairs` (sorted by `.0`) with strictly increasing `.1`.
fn longest_increasing(pairs: &[(usize, usize)]) -> Vec<(usize, usize)> {
    let (mut tails, mut prev): (Vec<usize>, Vec<Option<usize>>) = (Vec::new(), Vec::new());
    for (k, &(_, j)) in pairs.iter().enumerate() {
        let at = tails.partition_point(|&t| pairs[t].1 < j);
        prev.push(at.checked_sub(1).map(|a| tails[a]));
        if at == tails.len() {
            tails.push(k);
        } else {
            tails[at] = k;
        }
    }
    let mut out = Vec::new();
    let mut k = tails.last().copied();
    while let Some(i) = k {
        out.push(pairs[i]);
        k = prev[i];
    }
    out.reverse();
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mapping::approximator::Approximator;
    use crate::mapping::contour::Contours;
    use crate::testutil::arb_exploration;
    use proptest::prelude::*;
    use proto::grid::{Grid, Occ};

    fn v(x: i32) -> Vertex {
        Vertex {
            p: crate::mapping::qpoint::QPoint::new(x, 0),
            occ: Occ::Occupied,
            bound: 0,
        }
    }

    fn word(s: &str) -> Vec<Vertex> {
        s.bytes().map(|b| v(i32::from(b))).collect()
    }

    /// Applies vertex ops to an array the way a receiver does.
    fn apply(old: &[Vertex], ops: &[Op]) -> Vec<Vertex> {
        let mut a = old.to_vec();
        for op in ops {
            match *op {
                Op::Insert { pos, v } => a.insert(pos as usize, v),
                Op::Replace { pos, v } => a[pos as usize] = v,
                Op::Delete { pos } => {
                    a.remove(pos as usize);
                }
                _ => panic!("not a vertex op: {op:?}"),
            }
        }
        a
    }

    #[test]
    fn scripts_have_minimum_length() {
        for (a, b, d) in [
            ("kitten", "sitting", 3),
            ("", "abc", 3),
            ("abc", "", 3),
            ("abc", "abc", 0),
            ("ab", "ba", 2),
            ("flaw", "lawn", 2),
        ] {
            let ops = script(&word(a), &word(b));
            assert_eq!(ops.len(), d, "{a} -> {b}: {ops:?}");
            assert_eq!(apply(&word(a), &ops), word(b));
        }
    }

    #[test]
    fn an_occupancy_change_is_a_replace() {
        let old = word("abc");
        let mut new = old.clone();
        new[1].occ = Occ::Free;
        assert_eq!(script(&old, &new), vec![Op::Replace { pos: 1, v: new[1] }]);
    }

    #[test]
    fn huge_objects_use_anchors_and_stay_exact() {
        let old: Vec<Vertex> = (0..3000).map(v).collect();
        let mut new = old.clone();
        new.remove(2500);
        new.insert(100, v(-7));
        new[1500].occ = Occ::Unknown;
        let ops = script(&old, &new);
        assert_eq!(apply(&old, &ops), new);
        assert_eq!(ops.len(), 3, "{ops:?}");
    }

    /// The op kinds of the delta between consecutive ASCII grids (approximated with `s`).
    fn check(steps: &[&str], s: f64, expect: &[&str]) {
        let mut ax = Approximator::new();
        let mut prev = Approximation::default();
        for (pic, want) in steps.iter().zip(expect) {
            let g = Grid::from_ascii(pic);
            let a = ax.step(&Contours::extract(&g), &g, s).clone();
            let kinds: Vec<String> = diff(&prev, &a)
                .iter()
                .map(|o| format!("{:?}", o.kind()).to_lowercase())
                .collect();
            assert_eq!(kinds.join(" "), *want, "delta into\n{pic}");
            prev = a;
        }
    }

    #[test]
    fn deltas_of_the_thesis_cases() {
        let empty = "......\n......\n......";
        let one = "......\n..#...\n......";
        check(
            &[empty, one, one, empty],
            0.0,
            &["em ins ins save", "em ins ins save", "", "rm save"],
        );
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(128))]

        #[test]
        fn scripts_transform_exactly(a in proptest::collection::vec(0i32..6, 0..40), b in proptest::collection::vec(0i32..6, 0..40)) {
            let (a, b): (Vec<Vertex>, Vec<Vertex>) = (a.into_iter().map(v).collect(), b.into_iter().map(v).collect());
            prop_assert_eq!(apply(&a, &script(&a, &b)), b);
        }

        #[test]
        fn anchored_scripts_transform_exactly(edits in proptest::collection::vec((0usize..1200, 0i32..3, -50i32..0), 0..30)) {
            let old: Vec<Vertex> = (0..1200).map(v).collect();
            let mut new = old.clone();
            for (at, what, val) in edits {
                let at = at % (new.len() + 1);
                match what {
                    0 => new.insert(at, v(val)),
                    1 if at < new.len() => { new.remove(at); }
                    _ if at < new.len() => new[at] = v(val),
                    _ => {}
                }
            }
            prop_assert_eq!(apply(&old, &script(&old, &new)), new);
        }

        #[test]
        fn deltas_turn_each_step_into_the_next(seq in arb_exploration(18, 8), s in 0.0f64..5.0) {
            let mut ax = Approximator::new();
            let mut replica = crate::exchange::oplog::Replica::new();
            for g in &seq {
                let prev = ax.current().clone();
                let a = ax.step(&Contours::extract(g), g, s).clone();
                for op in diff(&prev, &a) {
                    replica.apply(&op).map_err(|e| TestCaseError::fail(e.to_string()))?;
                }
                prop_assert_eq!(replica.committed(), &a);
            }
        }
    }
}
