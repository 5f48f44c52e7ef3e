#!/usr/bin/env python3
"""Reads a binary little-endian PLY (a triangle mesh, or a point cloud such as
`svraster export --format ply`) with numpy, independently of our Rust writers, and
prints one JSON object: vertex and face counts, the vertex properties, the bounding box,
and for meshes the total area and the number of edges not shared by exactly two faces.

    python3 tools/ply_read.py mesh.ply
"""
import json
import sys

import numpy as np

TYPES = {"char": "i1", "uchar": "u1", "short": "<i2", "ushort": "<u2", "int": "<i4",
         "uint": "<u4", "float": "<f4", "double": "<f8", "int8": "i1", "uint8": "u1",
         "int32": "<i4", "uint32": "<u4", "float32": "<f4", "float64": "<f8"}


def read(path):
    data = open(path, "rb").read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    lines = data[:end].decode("ascii").splitlines()
    assert lines[0] == "ply", "not a PLY file"
    assert lines[1] == "format binary_little_endian 1.0", lines[1]
    elements = []
    for line in lines[2:]:
        w = line.split()
        if w[0] == "element":
            elements.append([w[1], int(w[2]), []])
        elif w[0] == "property":
            elements[-1][2].append(w[1:])
    pos = end
    out = {}
    for name, count, props in elements:
        if props and props[0][0] == "list":
            _, ctype, itype, pname = props[0]
            assert len(props) == 1
            dt = np.dtype([("n", TYPES[ctype]), ("i", TYPES[itype], (3,))])
            arr = np.frombuffer(data, dtype=dt, count=count, offset=pos)
            assert (arr["n"] == 3).all(), "non-triangle face"
            out[name] = arr["i"].astype(np.int64)
            pos += dt.itemsize * count
        else:
            dt = np.dtype([(p[1], TYPES[p[0]]) for p in props])
            out[name] = np.frombuffer(data, dtype=dt, count=count, offset=pos)
            pos += dt.itemsize * count
    assert pos == len(data), f"{len(data) - pos} trailing bytes"
    return out


def main():
    m = read(sys.argv[1])
    v = m["vertex"]
    f = m.get("face", np.zeros((0, 3), dtype=np.int64))
    xyz = np.stack([v["x"], v["y"], v["z"]], 1).astype(np.float64)
    a, b, c = xyz[f[:, 0]], xyz[f[:, 1]], xyz[f[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum()
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    print(json.dumps({
        "vertices": int(len(v)),
        "faces": int(len(f)),
        "properties": list(v.dtype.names),
        "min": xyz.min(0).tolist() if len(v) else None,
        "max": xyz.max(0).tolist() if len(v) else None,
        "area": float(area),
        "open_edges": int((counts != 2).sum()),
        "max_index": int(f.max()) if len(f) else -1,
    }))


if __name__ == "__main__":
    main()
