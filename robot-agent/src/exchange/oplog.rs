//! The op log and its save points, and a receiver's replica of another robot's approximation
//! (thesis §4.2.3, §5.1.2; docs/design.md §4.3).
//!
//! Each robot appends every step's delta ([`crate::exchange::delta::diff`]) to its own append-only,
//! indexed [`OpLog`](crate::exchange::oplog::OpLog); each step ends with a save point. Receivers
//! store other robots' logs as prefixes and apply them to a
//! [`Replica`](crate::exchange::oplog::Replica), which shows only the state at the last save point
//! it has applied: a transfer cut off mid-step never yields a broken polygon. Steps without change
//! append nothing (not even a save point).

use crate::exchange::delta::{diff, Op};
use crate::mapping::approx::{Approximation, ObjectId, Polygon, Vertex};

/// Why a received op cannot be applied.
#[derive(Debug, thiserror::Error, Clone, PartialEq, Eq)]
pub enum ApplyError {
    #[error("object {0} emerges but already exists")]
    Exists(ObjectId),
    #[error("object {0} does not exist")]
    Missing(ObjectId),
    #[error("vertex operation with no object selected")]
    NoObject,
    #[error("position {pos} out of range for {len} vertices")]
    Position { pos: u32, len: usize },
    #[error("object {id} has {got} vertices, its header announced {want}")]
    Length { id: ObjectId, got: usize, want: u32 },
    #[error("an earlier op failed; the replica must be rebuilt from its last save point")]
    Poisoned,
}

/// A receiver's copy of one robot's approximation, built op by op.
#[derive(Clone, Debug)]
pub struct Replica {
    committed: Approximation,
    /// [`Approximation::digest`] of `committed` (reported every step, changed only at a save).
    committed_digest: u64,
    working: Approximation,
    selected: Option<(ObjectId, u32)>,
    poisoned: bool,
}

impl Default for Replica {
    fn default() -> Replica {
        Replica {
            committed: Approximation::default(),
            committed_digest: Approximation::default().digest(),
            working: Approximation::default(),
            selected: None,
            poisoned: false,
        }
    }
}

impl Replica {
    pub fn new() -> Replica {
        Replica::default()
    }

    /// The approximation as of the last save point applied.
    pub fn committed(&self) -> &Approximation {
        &self.committed
    }

    /// [`Approximation::digest`] of [`Replica::committed`].
    pub fn committed_digest(&self) -> u64 {
        self.committed_digest
    }

    /// Forgets every op applied since the last save point, an error included: the replica is
    /// the committed approximation again, ready for the ops that follow that save point.
    pub fn rewind(&mut self) {
        self.working = self.committed.clone();
        self.selected = None;
        self.poisoned = false;
    }

    /// Applies one op. On error the replica refuses every further op (a later step's delta
    /// would apply to the wrong base); its committed state stays valid.
    pub fn apply(&mut self, op: &Op) -> Result<(), ApplyError> {
        if self.poisoned {
            return Err(ApplyError::Poisoned);
        }
        let r = self.apply_inner(op);
        self.poisoned = r.is_err();
        r
    }

    fn apply_inner(&mut self, op: &Op) -> Result<(), ApplyError> {
        match *op {
            Op::Emerge { id, kind, len } => {
                self.check_length()?;
                if self.working.objects.contains_key(&id) {
                    return Err(ApplyError::Exists(id));
                }
                self.working.objects.insert(
                    id,
                    Polygon {
                        kind,
                        vertices: Vec::new(),
                    },
                );
                self.selected = Some((id, len));
            }
            Op::Change { id, kind, len } => {
                self.check_length()?;
                self.working
                    .objects
                    .get_mut(&id)
                    .ok_or(ApplyError::Missing(id))?
                    .kind = kind;
                self.selected = Some((id, len));
            }
            Op::Remove { id } => {
                self.check_length()?;
                self.working
                    .objects
                    .remove(&id)
                    .ok_or(ApplyError::Missing(id))?;
                self.selected = None;
            }
            Op::Save => {
                self.check_length()?;
                self.selected = None;
                self.committed = self.working.clone();
                self.committed_digest = self.committed.digest();
            }
            Op::Insert { pos, v } => self.vertices(pos, 1)?.insert(pos as usize, v),
            Op::Replace { pos, v } => self.vertices(pos, 0)?[pos as usize] = v,
            Op::Delete { pos } => {
                self.vertices(pos, 0)?.remove(pos as usize);
            }
        }
        Ok(())
    }

    /// The selected object's vertices if `pos` < length + `slack`.
    fn vertices(&mut self, pos: u32, slack: usize) -> Result<&mut Vec<Vertex>, ApplyError> {
        let (id, _) = self.selected.ok_or(ApplyError::NoObject)?;
        let vs = &mut self
            .working
            .objects
            .get_mut(&id)
            .ok_or(ApplyError::Missing(id))?
            .vertices;
        if pos as usize >= vs.len() + slack {
            return Err(ApplyError::Position { pos, len: vs.len() });
        }
        Ok(vs)
    }

