//! The host-engine demo (examples/viewer.rs on src/viewer/) under a virtual X server: it opens a
//! window, draws its own grid and cube, embeds the field through `raster::host` and
//! writes a screenshot, with the validation layer on. Three screenshots of the same
//! view — composite, field only (`--no-mesh`), mesh only (`--no-field`) — show the
//! compositing: where the cube is drawn, some pixels keep the cube although the field
//! alone covers them (the cube occludes voxels behind it) and some show the field
//! instead of the cube (voxels in front of it cover it); elsewhere the composite is
//! the field over the host's clear colour.
//!
//! Needs `xvfb-run` (tools/setup.sh installs it); skipped with a printed reason without.

use std::path::{Path, PathBuf};
use std::process::Command;

/// Directory of the build profile the test runs from (`target/<profile>`).
fn profile_dir() -> PathBuf {
    let exe = std::env::current_exe().unwrap();
    exe.parent().unwrap().parent().unwrap().to_path_buf()
}

/// Builds an example in this test's profile (`cargo test --test viewer` alone does not
/// build examples; a no-op when it is up to date) and returns its path.
///
/// With the whole workspace selected, as `cargo test` at the root builds it: the
/// dependencies' features are then unified as in that build, which has built the
/// examples already, so this is a no-op there. Selecting the library package alone
/// (`--features viewer` without `--workspace`) resolves other features for shared
/// dependencies, recompiled 34 crates (~110 s on 2 cores, inside the suite) and made
/// the next `cargo test` recompile them back.
///
/// Test binaries run without cargo (the GPU kit's machine) take the example from
/// `target/<profile>/examples/` when `SVRASTER_PREBUILT_EXAMPLES` is set
/// (tools/gpu_prepare.sh packs it); without either, `None`: the test is skipped and
/// says why.
fn example(name: &str) -> Option<PathBuf> {
    let dir = profile_dir();
    let path = dir.join("examples").join(name);
    if std::env::var_os("SVRASTER_PREBUILT_EXAMPLES").is_some() {
        assert!(
            path.is_file(),
            "SVRASTER_PREBUILT_EXAMPLES is set but {} is missing",
            path.display()
        );
        return Some(path);
    }
    let mut cmd = Command::new(env!("CARGO"));
    cmd.args([
        "build",
        "--workspace",
        "--features",
        "svraster-vk/viewer",
        "--example",
        name,
    ])
    .current_dir(env!("CARGO_MANIFEST_DIR"));
    if dir.file_name().is_some_and(|n| n == "release") {
        cmd.arg("--release");
    }
    let status = match cmd.status() {
        Ok(s) => s,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            println!(
                "SKIPPED: cargo ({}) not found to build example {name} ({e}); with the \
                 example prebuilt at {}, set SVRASTER_PREBUILT_EXAMPLES=1",
                env!("CARGO"),
                path.display()
            );
            return None;
        }
        Err(e) => panic!("run cargo: {e}"),
    };
    assert!(status.success(), "cargo build --example {name} failed");
    Some(path)
}

fn screenshot(viewer: &Path, model: &Path, out: &Path, extra: &[&str]) -> image::RgbaImage {
    let o = Command::new("xvfb-run")
        .args(["-a", "-s", "-screen 0 640x480x24"])
        .arg(viewer)
        .arg(model)
        .args([
            "--width",
            "192",
            "--height",
            "144",
            "--frames",
            "3",
            "--validation",
        ])
        .arg("--screenshot")
        .arg(out)
        .args(extra)
        .output()
        .expect("run xvfb-run");
    let log = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    println!("viewer {extra:?}: {log}");
    assert!(o.status.success(), "viewer {extra:?} failed: {log}");
    assert!(!log.contains("[validation]"), "validation messages: {log}");
    image::open(out).expect("screenshot PNG").to_rgba8()
}

fn close(a: &image::Rgba<u8>, b: &image::Rgba<u8>, tol: i32) -> bool {
    (0..3).all(|c| (a[c] as i32 - b[c] as i32).abs() <= tol)
}

#[test]
fn viewer_composites_the_field_with_its_own_mesh() {
    if Command::new("xvfb-run").arg("--help").output().is_err() {
        println!("SKIPPED: xvfb-run not found (tools/setup.sh installs xvfb)");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let scene = svraster::data::demo::voxelize(5, 1).unwrap();
    let model = dir.path().join("model.safetensors");
    svraster::scene::checkpoint::save(&scene, &model).unwrap();
    let Some(viewer) = example("viewer") else {
        return;
    };
    let both = screenshot(&viewer, &model, &dir.path().join("both.png"), &[]);
    let field = screenshot(
        &viewer,
        &model,
        &dir.path().join("field.png"),
        &["--no-mesh"],
    );
    let mesh = screenshot(
        &viewer,
        &model,
        &dir.path().join("mesh.png"),
        &["--no-field"],
    );
    // The host's clear colour (examples/viewer.rs CLEAR, 8-bit).
    let clear = *mesh.get_pixel(0, 0);
    let (mut occluded, mut covering, mut elsewhere) = (0, 0, 0);
    for (x, y, m) in mesh.enumerate_pixels() {
        let (b, f) = (both.get_pixel(x, y), field.get_pixel(x, y));
        let field_there = !close(f, &clear, 12);
        if !close(m, &clear, 2) {
            // The host drew its mesh here.
            if close(b, m, 2) && field_there && !close(f, m, 24) {
                occluded += 1;
            } else if close(b, f, 3) && !close(b, m, 24) {
                covering += 1;
            }
        } else {
            assert!(
                close(b, f, 3),
                "({x}, {y}): no mesh here, but the composite {b:?} is not the field {f:?}"
            );
            elsewhere += 1;
        }
    }
    println!(
        "mesh pixels occluding the field: {occluded}; field pixels covering the mesh: \
         {covering}; pixels without mesh: {elsewhere}"
    );
    assert!(
        occluded >= 100,
        "the mesh occludes the field on only {occluded} pixels"
    );
    assert!(
        covering >= 30,
        "the field covers the mesh on only {covering} pixels"
    );
}

/// README's embedding snippet (examples/embed.rs) runs: a 640×480 PNG with the field
/// over transparency.
#[test]
fn embed_example_writes_the_field_over_transparency() {
    let dir = tempfile::tempdir().unwrap();
    let scene = svraster::data::demo::voxelize(5, 1).unwrap();
    let model = dir.path().join("model.safetensors");
    svraster::scene::checkpoint::save(&scene, &model).unwrap();
    let out = dir.path().join("embed.png");
    let Some(embed) = example("embed") else {
        return;
    };
    let o = Command::new(embed)
        .arg(&model)
        .arg(&out)
        .env("SVRASTER_VALIDATION", "1")
        .output()
        .expect("run embed");
    let log = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(o.status.success(), "embed failed: {log}");
    let img = image::open(&out).expect("PNG").to_rgba8();
    assert_eq!(img.dimensions(), (640, 480));
    let opaque = img.pixels().filter(|p| p[3] == 255).count();
    let clear = img.pixels().filter(|p| p[3] == 0).count();
    println!("embed: {opaque} opaque and {clear} transparent pixels; {log}");
    assert!(opaque > 1000 && clear > 1000, "{opaque} {clear}");
}
