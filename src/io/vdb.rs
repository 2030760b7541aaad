//! OpenVDB files of a float grid (`final_mass.vdb`): the published file layout (format version
//! 224), written directly since no Rust crate writes OpenVDB. The tree is the standard
//! `Tree_float_5_4_3`: a root with one 32^3 internal node at the origin (so grids up to 4096
//! voxels a side), 16^3 internal nodes below it and 8^3 leaves, each leaf written whole and
//! uncompressed. Only the nodes holding a nonzero value are written; zero is the background.
//! Voxel `(i, j, k)` is the node `origin + dx (i, j, k)` (an affine map), so tools place it in
//! the same world units as the `.mgrid` beside it. Read back by OpenVDB's own library in the
//! client check (`python3-openvdb`), with its sum.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

/// Voxels a side below one child of the root (the 5-level internal node).
pub const MAX_SIDE: usize = 4096;

/// No compression, every value written (OpenVDB's `NO_MASK_AND_ALL_VALS`).
const ALL_VALUES: u8 = 6;

/// Writes `values` (`dims` nodes, x slowest, z fastest, as in the `.mgrid`) as a float grid
/// named `name` at `origin` with spacing `dx`, to `path` atomically.
pub fn write_float_grid(
    path: &Path,
    name: &str,
    dims: [usize; 3],
    origin: [f64; 3],
    dx: f64,
    values: &[f64],
) -> std::io::Result<()> {
    if dims.iter().any(|&d| d > MAX_SIDE) || dims.iter().product::<usize>() != values.len() {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("a grid of {dims:?} nodes does not fit one OpenVDB root child"),
        ));
    }
    // Leaves by (internal-4 index, leaf index), in the order OpenVDB reads them: each node's
    // children by their bit in its mask.
    let mut leaves: BTreeMap<(u32, u32), [f32; 512]> = BTreeMap::new();
    for i in 0..dims[0] {
        for j in 0..dims[1] {
            for k in 0..dims[2] {
                let v = values[(i * dims[1] + j) * dims[2] + k];
                if v == 0.0 {
                    continue;
                }
                let bit = |shift: usize, bits: usize| {
                    let m = (1 << bits) - 1;
                    ((((i >> shift) & m) << (2 * bits))
                        | (((j >> shift) & m) << bits)
                        | ((k >> shift) & m)) as u32
                };
                let leaf = leaves.entry((bit(7, 5), bit(3, 4))).or_insert([0.0; 512]);
                leaf[bit(0, 3) as usize] = v as f32;
            }
        }
    }
    crate::io::write_atomically(path, |w| {
        let mut b = Vec::new();
        b.extend_from_slice(&[0x20, 0x42, 0x44, 0x56, 0, 0, 0, 0]); // magic " BDV"
        put_u32(&mut b, 224); // file format version
        put_u32(&mut b, 8); // library version the layout matches: 8.1
        put_u32(&mut b, 1);
        b.push(0); // no grid offsets table
        b.extend_from_slice(b"a7a2c7f0-6d5e-4f6b-9c1e-6d6f72706821"); // the file's UUID (36 chars)
        put_u32(&mut b, 0); // file metadata entries
        put_u32(&mut b, 1); // grids
        put_name(&mut b, name);
        put_name(&mut b, "Tree_float_5_4_3");
        put_u32(&mut b, 0); // no instance parent
        let start = b.len() as u64 + 24;
        put_u64(&mut b, start); // where the grid starts; block and end offsets unused here
        put_u64(&mut b, 0);
        put_u64(&mut b, 0);
        put_u32(&mut b, 0); // no compression
        put_u32(&mut b, 4); // grid metadata entries
        meta_string(&mut b, "class", "fog volume");
        meta_string(&mut b, "file_compression", "none");
        put_name(&mut b, "is_saved_as_half_float");
        put_name(&mut b, "bool");
        put_u32(&mut b, 1);
        b.push(0);
        meta_string(&mut b, "name", name);
        // The affine map, row by row: world = origin + dx * voxel.
        put_name(&mut b, "AffineMap");
        for row in [
            [dx, 0.0, 0.0, 0.0],
            [0.0, dx, 0.0, 0.0],
            [0.0, 0.0, dx, 0.0],
        ] {
            row.iter().for_each(|v| put_f64(&mut b, *v));
        }
        [origin[0], origin[1], origin[2], 1.0]
            .iter()
            .for_each(|v| put_f64(&mut b, *v));
        // The tree's topology: the root, its one child, the 16^3 nodes and the leaves' masks.
        put_u32(&mut b, 1); // buffers per leaf
        put_f32(&mut b, 0.0); // background
        put_u32(&mut b, 0); // root tiles
        put_u32(&mut b, 1); // root children
        let n4: Vec<u32> = {
            let mut v: Vec<u32> = leaves.keys().map(|k| k.0).collect();
            v.dedup();
            v
        };
        put_i32s(&mut b, [0, 0, 0]);
        put_mask(&mut b, &mask::<512>(n4.iter().copied()));
        put_mask(&mut b, &[0u64; 512]); // no active tiles
        b.push(ALL_VALUES);
        b.extend(std::iter::repeat_n(0u8, 32768 * 4));
        for &c in &n4 {
            let children = leaves.keys().filter(|k| k.0 == c).map(|k| k.1);
            put_mask(&mut b, &mask::<64>(children));
            put_mask(&mut b, &[0u64; 64]);
            b.push(ALL_VALUES);
            b.extend(std::iter::repeat_n(0u8, 4096 * 4));
            for leaf in leaves.range((c, 0)..=(c, u32::MAX)).map(|(_, l)| l) {
                put_mask(&mut b, &leaf_mask(leaf));
            }
        }
        // The leaves' values, in the same order.
        for leaf in leaves.values() {
            put_mask(&mut b, &leaf_mask(leaf));
            b.push(ALL_VALUES);
            leaf.iter().for_each(|v| put_f32(&mut b, *v));
        }
        w.write_all(&b)
    })
}