    /// The previously selected object must have the length its header announced.
    fn check_length(&self) -> Result<(), ApplyError> {
        let Some((id, want)) = self.selected else {
            return Ok(());
        };
        let got = self
            .working
            .objects
            .get(&id)
            .map_or(0, |o| o.vertices.len());
        if got != want as usize {
            return Err(ApplyError::Length { id, got, want });
        }
        Ok(())
    }
}

/// One robot's append-only op log: the steps of its approximation, each closed by a save.
#[derive(Clone, Debug, Default)]
pub struct OpLog {
    ops: Vec<Op>,
}

impl OpLog {
    pub fn new() -> OpLog {
        OpLog::default()
    }

    /// Appends the delta `old` → `new` (with its save point); returns how many ops.
    pub fn record(&mut self, old: &Approximation, new: &Approximation) -> usize {
        let d = diff(old, new);
        self.ops.extend_from_slice(&d);
        d.len()
    }

    /// Appends one op received from the owner (contiguously, in order).
    pub fn push(&mut self, op: Op) {
        self.ops.push(op);
    }

    pub fn len(&self) -> usize {
        self.ops.len()
    }

    pub fn is_empty(&self) -> bool {
        self.ops.is_empty()
    }

    /// The ops from index `from` on (what a peer knowing `from` ops lacks).
    pub fn since(&self, from: usize) -> &[Op] {
        self.ops.get(from..).unwrap_or(&[])
    }

    /// The approximation at the last save point among the first `prefix` ops.
    pub fn state_at(&self, prefix: usize) -> Result<Approximation, ApplyError> {
        let mut r = Replica::new();
        for op in &self.ops[..prefix.min(self.ops.len())] {
            r.apply(op)?;
        }
        Ok(r.committed().clone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mapping::approximator::Approximator;
    use crate::mapping::contour::{Contours, Kind};
    use crate::testutil::arb_exploration;
    use proptest::prelude::*;
    use proto::grid::Occ;

    fn vx(x: i32) -> Vertex {
        Vertex {
            p: crate::mapping::qpoint::QPoint::new(x, 1),
            occ: Occ::Unknown,
            bound: 0,
        }
    }

    #[test]
    fn replica_rejects_inconsistent_streams() {
        let mut r = Replica::new();
        assert_eq!(r.apply(&Op::Delete { pos: 0 }), Err(ApplyError::NoObject));
        assert_eq!(
            r.apply(&Op::Save),
            Err(ApplyError::Poisoned),
            "poisoned after an error"
        );

        let mut r = Replica::new();
        let em = Op::Emerge {
            id: 3,
            kind: Kind::Outside,
            len: 2,
        };
        assert_eq!(r.apply(&em), Ok(()));
        assert_eq!(
            r.apply(&Op::Insert { pos: 1, v: vx(0) }),
            Err(ApplyError::Position { pos: 1, len: 0 })
        );

        let mut r = Replica::new();
        r.apply(&em).ok();
        r.apply(&Op::Insert { pos: 0, v: vx(0) }).ok();
        assert_eq!(
            r.apply(&Op::Save),
            Err(ApplyError::Length {
                id: 3,
                got: 1,
                want: 2
            })
        );
        assert!(r.committed().objects.is_empty(), "nothing committed");

        let mut r = Replica::new();
        assert_eq!(
            r.apply(&Op::Change {
                id: 9,
                kind: Kind::Inside,
                len: 0
            }),
            Err(ApplyError::Missing(9))
        );
    }

    #[test]
    fn a_step_counts_only_after_its_save_point() {
        let mut r = Replica::new();
        let ops = [
            Op::Emerge {
                id: 0,
                kind: Kind::Inside,
                len: 2,
            },
            Op::Insert { pos: 0, v: vx(1) },
            Op::Insert { pos: 0, v: vx(2) },
        ];
        for op in &ops {
            r.apply(op).ok();
            assert!(r.committed().objects.is_empty());
        }
        r.apply(&Op::Save).ok();
        assert_eq!(r.committed().objects[&0].vertices, vec![vx(2), vx(1)]);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        #[test]
        fn every_prefix_renders_its_last_save_point(seq in arb_exploration(16, 6), s in 0.0f64..4.0) {
            let (mut ax, mut log) = (Approximator::new(), OpLog::new());
            let mut states = vec![(0, Approximation::default())];
            for g in &seq {
                let prev = ax.current().clone();
                let a = ax.step(&Contours::extract(g), g, s).clone();
                if log.record(&prev, &a) > 0 {
                    states.push((log.len(), a));
                }
            }
            let grid = seq.last().map_or((1, 1), |g| (g.width(), g.height()));
            for k in 0..=log.len() {
                let want = &states.iter().rev().find(|(at, _)| *at <= k).map(|(_, a)| a);
                let got = log.state_at(k).map_err(|e| TestCaseError::fail(e.to_string()))?;
                prop_assert_eq!(Some(&got), *want, "prefix {}", k);
                let render = |a: &Approximation| crate::mapping::render::render(a, grid.0, grid.1);
                prop_assert_eq!(want.map(render), Some(render(&got)));
            }
        }
    }
}
