#!/usr/bin/env python3
"""Writes an SVRaster checkpoint without PyTorch, for the importer's tests.

    svraster_checkpoint.py MODEL.safetensors OUT.pt [--active D] [--quantize]
                           [--drop KEY] [--set KEY=VALUE]

MODEL.safetensors is a model of ours (not quantized; the layout documented in
src/scene/checkpoint/mod.rs, read here with the standard library): its voxels' corner
densities are looked up by their keys x<<34 | y<<17 | z as that layout says. --active D
records active_sh_degree D (default: the model's degree; the SH rows are all kept).

The checkpoint is laid out as NVlabs/svraster's SVInOut.save (src/sparse_voxel_gears/io.py)
has torch.save write it: a ZIP archive ARCHIVE/{data.pkl, byteorder, version, data/KEY},
data.pkl a protocol-2 pickle of the state dict in which every tensor is
torch._utils._rebuild_tensor_v2(storage, offset, size, stride, requires_grad, hooks) and
every storage the persistent id ('storage', torch.<Type>Storage, key, 'cpu', numel).

The grid points are built as SVRaster builds them: octree_utils.build_grid_pts_link — the
voxels' corner coordinates at level 16 (gen_gridpoints_coordinate, octpath_2_ijk of
cuda/src/utils.cu), their unique (x, y, z) rows sorted, the inverse as vox_key — so
`_geo_grid_pts[vox_key[v][c]]` is corner c of voxel v. With --quantize every channel is
stored as SVRaster's quantize_state_dict stores it (index bytes into a 256-entry codebook;
here the codebook is 256 quantiles and the index the nearest entry), and
EXPECTED_corners.f32 (N x 8) / EXPECTED_sh0.f32 / EXPECTED_shs.f32 beside OUT.pt hold the
values SVRaster's dequantization gives back. --drop KEY leaves an entry out and --set
breaks one (active_sh_degree=INT, scene_extent=FLOAT, octlevel=INT for the first voxel,
geo_extra=1: one grid point too many), for the tests of refused files.
"""

import bisect
import collections
import json
import os
import pickle
import struct
import sys
import types
import zipfile

MAX_NUM_LEVELS = 16
SUBTREE_SHIFT = [(0, 0, 0), (0, 0, 1), (0, 1, 0), (0, 1, 1),
                 (1, 0, 0), (1, 0, 1), (1, 1, 0), (1, 1, 1)]


def octpath_2_ijk(path, lv):
    """cuda/src/utils.cu octpath_2_ijk_cuda."""
    path >>= 3 * (MAX_NUM_LEVELS - lv)
    i = j = k = 0
    for l in range(MAX_NUM_LEVELS):
        bits = path & 0b111
        i |= ((bits & 0b100) >> 2) << l
        j |= ((bits & 0b010) >> 1) << l
        k |= (bits & 0b001) << l
        path >>= 3
    return i, j, k


def corner_coords(p, lv):
    """gen_gridpoints_coordinate: a voxel's 8 corners at level 16, in SUBTREE_SHIFT order."""
    i, j, k = octpath_2_ijk(p, lv)
    s = MAX_NUM_LEVELS - lv
    return [((i + dx) << s, (j + dy) << s, (k + dz) << s) for dx, dy, dz in SUBTREE_SHIFT]


def build_grid_pts_link(octpath, octlevel):
    """src/utils/octree_utils.py build_grid_pts_link: (grid_pts_key, vox_key)."""
    gridpts = [corner_coords(p, lv) for p, lv in zip(octpath, octlevel)]
    keys = sorted({g for corners in gridpts for g in corners})
    index = {g: n for n, g in enumerate(keys)}
    vox_key = [[index[g] for g in corners] for corners in gridpts]
    return keys, vox_key


# --- torch's pickling, without torch --------------------------------------------------
torch = types.ModuleType("torch")
torch_utils = types.ModuleType("torch._utils")


