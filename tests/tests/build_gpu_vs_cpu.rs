//! The BVH build on the Vulkan device equals the CPU executor's bit for bit, stage by stage,
//! and both trees pass the validator: sizes around workgroup and tile edges and the sorts'
//! thresholds, 100,000 and the bunny; random, all-equal, far-outlier, collinear and
//! duplicate-heavy inputs; 30- and 63-bit codes, the wide collapse, and treelet
//! restructuring.
use integration_tests::{assert_no_validation_errors, dump_mismatch, gpu};
use raytrace::bvh::{validate, validate_wide, BuildOptions, BuildResult, MortonBits};
use raytrace::cpu;
use raytrace::gpu::{Gpu, GpuLbvh, Kernels};
use raytrace::inputs::{assets_dir, generate, load_obj, Distribution};
use shared::merge_sort::{self, BATCH, RUN};
use shared::radix_sort as sort;
use shared::types::{Sphere, Triangle, TILE, WORKGROUP};
use std::sync::Arc;

/// The GPU (see `gpu`) and a BVH builder on it.
fn builder(test: &str) -> Option<(Arc<Gpu>, GpuLbvh)> {
    let gpu = gpu(test)?;
    let kernels = Arc::new(Kernels::new(&gpu).unwrap());
    let lbvh = GpuLbvh::new(&gpu, &kernels).unwrap();
    Some((gpu, lbvh))
}

/// The bytes of one stage's output.
type StageBytes = fn(&BuildResult) -> Vec<u8>;

/// The builds every input is checked with: both code widths, binary and collapsed into the
/// wide BVH, 30-bit codes with treelet restructuring, once and in three rounds, and both
/// code widths with the tree built by H-PLOC.
const BUILDS: [BuildOptions; 8] = [
    BuildOptions {
        bits: MortonBits::B30,
        treelets: false,
        wide: false,
        rounds: 1,
        ploc: false,
        pairs: true,
    },
    BuildOptions {
        bits: MortonBits::B63,
        treelets: false,
        wide: false,
        rounds: 1,
        ploc: false,
        pairs: true,
    },
    BuildOptions {
        bits: MortonBits::B30,
        treelets: true,
        wide: false,
        rounds: 1,
        ploc: false,
        pairs: true,
    },
    BuildOptions {
        bits: MortonBits::B30,
        treelets: false,
        wide: true,
        rounds: 1,
        ploc: false,
        pairs: true,
    },
    BuildOptions {
        bits: MortonBits::B63,
        treelets: false,
        wide: true,
        rounds: 1,
        ploc: false,
        pairs: true,
    },
    BuildOptions {
        bits: MortonBits::B30,
        treelets: true,
        wide: false,
        rounds: 3,
        ploc: false,
        pairs: true,
    },
    BuildOptions {
        bits: MortonBits::B30,
        treelets: false,
        wide: false,
        rounds: 1,
        ploc: true,
        pairs: true,
    },
    BuildOptions {
        bits: MortonBits::B63,
        treelets: false,
        wide: false,
        rounds: 1,
        ploc: true,
        pairs: true,
    },
];

fn check(lbvh: &mut GpuLbvh, name: &str, tris: &[Triangle], spheres: &[Sphere], opts: BuildOptions) {
    lbvh.upload(tris, spheres).unwrap();
    check_uploaded(lbvh, name, tris, spheres, opts);
}

