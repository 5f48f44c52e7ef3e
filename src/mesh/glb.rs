//! Triangle meshes as glTF 2.0 binary (`.glb`): one mesh, one triangle primitive with
//! POSITION, NORMAL, optional COLOR_0 (RGBA8, normalised) and u32 indices, in one
//! buffer — what Blender, three.js and game engines import. Hand-written: the format is
//! a JSON document and a binary chunk, and the maintained glTF crates read rather than
//! write (the tests read our files back with the `gltf` crate).

use std::path::Path;

use super::ply::PlyMesh;
use crate::error::{Error, Result};

const MAGIC: u32 = 0x4654_6C67; // "glTF"
const CHUNK_JSON: u32 = 0x4E4F_534A; // "JSON"
const CHUNK_BIN: u32 = 0x004E_4942; // "BIN\0"
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const UNSIGNED_BYTE: u32 = 5121;
const UNSIGNED_INT: u32 = 5125;

/// The rotation (glTF's `[x, y, z, w]` quaternion) that turns `up` into +Y, glTF's up:
/// the shortest arc (a half turn about X when `up` is −Y); None when `up` is +Y already
/// or not a direction.
pub fn y_up_rotation(up: [f64; 3]) -> Option<[f64; 4]> {
    let u = glam::DVec3::from(up).try_normalize()?;
    let y = glam::DVec3::Y;
    let c = u.dot(y);
    if c > 1.0 - 1e-12 {
        return None;
    }
    if c < -1.0 + 1e-12 {
        return Some([1.0, 0.0, 0.0, 0.0]);
    }
    // q = (u × y, 1 + u·y), normalised: the rotation by the angle between them.
    let a = u.cross(y);
    let q = glam::DVec4::new(a.x, a.y, a.z, 1.0 + c).normalize();
    Some(q.to_array())
}

/// The bytes of `m` as a `.glb` file (positions and normals as f32, colours as RGBA8),
/// positions as they are (world coordinates) under a root node that turns the world's
/// `up` into glTF's +Y ([`y_up_rotation`]), so Y-up viewers (three.js, Blender's importer,
/// game engines) show the scene upright.
pub fn encode(m: &PlyMesh, up: [f64; 3]) -> Result<Vec<u8>> {
    let n = m.positions.len();
    if m.normals.len() != n || !(m.colors.is_empty() || m.colors.len() == n) {
        return Err(Error::Invalid(format!(
            "glb: {n} positions, {} normals, {} colours",
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
            "glb: triangle {t:?} indexes past {n} vertices"
        )));
    }
    let mut bin: Vec<u8> = Vec::new();
    let mut views = Vec::new();
    // Appends a buffer view (4-byte aligned) of `bytes` for `target`.
    let mut view = |bin: &mut Vec<u8>, bytes: &[u8], target: u32| -> usize {
        let offset = bin.len();
        bin.extend_from_slice(bytes);
        while !bin.len().is_multiple_of(4) {
            bin.push(0);
        }
        views.push(serde_json::json!({
            "buffer": 0, "byteOffset": offset, "byteLength": bytes.len(), "target": target,
        }));
        views.len() - 1
    };
    let f32s = |v: &[[f64; 3]]| -> Vec<u8> {
        v.iter()
            .flatten()
            .flat_map(|&x| (x as f32).to_le_bytes())
            .collect()
    };
    let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for p in &m.positions {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a] as f32);
            hi[a] = hi[a].max(p[a] as f32);
        }
    }
    if n == 0 {
        (lo, hi) = ([0.0; 3], [0.0; 3]);
    }
    let pos_view = view(&mut bin, &f32s(&m.positions), ARRAY_BUFFER);
    let nrm_view = view(&mut bin, &f32s(&m.normals), ARRAY_BUFFER);
    let mut accessors = vec![
        serde_json::json!({
            "bufferView": pos_view, "componentType": FLOAT, "count": n, "type": "VEC3",
            "min": lo, "max": hi,
        }),
        serde_json::json!({
            "bufferView": nrm_view, "componentType": FLOAT, "count": n, "type": "VEC3",
        }),
    ];
    let mut attributes = serde_json::json!({ "POSITION": 0, "NORMAL": 1 });
    if !m.colors.is_empty() {
        let rgba: Vec<u8> = m
            .colors
            .iter()
            .flat_map(|c| [c[0], c[1], c[2], 255])
            .collect();
        let v = view(&mut bin, &rgba, ARRAY_BUFFER);
        accessors.push(serde_json::json!({
            "bufferView": v, "componentType": UNSIGNED_BYTE, "normalized": true, "count": n,
            "type": "VEC4",
        }));
        attributes["COLOR_0"] = serde_json::json!(accessors.len() - 1);
    }
    let idx: Vec<u8> = m
        .triangles
        .iter()
        .flatten()
        .flat_map(|i| i.to_le_bytes())
        .collect();
    let idx_view = view(&mut bin, &idx, ELEMENT_ARRAY_BUFFER);
    accessors.push(serde_json::json!({
        "bufferView": idx_view, "componentType": UNSIGNED_INT,
        "count": 3 * m.triangles.len(), "type": "SCALAR",
    }));
    let mut node = serde_json::json!({ "mesh": 0 });
    if let Some(q) = y_up_rotation(up) {
        node["rotation"] = serde_json::json!(q);
    }
    let doc = serde_json::json!({
        "asset": { "version": "2.0", "generator": "svraster-vk" },
        "scene": 0,
        "scenes": [{ "nodes": [0] }],
        "nodes": [node],
        "meshes": [{ "primitives": [{
            "attributes": attributes, "indices": accessors.len() - 1, "mode": 4,
        }]}],
        "buffers": [{ "byteLength": bin.len() }],
        "bufferViews": views,
        "accessors": accessors,
    });
    let mut json = serde_json::to_vec(&doc).map_err(|e| Error::Invalid(format!("glb: {e}")))?;
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let total = 12 + 8 + json.len() + 8 + bin.len();
    let total = u32::try_from(total)
        .map_err(|_| Error::Invalid(format!("glb: {total} bytes exceed the format's 4 GiB")))?;
    let mut out = Vec::with_capacity(total as usize);
    for w in [MAGIC, 2, total, json.len() as u32, CHUNK_JSON] {
        out.extend_from_slice(&w.to_le_bytes());
    }
    out.extend_from_slice(&json);
    for w in [bin.len() as u32, CHUNK_BIN] {
        out.extend_from_slice(&w.to_le_bytes());
    }
    out.extend_from_slice(&bin);
    Ok(out)
}

/// Writes `m` to `path` as `.glb` ([`encode`]), atomically.
pub fn write(path: &Path, m: &PlyMesh, up: [f64; 3]) -> Result<()> {
    crate::fsio::write_atomic(path, &encode(m, up)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The root rotation turns each up into +Y (and leaves +Y alone).
    #[test]
    fn rotations_turn_up_into_y() {
        for up in [
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -2.0],
            [1.0, 0.0, 0.0],
            [0.3, -0.5, 0.8],
            [0.0, -1.0, 0.0],
        ] {
            let q = y_up_rotation(up).unwrap();
            let q = glam::DQuat::from_xyzw(q[0], q[1], q[2], q[3]);
            let v = q * glam::DVec3::from(up).normalize();
            assert!((v - glam::DVec3::Y).length() < 1e-12, "{up:?} -> {v}");
        }
        assert_eq!(y_up_rotation([0.0, 3.0, 0.0]), None);
        assert_eq!(y_up_rotation([0.0; 3]), None);
    }
}
