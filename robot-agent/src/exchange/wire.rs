//! The compact wire encoding of delta ops (thesis §6.4, Table 6.1; docs/design.md §4.3).
//!
//! A chunk is a sequence of ops, each one header byte plus varints. The encoding is delta
//! coded along the chunk, so consecutive ops — one object's edit script, emitted from its end
//! backwards — cost little: positions relative to the previous vertex op (edit scripts step
//! down by 0 or 1), ids relative to the previous object op (ops come in ascending id order),
//! coordinates relative to the previous coordinate (the neighbouring vertex, in a run of
//! inserts). Every chunk starts from a fresh context, so the exchange can cut a log at any op.
//!
//! Header bits 0–2 name the type (0 ins, 1 rep, 2 del, 3 em, 4 chg, 5 rm, 6 save).
//! ins/rep: bits 3–4 f_occ (0 free, 1 occupied, 2 unknown; 3: bounded, below), bits 5–7
//! position mode; then zigzag varints dx, dy. An exact edge (error bound 0, most of a fine
//! approximation) costs nothing more; a bounded one has f_occ 3 and, after dy, one varint
//! `bound << 2 | f_occ` (one byte up to 31 half cells). del: bits 3–7 position mode. Position
//! modes: `m` below the last two values means previous position − m; the last two mean
//! "absolute varint follows" and "zigzag delta varint follows". em/chg: bit 3 kind (0 inside,
//! 1 outside), bits 4–7 id mode, then varint vertex count; rm: bits 3–7 id mode. Id modes: `m`
//! below the last value means previous id + 1 + m, the last means "zigzag delta varint follows".
//! save: bits 3–7 zero.
//!
//! Mean sizes on exploration runs stay below Table 6.1 (ins 6, rep 6, del 2, em 5, chg 5,
//! rm 2, save 1 bytes); the tests measure them. Decoding is total: every byte string decodes
//! or yields a [`WireError`](crate::exchange::wire::WireError).

use proto::grid::Occ;

use crate::exchange::delta::Op;
use crate::mapping::approx::Vertex;
use crate::mapping::contour::Kind;
use crate::mapping::qpoint::QPoint;

/// Why bytes are not a valid chunk.
#[derive(Debug, thiserror::Error, Clone, PartialEq, Eq)]
pub enum WireError {
    #[error("chunk ends inside an op at byte {0}")]
    Truncated(usize),
    #[error("unknown op type 7 at byte {0}")]
    BadType(usize),
    #[error("bad occupancy code or error bound at byte {0}")]
    BadOcc(usize),
    #[error("save header with extra bits at byte {0}")]
    BadSave(usize),
    #[error("varint longer than 10 bytes at byte {0}")]
    BadVarint(usize),
    #[error("value out of range at byte {0}")]
    Range(usize),
}

/// The running context shared by encoder and decoder.
#[derive(Clone, Copy, Debug, Default)]
struct Context {
    id: i64,
    pos: i64,
    point: QPoint,
}

impl Context {
    fn new() -> Context {
        Context {
            id: -1,
            pos: 0,
            point: QPoint::default(),
        }
    }
}

/// Encodes ops into one chunk, reporting each op's size for per-type accounting.
#[derive(Clone, Debug)]
pub struct Encoder {
    out: Vec<u8>,
    ctx: Context,
}

impl Default for Encoder {
    fn default() -> Encoder {
        Encoder {
            out: Vec::new(),
            ctx: Context::new(),
        }
    }
}

impl Encoder {
    pub fn new() -> Encoder {
        Encoder::default()
    }

    /// Appends `op`; returns the bytes it took.
    pub fn push(&mut self, op: &Op) -> usize {
        let start = self.out.len();
        match *op {
            Op::Insert { pos, v } => self.vertex(0, pos, v),
            Op::Replace { pos, v } => self.vertex(1, pos, v),
            Op::Delete { pos } => {
                let (mode, extra) = pos_mode(&mut self.ctx, pos, 32);
                self.out.push(2 | mode << 3);
                if let Some(x) = extra {
                    put_varint(&mut self.out, x);
                }
            }
            Op::Emerge { id, kind, len } => self.object(3, id, Some((kind, len))),
            Op::Change { id, kind, len } => self.object(4, id, Some((kind, len))),
            Op::Remove { id } => self.object(5, id, None),
            Op::Save => self.out.push(6),
        }
        self.out.len() - start
    }

