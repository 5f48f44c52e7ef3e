//! Checkpoint I/O: a [`Scene`] as one [safetensors](https://github.com/huggingface/safetensors)
//! file, readable by any safetensors library or by hand.
//!
//! # Layout
//!
//! ```text
//! [8 bytes]  N: length of the JSON header, unsigned 64-bit little-endian
//! [N bytes]  JSON header (UTF-8), padded with spaces so that the data starts at a
//!            multiple of 8 bytes from the start of the file
//! [rest]     data buffer: the tensors' raw little-endian bytes, back to back, no gaps
//! ```
//!
//! The header is one JSON object. `"__metadata__"` maps strings to strings; every other
//! key is a tensor: `{"dtype": "U64"|"U8"|"F32", "shape": [..], "data_offsets": [begin,
//! end]}`, offsets in bytes relative to the start of the data buffer (`end` exclusive).
//! Tensors are row-major (C order). With `V` voxels, `G` grid points and SH degree `D`:
//!
//! | tensor         | dtype | shape                | content                                    |
//! |----------------|-------|----------------------|--------------------------------------------|
//! | `octpath`      | U64   | `[V]`                | Morton code per voxel (see [`crate::scene`]) |
//! | `octlevel`     | U8    | `[V]`                | octree level per voxel, 1..=16             |
//! | `geo_grid_pts` | F32   | `[G]`                | raw density per grid point                 |
//! | `sh0`          | F32   | `[V, 3]`             | degree-0 SH per voxel, RGB                 |
//! | `shs`          | F32   | `[V, (D+1)²−1, 3]`   | higher-degree SH (`[V, 0, 3]`, empty, for D = 0) |
//!
//! `octpath` holds 3 bits per level (`x<<2 | y<<1 | z`), level 1 in bits 45..48, all bits
//! below the voxel's own level zero. A voxel at level `l` with index `(i, j, k)` covers
//! `[i, i+1] × [j, j+1] × [k, k+1] · 2^(16−l)` in integer coordinates of the finest grid
//! (0..=65536 per axis). The grid points are the *unique* corners of all voxels, and
//! `geo_grid_pts` lists their densities ordered by ascending key `x<<34 | y<<17 | z`
//! (integer finest-grid coordinates); a voxel's 8 corner densities are found by
//! computing its corner keys and binary-searching them (e.g. `np.searchsorted`).
//!
//! Metadata (all values are strings, as safetensors requires):
//!
//! | key            | value                                                       |
//! |----------------|-------------------------------------------------------------|
//! | `format`       | `svraster-vk/1`                                             |
//! | `scene_center` | JSON array `[x,y,z]`: world centre of the root cube         |
//! | `scene_extent` | number: full edge length of the root cube in world units   |
//! | `sh_degree`    | `0`, `1`, `2` or `3`                                        |
//! | `background`   | JSON array `[r,g,b]`: background colour                     |
//! | `supersample`  | number in [1, 8]: default render supersampling (optional: 1) |
//! | `world_center` | JSON array `[x,y,z]` (optional: `[0,0,0]`); with `world_scale` (optional: 1) the capture's frame: model = (world − world_center) / world_scale; cameras of the capture are mapped so before rendering, depths scale back by `world_scale` |
//! | `world_scale`  | number > 0 (optional: 1), written as f64 text               |
//!
//! | `quantized`    | `kmeans8` (optional): an 8-bit file, see below              |
//!
//! An 8-bit quantized checkpoint ([`save_quantized`], metadata `quantized` = `kmeans8`)
//! replaces `geo_grid_pts`, `sh0` and `shs` by U8 codes of the same shapes
//! (`geo_grid_pts_q`, `sh0_q`, `shs_q`) and per-channel codebooks F32 `[channels, 256]`
//! (`geo_grid_pts_codebook` with 1 channel, `sh0_codebook` with 3, `shs_codebook` with
//! `3·((D+1)²−1)` in `shs`'s (coefficient, rgb) order); value = `codebook[channel][code]`.
//! [`load`] returns the dequantized scene.
//!
//! Numbers are written in the shortest form that reads back as the identical `f32`.
//! Other metadata keys are ignored on load. Loading is strict: unknown tensors, gaps or
//! overlaps in the data buffer, non-finite values, out-of-range levels, stray path bits,
//! overlapping voxels or a grid-point count that does not match the voxels are errors.
//!
//! # Reading it from Python with only `json` and `numpy`
//!
//! ```python
//! import json, numpy as np
//! def load_svraster(path):
//!     raw = open(path, "rb").read()
//!     n = int.from_bytes(raw[:8], "little")
//!     header = json.loads(raw[8:8 + n])
//!     meta = header.pop("__metadata__")  # strings; json.loads(meta["scene_center"]) etc.
//!     dt = {"U64": "<u8", "U8": "u1", "F32": "<f4"}
//!     t = {k: np.frombuffer(raw[8 + n + v["data_offsets"][0]:8 + n + v["data_offsets"][1]],
//!                           dtype=dt[v["dtype"]]).reshape(v["shape"]) for k, v in header.items()}
//!     return meta, t  # t["octpath"], t["octlevel"], t["geo_grid_pts"], t["sh0"], t["shs"]
//! ```