def _rebuild_tensor_v2(*args):
    raise RuntimeError("only pickled here, never loaded")


_rebuild_tensor_v2.__module__ = "torch._utils"
torch_utils._rebuild_tensor_v2 = _rebuild_tensor_v2
torch._utils = torch_utils
STORAGE_TYPES = {}
for name, fmt in [("FloatStorage", "f"), ("LongStorage", "q"), ("CharStorage", "b"),
                  ("ByteStorage", "B")]:
    cls = type(name, (), {"__module__": "torch"})
    setattr(torch, name, cls)
    STORAGE_TYPES[fmt] = cls
sys.modules["torch"] = torch
sys.modules["torch._utils"] = torch_utils


class Storage:
    def __init__(self, key, fmt, values):
        self.key, self.fmt, self.values = key, fmt, values

    def data(self):
        return struct.pack("<%d%s" % (len(self.values), self.fmt), *self.values)


class Tensor:
    def __init__(self, storage, shape):
        self.storage, self.shape = storage, tuple(shape)

    def __reduce_ex__(self, protocol):
        stride, acc = [], 1
        for d in reversed(self.shape):
            stride.insert(0, acc)
            acc *= d
        return (_rebuild_tensor_v2,
                (self.storage, 0, self.shape, tuple(stride), False, collections.OrderedDict()))


class Pickler(pickle.Pickler):
    def persistent_id(self, obj):
        if isinstance(obj, Storage):
            return ("storage", STORAGE_TYPES[obj.fmt], obj.key, "cpu", len(obj.values))
        return None


