//! Meshes: marching cubes over sparse voxels (closed, oriented, deduplicated; area and
//! volume of analytic level sets).

use crate::common;

use svraster::mesh::mc::CENTRE;
use svraster::mesh::{marching_cubes, TriMesh};

/// A dense `n³` block of unit-spaced voxels over `[lo, lo + n·h]³` (test scaffolding
/// only: the engine's own grids are sparse), with the grid points' field values.
fn block(
    n: usize,
    lo: f64,
    h: f64,
    f: impl Fn([f64; 3]) -> f64,
) -> (Vec<[u32; 8]>, Vec<f32>, Vec<[f64; 3]>) {
    let m = n + 1;
    let idx = |i: usize, j: usize, k: usize| ((i * m + j) * m + k) as u32;
    let mut points = Vec::new();
    let mut values = Vec::new();
    for i in 0..m {
        for j in 0..m {
            for k in 0..m {
                let p = [lo + i as f64 * h, lo + j as f64 * h, lo + k as f64 * h];
                points.push(p);
                values.push(f(p) as f32);
            }
        }
    }
    let mut corners = Vec::new();
    for i in 0..n {
        for j in 0..n {
            for k in 0..n {
                corners.push(std::array::from_fn(|c| {
                    idx(i + (c >> 2 & 1), j + (c >> 1 & 1), k + (c & 1))
                }));
            }
        }
    }
    (corners, values, points)
}

fn euler(m: &TriMesh) -> i64 {
    let mut e = std::collections::HashSet::new();
    for t in &m.triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            e.insert((a.min(b), a.max(b)));
        }
    }
    m.positions.len() as i64 - e.len() as i64 + m.triangles.len() as i64
}

