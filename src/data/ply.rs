//! Point positions from a PLY file (nerfstudio's `sparse_pc.ply`, COLMAP's exports):
//! the `x, y, z` of the `vertex` element, in ASCII or binary (either endianness), any
//! scalar property types. Hand-written because we read three properties of one element
//! (the PLY crates on crates.io are unmaintained since 2020); the vertex element must
//! come first, as every point-cloud writer puts it.

use std::path::Path;

use crate::error::{Error, Result};

/// Byte size of a PLY scalar type.
pub(crate) fn type_size(t: &str) -> Option<usize> {
    Some(match t {
        "char" | "uchar" | "int8" | "uint8" => 1,
        "short" | "ushort" | "int16" | "uint16" => 2,
        "int" | "uint" | "int32" | "uint32" | "float" | "float32" => 4,
        "double" | "float64" => 8,
        _ => return None,
    })
}

/// The header of a PLY file's `bytes` (read from `path`, for messages) and its body:
/// errors when there is no `end_header` line or the file does not start with `ply`.
pub(crate) fn split_header<'a>(bytes: &'a [u8], path: &Path) -> Result<(&'a str, &'a [u8])> {
    let bad = |m: &str| Error::Invalid(format!("{}: {m}", path.display()));
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .ok_or_else(|| bad("no `end_header` line: not a PLY file"))?;
    let header = std::str::from_utf8(&bytes[..end]).map_err(|_| bad("the header is not text"))?;
    if header.lines().next().map(str::trim) != Some("ply") {
        return Err(bad("does not start with `ply`"));
    }
    Ok((header, &bytes[end + 11..]))
}

/// A little-endian scalar of PLY type `t` (its [`type_size`] bytes of `b`) as f64.
pub(crate) fn le_value(t: &str, b: &[u8]) -> f64 {
    match t {
        "char" | "int8" => b[0] as i8 as f64,
        "uchar" | "uint8" => b[0] as f64,
        "short" | "int16" => i16::from_le_bytes([b[0], b[1]]) as f64,
        "ushort" | "uint16" => u16::from_le_bytes([b[0], b[1]]) as f64,
        "int" | "int32" => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
        "uint" | "uint32" => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
        "float" | "float32" => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
        _ => f64::from_le_bytes(b[..8].try_into().expect("8 bytes")),
    }
}

/// Reads the vertex positions of the PLY file at `path`.
pub fn read_points(path: &Path) -> Result<Vec<[f64; 3]>> {
    let bytes = std::fs::read(path).map_err(|error| Error::Io {
        path: path.display().to_string(),
        error,
    })?;
    let bad = |m: String| Error::Invalid(format!("{}: {m}", path.display()));
    let (header, body) = split_header(&bytes, path)?;
    let lines = header.lines().map(str::trim).skip(1);
    let mut format = "";
    let mut count = None;
    let mut props: Vec<(String, String)> = Vec::new();
    let mut in_vertex = false;
    for l in lines {
        let w: Vec<&str> = l.split_whitespace().collect();
        match w.as_slice() {
            ["format", f, _] => format = f,
            ["element", name, n] => {
                if count.is_some() {
                    // Elements after the vertices are not read.
                    in_vertex = false;
                    continue;
                }
                if *name != "vertex" {
                    return Err(bad(format!(
                        "element `{name}` comes before `vertex`; only files whose first \
                         element is `vertex` are read"
                    )));
                }
                count = Some(
                    n.parse::<usize>()
                        .map_err(|_| bad(format!("vertex count `{n}` is not a number")))?,
                );
                in_vertex = true;
            }
            ["property", "list", ..] if in_vertex => {
                return Err(bad("list properties in `vertex` are not supported".into()))
            }
            ["property", t, name] if in_vertex => props.push((t.to_string(), name.to_string())),
            _ => {}
        }
    }
    let n = count.ok_or_else(|| bad("no `element vertex`".into()))?;
    let idx = |axis: &str| {
        props
            .iter()
            .position(|p| p.1 == axis)
            .ok_or_else(|| bad(format!("the vertex element has no `{axis}` property")))
    };
    let xyz = [idx("x")?, idx("y")?, idx("z")?];
    // The count comes from the file: the allocation is bounded by what the body can hold
    // (an ASCII vertex takes at least two bytes per property), and a count the body
    // cannot hold is the truncation error below, never an allocation of its size.
    let fits = body.len() / (2 * props.len()).max(1) + 1;
    let mut points = Vec::with_capacity(n.min(fits));
    if format == "ascii" {
        let text = std::str::from_utf8(body).map_err(|_| bad("ASCII body is not text".into()))?;
        for (k, line) in text.lines().take(n).enumerate() {
            let v: Vec<&str> = line.split_whitespace().collect();
            let get = |i: usize| -> Result<f64> {
                v.get(i)
                    .and_then(|s| s.parse::<f64>().ok())
                    .ok_or_else(|| bad(format!("vertex {k}: property {i} missing or not a number")))
            };
            points.push([get(xyz[0])?, get(xyz[1])?, get(xyz[2])?]);
        }
    } else {
        let little = match format {
            "binary_little_endian" => true,
            "binary_big_endian" => false,
            f => return Err(bad(format!("unknown format `{f}`"))),
        };
        let sizes: Vec<usize> = props
            .iter()
            .map(|(t, _)| type_size(t).ok_or_else(|| bad(format!("unknown property type `{t}`"))))
            .collect::<Result<_>>()?;
        let stride: usize = sizes.iter().sum();
        let offset = |i: usize| sizes[..i].iter().sum::<usize>();
        match n.checked_mul(stride) {
            Some(need) if need <= body.len() => {}
            need => {
                return Err(bad(format!(
                    "truncated: {n} vertices of {stride} bytes need {} bytes, the body has {}",
                    need.map_or("more than 2^64".into(), |b| b.to_string()),
                    body.len()
                )))
            }
        }
        let read = |rec: &[u8], i: usize| -> f64 {
            let b = &rec[offset(i)..offset(i) + sizes[i]];
            let arr = |k: usize| -> [u8; 8] {
                let mut a = [0u8; 8];
                if little {
                    a[..k].copy_from_slice(&b[..k]);
                } else {
                    for (j, x) in b[..k].iter().rev().enumerate() {
                        a[j] = *x;
                    }
                }
                a
            };
            le_value(&props[i].0, &arr(sizes[i]))
        };
        for rec in body.chunks_exact(stride).take(n) {
            points.push([read(rec, xyz[0]), read(rec, xyz[1]), read(rec, xyz[2])]);
        }
    }
    if points.len() != n {
        return Err(bad(format!(
            "truncated: the header announces {n} vertices, the body has {}",
            points.len()
        )));
    }
    if let Some(k) = points.iter().position(|p| p.iter().any(|v| !v.is_finite())) {
        return Err(bad(format!("vertex {k} is not finite")));
    }
    Ok(points)
}