/// A child mask of `N` words with the given bits set.
fn mask<const N: usize>(bits: impl Iterator<Item = u32>) -> [u64; N] {
    let mut m = [0u64; N];
    for bit in bits {
        m[(bit / 64) as usize] |= 1 << (bit % 64);
    }
    m
}

/// A leaf's active voxels: those holding a nonzero value.
fn leaf_mask(leaf: &[f32; 512]) -> [u64; 8] {
    mask::<8>((0..512u32).filter(|&i| leaf[i as usize] != 0.0))
}

fn put_u32(b: &mut Vec<u8>, v: u32) {
    b.extend_from_slice(&v.to_le_bytes());
}
fn put_u64(b: &mut Vec<u8>, v: u64) {
    b.extend_from_slice(&v.to_le_bytes());
}
fn put_f32(b: &mut Vec<u8>, v: f32) {
    b.extend_from_slice(&v.to_le_bytes());
}
fn put_f64(b: &mut Vec<u8>, v: f64) {
    b.extend_from_slice(&v.to_le_bytes());
}
fn put_i32s(b: &mut Vec<u8>, v: [i32; 3]) {
    v.iter().for_each(|x| b.extend_from_slice(&x.to_le_bytes()));
}
fn put_mask(b: &mut Vec<u8>, m: &[u64]) {
    m.iter().for_each(|w| put_u64(b, *w));
}
fn put_name(b: &mut Vec<u8>, s: &str) {
    put_u32(b, s.len() as u32);
    b.extend_from_slice(s.as_bytes());
}
fn meta_string(b: &mut Vec<u8>, name: &str, value: &str) {
    put_name(b, name);
    put_name(b, "string");
    put_name(b, value);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_value_lands_in_its_leaf_at_its_bit_and_zero_is_background() {
        let dir = std::env::temp_dir().join(format!("morph-vdb-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("g.vdb");
        let dims = [3, 3, 3];
        let mut values = vec![0.0; 27];
        let node = (1, 2, 0);
        values[(node.0 * 3 + node.1) * 3 + node.2] = 5.0;
        write_float_grid(&path, "mass", dims, [0.5, -1.0, 2.0], 0.25, &values).unwrap();
        let b = std::fs::read(&path).unwrap();
        assert_eq!(&b[..8], &[0x20, 0x42, 0x44, 0x56, 0, 0, 0, 0]);
        // One leaf: the file ends with its mask, the no-compression byte and its 512 values.
        let values_at = b.len() - 512 * 4;
        let value = |i: usize| f32::from_le_bytes(b[values_at + 4 * i..][..4].try_into().unwrap());
        let bit = (1 << 6) | (2 << 3); // x slowest: x << 6 | y << 3 | z
        assert_eq!(value(bit), 5.0);
        assert_eq!((0..512).filter(|&i| value(i) != 0.0).count(), 1);
        assert_eq!(b[values_at - 1], ALL_VALUES);
        let words: Vec<u64> = (0..8)
            .map(|w| u64::from_le_bytes(b[values_at - 1 - 64 + 8 * w..][..8].try_into().unwrap()))
            .collect();
        let mut expected = [0u64; 8];
        expected[bit / 64] = 1 << (bit % 64);
        assert_eq!(words, expected, "only that voxel is active");
        // An empty grid has no leaves: just the root's child and nothing below.
        write_float_grid(&path, "mass", dims, [0.0; 3], 1.0, &[0.0; 27]).unwrap();
        let empty = std::fs::read(&path).unwrap().len();
        assert!(empty < b.len() && empty > 32768 * 4);
        // A grid wider than one root child is refused, not written wrong.
        assert!(
            write_float_grid(&path, "m", [4097, 1, 1], [0.0; 3], 1.0, &vec![0.0; 4097]).is_err()
        );
        std::fs::remove_dir_all(dir).unwrap();
    }
}