#[test]
fn sphere_is_closed_with_the_expected_area_and_volume() {
    let r = 0.7;
    let (c, v, p) = block(40, -1.0, 0.05, |x| {
        (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt() - r
    });
    let m = marching_cubes(&c, &v, &p, 0.0);
    assert_eq!(
        m.open_edges(),
        0,
        "the sphere must be closed and consistently oriented"
    );
    assert_eq!(euler(&m), 2, "a sphere has Euler characteristic 2");
    let pi = std::f64::consts::PI;
    let (area, vol) = (4.0 * pi * r * r, 4.0 / 3.0 * pi * r * r * r);
    // Chords under-estimate a convex surface: second order in h/r = 0.07.
    let (ea, ev) = (m.area() / area - 1.0, m.volume() / vol - 1.0);
    println!(
        "sphere: {} vertices, {} triangles, area {ea:+.4}, volume {ev:+.4}",
        m.positions.len(),
        m.triangles.len()
    );
    assert!(
        ea.abs() < 0.01 && ev.abs() < 0.01,
        "area {ea:+.4} volume {ev:+.4}"
    );
    assert!(m.volume() > 0.0, "normals point out of the negative region");
    for (q, n) in m.positions.iter().zip(m.vertex_normals()) {
        let d = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt();
        assert!((d - r).abs() < 2e-3, "vertex off the sphere by {}", d - r);
        let cos = (q[0] * n[0] + q[1] * n[1] + q[2] * n[2]) / d;
        assert!(cos > 0.99, "vertex normal not radial: cos {cos}");
    }
}

#[test]
fn torus_has_genus_one() {
    let (rr, r) = (0.6, 0.25);
    let (c, v, p) = block(36, -1.0, 2.0 / 36.0, |x| {
        let q = (x[0] * x[0] + x[1] * x[1]).sqrt() - rr;
        (q * q + x[2] * x[2]).sqrt() - r
    });
    let m = marching_cubes(&c, &v, &p, 0.0);
    assert_eq!(m.open_edges(), 0);
    assert_eq!(euler(&m), 0, "a torus has Euler characteristic 0");
    let pi = std::f64::consts::PI;
    let vol = 2.0 * pi * pi * rr * r * r;
    assert!(
        (m.volume() / vol - 1.0).abs() < 0.02,
        "volume {} vs {vol}",
        m.volume()
    );
}

/// Random values (every ambiguous face and cube case occurs) with a positive border:
/// every component closes, whatever the topology, and no vertex is duplicated.
#[test]
fn random_fields_give_closed_meshes_with_shared_vertices() {
    let mut rng = common::Rng(7);
    for round in 0..20 {
        let n = 10;
        let (c, mut v, p) = block(n, 0.0, 1.0, |_| 0.0);
        for (val, q) in v.iter_mut().zip(&p) {
            let border = q.iter().any(|&x| x == 0.0 || x == n as f64);
            *val = if border {
                1.0
            } else {
                rng.range(-1.0, 1.0) as f32
            };
        }
        let m = marching_cubes(&c, &v, &p, 0.0);
        assert!(m.triangles.len() > 100, "round {round}");
        assert_eq!(
            m.open_edges(),
            0,
            "round {round}: open or inconsistent edges"
        );
        let mut keys: Vec<_> = m.edges.iter().filter(|e| e.0 != CENTRE).copied().collect();
        let centres = m.positions.len() - keys.len();
        keys.sort();
        keys.dedup();
        assert_eq!(
            keys.len() + centres,
            m.positions.len(),
            "round {round}: duplicated vertices"
        );
        // One vertex per crossed grid edge.
        let mut crossed = std::collections::HashSet::new();
        for vox in &c {
            for a in 0..8usize {
                for bit in [4usize, 2, 1] {
                    if a & bit == 0 {
                        let (i, j) = (vox[a], vox[a | bit]);
                        if (v[i as usize] < 0.0) != (v[j as usize] < 0.0) {
                            crossed.insert((i.min(j), i.max(j)));
                        }
                    }
                }
            }
        }
        assert_eq!(crossed.len() + centres, m.positions.len(), "round {round}");
        println!(
            "round {round}: {} vertices ({centres} loop centres), {} triangles",
            m.positions.len(),
            m.triangles.len()
        );
        for (q, &(a, b)) in m.positions.iter().zip(&m.edges) {
            if a == CENTRE {
                continue;
            }
            let (va, vb) = (f64::from(v[a as usize]), f64::from(v[b as usize]));
            let t = va / (va - vb);
            for k in 0..3 {
                let want = p[a as usize][k] + t * (p[b as usize][k] - p[a as usize][k]);
                assert!((q[k] - want).abs() < 1e-12);
            }
        }
    }
}

/// Unobserved corners (NaN) drop their voxels; the rest is still extracted.
#[test]
fn voxels_with_unobserved_corners_are_skipped() {
    let (c, mut v, p) = block(8, -1.0, 0.25, |x| x[0] - 0.1);
    let full = marching_cubes(&c, &v, &p, 0.0);
    v[0] = f32::NAN;
    let cut = marching_cubes(&c, &v, &p, 0.0);
    assert_eq!(full.triangles.len(), 2 * 64);
    assert_eq!(cut.triangles.len(), full.triangles.len());
    // A NaN next to the plane removes that voxel's two triangles.
    let i = p
        .iter()
        .position(|q| q[0] == 0.0 && q[1] == 0.0 && q[2] == 0.0)
        .unwrap();
    v[i] = f32::NAN;
    let cut = marching_cubes(&c, &v, &p, 0.0);
    assert_eq!(cut.triangles.len(), full.triangles.len() - 2 * 4);
}

// ---------------------------------------------------------------------------------
// TSDF fusion on the GPU against an f64 reference.

use svraster::mesh::{DepthView, FuseParams, TsdfFuser};
use svraster::Camera;

/// One view's contribution to one point, in f64 (the kernel's rule, written plainly):
/// `Some((w, w·sdf))` when observed, and whether any decision was within rounding of
/// its threshold (such points are not compared).
fn reference_view(v: &DepthView, p: [f64; 3], fp: &FuseParams) -> (Option<(f64, f64)>, bool) {
    let c = &v.camera;
    let q = c.world_to_camera(p);
    let eps = 1e-4;
    let mut close = (q[2] - c.near).abs() < 1e-6;
    if q[2] <= c.near {
        return (None, close);
    }
    let u = c.fx * q[0] / q[2] + c.cx;
    let w = c.fy * q[1] / q[2] + c.cy;
    let (nu, nv) = (
        2.0 * u / c.width as f64 - 1.0,
        2.0 * w / c.height as f64 - 1.0,
    );
    let lim = 1.0 - fp.crop as f64;
    close |= (nu.abs() - lim).abs() < eps || (nv.abs() - lim).abs() < eps;
    if nu.abs() > lim || nv.abs() > lim {
        return (None, close);
    }
    let (x, y) = (u - 0.5, w - 0.5);
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    close |= fx < eps || fx > 1.0 - eps || fy < eps || fy > 1.0 - eps;
    let (mut depth, mut alpha) = (0.0, 0.0);
    for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
        let wgt = if dx == 1 { fx } else { 1.0 - fx } * if dy == 1 { fy } else { 1.0 - fy };
        if wgt == 0.0 {
            continue;
        }
        let px = (x0 as i64 + dx).clamp(0, c.width as i64 - 1) as usize;
        let py = (y0 as i64 + dy).clamp(0, c.height as i64 - 1) as usize;
        let i = py * c.width as usize + px;
        let (d, a) = (f64::from(v.depth[i]), f64::from(v.alpha[i]));
        if !(d > 0.0 && a >= f64::from(fp.alpha_min)) {
            return (None, close);
        }
        depth += wgt * d;
        alpha += wgt * a;
    }
    let sdf = (depth - q[2]) / fp.band;
    close |= (sdf + 1.0).abs() < eps;
    if sdf < -1.0 {
        return (None, close);
    }
    (Some((alpha, alpha * sdf.min(1.0))), close)
}

