//! Workgroup-wide exclusive prefix sum of one `u32` per lane, by raking (Blelloch 1990;
//! Merrill & Grimshaw 2011): `RAKES` lanes each scan a run of `RUN` sums serially, one lane
//! scans the run totals, and every lane reads its result. Three phases, two barriers:
//!
//! ```text
//! sums:    | run 0: lanes 0..16 | run 1: lanes 16..32 | ... | run 15 |
//! rake:      inclusive scan inside each run; totals[r] = last of run r
//! totals:    exclusive scan of the 16 run totals (lane 0)
//! result:    exclusive(l) = sums[l - 1] within its run (0 at a run start) + totals[l / RUN]
//! ```
use crate::sync::{elem, elem_mut};
use crate::types::WORKGROUP;
use seq_macro::seq;

/// Lanes per raking run, and number of runs.
pub const RUN: u32 = 16;
pub const RAKES: u32 = WORKGROUP / RUN;
const _: () = assert!(RUN * RAKES == WORKGROUP);
// The loops over a run and over the run totals are written out with `seq!`, which takes
// literal counts: rust-gpu emits no unroll hints, and the driver left these loops rolled, one
// dependent workgroup-memory round trip per iteration.
const _: () = assert!(RUN == 16 && RAKES == 16);

/// Workgroup memory of a block scan. Each lane writes its value to `sums[lane]`, then the
/// phases [`rake`] | barrier | [`rake_totals`] | barrier run, then [`exclusive`] reads.
pub struct BlockScan {
    pub sums: [u32; WORKGROUP as usize],
    pub totals: [u32; RAKES as usize],
}

/// Phase 1: lanes below `RAKES` scan their run in place (inclusive).
#[allow(clippy::erasing_op, clippy::identity_op)] // `seq!` starts at 0
pub fn rake(lane: u32, st: &mut BlockScan) {
    if lane < RAKES {
        // All loads first, then the sums in registers (written out: see `RUN`).
        seq!(K in 0..16 {
            let v~K = *elem(&st.sums, lane * RUN + K);
        });
        let mut run = 0;
        seq!(K in 0..16 {
            run += v~K;
            *elem_mut(&mut st.sums, lane * RUN + K) = run;
        });
        *elem_mut(&mut st.totals, lane) = run;
    }
}

/// Phase 2: lane 0 turns the run totals into exclusive offsets.
pub fn rake_totals(lane: u32, st: &mut BlockScan) {
    if lane == 0 {
        seq!(R in 0..16 {
            let t~R = *elem(&st.totals, R);
        });
        let mut run = 0;
        seq!(R in 0..16 {
            *elem_mut(&mut st.totals, R) = run;
            run += t~R;
        });
    }
}

/// Sum of every lane's value, once both phases are done.
pub fn total(st: &BlockScan) -> u32 {
    *elem(&st.totals, RAKES - 1) + *elem(&st.sums, WORKGROUP - 1)
}

/// Sum of the values of the lanes before `lane`, once both phases are done.
pub fn exclusive(lane: u32, st: &BlockScan) -> u32 {
    let within = if lane.is_multiple_of(RUN) {
        0
    } else {
        *elem(&st.sums, lane - 1)
    };
    within + *elem(&st.totals, lane / RUN)
}