use std::fs;
use std::io::{self, Write};
use std::path::Path;

use serde::de::{Deserialize, Deserializer, MapAccess, Visitor};
use serde_json::Value;

use super::{sh_coeffs, Scene, MAX_SH_DEGREE};
use crate::error::{Error, Result};

/// Value of the `format` metadata key.
pub const FORMAT: &str = "svraster-vk/1";

/// Largest accepted JSON header (the same bound the safetensors library uses).
pub const MAX_HEADER_BYTES: u64 = 100_000_000;

/// Tensor names, dtypes and element sizes, in the order they are laid out in the data
/// buffer (8-byte elements first, so every tensor starts aligned to its element size).
const TENSORS: [(&str, &str, usize); 5] = [
    ("octpath", "U64", 8),
    ("geo_grid_pts", "F32", 4),
    ("sh0", "F32", 4),
    ("shs", "F32", 4),
    ("octlevel", "U8", 1),
];

/// Value of the `quantized` metadata key of an 8-bit quantized checkpoint.
pub const QUANTIZED: &str = "kmeans8";

/// The tensors of a quantized checkpoint (metadata `quantized` = [`QUANTIZED`]): per
/// channel a codebook of 256 values (`*_codebook`, F32 `[channels, 256]`) and per value
/// the U8 index of its entry (`*_q`, the shape of the full-precision tensor).
const QTENSORS: [(&str, &str, usize); 8] = [
    ("octpath", "U64", 8),
    ("geo_grid_pts_codebook", "F32", 4),
    ("sh0_codebook", "F32", 4),
    ("shs_codebook", "F32", 4),
    ("geo_grid_pts_q", "U8", 1),
    ("sh0_q", "U8", 1),
    ("shs_q", "U8", 1),
    ("octlevel", "U8", 1),
];

/// Writes `scene` to `path` atomically: the checkpoint goes to a temporary file in the
/// same directory, is flushed to disk, then renamed over `path`. On any error the
/// temporary file is removed and an existing file at `path` is left untouched. The scene
/// is validated first; an invalid scene (e.g. containing NaN) is refused.
pub fn save(scene: &Scene, path: &Path) -> Result<()> {
    let header = encode_header(scene)?;
    crate::fsio::write_atomic_with(path, |w| {
        w.write_all(&header)?;
        write_data(scene, w)
    })
    .map_err(|e| match e {
        Error::Io { path, error } => Error::Io {
            path,
            error: io::Error::new(error.kind(), format!("cannot save the checkpoint: {error}")),
        },
        e => e,
    })
}

/// Writes `scene` 8-bit quantized (see [`crate::scene::quantize`]; ~70 % smaller) to
/// `path`, atomically like [`save`]. [`load`] reads it back as a full-precision scene
/// whose values are the codebook entries.
pub fn save_quantized(scene: &Scene, path: &Path) -> Result<()> {
    let bytes = to_bytes_quantized(scene)?;
    crate::fsio::write_atomic(path, &bytes)
}

