//! Reading a checkpoint: the safetensors framing parsed by our own reader (stricter than
//! the `safetensors` crate: duplicate keys are refused and every error names the tensor
//! or key), in steps — header, metadata, tensor entries, data layout, decoding, voxels.

use serde::de::{Deserialize, Deserializer, MapAccess, Visitor};
use serde_json::Value;

use super::{FORMAT, MAX_HEADER_BYTES, QTENSORS, QUANTIZED, TENSORS};
use crate::error::{Error, Result};
use crate::scene::{quantize, sh_coeffs, Scene, WorldFrame, MAX_SH_DEGREE};

pub(super) fn parse(bytes: &[u8], name: &str) -> Result<Scene> {
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

/// Reads a checkpoint, every step checked with a message naming what is wrong.
fn parse_inner(bytes: &[u8]) -> Msg<Scene> {
    let (top, data) = header(bytes)?;
    let meta = metadata(&top)?;
    let t = tensors(&top, &meta, data)?;
    check_layout(&t, data)?;
    let d = decode(&t, &meta, data)?;
    build_scene(meta, d)
}

/// Step 1: the length prefix and the header JSON (no duplicate keys); returns it and the
/// data buffer after it.
fn header(bytes: &[u8]) -> Msg<(Entries<Entries<Value>>, &[u8])> {
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
    Ok((top, &bytes[8 + n..]))
}

/// What the metadata says (step 2).
struct Meta {
    quantized: bool,
    /// The tensors the file must hold: [`TENSORS`] or [`QTENSORS`].
    table: &'static [(&'static str, &'static str, usize)],
    sh_degree: u32,
    center: [f32; 3],
    extent: f32,
    background: [f32; 3],
    background_frame_mean: bool,
    supersample: f32,
    world: WorldFrame,
}

/// Step 2: the metadata (every value a string, the format, the scene's frame and
/// options), and no tensor the format does not know.
fn metadata(top: &Entries<Entries<Value>>) -> Msg<Meta> {
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
    let table: &'static [(&'static str, &'static str, usize)] =
        if quantized { &QTENSORS } else { &TENSORS };
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
    let background_frame_mean = match meta.get("background_mode") {
        None => false,
        Some(_) => match meta_str("background_mode")? {
            super::BACKGROUND_FRAME_MEAN => true,
            super::BACKGROUND_COLOUR => false,
            m => {
                return Err(format!(
                    "metadata `background_mode` is `{m}`, expected `{}` or `{}`",
                    super::BACKGROUND_COLOUR,
                    super::BACKGROUND_FRAME_MEAN
                ))
            }
        },
    };
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
    let world = WorldFrame {
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
    Ok(Meta {
        quantized,
        table,
        sh_degree,
        center,
        extent,
        background,
        background_frame_mean,
        supersample,
        world,
    })
}

/// The tensors' header entries, in the order of [`Meta::table`] (step 3).
struct Tensors {
    table: &'static [(&'static str, &'static str, usize)],
    infos: Vec<TensorInfo>,
    /// SH coefficients per voxel and colour channel beyond degree 0.
    k: u64,
}

impl Tensors {
    fn info(&self, name: &str) -> &TensorInfo {
        &self.infos[self
            .table
            .iter()
            .position(|t| t.0 == name)
            .expect("in the table")]
    }

    /// The full-precision (or, quantized, the code) tensors of the geometry and colours.
    fn values_infos(&self, quantized: bool) -> (&TensorInfo, &TensorInfo, &TensorInfo) {
        if quantized {
            (
                self.info("geo_grid_pts_q"),
                self.info("sh0_q"),
                self.info("shs_q"),
            )
        } else {
            (
                self.info("geo_grid_pts"),
                self.info("sh0"),
                self.info("shs"),
            )
        }
    }
}

/// Step 3: every tensor's entry (dtype, offsets within the data) and shape, consistent
/// with the voxel count of `octpath` and the SH degree.
fn tensors(top: &Entries<Entries<Value>>, meta: &Meta, data: &[u8]) -> Msg<Tensors> {
    let (table, quantized, sh_degree) = (meta.table, meta.quantized, meta.sh_degree);
    let mut infos = Vec::with_capacity(table.len());
    for (name, dtype, _) in table {
        let entry = top
            .get(name)
            .ok_or_else(|| format!("tensor `{name}` is missing"))?;
        infos.push(tensor_info(name, dtype, entry, data.len() as u64)?);
    }
    let t = Tensors {
        table,
        infos,
        k: (sh_coeffs(sh_degree) - 1) as u64,
    };
    let info = |name: &str| t.info(name);
    let (octpath_i, octlevel_i) = (info("octpath"), info("octlevel"));
    let (geo_i, sh0_i, shs_i) = t.values_infos(quantized);
    let k = t.k;
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
    let codes = quantize::CODES as u64;
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
    Ok(t)
}

/// Step 4: each tensor's byte span matches its shape, and the tensors tile the data
/// buffer exactly (no overlap, no gap).
fn check_layout(t: &Tensors, data: &[u8]) -> Msg<()> {
    let (table, infos) = (t.table, t.infos.as_slice());
    for ((name, _, esize), info) in table.iter().zip(infos) {
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
    Ok(())
}

/// The decoded arrays (step 5).
struct Decoded {
    octpath: Vec<u64>,
    octlevel: Vec<u8>,
    geo: Vec<f32>,
    sh0: Vec<[f32; 3]>,
    shs: Vec<f32>,
}

/// Step 5: the arrays, dequantized through their codebooks if quantized; every value
/// finite.
fn decode(t: &Tensors, meta: &Meta, data: &[u8]) -> Msg<Decoded> {
    let quantized = meta.quantized;
    let k = t.k;
    let info = |name: &str| t.info(name);
    let (octpath_i, octlevel_i) = (info("octpath"), info("octlevel"));
    let (geo_i, sh0_i, shs_i) = t.values_infos(quantized);
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
        let books: Vec<[f32; quantize::CODES]> = flat
            .chunks_exact(quantize::CODES)
            .map(|c| c.try_into().expect("codebook rows"))
            .collect();
        Ok(quantize::dequantize_channels(&books, slice(q)))
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
    Ok(Decoded {
        octpath,
        octlevel,
        geo,
        sh0,
        shs,
    })
}

/// Step 6: the voxels (levels, path bits, overlap and duplicates checked once), their
/// unique sorted grid points, and the scene assembled and validated.
fn build_scene(meta: Meta, d: Decoded) -> Msg<Scene> {
    let Meta {
        sh_degree,
        center,
        extent,
        background,
        background_frame_mean,
        supersample,
        world,
        ..
    } = meta;
    let Decoded {
        octpath,
        octlevel,
        geo,
        sh0,
        shs,
    } = d;
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
    scene.background_frame_mean = background_frame_mean;
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
