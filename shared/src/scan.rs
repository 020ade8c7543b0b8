//! Workgroup-wide inclusive prefix sum (Hillis & Steele 1986), and the single-workgroup
//! exclusive scan of the radix sort's digit-count table that uses it.
//!
//! A scan is `SCAN_STEPS` phases of [`step`], each followed by a barrier; the sums ping-pong
//! between the two rows of [`BlockScan::sums`] and end in row 0 (the step count is even).
use crate::types::{BuildParams, WORKGROUP};

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

/// Length of the digit-count table: `RADIX * tiles`.
pub fn table_len(p: &BuildParams) -> u32 {
    crate::radix_sort::RADIX * p.tiles
}

/// The contiguous part of the table that `lane` owns.
fn segment(lane: u32, len: u32) -> (u32, u32) {
    let per = len.div_ceil(WORKGROUP);
    let start = (lane * per).min(len);
    (start, (start + per).min(len))
}

/// Phase 1 of the table scan: each lane sums its segment.
pub fn table_load(lane: u32, st: &mut BlockScan, p: &BuildParams, table: &[u32]) {
    let (start, end) = segment(lane, table_len(p));
    let mut s = 0;
    let mut i = start;
    while i < end {
        s += table[i as usize];
        i += 1;
    }
    st.sums[0][lane as usize] = s;
}

/// Last phase of the table scan: each lane rewrites its segment as an exclusive prefix sum.
pub fn table_store(lane: u32, st: &BlockScan, p: &BuildParams, table: &mut [u32]) {
    let (start, end) = segment(lane, table_len(p));
    let mut run = exclusive(lane, st);
    let mut i = start;
    while i < end {
        let c = table[i as usize];
        table[i as usize] = run;
        run += c;
        i += 1;
    }
}