/// The quantized checkpoint file's bytes for `scene` (validated first).
pub fn to_bytes_quantized(scene: &Scene) -> Result<Vec<u8>> {
    use super::quantize::{quantize_channels, CODES};
    let k = scene.shs_per_voxel();
    let (geo_b, geo_q) = quantize_channels(&scene.geo, 1);
    let (sh0_b, sh0_q) = quantize_channels(bytemuck::cast_slice(&scene.sh0), 3);
    let (shs_b, shs_q) = quantize_channels(&scene.shs, 3 * k);
    let n = scene.num_voxels();
    let m = scene.num_grid_points();
    let shapes: [(Vec<usize>, usize); 8] = [
        (vec![n], n * 8),
        (vec![1, CODES], CODES * 4),
        (vec![3, CODES], 3 * CODES * 4),
        (vec![3 * k, CODES], 3 * k * CODES * 4),
        (vec![m], m),
        (vec![n, 3], 3 * n),
        (vec![n, k, 3], 3 * k * n),
        (vec![n], n),
    ];
    let mut out = encode_header_for(scene, &QTENSORS, &shapes, true)?;
    for v in &scene.octpath {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for book in geo_b.iter().chain(&sh0_b).chain(&shs_b) {
        for v in book {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out.extend_from_slice(&geo_q);
    out.extend_from_slice(&sh0_q);
    out.extend_from_slice(&shs_q);
    out.extend_from_slice(&scene.octlevel);
    Ok(out)
}

/// Reads and fully validates a checkpoint written by [`save`] (or any tool following the
/// format in the module documentation).
pub fn load(path: &Path) -> Result<Scene> {
    let bytes = fs::read(path).map_err(|error| Error::Io {
        path: path.display().to_string(),
        error,
    })?;
    parse(&bytes, &path.display().to_string())
}

/// The checkpoint file's bytes for `scene` (validated first).
pub fn to_bytes(scene: &Scene) -> Result<Vec<u8>> {
    let header = encode_header(scene)?;
    let mut out = Vec::with_capacity(header.len() + data_len(scene));
    out.extend_from_slice(&header);
    write_data(scene, &mut out).map_err(|error| Error::Io {
        path: "<memory>".into(),
        error,
    })?;
    Ok(out)
}

/// Parses and fully validates checkpoint bytes (see [`load`]).
pub fn from_bytes(bytes: &[u8]) -> Result<Scene> {
    parse(bytes, "<memory>")
}

// ---------------------------------------------------------------------------------------
// Writing

/// Shapes and byte sizes of the tensors, in [`TENSORS`] order.
fn shapes(scene: &Scene) -> [(Vec<usize>, usize); 5] {
    let n = scene.num_voxels();
    let k = scene.shs_per_voxel();
    let m = scene.num_grid_points();
    [
        (vec![n], n * 8),
        (vec![m], m * 4),
        (vec![n, 3], n * 12),
        (vec![n, k, 3], n * k * 12),
        (vec![n], n),
    ]
}

fn data_len(scene: &Scene) -> usize {
    shapes(scene).iter().map(|s| s.1).sum()
}

/// Validates the scene and returns the length prefix plus the padded JSON header.
fn encode_header(scene: &Scene) -> Result<Vec<u8>> {
    encode_header_for(scene, &TENSORS, &shapes(scene), false)
}

/// [`encode_header`] for a tensor table and its shapes and byte sizes.
fn encode_header_for(
    scene: &Scene,
    table: &[(&str, &str, usize)],
    shapes: &[(Vec<usize>, usize)],
    quantized: bool,
) -> Result<Vec<u8>> {
    scene.validate().map_err(|e| match e {
        Error::Invalid(m) => Error::Invalid(format!("refusing to save an invalid scene: {m}")),
        e => e,
    })?;
    let mut header = serde_json::Map::new();
    let mut meta = serde_json::Map::new();
    let vec3 = |v: [f32; 3]| format!("[{},{},{}]", num(v[0]), num(v[1]), num(v[2]));
    meta.insert("format".into(), FORMAT.into());
    meta.insert("scene_center".into(), vec3(scene.center).into());
    meta.insert("scene_extent".into(), num(scene.extent).into());
    meta.insert("sh_degree".into(), scene.sh_degree.to_string().into());
    meta.insert("background".into(), vec3(scene.background).into());
    meta.insert("supersample".into(), num(scene.supersample).into());
    if quantized {
        meta.insert("quantized".into(), QUANTIZED.into());
    }
    if !scene.world.is_identity() {
        let c = scene.world.center;
        meta.insert(
            "world_center".into(),
            format!("[{:?},{:?},{:?}]", c[0], c[1], c[2]).into(),
        );
        meta.insert(
            "world_scale".into(),
            format!("{:?}", scene.world.scale).into(),
        );
    }
    header.insert("__metadata__".into(), Value::Object(meta));
    let mut offset = 0usize;
    for ((name, dtype, _), (shape, bytes)) in table.iter().zip(shapes) {
        header.insert(
            (*name).into(),
            serde_json::json!({
                "dtype": dtype,
                "shape": shape,
                "data_offsets": [offset, offset + *bytes],
            }),
        );
        offset += *bytes;
    }
    let mut json = serde_json::to_vec(&Value::Object(header))
        .map_err(|e| Error::Invalid(format!("cannot encode the checkpoint header: {e}")))?;
    while (8 + json.len()) % 8 != 0 {
        json.push(b' ');
    }
    let mut out = Vec::with_capacity(8 + json.len());
    out.extend_from_slice(&(json.len() as u64).to_le_bytes());
    out.extend_from_slice(&json);
    Ok(out)
}

/// Shortest decimal text that parses back to the identical `f32` (a valid JSON number):
/// plain notation for ordinary magnitudes, exponent notation for tiny or huge ones.
fn num(v: f32) -> String {
    let a = v.abs();
    if a != 0.0 && !(1e-5..1e16).contains(&a) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

/// Writes the data buffer (tensors in [`TENSORS`] order, little-endian).
fn write_data<W: Write + ?Sized>(scene: &Scene, w: &mut W) -> io::Result<()> {
    if cfg!(target_endian = "little") {
        w.write_all(bytemuck::cast_slice(&scene.octpath))?;
        w.write_all(bytemuck::cast_slice(&scene.geo))?;
        w.write_all(bytemuck::cast_slice(&scene.sh0))?;
        w.write_all(bytemuck::cast_slice(&scene.shs))?;
    } else {
        for v in &scene.octpath {
            w.write_all(&v.to_le_bytes())?;
        }
        let sh0: &[f32] = bytemuck::cast_slice(&scene.sh0);
        for v in scene.geo.iter().chain(sh0).chain(&scene.shs) {
            w.write_all(&v.to_le_bytes())?;
        }
    }
    w.write_all(&scene.octlevel)
}

// ---------------------------------------------------------------------------------------
// Reading

fn parse(bytes: &[u8], name: &str) -> Result<Scene> {
    parse_inner(bytes).map_err(|m| Error::Invalid(format!("checkpoint {name}: {m}")))
}

/// A JSON object kept as its entries in file order, so duplicate keys can be detected
/// (a plain map would silently keep the last one).
struct Entries<T>(Vec<(String, T)>);

impl<'de, T: Deserialize<'de>> Deserialize<'de> for Entries<T> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        struct V<T>(std::marker::PhantomData<T>);
        impl<'de, T: Deserialize<'de>> Visitor<'de> for V<T> {
            type Value = Entries<T>;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a JSON object")
            }
            fn visit_map<A: MapAccess<'de>>(
                self,
                mut a: A,
            ) -> std::result::Result<Self::Value, A::Error> {
                let mut v = Vec::new();
                while let Some(e) = a.next_entry::<String, T>()? {
                    v.push(e);
                }
                Ok(Entries(v))
            }
        }
        d.deserialize_map(V(std::marker::PhantomData))
    }
}