fn random_view(rng: &mut common::Rng, w: u32, h: u32) -> DepthView {
    let eye = {
        let d = rng.dir();
        [3.0 * d[0], 3.0 * d[1], 3.0 * d[2]]
    };
    let camera = Camera::look_at(eye, [0.0; 3], [0.0, 0.0, 1.0], 0.9, w, h);
    let n = (w * h) as usize;
    let depth = (0..n)
        .map(|_| {
            if rng.unit() < 0.05 {
                0.0
            } else {
                rng.range(1.5, 4.5) as f32
            }
        })
        .collect();
    let alpha = (0..n).map(|_| rng.range(0.3, 1.0) as f32).collect();
    DepthView {
        camera,
        depth,
        alpha,
    }
}

#[test]
fn tsdf_fusion_matches_the_f64_reference_on_random_views() {
    let ctx = common::context();
    let mut rng = common::Rng(11);
    let views: Vec<DepthView> = (0..6)
        .map(|i| random_view(&mut rng, 32 + 3 * i, 24 + i))
        .collect();
    let points: Vec<[f64; 3]> = (0..20_000)
        .map(|_| {
            [
                rng.range(-1.5, 1.5),
                rng.range(-1.5, 1.5),
                rng.range(-1.5, 1.5),
            ]
        })
        .collect();
    let fp = FuseParams {
        band: 0.5,
        alpha_min: 0.4,
        crop: 0.05,
    };
    let fuser = TsdfFuser::new(&ctx, &views).unwrap();
    let (tsdf, weight) = fuser.fuse(&points, &fp).unwrap();
    let (mut compared, mut observed, mut close_n) = (0, 0, 0);
    for (i, &p) in points.iter().enumerate() {
        let (mut sw, mut ss, mut close) = (0.0, 0.0, false);
        for v in &views {
            let (o, c) = reference_view(v, p, &fp);
            close |= c;
            if let Some((w, s)) = o {
                sw += w;
                ss += s;
            }
        }
        if close {
            close_n += 1;
            continue;
        }
        compared += 1;
        if sw > 0.0 {
            observed += 1;
            let want = ss / sw;
            assert!(
                (f64::from(tsdf[i]) - want).abs() < 1e-4,
                "point {i}: tsdf {} vs reference {want}",
                tsdf[i]
            );
            assert!((f64::from(weight[i]) - sw).abs() < 1e-4 * sw.max(1.0));
        } else {
            assert!(
                tsdf[i].is_nan() && weight[i] == 0.0,
                "point {i} must be unobserved"
            );
        }
    }
    println!("{compared} compared ({observed} observed), {close_n} within rounding of a threshold");
    assert!(
        close_n * 50 < points.len(),
        "too many points near thresholds: {close_n}"
    );
    assert!(
        observed * 5 > compared,
        "too few observed points to test: {observed}"
    );
    common::finish(&ctx);
}

