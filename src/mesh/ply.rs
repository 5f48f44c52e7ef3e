//! Binary little-endian PLY output of a triangle mesh: `vertex` (float x, y, z, nx, ny,
//! nz, optional uchar red, green, blue) and `face` (uchar count, int indices), the form
//! MeshLab, Blender, Open3D, trimesh and plyfile read. Written atomically. Hand-written
//! for the same reason as [`crate::data::ply`]: the PLY crates are unmaintained, and
//! the format is a short header and packed records.

use std::path::Path;

use crate::error::{Error, Result};

/// A mesh ready to write (world coordinates).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PlyMesh {
    pub positions: Vec<[f64; 3]>,
    pub normals: Vec<[f64; 3]>,
    /// Empty, or one colour per vertex.
    pub colors: Vec<[u8; 3]>,
    pub triangles: Vec<[u32; 3]>,
}

/// The bytes of `m` as a binary little-endian PLY file.
pub fn encode(m: &PlyMesh) -> Result<Vec<u8>> {
    let n = m.positions.len();
    if m.normals.len() != n || !(m.colors.is_empty() || m.colors.len() == n) {
        return Err(Error::Invalid(format!(
            "PLY: {n} vertices, {} normals, {} colours",
            m.normals.len(),
            m.colors.len()
        )));
    }
    if let Some(t) = m
        .triangles
        .iter()
        .find(|t| t.iter().any(|&i| i as usize >= n))
    {
        return Err(Error::Invalid(format!(
            "PLY: triangle {t:?} indexes past the {n} vertices"
        )));
    }
    if n > i32::MAX as usize {
        return Err(Error::Invalid(format!(
            "PLY: {n} vertices exceed the int indices"
        )));
    }
    let mut header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment svraster-vk mesh\nelement vertex {n}\n\
         property float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\n"
    );
    if !m.colors.is_empty() {
        header.push_str("property uchar red\nproperty uchar green\nproperty uchar blue\n");
    }
    header.push_str(&format!(
        "element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        m.triangles.len()
    ));
    let vsize = 24 + if m.colors.is_empty() { 0 } else { 3 };
    let mut out = Vec::with_capacity(header.len() + n * vsize + m.triangles.len() * 13);
    out.extend_from_slice(header.as_bytes());
    for i in 0..n {
        for x in m.positions[i].iter().chain(&m.normals[i]) {
            out.extend_from_slice(&(*x as f32).to_le_bytes());
        }
        if let Some(c) = m.colors.get(i) {
            out.extend_from_slice(c);
        }
    }
    for t in &m.triangles {
        out.push(3);
        for &i in t {
            out.extend_from_slice(&(i as i32).to_le_bytes());
        }
    }
    Ok(out)
}

/// Writes `m` to `path` atomically (a failure leaves no partial file).
pub fn write(path: &Path, m: &PlyMesh) -> Result<()> {
    crate::fsio::write_atomic(path, &encode(m)?)
}

/// Vertex positions and triangles.
pub type PositionsAndTriangles = (Vec<[f64; 3]>, Vec<[u32; 3]>);