def main():
    model, out = sys.argv[1], sys.argv[2]
    args = sys.argv[3:]
    quantize = "--quantize" in args
    drops = [args[i + 1] for i, a in enumerate(args) if a == "--drop"]
    sets = dict(args[i + 1].split("=", 1) for i, a in enumerate(args) if a == "--set")
    raw = open(model, "rb").read()
    hlen = struct.unpack("<Q", raw[:8])[0]
    header = json.loads(raw[8:8 + hlen])
    meta = header.pop("__metadata__")
    base = 8 + hlen
    fmt = {"U64": "Q", "U8": "B", "F32": "f"}

    def tensor_values(name):
        h = header[name]
        b, e = h["data_offsets"]
        f = fmt[h["dtype"]]
        return list(struct.unpack("<%d%s" % ((e - b) // struct.calcsize(f), f), raw[base + b:base + e])), h["shape"]

    octpath, _ = tensor_values("octpath")
    octlevel, _ = tensor_values("octlevel")
    geo_ours, _ = tensor_values("geo_grid_pts")
    sh0, _ = tensor_values("sh0")
    shs, shs_shape = tensor_values("shs")
    n, rows = len(octpath), shs_shape[1]
    degree = int(meta["sh_degree"])
    active = int(args[args.index("--active") + 1]) if "--active" in args else degree
    meta = {"active_sh_degree": active, "scene_center": json.loads(meta["scene_center"]),
            "scene_extent": float(meta["scene_extent"])}
    meta["inside_extent"] = meta["scene_extent"]
    # Our file: corner densities by key x<<34 | y<<17 | z, ascending.
    our_keys = sorted({(x << 34) | (y << 17) | z
                       for p, lv in zip(octpath, octlevel)
                       for x, y, z in corner_coords(p, lv)})
    assert len(our_keys) == len(geo_ours), "grid points do not match the voxels"
    corners = []
    for p, lv in zip(octpath, octlevel):
        for x, y, z in corner_coords(p, lv):
            corners.append(geo_ours[bisect.bisect_left(our_keys, (x << 34) | (y << 17) | z)])

    keys, vox_key = build_grid_pts_link(octpath, octlevel)
    geo = [None] * len(keys)
    for v in range(n):
        for c in range(8):
            g = corners[8 * v + c]
            # Shared corners carry one value: the dump must agree with itself.
            assert geo[vox_key[v][c]] in (None, g), "voxels disagree on a shared corner"
            geo[vox_key[v][c]] = g

    storages = []

    def tensor(fmt, values, shape):
        s = Storage(str(len(storages)), fmt, values)
        storages.append(s)
        return Tensor(s, shape)

    def quantization(values, shape):
        book = sorted(values)
        book = [book[min(len(book) - 1, (len(book) - 1) * q // 255)] for q in range(256)]
        index = []
        for x in values:
            i = min(255, bisect.bisect_left(book, x))
            if i > 0 and abs(book[i - 1] - x) <= abs(book[i] - x):
                i -= 1
            index.append(i)
        deq = [struct.unpack("<f", struct.pack("<f", book[i]))[0] for i in index]
        return {"index": tensor("B", index, shape), "codebook": tensor("f", book, (256,))}, deq

    state = {
        "active_sh_degree": meta["active_sh_degree"],
        "scene_center": tensor("f", meta["scene_center"], (3,)),
        "inside_extent": tensor("f", [meta["inside_extent"]], (1,)),
        "scene_extent": tensor("f", [meta["scene_extent"]], (1,)),
        "octpath": tensor("q", octpath, (n, 1)),
        "octlevel": tensor("b", octlevel, (n, 1)),
    }
    if quantize:
        state["_geo_grid_pts"], geo_q = quantization(geo, (len(geo), 1))
        sh0_q, state["_sh0"] = [0.0] * (3 * n), []
        for c in range(3):
            q, deq = quantization(sh0[c::3], (n, 1))
            state["_sh0"].append(q)
            sh0_q[c::3] = deq
        shs_q, state["_shs"] = [0.0] * (3 * rows * n), []
        for k in range(rows):
            vals = [shs[(v * rows + k) * 3 + c] for v in range(n) for c in range(3)]
            q, deq = quantization(vals, (n, 1, 3))
            state["_shs"].append(q)
            for v in range(n):
                for c in range(3):
                    shs_q[(v * rows + k) * 3 + c] = deq[3 * v + c]
        state["quantized"] = True
        base = os.path.dirname(os.path.abspath(out))
        for name, vals in [("corners", [geo_q[vox_key[v][c]] for v in range(n) for c in range(8)]),
                           ("sh0", sh0_q), ("shs", shs_q)]:
            with open(os.path.join(base, "EXPECTED_%s.f32" % name), "wb") as f:
                f.write(struct.pack("<%df" % len(vals), *vals))
    else:
        state["_geo_grid_pts"] = tensor("f", geo, (len(geo), 1))
        state["_sh0"] = tensor("f", sh0, (n, 3))
        state["_shs"] = tensor("f", shs, (n, rows, 3))
        state["quantized"] = False

    for key in drops:
        del state[key]
    for key, value in sets.items():
        if key == "active_sh_degree":
            state[key] = int(value)
        elif key == "scene_extent":
            state[key].storage.values = [float(value)]
        elif key == "octlevel":
            state[key].storage.values[0] = int(value)
        elif key == "geo_extra":
            t = state["_geo_grid_pts"]
            t.storage.values = t.storage.values + [0.0]
            t.shape = (len(t.storage.values), 1)
        else:
            raise SystemExit("--set %s: unknown" % key)

    import io
    buf = io.BytesIO()
    Pickler(buf, protocol=2).dump(state)
    archive = os.path.splitext(os.path.basename(out))[0]
    with zipfile.ZipFile(out, "w", zipfile.ZIP_STORED) as z:
        z.writestr(archive + "/data.pkl", buf.getvalue())
        z.writestr(archive + "/byteorder", "little")
        for s in storages:
            z.writestr(archive + "/data/" + s.key, s.data())
        z.writestr(archive + "/version", "3\n")
        z.writestr(archive + "/.data/serialization_id", "0" * 40)
    print("%s: %d voxels, %d grid points, %d storages%s" %
          (out, n, len(geo), len(storages), ", quantized" if quantize else ""))


if __name__ == "__main__":
    main()