    fn vertex(&mut self, ty: u8, pos: u32, v: Vertex) {
        let (mode, extra) = pos_mode(&mut self.ctx, pos, 8);
        let code = if v.bound == 0 { occ_code(v.occ) } else { 3 };
        self.out.push(ty | code << 3 | mode << 5);
        if let Some(x) = extra {
            put_varint(&mut self.out, x);
        }
        put_varint(
            &mut self.out,
            zigzag(i64::from(v.p.x) - i64::from(self.ctx.point.x)),
        );
        put_varint(
            &mut self.out,
            zigzag(i64::from(v.p.y) - i64::from(self.ctx.point.y)),
        );
        if v.bound != 0 {
            put_varint(
                &mut self.out,
                u64::from(v.bound) << 2 | u64::from(occ_code(v.occ)),
            );
        }
        self.ctx.point = v.p;
    }

    fn object(&mut self, ty: u8, id: u32, body: Option<(Kind, u32)>) {
        let modes = if body.is_some() { 16 } else { 32 };
        let step = i64::from(id) - self.ctx.id - 1;
        let mode = if (0..modes - 1).contains(&step) {
            step as u8
        } else {
            modes as u8 - 1
        };
        let kind_bit = u8::from(body.is_some_and(|(k, _)| k == Kind::Outside));
        let header = match body {
            Some(_) => ty | kind_bit << 3 | mode << 4,
            None => ty | mode << 3,
        };
        self.out.push(header);
        if i64::from(mode) == modes - 1 {
            put_varint(&mut self.out, zigzag(i64::from(id) - self.ctx.id));
        }
        if let Some((_, len)) = body {
            put_varint(&mut self.out, u64::from(len));
        }
        self.ctx.id = i64::from(id);
        self.ctx.pos = 0;
    }

    pub fn finish(self) -> Vec<u8> {
        self.out
    }

    /// Takes `op` into the running context without keeping its bytes; returns how many it took
    /// (a running measure of a log's encoded size).
    pub fn measure(&mut self, op: &Op) -> usize {
        let n = self.push(op);
        self.out.clear();
        n
    }
}

/// Encodes a chunk.
pub fn encode(ops: &[Op]) -> Vec<u8> {
    let mut e = Encoder::new();
    ops.iter().for_each(|op| {
        e.push(op);
    });
    e.finish()
}

/// Position mode for `pos` with `modes` codes: (mode, varint to follow).
fn pos_mode(ctx: &mut Context, pos: u32, modes: i64) -> (u8, Option<u64>) {
    let back = ctx.pos - i64::from(pos);
    ctx.pos = i64::from(pos);
    if (0..modes - 2).contains(&back) {
        (back as u8, None)
    } else if i64::from(pos) <= back.abs() {
        ((modes - 2) as u8, Some(u64::from(pos)))
    } else {
        ((modes - 1) as u8, Some(zigzag(-back)))
    }
}

fn occ_code(o: Occ) -> u8 {
    match o {
        Occ::Free => 0,
        Occ::Occupied => 1,
        Occ::Unknown => 2,
    }
}

fn zigzag(v: i64) -> u64 {
    ((v << 1) ^ (v >> 63)) as u64
}

fn unzigzag(v: u64) -> i64 {
    (v >> 1) as i64 ^ -((v & 1) as i64)
}

fn put_varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push(v as u8 | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

/// Decodes a chunk made by [`encode`] (or fails; never panics).
pub fn decode(bytes: &[u8]) -> Result<Vec<Op>, WireError> {
    let mut r = Reader {
        bytes,
        at: 0,
        ctx: Context::new(),
    };
    let mut ops = Vec::new();
    while r.at < bytes.len() {
        ops.push(r.op()?);
    }
    Ok(ops)
}

struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
    ctx: Context,
}

