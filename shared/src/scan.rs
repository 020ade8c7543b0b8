//! Workgroup-wide inclusive prefix sum (Hillis & Steele 1986).
//!
//! A scan is `SCAN_STEPS` phases of [`step`], each followed by a barrier; the sums ping-pong
//! between the two rows of [`BlockScan::sums`] and end in row 0 (the step count is even).
use crate::types::WORKGROUP;

/// log2(WORKGROUP) Hillis-Steele steps.
pub const SCAN_STEPS: u32 = 8;
const _: () = assert!(1 << SCAN_STEPS == WORKGROUP && SCAN_STEPS % 2 == 0);

/// Workgroup memory of a block scan.
pub struct BlockScan {
    pub sums: [[u32; WORKGROUP as usize]; 2],
}

/// One Hillis-Steele step: `out[l] = in[l] + in[l - 2^step]`.
pub fn step(lane: u32, step: u32, st: &mut BlockScan) {
    let src = (step & 1) as usize;
    let off = 1u32 << step;
    let mut v = st.sums[src][lane as usize];
    if lane >= off {
        v += st.sums[src][(lane - off) as usize];
    }
    st.sums[1 - src][lane as usize] = v;
}

/// Sum of the lanes before `lane`, once the steps are done.
pub fn exclusive(lane: u32, st: &BlockScan) -> u32 {
    if lane == 0 {
        0
    } else {
        st.sums[0][(lane - 1) as usize]
    }
}