/// Cameras looking straight at the plane z = 0 from above see a constant depth per view:
/// the projective distance is the exact signed distance, truncated at one band above and
/// unobserved beyond one band below.
#[test]
fn tsdf_of_a_plane_is_the_exact_signed_distance_within_the_band() {
    let ctx = common::context();
    let mut views = Vec::new();
    for (i, &(x, y, hgt)) in [(0.0, 0.0, 2.0), (0.3, -0.2, 2.5), (-0.4, 0.1, 1.7)]
        .iter()
        .enumerate()
    {
        let camera = Camera::look_at(
            [x, y, hgt],
            [x, y, 0.0],
            [0.0, 1.0, 0.0],
            1.2,
            40 + i as u32,
            30,
        );
        let n = (camera.width * camera.height) as usize;
        views.push(DepthView {
            depth: vec![hgt as f32; n],
            alpha: vec![1.0; n],
            camera,
        });
    }
    let band = 0.1;
    let fp = FuseParams {
        band,
        alpha_min: 0.5,
        crop: 0.0,
    };
    let points: Vec<[f64; 3]> = (0..200)
        .map(|i| {
            [
                0.05 * ((i % 7) as f64 - 3.0),
                0.04 * ((i % 5) as f64 - 2.0),
                -0.15 + 0.3 * i as f64 / 199.0,
            ]
        })
        .collect();
    let (tsdf, _) = TsdfFuser::new(&ctx, &views)
        .unwrap()
        .fuse(&points, &fp)
        .unwrap();
    for (p, t) in points.iter().zip(&tsdf) {
        let s = p[2] / band;
        if s < -1.0 - 1e-4 {
            assert!(
                t.is_nan(),
                "z {}: beyond the band behind the surface, unobserved",
                p[2]
            );
        } else if s > -1.0 + 1e-4 {
            let want = s.min(1.0);
            assert!(
                (f64::from(*t) - want).abs() < 1e-4,
                "z {}: tsdf {t} vs {want}",
                p[2]
            );
        }
    }
    common::finish(&ctx);
}

// ---------------------------------------------------------------------------------
// Extraction end to end on analytic depth maps.

use svraster::mesh::{extract, MeshOptions};
use svraster::scene::{octpath_from_ijk, Scene};

/// Depth (camera z) and opacity of a sphere of radius `r` at the origin, per pixel centre.
fn sphere_view(camera: Camera, r: f64) -> DepthView {
    let n = (camera.width * camera.height) as usize;
    let (mut depth, mut alpha) = (vec![0.0f32; n], vec![0.0f32; n]);
    for py in 0..camera.height {
        for px in 0..camera.width {
            let (o, d) = camera.pixel_ray(px, py);
            let b = o[0] * d[0] + o[1] * d[1] + o[2] * d[2];
            let c = o[0] * o[0] + o[1] * o[1] + o[2] * o[2] - r * r;
            let disc = b * b - c;
            if disc > 0.0 {
                let t = -b - disc.sqrt();
                let hit = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
                let i = (py * camera.width + px) as usize;
                depth[i] = camera.world_to_camera(hit)[2] as f32;
                alpha[i] = 1.0;
            }
        }
    }
    DepthView {
        camera,
        depth,
        alpha,
    }
}

