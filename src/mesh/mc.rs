//! Marching cubes over sparse voxels (paper §3.2.4: the mesh is the zero level set of a
//! field stored on the voxels' shared grid points).
//!
//! Every voxel is a cube given by the indices of its 8 corners (corner order
//! `x<<2 | y<<1 | z`, docs/ARCHITECTURE.md §2) into one array of grid points with one value each. No
//! case table: each voxel's surface is built from its faces, which makes the result
//! watertight by construction.
//!
//! * **Faces.** On each of the cube's 6 faces the sign changes along its 4 sides give 0,
//!   2 or 4 crossing points, joined by segments. A face with 4 crossings (diagonal
//!   corners of equal sign) is resolved by the *asymptotic decider*: the bilinear
//!   interpolant's saddle value `(n₀n₁ − p₀p₁) / (n₀ + n₁ − p₀ − p₁)` (n: the negative
//!   diagonal, p: the positive one) says whether the negative corners are joined across
//!   the face. The decision depends only on the face's 4 values, so the two voxels that
//!   share a face (and its grid points) always draw the same segments there.
//! * **Orientation.** Sides are walked counter-clockwise seen from outside the cube and
//!   each segment runs from the side where the walk leaves the negative region to the
//!   side where it enters it (negative region on the segment's left). A crossed cube
//!   edge is then the end of exactly one segment and the start of exactly one other, so
//!   the segments chain into closed loops; each loop becomes a triangle fan whose
//!   normals point towards the positive side (for a signed distance: out of the solid).
//!   The fan starts at a loop vertex unless one of its diagonals would join two
//!   crossings of the same ambiguous face (the neighbour across that face could draw the
//!   same diagonal, giving an edge of four triangles); such a loop is fanned from an
//!   added centre vertex (the mean of its crossings) instead.
//! * **Shared vertices.** A crossing point sits on the grid-point pair of its edge,
//!   interpolated linearly at the iso value, and is keyed by that pair: voxels of equal
//!   level share their edges' grid points, so their vertices are deduplicated exactly
//!   and the mesh is closed wherever the field is defined. Where a large voxel meets
//!   smaller ones their edges do not coincide (cracks at T-junctions); the extraction
//!   (`super::extract`) refines every voxel the surface can cross to one level first.
//! * Values `≥ iso` count as positive; a voxel with a non-finite corner (unobserved) is
//!   skipped, which leaves an open boundary there.

use std::collections::HashMap;

/// Corners of each cube face, counter-clockwise seen from outside (corner `x<<2|y<<1|z`):
/// −x, +x, −y, +y, −z, +z.
pub const FACES: [[usize; 4]; 6] = [
    [0, 1, 3, 2],
    [4, 6, 7, 5],
    [0, 4, 5, 1],
    [2, 3, 7, 6],
    [0, 2, 6, 4],
    [1, 5, 7, 3],
];

/// Index 0..12 of the cube edge between corners `a` and `b` (one bit apart).
fn edge_id(a: usize, b: usize) -> usize {
    let d = a ^ b;
    debug_assert!(d.count_ones() == 1);
    let lo = a & b;
    // Axis of the edge and the two remaining corner bits of its lower end.
    let (axis, rest) = match d {
        4 => (0, lo & 3),
        2 => (1, ((lo >> 2) << 1) | (lo & 1)),
        _ => (2, lo >> 1),
    };
    axis * 4 + rest
}

/// The 12 cube edges as corner pairs (lower corner first), indexed by [`edge_id`].
fn edge_corners() -> [(usize, usize); 12] {
    let mut e = [(0, 0); 12];
    for a in 0..8usize {
        for bit in [4usize, 2, 1] {
            if a & bit == 0 {
                e[edge_id(a, a | bit)] = (a, a | bit);
            }
        }
    }
    e
}