/// [`check`] of the primitives `lbvh` holds already (`tris` and `spheres`).
fn check_uploaded(lbvh: &mut GpuLbvh, name: &str, tris: &[Triangle], spheres: &[Sphere], opts: BuildOptions) {
    lbvh.build(opts, true).unwrap();
    let g = lbvh.result(opts).unwrap();
    let (c, _) = cpu::build(tris, spheres, opts);
    let name = match (opts.treelets, opts.wide, opts.ploc) {
        (true, _, _) => format!("{name}-treelets{}", opts.rounds),
        (_, true, _) => format!("{name}-wide"),
        (_, _, true) => format!("{name}-ploc"),
        _ => name.to_string(),
    };
    let bits = opts.bits;
    let stages: [(&str, StageBytes); 8] = [
        ("bounds", |r| bytemuck::bytes_of(&r.bounds).to_vec()),
        ("morton", |r| bytemuck::cast_slice(&r.morton).to_vec()),
        ("sorted keys", |r| bytemuck::cast_slice(&r.sorted_keys).to_vec()),
        ("sorted primitives", |r| bytemuck::cast_slice(&r.sorted_prims).to_vec()),
        ("nodes", |r| bytemuck::cast_slice(&r.nodes).to_vec()),
        ("parents", |r| bytemuck::cast_slice(&r.parents).to_vec()),
        ("wide nodes", |r| bytemuck::cast_slice(&r.wide).to_vec()),
        ("pairs", |r| bytemuck::cast_slice(&r.pairs).to_vec()),
    ];
    for (stage, bytes) in stages {
        if bytes(&g) != bytes(&c) {
            let file = dump_mismatch(&format!("{name}-{bits:?}"), "GPU", &g, "CPU", &c);
            panic!(
                "{name} ({bits:?}): GPU and CPU differ at stage {stage}; both written to {}",
                file.display()
            );
        }
    }
    for (who, r) in [("GPU", &g), ("CPU", &c)] {
        if let Err(e) = validate(&r.nodes, &r.parents, tris, spheres) {
            let file = dump_mismatch(&format!("{name}-{bits:?}-invalid"), who, r, "error", &e);
            panic!(
                "{name} ({bits:?}): {who} BVH invalid (written to {}):\n{e}",
                file.display()
            );
        }
        if opts.wide {
            if let Err(e) = validate_wide(&r.wide, &r.sorted_prims, tris, spheres) {
                let file = dump_mismatch(&format!("{name}-{bits:?}-invalid"), who, r, "error", &e);
                panic!(
                    "{name} ({bits:?}): {who} wide BVH invalid (written to {}):\n{e}",
                    file.display()
                );
            }
        }
    }
}

#[test]
fn generated_inputs_build_identically_on_gpu_and_cpu() {
    let Some((gpu, mut lbvh)) = builder("generated_inputs_build_identically_on_gpu_and_cpu") else {
        return;
    };
    // The tile of the sorts below `sort::MANY` keys.
    let (wg, tile) = (WORKGROUP as usize, (WORKGROUP * sort::FEW) as usize);
    let sizes = [
        0,
        1,
        2,
        3,
        wg - 1,
        wg,
        wg + 1,
        17 * wg + 1,
        tile + 1,
        3 * tile + 1,
        (BATCH * RUN) as usize,
        (BATCH * RUN + RUN + 1) as usize,
        merge_sort::max(30) as usize,
        merge_sort::max(30) as usize + 1,
        merge_sort::max(63) as usize,
        merge_sort::max(63) as usize + 1,
        100_000,
    ];
    for (d, dist) in Distribution::ALL.into_iter().enumerate() {
        for &n in &sizes {
            for opts in BUILDS {
                let (t, s) = generate(n, dist, n % 2 == 1, 1000 + d as u64);
                check(&mut lbvh, &format!("{dist:?}-{n}"), &t, &s, opts);
            }
        }
    }
    // Look-backs over many windows of status words, then smaller sorts, which need the
    // status tables, totals and tile counters that sort left cleared (a left-over word
    // breaks them).
    let window = sort::WINDOW as usize;
    for n in [3 * window * tile + 1, tile + 1, 2 * tile + 1] {
        for opts in BUILDS {
            let (t, s) = generate(n, Distribution::Random, true, 77);
            check(&mut lbvh, &format!("Random-{n}"), &t, &s, opts);
        }
    }
    assert_no_validation_errors(&gpu);
    // A large sort (lanes owning `SORT_ITEMS` keys, tiles of `TILE`, past a tile's edge), then
    // a small one on the tables it left, both code widths, in a builder of their own without
    // the pairs: a builder keeps the room it once made for the pairs or the wide BVH, and
    // lavapipe's bindings cannot hold them at this size.
    let Some((gpu, mut lbvh)) = builder("generated_inputs_build_identically_on_gpu_and_cpu") else {
        return;
    };
    for n in [sort::MANY as usize + TILE as usize + 1, tile + 1] {
        for opts in &BUILDS[..2] {
            let (t, s) = generate(n, Distribution::Random, true, 78);
            check(
                &mut lbvh,
                &format!("Random-{n}"),
                &t,
                &s,
                BuildOptions { pairs: false, ..*opts },
            );
        }
    }
    assert_no_validation_errors(&gpu);
}