impl<T> Entries<T> {
    fn check_unique(&self, what: &str) -> std::result::Result<(), String> {
        let mut keys: Vec<&str> = self.0.iter().map(|(k, _)| k.as_str()).collect();
        keys.sort_unstable();
        match keys.windows(2).find(|w| w[0] == w[1]) {
            Some(w) => Err(format!("{what} has the key `{}` more than once", w[0])),
            None => Ok(()),
        }
    }

    fn get(&self, key: &str) -> Option<&T> {
        self.0.iter().find(|(k, _)| k == key).map(|(_, v)| v)
    }
}

/// One tensor's header entry, checked against its expected dtype.
struct TensorInfo {
    shape: Vec<u64>,
    begin: u64,
    end: u64,
}

type Msg<T> = std::result::Result<T, String>;

fn parse_inner(bytes: &[u8]) -> Msg<Scene> {
    // --- length prefix and header JSON
    if bytes.len() < 8 {
        return Err(format!(
            "file is {} bytes, too short for the 8-byte header length",
            bytes.len()
        ));
    }
    let mut prefix = [0u8; 8];
    prefix.copy_from_slice(&bytes[..8]);
    let n = u64::from_le_bytes(prefix);
    if n > MAX_HEADER_BYTES {
        return Err(format!(
            "header length {n} is absurd (more than {MAX_HEADER_BYTES} bytes): not a checkpoint, or corrupt"
        ));
    }
    let rest = (bytes.len() - 8) as u64;
    if n > rest {
        return Err(format!(
            "header length {n} runs beyond the end of the file ({rest} bytes after the length prefix): truncated or corrupt"
        ));
    }
    let n = n as usize;
    let text = std::str::from_utf8(&bytes[8..8 + n])
        .map_err(|e| format!("header is not valid UTF-8: {e}"))?;
    let top: Entries<Entries<Value>> =
        serde_json::from_str(text).map_err(|e| format!("header is malformed JSON: {e}"))?;
    top.check_unique("header")?;
    let data = &bytes[8 + n..];

    // --- metadata
    let meta = top
        .get("__metadata__")
        .ok_or("header has no `__metadata__` (not an svraster checkpoint?)")?;
    meta.check_unique("`__metadata__`")?;
    let meta_str = |key: &str| -> Msg<&str> {
        match meta.get(key) {
            None => Err(format!("metadata key `{key}` is missing")),
            Some(Value::String(s)) => Ok(s.as_str()),
            Some(v) => Err(format!("metadata `{key}` must be a string, got {v}")),
        }
    };
    for (key, v) in &meta.0 {
        if !v.is_string() {
            return Err(format!("metadata `{key}` must be a string, got {v}"));
        }
    }
    let quantized = match meta.get("quantized") {
        None => false,
        Some(_) => match meta_str("quantized")? {
            QUANTIZED => true,
            q => {
                return Err(format!(
                "metadata `quantized` is `{q}`, expected `{QUANTIZED}` (unsupported quantization)"
            ))
            }
        },
    };
    let table: &[(&str, &str, usize)] = if quantized { &QTENSORS } else { &TENSORS };
    for (key, _) in &top.0 {
        if key != "__metadata__" && !table.iter().any(|t| t.0 == key) {
            return Err(format!(
                "unknown tensor `{key}` in the header (expected only {}{})",
                table
                    .iter()
                    .map(|t| format!("`{}`", t.0))
                    .collect::<Vec<_>>()
                    .join(", "),
                if quantized { ", quantized" } else { "" }
            ));
        }
    }
    let format = meta_str("format")?;
    if format != FORMAT {
        return Err(format!(
            "metadata `format` is `{format}`, expected `{FORMAT}` (unsupported format or version)"
        ));
    }
    let sh_text = meta_str("sh_degree")?;
    let sh_degree: u32 = sh_text
        .trim()
        .parse()
        .map_err(|_| format!("metadata `sh_degree` is `{sh_text}`, not an integer"))?;
    if sh_degree > MAX_SH_DEGREE {
        return Err(format!(
            "metadata `sh_degree` is {sh_degree}, outside 0..={MAX_SH_DEGREE}"
        ));
    }
    let center = parse_vec3::<f32>("scene_center", meta_str("scene_center")?)?;
    let extent = parse_num::<f32>("scene_extent", meta_str("scene_extent")?)?;
    if extent <= 0.0 {
        return Err(format!("metadata `scene_extent` is {extent}, must be > 0"));
    }
    let background = parse_vec3::<f32>("background", meta_str("background")?)?;
    // Optional (files written before it existed render without supersampling).
    let supersample = match meta.get("supersample") {
        None => 1.0,
        Some(_) => parse_num::<f32>("supersample", meta_str("supersample")?)?,
    };
    if !(1.0..=8.0).contains(&supersample) {
        return Err(format!(
            "metadata `supersample` is {supersample}, must be in [1, 8]"
        ));
    }
    let world = super::WorldFrame {
        center: match meta.get("world_center") {
            None => [0.0; 3],
            Some(_) => parse_vec3::<f64>("world_center", meta_str("world_center")?)?,
        },
        scale: match meta.get("world_scale") {
            None => 1.0,
            Some(_) => parse_num::<f64>("world_scale", meta_str("world_scale")?)?,
        },
    };
    if world.scale <= 0.0 {
        return Err(format!(
            "metadata `world_scale` is {}, must be > 0",
            world.scale
        ));
    }

    // --- tensor entries
    let mut infos = Vec::with_capacity(table.len());
    for (name, dtype, _) in table {
        let entry = top
            .get(name)
            .ok_or_else(|| format!("tensor `{name}` is missing"))?;
        infos.push(tensor_info(name, dtype, entry, data.len() as u64)?);
    }
    let info = |name: &str| {
        &infos[table
            .iter()
            .position(|t| t.0 == name)
            .expect("in the table")]
    };
    let (octpath_i, octlevel_i) = (info("octpath"), info("octlevel"));
    let (geo_i, sh0_i, shs_i) = if quantized {
        (info("geo_grid_pts_q"), info("sh0_q"), info("shs_q"))
    } else {
        (info("geo_grid_pts"), info("sh0"), info("shs"))
    };
    let k = (sh_coeffs(sh_degree) - 1) as u64;
    let nv = match octpath_i.shape[..] {
        [nv] => nv,
        _ => return Err(shape_msg("octpath", &octpath_i.shape, "[N]")),
    };
    let want = |name: &str, info: &TensorInfo, expect: &[u64], form: &str| -> Msg<()> {
        if info.shape.len() != expect.len() {
            return Err(shape_msg(name, &info.shape, form));
        }
        if info.shape != expect {
            return Err(format!(
                "tensor `{name}` has shape {:?}, expected {expect:?} ({form} with N = {nv} voxels from `octpath`{})",
                info.shape,
                if name == "shs" { format!(", sh_degree {sh_degree}") } else { String::new() }
            ));
        }
        Ok(())
    };
    let (sh0_name, shs_name, geo_name) = if quantized {
        ("sh0_q", "shs_q", "geo_grid_pts_q")
    } else {
        ("sh0", "shs", "geo_grid_pts")
    };
    want("octlevel", octlevel_i, &[nv], "[N]")?;
    want(sh0_name, sh0_i, &[nv, 3], "[N, 3]")?;
    want(shs_name, shs_i, &[nv, k, 3], "[N, (D+1)²−1, 3]")?;
    if geo_i.shape.len() != 1 {
        return Err(shape_msg(geo_name, &geo_i.shape, "[M]"));
    }
    let codes = super::quantize::CODES as u64;
    if quantized {
        for (name, channels) in [
            ("geo_grid_pts_codebook", 1),
            ("sh0_codebook", 3),
            ("shs_codebook", 3 * k),
        ] {
            let i = info(name);
            if i.shape != [channels, codes] {
                return Err(format!(
                    "tensor `{name}` has shape {:?}, expected [{channels}, {codes}]",
                    i.shape
                ));
            }
        }
    }

    // --- data buffer: sizes, bounds, tiling
    for ((name, _, esize), info) in table.iter().zip(&infos) {
        let size = info
            .shape
            .iter()
            .try_fold(*esize as u64, |a, &d| a.checked_mul(d))
            .ok_or_else(|| format!("tensor `{name}` shape {:?} is absurdly large", info.shape))?;
        if info.end - info.begin != size {
            return Err(format!(
                "tensor `{name}`: data_offsets [{}, {}] span {} bytes but shape {:?} needs {size}",
                info.begin,
                info.end,
                info.end - info.begin,
                info.shape
            ));
        }
    }
    let mut order: Vec<usize> = (0..table.len()).collect();
    order.sort_by_key(|&i| (infos[i].begin, infos[i].end));
    let mut pos = 0u64;
    let mut prev: Option<usize> = None;
    for &i in &order {
        let info = &infos[i];
        if info.begin < pos {
            let p = prev.map_or("?", |p| table[p].0);
            return Err(format!(
                "tensors `{p}` and `{}` overlap in the data buffer (byte {} is inside `{p}`)",
                table[i].0, info.begin
            ));
        }
        if info.begin > pos {
            return Err(format!(
                "gap in the data buffer: bytes {pos}..{} belong to no tensor",
                info.begin
            ));
        }
        pos = info.end;
        prev = Some(i);
    }
    if pos != data.len() as u64 {
        return Err(format!(
            "gap in the data buffer: {} trailing bytes after the last tensor belong to no tensor",
            data.len() as u64 - pos
        ));
    }

    // --- decode
    let slice = |info: &TensorInfo| &data[info.begin as usize..info.end as usize];
    let octpath: Vec<u64> = slice(octpath_i)
        .chunks_exact(8)
        .map(|c| u64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]))
        .collect();
    let octlevel: Vec<u8> = slice(octlevel_i).to_vec();
    let f32s = |info: &TensorInfo| -> Vec<f32> {
        slice(info)
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect()
    };
    // Full precision, or codebook entries by code.
    let values = |name: &str, q: &TensorInfo| -> Msg<Vec<f32>> {
        if !quantized {
            return Ok(f32s(q));
        }
        let flat = f32s(info(&format!("{name}_codebook")));
        if let Some(i) = flat.iter().position(|v| !v.is_finite()) {
            return Err(format!(
                "{name}_codebook value {i} is not finite ({})",
                flat[i]
            ));
        }
        let books: Vec<[f32; super::quantize::CODES]> = flat
            .chunks_exact(super::quantize::CODES)
            .map(|c| c.try_into().expect("codebook rows"))
            .collect();
        Ok(super::quantize::dequantize_channels(&books, slice(q)))
    };
    let geo = values("geo_grid_pts", geo_i)?;
    let sh0: Vec<[f32; 3]> = values("sh0", sh0_i)?
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    let shs = values("shs", shs_i)?;
    if let Some(i) = geo.iter().position(|v| !v.is_finite()) {
        return Err(format!("geo_grid_pts[{i}] is not finite ({})", geo[i]));
    }
    if let Some(i) = sh0.iter().position(|v| v.iter().any(|x| !x.is_finite())) {
        return Err(format!("sh0[{i}] is not finite ({:?})", sh0[i]));
    }
    if let Some(i) = shs.iter().position(|v| !v.is_finite()) {
        return Err(format!(
            "shs value {i} (voxel {}) is not finite ({})",
            i / (3 * k.max(1) as usize),
            shs[i]
        ));
    }

    // --- voxels
    // Checks levels, path bits, overlap and duplicates once, and builds the unique,
    // sorted grid points.
    let mut scene =
        Scene::from_voxels(center, extent, 0, octpath, octlevel, 0.0).map_err(|e| match e {
            Error::Invalid(m) => m,
            e => e.to_string(),
        })?;
    if scene.grid_keys.len() != geo.len() {
        return Err(format!(
            "geo_grid_pts has {} values but the voxels have {} unique corners (grid points)",
            geo.len(),
            scene.grid_keys.len()
        ));
    }
    scene.sh_degree = sh_degree;
    scene.background = background;
    scene.supersample = supersample;
    scene.world = world;
    scene.geo = geo;
    scene.sh0 = sh0;
    scene.shs = shs;
    scene.validate_arrays().map_err(|e| match e {
        Error::Invalid(m) => m,
        e => e.to_string(),
    })?;
    Ok(scene)
}