/// Whether two cube edges lie on a common face, by [`edge_id`].
fn shared_faces() -> [[bool; 12]; 12] {
    let mut t = [[false; 12]; 12];
    for f in FACES {
        let ids: [usize; 4] = std::array::from_fn(|k| edge_id(f[k], f[(k + 1) % 4]));
        for a in ids {
            for b in ids {
                t[a][b] = true;
            }
        }
    }
    t
}

/// [`TriMesh::edges`] entry of a loop's centre vertex: `(CENTRE, voxel)`.
pub const CENTRE: u32 = u32::MAX;

/// A triangle mesh whose vertices lie on grid-point edges.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriMesh {
    pub positions: Vec<[f64; 3]>,
    /// Counter-clockwise seen from the positive side.
    pub triangles: Vec<[u32; 3]>,
    /// Per vertex: the grid points `(a, b)`, `a < b`, of the edge it lies on, or
    /// `(CENTRE, voxel)` for the centre of a loop that is not fanned from a corner.
    pub edges: Vec<(u32, u32)>,
}

impl TriMesh {
    /// `(b − a) × (c − a)` of triangle `t`: twice its area along its normal.
    fn face_cross(&self, t: &[u32; 3]) -> [f64; 3] {
        let [a, b, c] = t.map(|i| self.positions[i as usize]);
        let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ]
    }

    /// Area-weighted vertex normals (unit; zero for a vertex of degenerate triangles only).
    pub fn vertex_normals(&self) -> Vec<[f64; 3]> {
        let mut n = vec![[0.0f64; 3]; self.positions.len()];
        for t in &self.triangles {
            let f = self.face_cross(t);
            for &i in t {
                for k in 0..3 {
                    n[i as usize][k] += f[k];
                }
            }
        }
        for v in &mut n {
            let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            if l > 0.0 {
                *v = v.map(|x| x / l);
            }
        }
        n
    }

    /// Total triangle area.
    pub fn area(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let f = self.face_cross(t);
                0.5 * (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt()
            })
            .sum()
    }

    /// Signed enclosed volume (divergence theorem; positive when the normals point out
    /// of the enclosed region, i.e. the negative values are inside).
    pub fn volume(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.positions[i as usize]);
                (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                    + a[2] * (b[0] * c[1] - b[1] * c[0]))
                    / 6.0
            })
            .sum()
    }

    /// Directed edges used by other than exactly one triangle, or whose reverse is not
    /// used by exactly one triangle: 0 for a closed, consistently oriented mesh.
    pub fn open_edges(&self) -> usize {
        let mut count: HashMap<(u32, u32), i32> = HashMap::new();
        for t in &self.triangles {
            for k in 0..3 {
                *count.entry((t[k], t[(k + 1) % 3])).or_default() += 1;
            }
        }
        count
            .iter()
            .filter(|(&(a, b), &n)| n != 1 || count.get(&(b, a)) != Some(&1))
            .count()
    }
}