/// Cameras on a sphere of radius `dist` (golden-angle spiral) looking at the origin.
fn orbit(n: usize, dist: f64, size: u32) -> Vec<Camera> {
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let phi = i as f64 * 2.399_963_229_728_653;
            let s = (1.0 - z * z).sqrt();
            let eye = [dist * s * phi.cos(), dist * s * phi.sin(), dist * z];
            let up = if z.abs() > 0.9 {
                [0.0, 1.0, 0.0]
            } else {
                [0.0, 0.0, 1.0]
            };
            Camera::look_at(eye, [0.0; 3], up, 0.9, size, size)
        })
        .collect()
}

/// A model of every level-`l` voxel of the cube [-1, 1]³ (densities and colours unused).
fn uniform_scene(l: u32) -> Scene {
    let n = 1u32 << l;
    let mut paths = Vec::new();
    for i in 0..n {
        for j in 0..n {
            for k in 0..n {
                paths.push(octpath_from_ijk([i, j, k], l));
            }
        }
    }
    let levels = vec![l as u8; paths.len()];
    Scene::from_voxels([0.0; 3], 2.0, 0, paths, levels, 0.0).unwrap()
}

#[test]
fn extraction_of_a_fused_sphere_is_closed_and_on_the_sphere() {
    let ctx = common::context();
    let r = 0.6;
    let views: Vec<DepthView> = orbit(40, 2.5, 64)
        .into_iter()
        .map(|c| sphere_view(c, r))
        .collect();
    let scene = uniform_scene(3);
    let opts = MeshOptions {
        level: Some(6),
        ..MeshOptions::default()
    };
    let ex = extract(&ctx, &scene, &views, &opts).unwrap();
    let m = &ex.mesh;
    let s = ex.voxel_size;
    println!("{:?}", ex.report);
    let (mut worst, mut sum) = (0.0f64, 0.0);
    for q in &m.positions {
        let e = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt() - r;
        worst = worst.max(e.abs());
        sum += e.abs();
    }
    let pi = std::f64::consts::PI;
    let ea = m.area() / (4.0 * pi * r * r) - 1.0;
    println!(
        "level {} (voxel {s:.4}): {} vertices, {} triangles, {} open edges, mean |r − {r}| {:.5}, max {worst:.5}, area {ea:+.4}",
        ex.level,
        m.positions.len(),
        m.triangles.len(),
        m.open_edges(),
        sum / m.positions.len() as f64
    );
    assert_eq!(ex.level, 6);
    assert_eq!(m.open_edges(), 0, "the fused sphere must be closed");
    // The projective distance is exact on the surface only: between grid points the
    // views' averaged values bend the crossing (measured: mean 0.03, max 0.32 voxels).
    assert!(
        worst < 0.4 * s,
        "vertex off the sphere by {worst} (voxel {s})"
    );
    assert!(sum / (m.positions.len() as f64) < 0.06 * s, "mean error");
    assert!(ea.abs() < 0.01, "area {ea:+.4}");
    // Sparse: only voxels near the surface (a shell about 3 voxels thick).
    let shell = 4.0 * pi * r * r / (s * s);
    assert!(
        (ex.voxels.len() as f64) < 5.0 * shell,
        "{} voxels for a shell of ~{shell:.0}",
        ex.voxels.len()
    );
    common::finish(&ctx);
}