fn shape_msg(name: &str, shape: &[u64], form: &str) -> String {
    format!(
        "tensor `{name}` has rank {} (shape {shape:?}), expected rank {} ({form})",
        shape.len(),
        form.matches(',').count() + 1
    )
}

/// Checks one tensor entry's fields and dtype; offsets must lie within the data buffer.
fn tensor_info(name: &str, dtype: &str, entry: &Entries<Value>, data_len: u64) -> Msg<TensorInfo> {
    entry.check_unique(&format!("tensor `{name}`"))?;
    for (key, _) in &entry.0 {
        if !["dtype", "shape", "data_offsets"].contains(&key.as_str()) {
            return Err(format!("tensor `{name}` has an unknown field `{key}`"));
        }
    }
    let field = |key: &str| {
        entry
            .get(key)
            .ok_or_else(|| format!("tensor `{name}` has no `{key}`"))
    };
    match field("dtype")? {
        Value::String(s) if s == dtype => {}
        v => {
            return Err(format!(
                "tensor `{name}` has dtype {v}, expected \"{dtype}\""
            ))
        }
    }
    let ints = |key: &str| -> Msg<Vec<u64>> {
        let v = field(key)?;
        v.as_array()
            .and_then(|a| a.iter().map(Value::as_u64).collect::<Option<Vec<u64>>>())
            .ok_or_else(|| {
                format!(
                    "tensor `{name}`: `{key}` must be an array of non-negative integers, got {v}"
                )
            })
    };
    let shape = ints("shape")?;
    let offsets = ints("data_offsets")?;
    let [begin, end] = offsets[..] else {
        return Err(format!(
            "tensor `{name}`: `data_offsets` must be [begin, end], got {offsets:?}"
        ));
    };
    if end < begin {
        return Err(format!(
            "tensor `{name}`: data_offsets end {end} < begin {begin}"
        ));
    }
    if end > data_len {
        return Err(format!(
            "tensor `{name}`: data_offsets [{begin}, {end}] out of bounds of the {data_len}-byte data buffer (truncated file?)"
        ));
    }
    Ok(TensorInfo { shape, begin, end })
}