/// A refit (`GpuLbvh::record_refit`, `cpu::refit`) keeps a build's tree and fits its boxes
/// to the primitives as they are now: here other primitives of the same count (the tree then
/// fits them badly, but soundly). Both backends' refits are equal bit for bit and valid,
/// including the adversarial inputs (equal centres, a far outlier) and the sizes past which
/// the fit tests fewer ancestors before merging, for Karras trees (the fit) and trees
/// restructured by treelets, once or in three rounds, and H-PLOC trees (the counter refit);
/// a refit back to the
/// first primitives gives the build's tree again.
#[test]
fn refits_equal_on_gpu_and_cpu() {
    let Some((gpu, mut lbvh)) = builder("refits_equal_on_gpu_and_cpu") else {
        return;
    };
    let wg = WORKGROUP as usize;
    let mut inputs: Vec<(Distribution, usize)> = Vec::new();
    for dist in Distribution::ALL {
        inputs.extend([0, 1, 2, 3, wg + 1, 17 * wg + 1, 100_000].map(|n| (dist, n)));
    }
    inputs.push((Distribution::Random, 300_000));
    let [b30, b63, treelets, _, _, rounds, ploc30, ploc63] = BUILDS;
    for (dist, n) in inputs {
        for opts in [b30, b63, treelets, rounds, ploc30, ploc63] {
            let name = format!("{dist:?}-{n} ({opts:?})");
            let (t, s) = generate(n, dist, n % 2 == 1, 500 + n as u64);
            let (t2, s2) = generate(n, Distribution::Random, n % 2 == 1, 900 + n as u64);
            assert_eq!((t.len(), s.len()), (t2.len(), s2.len()));
            lbvh.upload(&t, &s).unwrap();
            lbvh.build(opts, false).unwrap();
            let built = lbvh.result(opts).unwrap();
            let c = cpu::build(&t, &s, opts).0;
            assert_eq!(built.nodes, c.nodes, "{name}: the builds differ");
            lbvh.upload(&t2, &s2).unwrap();
            lbvh.refit(opts).unwrap();
            let g = lbvh.result(opts).unwrap();
            let r = cpu::refit(&c, &t2, &s2, opts).unwrap();
            assert_eq!(g.nodes, r.nodes, "{name}: the refits differ");
            assert_eq!(g.pairs, r.pairs, "{name}: the refits' pairs differ");
            assert_eq!((&g.parents, &g.sorted_prims), (&c.parents, &c.sorted_prims), "{name}");
            if let Err(e) = validate(&r.nodes, &r.parents, &t2, &s2) {
                panic!("{name}: the refit BVH is invalid:\n{e}");
            }
            lbvh.upload(&t, &s).unwrap();
            lbvh.refit(opts).unwrap();
            assert_eq!(lbvh.result(opts).unwrap().nodes, c.nodes, "{name}: refit back");
        }
    }
    // What cannot be refit is refused by name.
    let (t, s) = generate(100, Distribution::Random, false, 3);
    let c = cpu::build(&t, &s, b30).0;
    let e = cpu::refit(&c, &t[..99], &s, b30).unwrap_err();
    assert!(e.contains("100 primitives given 99"), "{e}");
    let wide = BUILDS[3];
    assert!(cpu::refit(&c, &t, &s, wide).unwrap_err().contains("wide"));
    assert!(lbvh.refit(wide).unwrap_err().to_string().contains("wide"));
    assert_no_validation_errors(&gpu);
}

#[test]
fn bunny_builds_identically_on_gpu_and_cpu() {
    let Some((gpu, mut lbvh)) = builder("bunny_builds_identically_on_gpu_and_cpu") else {
        return;
    };
    let bunny = load_obj(&assets_dir().join("bunny.obj")).unwrap();
    assert_eq!(bunny.len(), 69_666);
    for opts in BUILDS {
        check(&mut lbvh, "bunny", &bunny, &[], opts);
    }
    assert_no_validation_errors(&gpu);
}