/// The CPU mesh rasterizer: a marching-cubes sphere covers the sphere's analytic
/// silhouette (IoU ≈ 1) and its depth; moved aside, the IoU drops.
#[test]
fn mesh_silhouettes_match_the_analytic_sphere() {
    use svraster::mesh::view::{rasterize, silhouette_iou};
    let r = 0.6;
    let (c, v, p) = block(48, -1.0, 2.0 / 48.0, |x| {
        (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt() - r
    });
    let m = marching_cubes(&c, &v, &p, 0.0);
    for cam in orbit(6, 2.5, 64) {
        let truth = sphere_view(cam.clone(), r);
        let view = rasterize(&cam, &m.positions, &m.triangles);
        let iou = silhouette_iou(&view, &truth.alpha);
        assert!(iou > 0.97, "IoU {iou}");
        // Chords lie inside the sphere: small depth errors, larger at grazing angles.
        let (mut sum, mut n, mut worst) = (0.0f32, 0, 0.0f32);
        for (i, &a) in truth.alpha.iter().enumerate() {
            if a > 0.0 && view.covered(i) {
                let e = (view.depth[i] - truth.depth[i]).abs();
                sum += e;
                n += 1;
                worst = worst.max(e);
            }
        }
        assert!(
            sum / (n as f32) < 0.002 && worst < 0.05,
            "depth error mean {} max {worst}",
            sum / n as f32
        );
        let moved: Vec<[f64; 3]> = m
            .positions
            .iter()
            .map(|q| [q[0] + 0.3, q[1], q[2] + 0.3])
            .collect();
        let off = silhouette_iou(&rasterize(&cam, &moved, &m.triangles), &truth.alpha);
        assert!(off < 0.8, "moved mesh IoU {off}");
    }
}

/// Vertex colours come from the model voxel just inside the surface (SH degree 0).
#[test]
fn vertex_colors_come_from_the_voxel_inside() {
    let mut scene = uniform_scene(2);
    const C0: f32 = 0.282_094_8;
    for (i, s) in scene.sh0.iter_mut().enumerate() {
        // Voxel i gets colour (i/64, 1 − i/64, 0.5) through 0.5 + C0·sh0.
        let want = [i as f32 / 64.0, 1.0 - i as f32 / 64.0, 0.5];
        *s = want.map(|w| (w - 0.5) / C0);
    }
    // Level-2 voxels are 0.5 wide over [-1, 1]³. A vertex on the face x = 0 between
    // voxel columns, normal +x: the colour of the voxel at x < 0.
    let positions = vec![[0.0, 0.1, 0.6], [0.0, -0.9, -0.2], [5.0, 5.0, 5.0]];
    let normals = vec![[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]];
    let cols = svraster::mesh::extract::vertex_colors(&scene, &positions, &normals, 0.1);
    let idx = |p: [f64; 3]| {
        let ijk = p.map(|x| ((x + 1.0) / 0.5).floor() as u32);
        let path = octpath_from_ijk(ijk, 2);
        scene.octpath.iter().position(|&q| q == path).unwrap()
    };
    for (k, inside) in [[-0.05, 0.1, 0.6], [0.05, -0.9, -0.2]]
        .into_iter()
        .enumerate()
    {
        let i = idx(inside);
        let want = [i as f32 / 64.0, 1.0 - i as f32 / 64.0, 0.5].map(|w| (w * 255.0).round() as u8);
        assert_eq!(cols[k], want, "vertex {k}");
    }
    assert_eq!(cols[2], [128; 3], "outside every voxel: grey");
}

/// The default mesh level is the one most of the model's voxels have (finer on a tie).
#[test]
fn default_mesh_level_is_the_most_common_level() {
    use svraster::mesh::extract::LevelHistogram;
    let h = |v: &[(u8, usize)]| LevelHistogram(v.iter().copied().collect()).default_level();
    assert_eq!(
        h(&[(8, 52), (11, 114_842), (12, 251_395), (14, 51_848)]),
        12
    );
    assert_eq!(h(&[(5, 10), (6, 10)]), 6);
    assert_eq!(h(&[]), 1);
    let scene = uniform_scene(3);
    let hist = svraster::mesh::extract::level_histogram(&scene, Some(&([-1.0; 3], [-0.5; 3])));
    assert_eq!(
        hist.0.get(&3),
        Some(&8),
        "the 2×2×2 level-3 voxels in [-1, -0.5]³"
    );
}

/// Meshes are read from binary little-endian and ASCII PLY alike (other tools write
/// either): the same positions and triangles, a quad fanned into two triangles, extra
/// vertex properties skipped; a truncated ASCII body and a word for a number are errors
/// naming the file.
#[test]
fn meshes_read_from_binary_and_ascii_ply_alike() {
    use svraster::mesh::ply;
    let dir = tempfile::tempdir().unwrap();
    let m = ply::PlyMesh {
        positions: vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.5],
            [0.0, 1.0, -0.25],
        ],
        normals: vec![[0.0, 0.0, 1.0]; 4],
        colors: vec![[10, 20, 30]; 4],
        triangles: vec![[0, 1, 2], [0, 2, 3]],
    };
    let bin = dir.path().join("b.ply");
    ply::write(&bin, &m).unwrap();
    let ascii = dir.path().join("a.ply");
    std::fs::write(
        &ascii,
        "ply\nformat ascii 1.0\ncomment by hand\nelement vertex 4\nproperty float x\n\
         property float y\nproperty float z\nproperty uchar red\nelement face 1\n\
         property list uchar int vertex_indices\nend_header\n\
         0 0 0 7\n1 0 0 7\n1 1 0.5 7\n0 1 -0.25 7\n4 0 1 2 3\n",
    )
    .unwrap();
    let (pb, tb) = ply::read(&bin).unwrap();
    let (pa, ta) = ply::read(&ascii).unwrap();
    assert_eq!(pb, m.positions);
    assert_eq!((pa, ta.clone()), (pb, tb));
    assert_eq!(ta, m.triangles);
    // Counts and indices from the file: a face list of 1e308 entries panicked while
    // sizing its allocation, -1 was read as vertex 0.
    let four = "0 0 0 7\n1 0 0 7\n1 1 0.5 7\n0 1 -0.25 7\n";
    for (body, needle) in [
        ("0 0 0 7\n1 0 0 7\n", "ends inside"),
        ("0 0 zero 7\n", "`zero` is not a number"),
        (&format!("{four}1e308 0 1 2\n") as &str, "is not a count"),
        (&format!("{four}-3 0 1 2\n"), "is not a count"),
        (&format!("{four}3 0 -1 2\n"), "`-1` is not a vertex index"),
        (&format!("{four}3 0 1.5 2\n"), "`1.5` is not a vertex index"),
        (&format!("{four}9 0 1 2\n"), "ends inside"),
    ] {
        let bad = dir.path().join("bad.ply");
        let text = std::fs::read_to_string(&ascii).unwrap();
        let head = &text[..text.find("end_header\n").unwrap() + 11];
        std::fs::write(&bad, format!("{head}{body}")).unwrap();
        let e = ply::read(&bad).unwrap_err().to_string();
        assert!(e.contains("bad.ply") && e.contains(needle), "{e}");
    }
}