/// The level set `value = iso` of the field given on `points` (one value each) over the
/// voxels `corners` (8 grid-point indices each, corner order `x<<2|y<<1|z`).
///
/// Panics if an index is out of range.
pub fn marching_cubes(
    corners: &[[u32; 8]],
    values: &[f32],
    points: &[[f64; 3]],
    iso: f64,
) -> TriMesh {
    assert_eq!(values.len(), points.len(), "one value per grid point");
    let edges = edge_corners();
    let share_face = shared_faces();
    let mut mesh = TriMesh::default();
    let mut vertex_of: HashMap<u64, u32> = HashMap::new();
    for (voxel, vox) in corners.iter().enumerate() {
        let v: [f64; 8] = vox.map(|i| f64::from(values[i as usize]) - iso);
        if v.iter().any(|x| !x.is_finite()) {
            continue;
        }
        let neg = v.map(|x| x < 0.0);
        if neg.iter().all(|&n| n) || neg.iter().all(|&n| !n) {
            continue;
        }
        // next[e]: the edge the segment starting at crossed edge e ends at.
        let mut next = [u8::MAX; 12];
        for face in FACES {
            let side = |k: usize| (face[k % 4], face[(k + 1) % 4]);
            let leaving: Vec<usize> = (0..4)
                .filter(|&k| neg[side(k).0] && !neg[side(k).1])
                .collect();
            let entering: Vec<usize> = (0..4)
                .filter(|&k| !neg[side(k).0] && neg[side(k).1])
                .collect();
            let eid = |k: usize| {
                let (a, b) = side(k);
                edge_id(a, b)
            };
            match leaving.len() {
                0 => {}
                1 => next[eid(leaving[0])] = eid(entering[0]) as u8,
                _ => {
                    // Ambiguous face: asymptotic decider on the bilinear saddle value.
                    let (mut n, mut p) = (Vec::new(), Vec::new());
                    for &c in &face {
                        if neg[c] {
                            n.push(v[c]);
                        } else {
                            p.push(v[c]);
                        }
                    }
                    let den = (n[0] + n[1]) - (p[0] + p[1]);
                    let joined = den != 0.0 && (n[0] * n[1] - p[0] * p[1]) / den < 0.0;
                    for &k in &leaving {
                        let e = if joined { (k + 1) % 4 } else { (k + 3) % 4 };
                        debug_assert!(entering.contains(&e));
                        next[eid(k)] = eid(e) as u8;
                    }
                }
            }
        }
        let mut used = [false; 12];
        let mut ring: Vec<u32> = Vec::with_capacity(12);
        let mut ring_edges: Vec<usize> = Vec::with_capacity(12);
        for start in 0..12 {
            if next[start] == u8::MAX || used[start] {
                continue;
            }
            ring.clear();
            ring_edges.clear();
            let mut e = start;
            while !used[e] {
                used[e] = true;
                let (ca, cb) = edges[e];
                let (mut ia, mut ib) = (vox[ca], vox[cb]);
                let (mut va, mut vb) = (v[ca], v[cb]);
                if ia > ib {
                    std::mem::swap(&mut ia, &mut ib);
                    std::mem::swap(&mut va, &mut vb);
                }
                let key = (u64::from(ia) << 32) | u64::from(ib);
                let id = *vertex_of.entry(key).or_insert_with(|| {
                    let t = va / (va - vb);
                    let (pa, pb) = (points[ia as usize], points[ib as usize]);
                    mesh.positions
                        .push(std::array::from_fn(|k| pa[k] + t * (pb[k] - pa[k])));
                    mesh.edges.push((ia, ib));
                    (mesh.positions.len() - 1) as u32
                });
                ring.push(id);
                ring_edges.push(e);
                e = next[e] as usize;
                debug_assert!(e != u8::MAX as usize, "segments must chain into loops");
            }
            // The loop runs with the negative region on its left seen from outside the
            // cube, i.e. clockwise around the negative side: reversed, the fan faces the
            // positive side. A fan diagonal between two crossings of one (ambiguous)
            // face could be drawn by the neighbour too; such loops get a centre vertex.
            let fan_ok = ring_edges[1..ring.len() - 1]
                .iter()
                .skip(1)
                .all(|&e| !share_face[ring_edges[0]][e]);
            if ring.len() == 3 || fan_ok {
                for i in 1..ring.len() - 1 {
                    mesh.triangles.push([ring[0], ring[i + 1], ring[i]]);
                }
            } else {
                let mut c = [0.0f64; 3];
                for &i in &ring {
                    let q = mesh.positions[i as usize];
                    for (ck, qk) in c.iter_mut().zip(q) {
                        *ck += qk / ring.len() as f64;
                    }
                }
                mesh.positions.push(c);
                mesh.edges.push((CENTRE, voxel as u32));
                let centre = (mesh.positions.len() - 1) as u32;
                for i in 0..ring.len() {
                    mesh.triangles
                        .push([centre, ring[(i + 1) % ring.len()], ring[i]]);
                }
            }
        }
    }
    mesh
}
