// The kernel-variant table, read by build.rs (`#[path]` module): kernels compiled from
// one GLSL body with `#define`s, in families. A family's variants are every combination
// of its axes' options; build.rs compiles each (no stub `.comp` files), and emits, per
// family, the variants as a nested array `kernels::<FAMILY>_VARIANTS` (outermost axis
// first) that the host code indexes — so no list of variants is kept by hand — and a
// `push_constants!(<FAMILY>_VARIANTS, Mirror)` arm that checks every member.
//
// - `raster/composite_k{K}[_maxw|_counters][_nonormal]`: forward compositing with K
//   samples per segment; `_maxw` also folds per-voxel max blend weights (the adaptive
//   statistics pass only); `_counters` also counts the walk's work (`bench --json`);
//   `_nonormal` for frames without a normal image (`FrameOutputs`).
// - `train/backward_k{K}[_cas|_det][_counters|_nonormal]`: its backward; `_cas` adds
//   floats with a compare-and-swap loop (devices without float atomics), `_det` writes
//   per-entry records for the ordered reduction (`--deterministic`); `_nonormal` for
//   frames without a normal image.
// - `train/tv[_cas|_det]`, `train/voxel_backward[_cas|_det]`: TV and the per-voxel
//   backward, with native float atomic adds, (`_cas`) a compare-and-swap loop, or
//   (`_det`) plain per-voxel-corner writes for the ordered reduction.
// - `sort/histogram[_k32]`, `sort/onesweep[_k32]`: the radix sort's digit histogram and
//   its direct pass over u64 keys, or (`_k32`) u32 keys for a sort whose bits all lie
//   below 32; `sort/onesweep_c{256,128}[_k32]`: the pass with coalesced writes (GPUs),
//   256 invocations for subgroups of ≥ 16 lanes, 128 for any size;
//   `sort/scanpass_s{256,128}[_k32]` the same pass reading prefixes instead of looking
//   back, and `sort/tile_count_s{256,128}[_k32]` its tiles' digit counts (the
//   reduce-then-scan passes); `sort/probe_{copy,tile}_c{256,128}[_k32]` the coalesced
//   pass doing part of its work (`bench sort --probe`, timing instruments).

