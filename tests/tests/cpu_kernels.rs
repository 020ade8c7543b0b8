//! The build kernels run by the CPU executor: sort order and stability, Karras's worked
//! example, valid trees on every input shape, a validator that catches broken trees, and
//! clear errors for bad mesh files.
use raytrace::bvh::MortonBits;
use raytrace::cpu;
use raytrace::inputs::{generate, load_obj, Distribution};
use raytrace::validate::validate;
use shared::karras::range_and_split;
use shared::radix_sort::SUPER;
use shared::types::{TILE, WORKGROUP};

#[test]
fn radix_sort_is_a_stable_sort_of_the_morton_codes() {
    for bits in [MortonBits::B30, MortonBits::B63] {
        for dist in Distribution::ALL {
            // The last size spans three super-tiles of the scatter's offset tables.
            for n in [
                0,
                1,
                2,
                3,
                257,
                TILE as usize + 1,
                20_000,
                (2 * SUPER * TILE + 1) as usize,
            ] {
                let (t, s) = generate(n, dist, true, 3);
                let (r, _) = cpu::build(&t, &s, bits);
                let mut expected: Vec<u32> = (0..r.morton.len() as u32).collect();
                expected.sort_by_key(|&i| r.morton[i as usize]);
                assert_eq!(r.sorted_prims, expected, "{dist:?} n={n} {bits:?}");
                let keys: Vec<u64> = expected.iter().map(|&i| r.morton[i as usize]).collect();
                assert_eq!(r.sorted_keys, keys);
            }
        }
    }
}

#[test]
fn karras_splits_match_the_papers_figure() {
    // Karras 2012, figure 3: eight 5-bit codes.
    let keys: [u32; 8] = [0b00001, 0b00010, 0b00100, 0b00101, 0b10011, 0b11000, 0b11001, 0b11110];
    assert_eq!(range_and_split(&keys, 8, 0), (0, 7, 3));
    assert_eq!(range_and_split(&keys, 8, 1), (0, 1, 0));
    assert_eq!(range_and_split(&keys, 8, 3), (0, 3, 1));
    assert_eq!(range_and_split(&keys, 8, 4), (4, 7, 4));
    assert_eq!(range_and_split(&keys, 8, 5), (5, 7, 6));
    // Equal codes are split by index (the 32 + clz(i ^ j) tie-break): a balanced tree.
    let equal = [7u32; 8];
    assert_eq!(range_and_split(&equal, 8, 0), (0, 7, 3));
}

#[test]
fn every_input_shape_gives_a_valid_tree() {
    let wg = WORKGROUP as usize;
    for bits in [MortonBits::B30, MortonBits::B63] {
        for dist in Distribution::ALL {
            for n in [0, 1, 2, 3, wg - 1, wg, wg + 1, 5000] {
                let (t, s) = generate(n, dist, n % 2 == 0, 9);
                let (r, _) = cpu::build(&t, &s, bits);
                let stats =
                    validate(&r.nodes, &r.parents, &t, &s).unwrap_or_else(|e| panic!("{dist:?} n={n} {bits:?}: {e}"));
                assert_eq!(stats.leaves, n);
                if dist == Distribution::AllEqual && n % 2 == 1 {
                    // Only identical triangles (odd n has no spheres): every code is equal, and
                    // the index tie-break keeps the tree balanced.
                    assert!(
                        stats.depth <= 1 + (n as f64).log2().ceil() as u32,
                        "depth {} for {n}",
                        stats.depth
                    );
                }
            }
        }
    }
}

#[test]
fn the_validator_catches_broken_trees() {
    let (t, s) = generate(100, Distribution::Random, true, 5);
    let (r, _) = cpu::build(&t, &s, MortonBits::B30);
    validate(&r.nodes, &r.parents, &t, &s).unwrap();

    let mut shrunk = r.nodes.clone();
    shrunk[0].max[1] = shrunk[0].min[1];
    assert!(validate(&shrunk, &r.parents, &t, &s)
        .unwrap_err()
        .contains("does not contain"));

    let mut shared_child = r.nodes.clone();
    shared_child[0].b = shared_child[0].a;
    assert!(validate(&shared_child, &r.parents, &t, &s).is_err());

    let mut lost_prim = r.nodes.clone();
    let leaf = lost_prim.iter().position(|n| n.is_leaf()).unwrap();
    lost_prim[leaf].a = (lost_prim[leaf].a + 1) % 100;
    assert!(validate(&lost_prim, &r.parents, &t, &s).is_err());

    assert!(validate(&r.nodes[1..], &r.parents, &t, &s)
        .unwrap_err()
        .contains("nodes for"));
}

fn obj_error(name: &str, text: &str) -> String {
    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR"));
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    let e = load_obj(&path).unwrap_err();
    format!("{e:#}")
}

#[test]
fn bad_mesh_files_get_errors_naming_file_and_problem() {
    let missing = format!("{:#}", load_obj(std::path::Path::new("/no/such/mesh.obj")).unwrap_err());
    assert!(missing.contains("/no/such/mesh.obj"), "{missing}");

    let nan = obj_error("nan.obj", "v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n");
    assert!(
        nan.contains("nan.obj") && nan.contains("vertex 3") && nan.contains("non-finite"),
        "{nan}"
    );

    let inf = obj_error("inf.obj", "v 0 0 0\nv 1 0 inf\nv 0 1 0\nf 1 2 3\n");
    assert!(inf.contains("inf.obj") && inf.contains("vertex 2"), "{inf}");

    let empty = obj_error("empty.obj", "# nothing\n");
    assert!(empty.contains("empty.obj") && empty.contains("no triangles"), "{empty}");

    let bad_index = obj_error("bad_index.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n");
    assert!(bad_index.contains("bad_index.obj"), "{bad_index}");

    let garbage = obj_error("garbage.obj", "v 0 zero 0\nf 1 2 3\n");
    assert!(garbage.contains("garbage.obj"), "{garbage}");
}
