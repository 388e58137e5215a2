"""Files of a reconstruction: binary PLY point clouds and float32 .npy depth maps, written atomically.

PLY: `binary_little_endian 1.0`, one `vertex` element with float `x y z` (world = projector frame, mm,
CONVENTIONS.md) followed by any extra per-vertex properties, in the order given.
"""

from __future__ import annotations

import os

import numpy as np

from calibration.file import atomic_write

_PLY_TYPES = {
    np.dtype(np.int8): "char",
    np.dtype(np.uint8): "uchar",
    np.dtype(np.int16): "short",
    np.dtype(np.uint16): "ushort",
    np.dtype(np.int32): "int",
    np.dtype(np.uint32): "uint",
    np.dtype(np.float32): "float",
    np.dtype(np.float64): "double",
}


def write_ply(path: str | os.PathLike, points: np.ndarray, **properties: np.ndarray) -> None:
    """Write points (N, 3) (stored as float32) and per-vertex properties (each (N,)) as a binary PLY.

    Property dtypes map to PLY types (int8 char, uint8 uchar, int16 short, uint16 ushort, int32 int,
    uint32 uint, float32 float, float64 double; int64 is stored as int, bool as uchar). ValueError on a
    length mismatch or a name that is not a plain identifier.
    """
    pts = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    n = len(pts)
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    cols = [pts[:, 0], pts[:, 1], pts[:, 2]]
    header = ["ply", "format binary_little_endian 1.0", "comment rig reconstruction: world (projector) frame, mm",
              f"element vertex {n}", "property float x", "property float y", "property float z"]
    for name, values in properties.items():
        if not name.isidentifier() or name in ("x", "y", "z"):
            raise ValueError(f"PLY property name {name!r} must be an identifier other than x, y, z")
        a = np.asarray(values).reshape(-1)
        if len(a) != n:
            raise ValueError(f"PLY property {name!r} has {len(a)} values for {n} points")
        if a.dtype == np.bool_:
            a = a.astype(np.uint8)
        elif a.dtype == np.int64:
            a = a.astype(np.int32)
        elif a.dtype == np.uint64:
            a = a.astype(np.uint32)
        if a.dtype not in _PLY_TYPES:
            raise ValueError(f"PLY property {name!r}: unsupported dtype {a.dtype}")
        header.append(f"property {_PLY_TYPES[a.dtype]} {name}")
        fields.append((name, a.dtype.newbyteorder("<")))
        cols.append(a)
    header.append("end_header")
    rec = np.empty(n, dtype=np.dtype(fields))
    for (name, _), c in zip(fields, cols):
        rec[name] = c
    head = ("\n".join(header) + "\n").encode("ascii")
    atomic_write(path, lambda f: (f.write(head), f.write(rec.tobytes())))


def write_depth_npy(path: str | os.PathLike, depth: np.ndarray) -> None:
    """Write a depth map (H, W) as float32 .npy (camera-frame z in mm, NaN where nothing was measured)."""
    d = np.asarray(depth, dtype=np.float32)
    if d.ndim != 2:
        raise ValueError(f"a depth map is (H, W), got shape {d.shape}")
    atomic_write(path, lambda f: np.save(f, d, allow_pickle=False))
