//! `svraster fuse` and `svraster render --field` end to end: labels and a 16-channel
//! feature field fused from files and rendered with their outputs, and the sources
//! `fuse` refuses with one clear error.

use super::{svraster, tmp};
use std::path::Path;

/// The voxelized demo (level 6, 32² views) with its label images: (run, data, labels).
fn labelled_demo(dir: &Path) -> (String, String, std::path::PathBuf) {
    let (ok, _, err) = svraster(&[
        "demo",
        "--out",
        dir.to_str().unwrap(),
        "--size",
        "32",
        "--voxelize",
        "--level",
        "6",
        "--labels",
    ]);
    assert!(ok, "demo failed: {err}");
    (
        dir.join("run").to_str().unwrap().to_string(),
        dir.join("data").to_str().unwrap().to_string(),
        dir.join("labels"),
    )
}

/// 16-channel features of a label image at half its size: channel c of a pixel is
/// 1 where its label is the c-th class value 40·c (c = 0: background), plus a ramp.
fn write_features(labels: &Path, out: &Path) {
    std::fs::create_dir_all(out).unwrap();
    for e in std::fs::read_dir(labels).unwrap() {
        let p = e.unwrap().path();
        let (w, h, l) = svraster::data::pixels::load_labels(&p).unwrap();
        let (hw, hh) = (w / 2, h / 2);
        let mut v = Vec::with_capacity((hw * hh * 16) as usize);
        for y in 0..hh {
            for x in 0..hw {
                let lab = l[(2 * y * w + 2 * x) as usize];
                for c in 0..16u32 {
                    let hot = f32::from(u8::from(u32::from(lab) == 40 * c));
                    v.push(hot + 0.01 * c as f32 * x as f32 / hw as f32);
                }
            }
        }
        let stem = p.file_stem().unwrap().to_str().unwrap().to_string();
        svraster::data::pixels::save_npy(
            &out.join(format!("{stem}.npy")),
            &[u64::from(hh), u64::from(hw), 16],
            &v,
        )
        .unwrap();
    }
}

#[test]
fn fuse_and_render_label_and_feature_fields() {
    let dir = tmp("fuse");
    let (run, data, labels) = labelled_demo(dir.path());
    let field = dir.path().join("labels.safetensors");
    let (ok, out, err) = svraster(&[
        "fuse",
        &run,
        "--data",
        &data,
        "--from",
        labels.join("train").to_str().unwrap(),
        "--out",
        field.to_str().unwrap(),
        "--json",
    ]);
    assert!(ok, "fuse failed: {err}");
    let summary: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(summary["kind"], "labels");
    assert_eq!(summary["classes"].as_array().unwrap().len(), 7, "{summary}");
    let renders = dir.path().join("fr");
    let (ok, out, err) = svraster(&[
        "render",
        &run,
        "--data",
        &data,
        "--field",
        field.to_str().unwrap(),
        "--split",
        "test",
        "--out",
        renders.to_str().unwrap(),
        "--truth",
        labels.join("test").to_str().unwrap(),
    ]);
    assert!(ok, "render --field failed: {err}");
    assert!(out.contains("IoU against the truth"), "{out}");
    let scores: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(renders.join("field_scores.json")).unwrap())
            .unwrap();
    let mean = scores["mean_iou_over_classes"].as_f64().unwrap();
    assert!(mean > 0.75, "mean IoU {mean} at 32² on a level-6 model");
    let (w, h, l) = svraster::data::pixels::load_labels(&renders.join("r_0_field.png")).unwrap();
    assert_eq!((w, h), (32, 32));
    assert!(l.iter().all(|v| v % 40 == 0), "labels are class values");
    let (w, h, c, _) =
        svraster::data::pixels::load_features(&renders.join("r_0_field.npy")).unwrap();
    assert_eq!((w, h, c), (32, 32, 7));

    // 16 features per pixel at half the views' size.
    let feats = dir.path().join("feats");
    write_features(&labels.join("train"), &feats);
    let ffield = dir.path().join("feats.safetensors");
    let (ok, _, err) = svraster(&[
        "fuse",
        &run,
        "--data",
        &data,
        "--from",
        feats.to_str().unwrap(),
        "--out",
        ffield.to_str().unwrap(),
    ]);
    assert!(ok, "fuse of features failed: {err}");
    let fr = dir.path().join("ffr");
    let (ok, _, err) = svraster(&[
        "render",
        &run,
        "--data",
        &data,
        "--field",
        ffield.to_str().unwrap(),
        "--split",
        "test",
        "--out",
        fr.to_str().unwrap(),
    ]);
    assert!(ok, "render of features failed: {err}");
    let pca: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(fr.join("field_pca.json")).unwrap()).unwrap();
    assert_eq!(pca["components"].as_array().unwrap().len(), 3);
    let (w, h, c, _) = svraster::data::pixels::load_features(&fr.join("r_0_field.npy")).unwrap();
    assert_eq!((w, h, c), (32, 32, 16));
    assert!(fr.join("r_0_field.png").is_file());
}