/// One `#define NAME VALUE`.
pub type Define = (&'static str, String);

/// One option of an axis: the suffix it adds to the kernel's name, and its defines.
pub type Opt = (&'static str, Vec<Define>);

/// A family of kernels built from one body.
pub struct Family {
    /// The array's name in `kernels` (without `_VARIANTS`).
    pub name: &'static str,
    /// Kernel path below glsl/ of every variant, before the suffixes.
    pub path: &'static str,
    /// The body, a path below glsl/ (its module's folder).
    pub body: &'static str,
    /// The axes, outermost first (the array's index order).
    pub axes: Vec<Vec<Opt>>,
    /// The order in which the axes' suffixes make the kernel's name (axis indices).
    pub name_order: Vec<usize>,
    /// Suffix and defines every variant has.
    pub fixed: Opt,
}

fn d(name: &'static str, value: impl ToString) -> Define {
    (name, value.to_string())
}

fn samples() -> Vec<Opt> {
    vec![
        ("_k1", vec![d("N_SAMP", 1)]),
        ("_k2", vec![d("N_SAMP", 2)]),
        ("_k3", vec![d("N_SAMP", 3)]),
    ]
}

/// Float adds: native atomics (VK_EXT_shader_atomic_float), a CAS loop (any device), or
/// the ordered reduction's plain writes — in `Reduction`'s order.
fn reductions() -> Vec<Opt> {
    vec![
        ("", vec![d("FLOAT_ATOMICS", 1)]),
        ("_cas", vec![]),
        ("_det", vec![d("DETERMINISTIC", 1)]),
    ]
}

fn key_widths() -> Vec<Opt> {
    vec![("", vec![]), ("_k32", vec![d("KEY32", 1)])]
}

fn nonormal() -> Opt {
    ("_nonormal", vec![d("NO_NORMALS", 1)])
}

/// Every family.
pub fn families() -> Vec<Family> {
    let mut f = Vec::new();
    let composite_modes = vec![
        ("", vec![]),
        ("_maxw", vec![d("TRACK_MAXW", 1)]),
        ("_counters", vec![d("COUNTERS", 1)]),
    ];
    f.push(Family {
        name: "RASTER_COMPOSITE",
        path: "raster/composite",
        body: "raster/composite.glsl",
        axes: vec![composite_modes.clone(), samples()],
        name_order: vec![1, 0],
        fixed: ("", vec![]),
    });
    f.push(Family {
        name: "RASTER_COMPOSITE_NONORMAL",
        path: "raster/composite",
        body: "raster/composite.glsl",
        axes: vec![composite_modes[..2].to_vec(), samples()],
        name_order: vec![1, 0],
        fixed: nonormal(),
    });
    for (name, fixed) in [
        ("TRAIN_BACKWARD", ("", vec![])),
        (
            "TRAIN_BACKWARD_COUNTERS",
            ("_counters", vec![d("COUNTERS", 1)]),
        ),
        ("TRAIN_BACKWARD_NONORMAL", nonormal()),
    ] {
        f.push(Family {
            name,
            path: "train/backward",
            body: "train/backward.glsl",
            axes: vec![reductions(), samples()],
            name_order: vec![1, 0],
            fixed,
        });
    }
    for (name, path) in [
        ("TRAIN_TV", "train/tv"),
        ("TRAIN_VOXEL_BACKWARD", "train/voxel_backward"),
    ] {
        f.push(Family {
            name,
            path,
            body: if name == "TRAIN_TV" {
                "train/tv.glsl"
            } else {
                "train/voxel_backward.glsl"
            },
            axes: vec![reductions()],
            name_order: vec![0],
            fixed: ("", vec![]),
        });
    }
    // The sort's kernels: each in a u64- and a u32-key variant.
    let sort = |name, path, body, fixed| Family {
        name,
        path,
        body,
        axes: vec![key_widths()],
        name_order: vec![0],
        fixed: ("", fixed),
    };
    f.push(sort(
        "SORT_HISTOGRAM",
        "sort/histogram",
        "sort/histogram.glsl",
        vec![],
    ));
    f.push(sort(
        "SORT_ONESWEEP",
        "sort/onesweep",
        "sort/onesweep.glsl",
        vec![],
    ));
    // The coalesced passes, and the reduce-then-scan passes: the coalesced pass reading
    // prefixes, and its tile counts.
    let coalesced = "sort/onesweep_coalesced.glsl";
    // The probes (PROBE 1 copy, 2 tile) of each coalesced pass.
    for (wg, min_sg, c, s, count, probes) in [
        (
            256,
            16,
            ("SORT_ONESWEEP_C256", "sort/onesweep_c256"),
            ("SORT_SCANPASS_S256", "sort/scanpass_s256"),
            ("SORT_TILE_COUNT_S256", "sort/tile_count_s256"),
            [
                ("SORT_PROBE_COPY_C256", "sort/probe_copy_c256"),
                ("SORT_PROBE_TILE_C256", "sort/probe_tile_c256"),
            ],
        ),
        (
            128,
            8,
            ("SORT_ONESWEEP_C128", "sort/onesweep_c128"),
            ("SORT_SCANPASS_S128", "sort/scanpass_s128"),
            ("SORT_TILE_COUNT_S128", "sort/tile_count_s128"),
            [
                ("SORT_PROBE_COPY_C128", "sort/probe_copy_c128"),
                ("SORT_PROBE_TILE_C128", "sort/probe_tile_c128"),
            ],
        ),
    ] {
        let fixed = vec![d("WG", wg), d("KPT", 15), d("MIN_SG", min_sg)];
        let scan = [fixed.clone(), vec![d("SCAN_PREFIX", 1)]].concat();
        f.push(sort(c.0, c.1, coalesced, fixed.clone()));
        f.push(sort(s.0, s.1, coalesced, scan));
        for (i, p) in probes.into_iter().enumerate() {
            let defs = [fixed.clone(), vec![d("PROBE", i + 1)]].concat();
            f.push(sort(p.0, p.1, coalesced, defs));
        }
        f.push(sort(count.0, count.1, "sort/tile_count.glsl", fixed));
    }
    f
}

/// A family's variants in array order (outermost axis first): kernel path and defines.
pub fn expand(f: &Family) -> Vec<(String, Vec<Define>)> {
    let mut combos: Vec<Vec<usize>> = vec![vec![]];
    for axis in &f.axes {
        combos = combos
            .into_iter()
            .flat_map(|c| {
                (0..axis.len()).map(move |i| {
                    let mut c = c.clone();
                    c.push(i);
                    c
                })
            })
            .collect();
    }
    combos
        .into_iter()
        .map(|c| {
            let mut name = f.path.to_string();
            for &a in &f.name_order {
                name.push_str(f.axes[a][c[a]].0);
            }
            name.push_str(f.fixed.0);
            let mut defines = f.fixed.1.clone();
            for (a, &i) in c.iter().enumerate() {
                defines.extend(f.axes[a][i].1.iter().cloned());
            }
            (name, defines)
        })
        .collect()
}