/// Mesh sampling is bounded before it allocates: a vertex at 3.4e38, one at infinity or a
/// spacing of 0 allocated until the process aborted; the error names the threshold to
/// raise. The demo's analytic surface is bounded the same way.
#[test]
fn mesh_sampling_refuses_counts_it_cannot_hold() {
    use svraster::mesh::metrics::sample_mesh;
    let tri = [[0u32, 1, 2]];
    let unit = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let n = sample_mesh(&unit, &tri, 0.01).unwrap().len();
    assert!(
        (4990..=5000).contains(&n),
        "{n} samples on half a unit square"
    );
    for (p, spacing) in [
        ([3.4e38, 0.0, 0.0], 0.01),
        ([f64::INFINITY, 0.0, 0.0], 0.01),
        ([f64::NAN, 0.0, 0.0], 0.01),
        ([1.0, 0.0, 0.0], 0.0),
        ([1.0, 0.0, 0.0], 1e-5),
    ] {
        let v = [[0.0, 0.0, 0.0], p, [0.0, 1.0, 0.0]];
        let e = sample_mesh(&v, &tri, spacing).unwrap_err().to_string();
        assert!(e.contains("--threshold"), "{p:?} at {spacing}: {e}");
    }
    let eyes = [[3.0, 0.0, 1.0]];
    assert!(!svraster::data::demo::surface_samples(&eyes, 0.05)
        .unwrap()
        .is_empty());
    let e = svraster::data::demo::surface_samples(&eyes, 1e-6)
        .unwrap_err()
        .to_string();
    assert!(e.contains("--threshold"), "{e}");
}
