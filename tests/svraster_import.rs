//! SVRaster checkpoints (src/scene/svraster.rs): a model saved by the test is written as
//! SVRaster's `SVInOut.save` has `torch.save` lay it out, by tools/svraster_checkpoint.py
//! (no PyTorch: the same ZIP entries and protocol-2 pickle, storages as persistent ids),
//! whose grid points are built as SVRaster builds them (`build_grid_pts_link`, ported to
//! Python from its code) rather than from our keys. Imported, every voxel's corners,
//! SH and octree path are the dumped ones exactly — plain, with SH degrees above the
//! active one dropped, and quantized (SVRaster's index + codebook per channel, against
//! the script's dequantized values) — and broken or incomplete files are refused naming
//! the file and the entry. Needs `python3` (standard library only); skipped without it.

use std::path::Path;
use std::process::Command;

use crate::common::{random_scene, Rng};
use svraster::scene::svraster::{import_svraster, is_torch_checkpoint, SvrasterImport};
use svraster::scene::Scene;

fn python() -> Option<&'static str> {
    Command::new("python3")
        .arg("--version")
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map(|_| "python3")
}

/// Saves `scene` as a model of ours (the script's input).
fn dump(scene: &Scene, dir: &Path) -> std::path::PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let p = dir.join("model.safetensors");
    svraster::scene::checkpoint::save(scene, &p).unwrap();
    p
}

fn write_checkpoint(py: &str, model: &Path, out: &Path, extra: &[&str]) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/svraster_checkpoint.py");
    let o = Command::new(py)
        .arg(script)
        .arg(model)
        .arg(out)
        .args(extra)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "svraster_checkpoint.py: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    print!("{}", String::from_utf8_lossy(&o.stdout));
}

fn f32s(path: &Path) -> Vec<f32> {
    std::fs::read(path)
        .unwrap()
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect()
}

/// The imported scene holds `corners` (N×8), `sh0` (N×3) and the first `keep` SH rows of
/// `shs` (N×rows×3) of the dumped scene, voxel for voxel.
fn assert_same(got: &Scene, want: &Scene, corners: &[f32], sh0: &[f32], shs: &[f32], keep: usize) {
    assert_eq!(got.octpath, want.octpath);
    assert_eq!(got.octlevel, want.octlevel);
    assert_eq!((got.center, got.extent), (want.center, want.extent));
    let n = want.num_voxels();
    let rows = shs.len() / (3 * n);
    for v in 0..n {
        for c in 0..8 {
            let g = got.geo[got.corners[v][c] as usize];
            assert_eq!(g, corners[8 * v + c], "voxel {v} corner {c}");
        }
        assert_eq!(
            got.sh0[v],
            [sh0[3 * v], sh0[3 * v + 1], sh0[3 * v + 2]],
            "voxel {v} sh0"
        );
        assert_eq!(
            got.shs[v * keep * 3..][..keep * 3],
            shs[v * rows * 3..][..keep * 3],
            "voxel {v} shs"
        );
    }
}