/// A finite number (f32 or f64, parsed at its own precision).
fn parse_num<T: std::str::FromStr + Copy + Into<f64>>(key: &str, s: &str) -> Msg<T> {
    let v: T = s
        .trim()
        .parse()
        .map_err(|_| format!("metadata `{key}`: `{s}` is not a number"))?;
    if !v.into().is_finite() {
        return Err(format!("metadata `{key}`: `{s}` is not finite"));
    }
    Ok(v)
}

/// A JSON array text `[x,y,z]` of finite numbers.
fn parse_vec3<T: std::str::FromStr + Copy + Into<f64>>(key: &str, s: &str) -> Msg<[T; 3]> {
    let inner = s
        .trim()
        .strip_prefix('[')
        .and_then(|t| t.strip_suffix(']'))
        .ok_or_else(|| format!("metadata `{key}` is `{s}`, expected a JSON array [x,y,z]"))?;
    let parts: Vec<&str> = inner.split(',').collect();
    if parts.len() != 3 {
        return Err(format!(
            "metadata `{key}` is `{s}`, expected exactly 3 numbers [x,y,z]"
        ));
    }
    Ok([
        parse_num(key, parts[0])?,
        parse_num(key, parts[1])?,
        parse_num(key, parts[2])?,
    ])
}