impl Reader<'_> {
    fn op(&mut self) -> Result<Op, WireError> {
        let start = self.at;
        let h = self.byte()?;
        Ok(match h & 7 {
            0 | 1 => {
                let pos = self.pos(h >> 5, 8)?;
                let x = self.coord(self.ctx.point.x)?;
                let y = self.coord(self.ctx.point.y)?;
                self.ctx.point = QPoint::new(x, y);
                let (code, bound) = match h >> 3 & 3 {
                    3 => {
                        let b = self.varint()?;
                        let bound = u16::try_from(b >> 2).map_err(|_| WireError::BadOcc(start))?;
                        if bound == 0 {
                            return Err(WireError::BadOcc(start));
                        }
                        (b & 3, bound)
                    }
                    c => (u64::from(c), 0),
                };
                let occ = [Occ::Free, Occ::Occupied, Occ::Unknown].get(code as usize);
                let occ = *occ.ok_or(WireError::BadOcc(start))?;
                let v = Vertex {
                    p: self.ctx.point,
                    occ,
                    bound,
                };
                if h & 7 == 0 {
                    Op::Insert { pos, v }
                } else {
                    Op::Replace { pos, v }
                }
            }
            2 => Op::Delete {
                pos: self.pos(h >> 3, 32)?,
            },
            3 | 4 => {
                let kind = if h >> 3 & 1 == 1 {
                    Kind::Outside
                } else {
                    Kind::Inside
                };
                let id = self.id(h >> 4, 16)?;
                let len = u32::try_from(self.varint()?).map_err(|_| WireError::Range(start))?;
                if h & 7 == 3 {
                    Op::Emerge { id, kind, len }
                } else {
                    Op::Change { id, kind, len }
                }
            }
            5 => Op::Remove {
                id: self.id(h >> 3, 32)?,
            },
            6 if h == 6 => Op::Save,
            6 => return Err(WireError::BadSave(start)),
            _ => return Err(WireError::BadType(start)),
        })
    }

    fn byte(&mut self) -> Result<u8, WireError> {
        let b = *self
            .bytes
            .get(self.at)
            .ok_or(WireError::Truncated(self.at))?;
        self.at += 1;
        Ok(b)
    }

    fn varint(&mut self) -> Result<u64, WireError> {
        let start = self.at;
        let mut v = 0u64;
        for shift in (0..64).step_by(7) {
            let b = self.byte()?;
            v |= u64::from(b & 0x7f) << shift;
            if b & 0x80 == 0 {
                return Ok(v);
            }
        }
        Err(WireError::BadVarint(start))
    }

    fn pos(&mut self, mode: u8, modes: u8) -> Result<u32, WireError> {
        let start = self.at;
        let pos = match mode {
            m if m < modes - 2 => self.ctx.pos - i64::from(m),
            m if m == modes - 2 => {
                i64::try_from(self.varint()?).map_err(|_| WireError::Range(start))?
            }
            _ => self
                .ctx
                .pos
                .checked_add(unzigzag(self.varint()?))
                .ok_or(WireError::Range(start))?,
        };
        let pos = u32::try_from(pos).map_err(|_| WireError::Range(start))?;
        self.ctx.pos = i64::from(pos);
        Ok(pos)
    }

    fn id(&mut self, mode: u8, modes: u8) -> Result<u32, WireError> {
        let start = self.at;
        let id = if mode < modes - 1 {
            self.ctx.id + 1 + i64::from(mode)
        } else {
            self.ctx
                .id
                .checked_add(unzigzag(self.varint()?))
                .ok_or(WireError::Range(start))?
        };
        let id = u32::try_from(id).map_err(|_| WireError::Range(start))?;
        (self.ctx.id, self.ctx.pos) = (i64::from(id), 0);
        Ok(id)
    }

    fn coord(&mut self, prev: i32) -> Result<i32, WireError> {
        let start = self.at;
        let v = i64::from(prev)
            .checked_add(unzigzag(self.varint()?))
            .ok_or(WireError::Range(start))?;
        i32::try_from(v).map_err(|_| WireError::Range(start))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::exchange::delta::diff;
    use crate::mapping::approx::Approximation;
    use crate::mapping::approximator::Approximator;
    use crate::mapping::contour::Contours;
    use crate::testutil::{explore, maps, window};
    use proptest::prelude::*;
    use proto::msg::Traffic;

    fn arb_op() -> impl Strategy<Value = Op> {
        let occ = prop_oneof![Just(Occ::Free), Just(Occ::Occupied), Just(Occ::Unknown)];
        let kind = prop_oneof![Just(Kind::Inside), Just(Kind::Outside)];
        let v =
            (any::<i32>(), any::<i32>(), occ, any::<u16>()).prop_map(|(x, y, occ, bound)| Vertex {
                p: QPoint::new(x, y),
                occ,
                bound,
            });
        let small_v =
            (-300i32..300, -300i32..300, Just(Occ::Occupied)).prop_map(|(x, y, occ)| Vertex {
                p: QPoint::new(x, y),
                occ,
                bound: 0,
            });
        let pos = prop_oneof![0u32..8, any::<u32>()];
        let id = prop_oneof![0u32..40, any::<u32>()];
        prop_oneof![
            (pos.clone(), prop_oneof![v.clone(), small_v])
                .prop_map(|(pos, v)| Op::Insert { pos, v }),
            (pos.clone(), v).prop_map(|(pos, v)| Op::Replace { pos, v }),
            pos.prop_map(|pos| Op::Delete { pos }),
            (id.clone(), kind.clone(), any::<u32>()).prop_map(|(id, kind, len)| Op::Emerge {
                id,
                kind,
                len
            }),
            (id.clone(), kind, 0u32..50).prop_map(|(id, kind, len)| Op::Change { id, kind, len }),
            id.prop_map(|id| Op::Remove { id }),
            Just(Op::Save),
        ]
    }

    #[test]
    fn small_ops_take_one_byte() {
        let ops = [
            Op::Delete { pos: 7 },
            Op::Delete { pos: 6 },
            Op::Delete { pos: 5 },
            Op::Save,
        ];
        assert_eq!(
            encode(&ops),
            vec![2 | 30 << 3, 7, 2 | 1 << 3, 2 | 1 << 3, 6]
        );
        assert_eq!(decode(&[6, 6]), Ok(vec![Op::Save, Op::Save]));
        assert_eq!(decode(&[7]), Err(WireError::BadType(0)));
        assert_eq!(decode(&[6 | 8]), Err(WireError::BadSave(0)));
        // A bounded vertex: its bound and f_occ after the coordinates, neither may be invalid.
        let bounded = Vertex {
            p: QPoint::new(1, 0),
            occ: Occ::Unknown,
            bound: 5,
        };
        assert_eq!(
            encode(&[Op::Insert { pos: 0, v: bounded }]),
            vec![3 << 3, 2, 0, 5 << 2 | 2]
        );
        assert_eq!(decode(&[3 << 3, 0, 0, 0]), Err(WireError::BadOcc(0)));
        assert_eq!(
            decode(&[3 << 3, 0, 0, 1 << 2 | 3]),
            Err(WireError::BadOcc(0))
        );
        assert_eq!(decode(&[3 << 3, 0, 0]), Err(WireError::Truncated(3)));
        assert_eq!(decode(&[3]), Err(WireError::Truncated(1)));
    }

    /// Mean encoded bytes per op type over single-robot explorations of the shipped maps, each
    /// step's delta in its own chunk (the worst case: no context carried between steps).
    fn mean_sizes() -> Vec<(Traffic, f64, usize)> {
        let mut total: std::collections::BTreeMap<Traffic, (usize, usize)> = Default::default();
        for (m, map) in maps().iter().enumerate() {
            let truth = window(map, 160, 160, map.width() / 3, map.height() / 3);
            let (mut ax, mut prev) = (Approximator::new(), Approximation::default());
            for g in explore(&truth, 40, 25, m as u64 + 1) {
                let a = ax.step(&Contours::extract(&g), &g, 2.0).clone();
                let mut e = Encoder::new();
                for op in diff(&prev, &a) {
                    let t = total.entry(op.kind()).or_default();
                    (t.0, t.1) = (t.0 + e.push(&op), t.1 + 1);
                }
                prev = a;
            }
        }
        total
            .into_iter()
            .map(|(k, (bytes, n))| (k, bytes as f64 / n as f64, n))
            .collect()
    }

    #[test]
    fn mean_sizes_stay_below_table_6_1() {
        if maps().is_empty() {
            return;
        }
        let sizes = mean_sizes();
        println!("mean bytes per op: {sizes:?}");
        for (kind, mean, _) in sizes {
            let limit = kind.thesis_bytes().unwrap_or(0.0);
            assert!(mean <= limit, "{kind:?}: {mean:.2} bytes > {limit}");
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]

        #[test]
        fn decode_inverts_encode(ops in proptest::collection::vec(arb_op(), 0..40)) {
            prop_assert_eq!(decode(&encode(&ops)), Ok(ops));
        }

        #[test]
        fn decoding_arbitrary_bytes_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..64)) {
            let _ = decode(&bytes);
        }

        #[test]
        fn decoding_mutated_chunks_never_panics(ops in proptest::collection::vec(arb_op(), 1..20), flips in proptest::collection::vec((any::<usize>(), any::<u8>()), 1..4)) {
            let mut bytes = encode(&ops);
            for (at, b) in flips {
                let n = bytes.len();
                bytes[at % n] ^= b;
            }
            if let Ok(ops) = decode(&bytes) {
                prop_assert_eq!(decode(&encode(&ops)), Ok(ops));
            }
        }
    }
}