#[test]
fn fuse_refuses_sources_it_cannot_use() {
    let dir = tmp("fuse-bad");
    let (run, data, labels) = labelled_demo(dir.path());
    let fuse = |from: &Path, out: &str| {
        let o = dir.path().join(out);
        let r = svraster(&[
            "fuse",
            &run,
            "--data",
            &data,
            "--from",
            from.to_str().unwrap(),
            "--out",
            o.to_str().unwrap(),
        ]);
        if !r.0 {
            assert!(!o.exists(), "{out} written by a refused fuse");
        }
        r
    };
    // A frame without its file.
    let few = dir.path().join("few");
    std::fs::create_dir_all(&few).unwrap();
    for e in std::fs::read_dir(labels.join("train")).unwrap() {
        let p = e.unwrap().path();
        if p.file_name().unwrap() != "r_3.png" {
            std::fs::copy(&p, few.join(p.file_name().unwrap())).unwrap();
        }
    }
    let (ok, _, err) = fuse(&few, "a.safetensors");
    assert!(
        !ok && err.contains("no STEM.png or STEM.npy for 1 of the split's") && err.contains("r_3"),
        "{err}"
    );
    // A feature map of another aspect ratio.
    let feats = dir.path().join("feats");
    write_features(&labels.join("train"), &feats);
    svraster::data::pixels::save_npy(
        &feats.join("r_5.npy"),
        &[4, 16, 16],
        &vec![0.0; 4 * 16 * 16],
    )
    .unwrap();
    let (ok, _, err) = fuse(&feats, "b.safetensors");
    assert!(
        !ok && err.contains("r_5.npy is 16×4") && err.contains("aspect ratio"),
        "{err}"
    );
    // NaN in a feature map.
    let mut v = vec![0.5f32; 16 * 16 * 16];
    v[16 * 17 + 2] = f32::NAN;
    svraster::data::pixels::save_npy(&feats.join("r_5.npy"), &[16, 16, 16], &v).unwrap();
    let (ok, _, err) = fuse(&feats, "c.safetensors");
    assert!(
        !ok && err.contains("r_5.npy") && err.contains("row 1, column 1, channel 2 is NaN"),
        "{err}"
    );
    // Other channels in one frame.
    svraster::data::pixels::save_npy(
        &feats.join("r_5.npy"),
        &[16, 16, 3],
        &vec![0.0; 16 * 16 * 3],
    )
    .unwrap();
    let (ok, _, err) = fuse(&feats, "d.safetensors");
    assert!(!ok && err.contains("r_5.npy has 3 channels"), "{err}");
    // Labels and features mixed.
    std::fs::copy(labels.join("train/r_0.png"), feats.join("r_0.png")).unwrap();
    std::fs::remove_file(feats.join("r_0.npy")).unwrap();
    let (ok, _, err) = fuse(&feats, "e.safetensors");
    assert!(!ok && err.contains("mixes label images"), "{err}");
    // A field of another model.
    let field = dir.path().join("f.safetensors");
    let (ok, _, err) = fuse(&labels.join("train"), "f.safetensors");
    assert!(ok && field.is_file(), "{err}");
    let other = dir.path().join("other");
    let (ok, _, err) = svraster(&[
        "demo",
        "--out",
        other.to_str().unwrap(),
        "--size",
        "16",
        "--voxelize",
        "--level",
        "5",
    ]);
    assert!(ok, "{err}");
    let (ok, _, err) = svraster(&[
        "render",
        other.join("run").to_str().unwrap(),
        "--data",
        &data,
        "--field",
        field.to_str().unwrap(),
        "--out",
        dir.path().join("x").to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("another model"), "{err}");
}

/// `--by-order` pairs files with views by natural name order (DTU's masks are named
/// unlike its images) and gives the field of pairing by name; `--mask` reads soft,
/// unequal-channel masks as {0, 255}; a truth of another size is scored after an area
/// resample.
#[test]
fn fuse_pairs_by_order_and_scores_masks_of_any_size() {
    let dir = tmp("fuse-order");
    let (run, data, labels) = labelled_demo(dir.path());
    // Masks (label > 0) as RGB with unequal channels, renamed m_0.png … (natural order), and the test
    // split's at twice the size.
    let masks = |split: &str, scale: u32| -> std::path::PathBuf {
        let out = dir.path().join(format!("masks-{split}"));
        std::fs::create_dir_all(&out).unwrap();
        for e in std::fs::read_dir(labels.join(split)).unwrap() {
            let p = e.unwrap().path();
            let stem = p.file_stem().unwrap().to_str().unwrap().to_string();
            let i: usize = stem.trim_start_matches("r_").parse().unwrap();
            let (w, h, l) = svraster::data::pixels::load_labels(&p).unwrap();
            let (ow, oh) = (w * scale, h * scale);
            let rgb: Vec<[f32; 3]> = (0..oh * ow)
                .map(|q| {
                    let v = l[((q / ow / scale) * w + (q % ow) / scale) as usize];
                    let f = if v > 0 { 0.98 } else { 0.02 };
                    [f, f - 0.01, f + 0.01]
                })
                .collect();
            svraster::data::image::save_rgb_png(&out.join(format!("m_{i}.png")), ow, oh, &rgb)
                .unwrap();
        }
        out
    };
    let (train, test) = (masks("train", 1), masks("test", 2));
    let fuse = |from: &Path, extra: &[&str], out: &str| {
        let o = dir.path().join(out);
        let mut args = vec![
            "fuse",
            &run,
            "--data",
            &data,
            "--from",
            from.to_str().unwrap(),
            "--out",
            o.to_str().unwrap(),
            "--mask",
        ];
        args.extend_from_slice(extra);
        let (ok, _, err) = svraster(&args);
        (ok, err, o)
    };
    let (ok, err, _) = fuse(&train, &[], "a.safetensors");
    assert!(!ok && err.contains("--by-order"), "{err}");
    let (ok, err, by_order) = fuse(&train, &["--by-order"], "b.safetensors");
    assert!(ok, "{err}");
    // The same masks named after the frames.
    let named = dir.path().join("named");
    std::fs::create_dir_all(&named).unwrap();
    for i in 0..60 {
        std::fs::copy(
            train.join(format!("m_{i}.png")),
            named.join(format!("r_{i}.png")),
        )
        .unwrap();
    }
    let (ok, err, by_name) = fuse(&named, &[], "c.safetensors");
    assert!(ok, "{err}");
    let (fa, fb) = (
        svraster::field::Field::load(&by_order).unwrap(),
        svraster::field::Field::load(&by_name).unwrap(),
    );
    assert_eq!(fa.kind, svraster::field::FieldKind::Labels(vec![0, 255]));
    assert!(
        fa.values == fb.values,
        "pairing by order gave another field than by name"
    );
    let out = dir.path().join("r");
    let (ok, stdout, err) = svraster(&[
        "render",
        &run,
        "--data",
        &data,
        "--field",
        by_order.to_str().unwrap(),
        "--split",
        "test",
        "--out",
        out.to_str().unwrap(),
        "--truth",
        test.to_str().unwrap(),
        "--mask",
        "--by-order",
    ]);
    assert!(ok, "{err}");
    let scores: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("field_scores.json")).unwrap())
            .unwrap();
    let fg = scores["classes"][1]["iou_mean_over_views"]
        .as_f64()
        .unwrap();
    assert!(fg > 0.9, "foreground IoU {fg}: {stdout}");
}