/// Reads a triangle mesh, binary little-endian (the form [`write()`] and most mesh tools
/// write) or ASCII: the `x, y, z` of each vertex (any scalar types; other properties
/// skipped) and the faces (`list` of any integer count and index types; polygons fanned
/// into triangles).
pub fn read(path: &Path) -> Result<PositionsAndTriangles> {
    let bytes = std::fs::read(path).map_err(|error| Error::Io {
        path: path.display().to_string(),
        error,
    })?;
    let bad = |m: String| Error::Invalid(format!("{}: {m}", path.display()));
    let (header, body) = crate::data::ply::split_header(&bytes, path)?;
    let lines = header.lines().map(str::trim).skip(1);
    // (name, count, properties: (name, type, list count type))
    type Prop = (String, String, Option<String>);
    let mut elements: Vec<(String, usize, Vec<Prop>)> = Vec::new();
    let mut ascii = false;
    for l in lines {
        let w: Vec<&str> = l.split_whitespace().collect();
        match w.as_slice() {
            ["format", f, ..] if *f == "ascii" => ascii = true,
            ["format", f, ..] if *f != "binary_little_endian" => {
                return Err(bad(format!(
                    "format `{f}`: binary_little_endian and ascii meshes are read (convert \
                     with MeshLab, trimesh or Open3D)"
                )))
            }
            ["element", name, n] => elements.push((
                name.to_string(),
                n.parse()
                    .map_err(|_| bad(format!("bad element count `{n}`")))?,
                Vec::new(),
            )),
            ["property", "list", ct, it, name] => elements
                .last_mut()
                .ok_or_else(|| bad("property before any element".into()))?
                .2
                .push((name.to_string(), it.to_string(), Some(ct.to_string()))),
            ["property", t, name] => elements
                .last_mut()
                .ok_or_else(|| bad("property before any element".into()))?
                .2
                .push((name.to_string(), t.to_string(), None)),
            _ => {}
        }
    }
    let size = |t: &str| -> Result<usize> {
        crate::data::ply::type_size(t).ok_or_else(|| bad(format!("unknown property type `{t}`")))
    };
    let short = || bad("the file ends inside its data (truncated?)".into());
    // The next value of PLY type `t`: its bytes (binary), or the next token (ASCII).
    let mut tokens = if ascii {
        Some(
            std::str::from_utf8(body)
                .map_err(|_| bad("the ASCII data is not text".into()))?
                .split_ascii_whitespace(),
        )
    } else {
        None
    };
    let mut pos = 0;
    let mut next = |t: &str| -> Result<f64> {
        let s = size(t)?;
        if let Some(tok) = tokens.as_mut() {
            let w = tok.next().ok_or_else(short)?;
            return w
                .parse::<f64>()
                .map_err(|_| bad(format!("`{w}` is not a number")));
        }
        let v = crate::data::ply::le_value(t, body.get(pos..pos + s).ok_or_else(short)?);
        pos += s;
        Ok(v)
    };
    let (mut xyz, mut tris) = (Vec::new(), Vec::new());
    for (name, count, props) in &elements {
        if name == "vertex" {
            for axis in ["x", "y", "z"] {
                if !props.iter().any(|p| p.0 == axis && p.2.is_none()) {
                    return Err(bad(format!("the vertex element has no `{axis}` property")));
                }
            }
        }
        if props.is_empty() {
            // Holds no data: nothing to read (a huge count would loop for nothing).
            continue;
        }
        for _ in 0..*count {
            let mut p = [0.0f64; 3];
            for (pname, t, list) in props {
                if let Some(ct) = list {
                    // Counts and indices come from the file: whole numbers in range, or
                    // an error (an ASCII count of 1e308 sized an allocation; -1 read
                    // as vertex 0). The list grows as its entries are read, so a count
                    // past the data ends as "truncated".
                    let c = next(ct)?;
                    if !(c >= 0.0 && c.fract() == 0.0 && c < f64::from(u32::MAX)) {
                        return Err(bad(format!("{name}: list length `{c}` is not a count")));
                    }
                    let mut idx = Vec::new();
                    for _ in 0..c as usize {
                        let i = next(t)?;
                        if !(i >= 0.0 && i.fract() == 0.0 && i <= f64::from(u32::MAX)) {
                            return Err(bad(format!("{name}: `{i}` is not a vertex index")));
                        }
                        idx.push(i as u32);
                    }
                    let n = idx.len();
                    if name == "face" {
                        for k in 1..n.saturating_sub(1) {
                            tris.push([idx[0], idx[k], idx[k + 1]]);
                        }
                    }
                } else {
                    let v = next(t)?;
                    if name == "vertex" {
                        match pname.as_str() {
                            "x" => p[0] = v,
                            "y" => p[1] = v,
                            "z" => p[2] = v,
                            _ => {}
                        }
                    }
                }
            }
            if name == "vertex" {
                xyz.push(p);
            }
        }
    }
    if let Some(t) = tris
        .iter()
        .find(|t| t.iter().any(|&i| i as usize >= xyz.len()))
    {
        return Err(bad(format!(
            "face {t:?} indexes past the {} vertices",
            xyz.len()
        )));
    }
    Ok((xyz, tris))
}