#[test]
fn svraster_checkpoints_import_exactly() {
    let Some(py) = python() else {
        println!("SKIPPED: python3 not found (the test writes SVRaster checkpoints with it)");
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let mut rng = Rng(91);
    let scene = random_scene(&mut rng, 5, 3);
    let n = scene.num_voxels();
    let corners: Vec<f32> = scene
        .corners
        .iter()
        .flat_map(|c| c.map(|g| scene.geo[g as usize]))
        .collect();
    let sh0: Vec<f32> = scene.sh0.iter().flatten().copied().collect();
    let opts = SvrasterImport {
        background: [1.0; 3],
        background_frame_mean: false,
        supersample: 1.5,
    };
    // Plain, all degrees active.
    let model = dump(&scene, &dir.path().join("d3"));
    let pt = dir.path().join("iter000300_model.pt");
    write_checkpoint(py, &model, &pt, &[]);
    assert!(is_torch_checkpoint(&pt) && !is_torch_checkpoint(&model));
    let got = import_svraster(&pt, &opts).unwrap();
    assert_eq!(
        (got.sh_degree, got.background, got.supersample),
        (3, [1.0; 3], 1.5)
    );
    assert_eq!(got.num_grid_points(), scene.num_grid_points());
    assert_same(&got, &scene, &corners, &sh0, &scene.shs, 15);
    println!("plain: {n} voxels, {} grid points", got.num_grid_points());
    // Active degree 1 of 3 stored: the higher rows are dropped.
    let pt1 = dir.path().join("deg1.pt");
    write_checkpoint(py, &model, &pt1, &["--active", "1"]);
    let got = import_svraster(&pt1, &opts).unwrap();
    assert_eq!((got.sh_degree, got.shs.len()), (1, n * 3 * 3));
    assert_same(&got, &scene, &corners, &sh0, &scene.shs, 3);
    // Quantized: SVRaster's dequantization of the stored codes, on a scene with more
    // distinct values than a codebook holds (so the codes lose something).
    let scene = (0..)
        .map(|_| random_scene(&mut rng, 8, 3))
        .find(|s| s.num_grid_points() > 600)
        .unwrap();
    let corners: Vec<f32> = scene
        .corners
        .iter()
        .flat_map(|c| c.map(|g| scene.geo[g as usize]))
        .collect();
    let model = dump(&scene, &dir.path().join("dq"));
    let q = dir.path().join("q");
    std::fs::create_dir_all(&q).unwrap();
    let ptq = q.join("quant.pt");
    write_checkpoint(py, &model, &ptq, &["--quantize"]);
    let got = import_svraster(&ptq, &opts).unwrap();
    let (ec, es, eh) = (
        f32s(&q.join("EXPECTED_corners.f32")),
        f32s(&q.join("EXPECTED_sh0.f32")),
        f32s(&q.join("EXPECTED_shs.f32")),
    );
    assert_same(&got, &scene, &ec, &es, &eh, 15);
    let err = ec
        .iter()
        .zip(&corners)
        .map(|(a, b)| (a - b).abs())
        .fold(0f32, f32::max);
    println!("quantized: corner values moved by up to {err:.3} (256-entry codebooks)");
    assert!(
        err > 0.0,
        "the quantized fixture must differ from the original"
    );
}

#[test]
fn broken_svraster_checkpoints_are_refused_naming_the_entry() {
    let Some(py) = python() else {
        println!("SKIPPED: python3 not found (the test writes SVRaster checkpoints with it)");
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let scene = random_scene(&mut Rng(5), 3, 1);
    let model = dump(&scene, &dir.path().join("d"));
    let opts = SvrasterImport::default();
    let pt = dir.path().join("good.pt");
    write_checkpoint(py, &model, &pt, &[]);
    let bytes = std::fs::read(&pt).unwrap();
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        (
            "truncated.pt",
            bytes[..bytes.len() / 2].to_vec(),
            "not a readable PyTorch checkpoint",
        ),
        ("empty.pt", vec![], "not a readable PyTorch checkpoint"),
    ];
    for (name, data, want) in cases {
        let p = dir.path().join(name);
        std::fs::write(&p, data).unwrap();
        let e = import_svraster(&p, &opts).unwrap_err().to_string();
        assert!(e.contains(want) && e.contains(name), "{name}: {e}");
    }
    // Entries missing or wrong: the script's --drop / --set.
    for (extra, want) in [
        (["--drop", "_sh0"], "no tensor `_sh0`"),
        (["--drop", "active_sh_degree"], "no `active_sh_degree`"),
        (["--drop", "_geo_grid_pts"], "no tensor `_geo_grid_pts`"),
        (
            ["--set", "active_sh_degree=7"],
            "`active_sh_degree` is Int(7)",
        ),
        (["--set", "scene_extent=nan"], "`scene_extent` holds NaN"),
        (["--set", "octlevel=17"], "`octlevel`[0] is 17"),
        (["--set", "geo_extra=1"], "`_geo_grid_pts` has shape"),
    ] {
        let p = dir.path().join("bad.pt");
        write_checkpoint(py, &model, &p, &extra);
        let e = import_svraster(&p, &opts).unwrap_err().to_string();
        assert!(e.contains(want) && e.contains("bad.pt"), "{extra:?}: {e}");
    }
}
