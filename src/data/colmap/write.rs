//! Writing COLMAP models (test fixtures, conversions), in the formats [`super`] reads.

use std::fmt::Write as _;
use std::path::Path;

use super::Reconstruction;
use crate::error::Result;

/// Writes `rec` as `cameras.bin`, `images.bin` and `points3D.bin` into `dir`.
pub fn write_bin(dir: &Path, rec: &Reconstruction) -> Result<()> {
    let mut b = Vec::new();
    b.extend((rec.cameras.len() as u64).to_le_bytes());
    for c in rec.cameras.values() {
        b.extend(c.id.to_le_bytes());
        b.extend(c.model.id().to_le_bytes());
        b.extend(c.width.to_le_bytes());
        b.extend(c.height.to_le_bytes());
        c.params.iter().for_each(|p| b.extend(p.to_le_bytes()));
    }
    write(&dir.join("cameras.bin"), &b)?;
    let mut b = Vec::new();
    b.extend((rec.images.len() as u64).to_le_bytes());
    for i in rec.images.values() {
        b.extend(i.id.to_le_bytes());
        i.qvec
            .iter()
            .chain(&i.tvec)
            .for_each(|v| b.extend(v.to_le_bytes()));
        b.extend(i.camera_id.to_le_bytes());
        b.extend(i.name.as_bytes());
        b.push(0);
        b.extend((i.points2d.len() as u64).to_le_bytes());
        for (xy, id) in &i.points2d {
            b.extend(xy[0].to_le_bytes());
            b.extend(xy[1].to_le_bytes());
            b.extend(id.to_le_bytes());
        }
    }
    write(&dir.join("images.bin"), &b)?;
    let mut b = Vec::new();
    b.extend((rec.points.len() as u64).to_le_bytes());
    for p in &rec.points {
        b.extend(p.id.to_le_bytes());
        p.xyz.iter().for_each(|v| b.extend(v.to_le_bytes()));
        b.extend(p.rgb);
        b.extend(p.error.to_le_bytes());
        b.extend((p.track.len() as u64).to_le_bytes());
        for (i, k) in &p.track {
            b.extend(i.to_le_bytes());
            b.extend(k.to_le_bytes());
        }
    }
    write(&dir.join("points3D.bin"), &b)
}

/// Writes `rec` as `cameras.txt`, `images.txt` and `points3D.txt` into `dir` (numbers
/// in Rust's shortest round-trip form, so the text model reads back bit-identical).
pub fn write_txt(dir: &Path, rec: &Reconstruction) -> Result<()> {
    let mut s = String::from("# Camera list with one line of data per camera:\n");
    s += "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n";
    for c in rec.cameras.values() {
        let _ = write!(s, "{} {} {} {}", c.id, c.model.name(), c.width, c.height);
        c.params.iter().for_each(|p| {
            let _ = write!(s, " {p:?}");
        });
        s.push('\n');
    }
    write(&dir.join("cameras.txt"), s.as_bytes())?;
    let mut s = String::from("# Image list with two lines of data per image:\n");
    s += "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n";
    s += "#   POINTS2D[] as (X, Y, POINT3D_ID)\n";
    for i in rec.images.values() {
        let _ = write!(s, "{}", i.id);
        i.qvec.iter().chain(&i.tvec).for_each(|v| {
            let _ = write!(s, " {v:?}");
        });
        let _ = writeln!(s, " {} {}", i.camera_id, i.name);
        let pts: Vec<String> = i
            .points2d
            .iter()
            .map(|(xy, id)| format!("{:?} {:?} {id}", xy[0], xy[1]))
            .collect();
        s += &pts.join(" ");
        s.push('\n');
    }
    write(&dir.join("images.txt"), s.as_bytes())?;
    let mut s = String::from("# 3D point list with one line of data per point:\n");
    s += "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n";
    for p in &rec.points {
        let _ = write!(
            s,
            "{} {:?} {:?} {:?} {} {} {} {:?}",
            p.id, p.xyz[0], p.xyz[1], p.xyz[2], p.rgb[0], p.rgb[1], p.rgb[2], p.error
        );
        p.track.iter().for_each(|(i, k)| {
            let _ = write!(s, " {i} {k}");
        });
        s.push('\n');
    }
    write(&dir.join("points3D.txt"), s.as_bytes())
}

fn write(path: &Path, bytes: &[u8]) -> Result<()> {
    crate::fsio::write_atomic(path, bytes)
}