#[test]
fn room_for_the_pairs_and_the_wide_bvh_is_made_by_the_first_build_asking() {
    let Some((gpu, mut lbvh)) = builder("room_for_the_pairs_and_the_wide_bvh_is_made_by_the_first_build_asking") else {
        return;
    };
    let (t, s) = generate(3000, Distribution::Random, true, 11);
    let [binary, _, _, wide, _, _, _, _] = BUILDS;
    // The renderer's builder (its transform kernel writes the primitives, nothing is captured)
    // holds no host copy of the primitives: `upload` makes it.
    lbvh.reserve(t.len(), s.len()).unwrap();
    let (_, reserved) = lbvh.memory();
    lbvh.upload(&t, &s).unwrap();
    let (_, uploaded) = lbvh.memory();
    assert!(
        uploaded >= reserved + 48 * t.len() as u64,
        "{reserved} -> {uploaded} bytes: the upload made no staging copy"
    );
    let n = (t.len() + s.len()) as u64;
    // Builds without pairs hold the tree alone (64 bytes a primitive; both backends write
    // no pairs), the first with pairs makes room for them (64 more) and keeps the
    // primitives; neither holds a wide BVH (whose worst case is 128 bytes a primitive).
    check_uploaded(&mut lbvh, "room", &t, &s, BuildOptions { pairs: false, ..binary });
    let (tree_nodes, _) = lbvh.memory();
    assert!(
        tree_nodes < 2 * n * 32 * 5 / 4 + 64,
        "{tree_nodes} bytes of nodes for {n} primitives without pairs"
    );
    check_uploaded(&mut lbvh, "room", &t, &s, binary);
    let (nodes, rest) = lbvh.memory();
    assert!(
        nodes >= (4 * n - 2) * 32 && nodes < 4 * n * 32 * 5 / 4 + 64,
        "{nodes} bytes of nodes for {n} primitives"
    );
    // The first wide build makes the buffers again and keeps the primitives uploaded.
    check_uploaded(&mut lbvh, "room", &t, &s, wide);
    let (wide_nodes, wide_rest) = lbvh.memory();
    assert!(wide_nodes >= nodes + (n - 1) * 128, "{nodes} -> {wide_nodes} bytes");
    assert!(
        wide_rest > rest,
        "no room for the collapse's scratch: {rest} -> {wide_rest}"
    );
    // The room is kept for later builds of either kind.
    check_uploaded(&mut lbvh, "room", &t, &s, binary);
    check_uploaded(&mut lbvh, "room", &t, &s, wide);
    assert_eq!(lbvh.memory(), (wide_nodes, wide_rest));
    assert_no_validation_errors(&gpu);
}

/// Builds of every kind and size one after another on the same buffers, each equal to the
/// CPU executor's: no build reads what an earlier one left behind. (An H-PLOC build once took
/// a smaller earlier build's leaf ranges or cluster lists, left past that build's `n - 1`
/// in the visit buffer, for its own links: `bench build` caught it on the H100.)
#[test]
fn builds_of_every_kind_follow_each_other() {
    let Some((gpu, mut lbvh)) = builder("builds_of_every_kind_follow_each_other") else {
        return;
    };
    for (k, n) in [37, 3000, 20_000, 5000, 100, 7000].into_iter().enumerate() {
        let (t, s) = generate(n, Distribution::Random, true, 40 + k as u64);
        for opts in BUILDS.into_iter().rev() {
            check(&mut lbvh, &format!("sequence-{n}"), &t, &s, opts);
        }
    }
    assert_no_validation_errors(&gpu);
}

#[test]
fn buffers_are_reused_across_builds() {
    let Some((gpu, mut lbvh)) = builder("buffers_are_reused_across_builds") else {
        return;
    };
    let (t, s) = generate(5000, Distribution::Random, true, 7);
    lbvh.upload(&t, &s).unwrap();
    // The first build makes the room for its pairs (`room_for_the_pairs_and_..`); none after.
    lbvh.build(BuildOptions::lbvh(MortonBits::B30), false).unwrap();
    let before = lbvh.memory();
    for n in [4000, 5000, 10] {
        lbvh.upload(&t[..n.min(t.len())], &s[..n.min(s.len()) / 5]).unwrap();
        lbvh.build(BuildOptions::lbvh(MortonBits::B30), false).unwrap();
        assert_eq!(lbvh.memory(), before, "buffers were reallocated for {n} primitives");
    }
    assert_no_validation_errors(&gpu);
}
