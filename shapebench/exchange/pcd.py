"""Reading and writing PCD files (the Point Cloud Library's format; PCN ships its partial and
complete clouds in it, and completions made elsewhere come back in it). Here, in the core, because
both a dataset (``shapebench_pointclouds``) and the ``files`` method read it: the method's key
covers this file alone, not a dataset package.

A PCD file is a text header (``VERSION``, ``FIELDS``, ``SIZE``, ``TYPE``, ``COUNT``, ``WIDTH``,
``HEIGHT``, ``VIEWPOINT``, ``POINTS``, ``DATA``) followed by the points, ``DATA ascii`` (one point
per line) or ``DATA binary`` (packed little-endian records in field order). ``binary_compressed``
(LZF, column-major) is refused with a line that says how to convert it: PoinTr's reader does not
read it either. Only ``x``, ``y`` and ``z`` are returned; points with a non-finite coordinate (how
PCD marks an invalid point of an organised cloud) are dropped.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from shapebench.api.dataset import ObjectLoadError

#: (TYPE, SIZE) of a PCD field -> its numpy dtype (PCD is little-endian).
_TYPES = {
    (kind, size): f"<{code}{size}"
    for kind, code in (("F", "f"), ("U", "u"), ("I", "i"))
    for size in (1, 2, 4, 8)
    if not (kind == "F" and size < 4)
}


def read_pcd(path: Path | str) -> np.ndarray:
    """The ``(n, 3)`` float32 points of the PCD file ``path``; :class:`ObjectLoadError` naming
    the file and the problem otherwise."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ObjectLoadError(f"cannot read point cloud {path}: {exc.strerror or exc}") from exc
    header: dict[str, list[str]] = {}
    offset = 0
    while True:
        end = raw.find(b"\n", offset)
        if end < 0:
            raise ObjectLoadError(f"point cloud {path} is not a PCD file (no DATA line)")
        line = raw[offset:end].decode("ascii", errors="replace").strip()
        offset = end + 1
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        header[key.upper()] = values
        if key.upper() == "DATA":
            break
    return _points(path, header, raw[offset:])


def _points(path: Path, header: dict[str, list[str]], body: bytes) -> np.ndarray:
    fields = header.get("FIELDS", [])
    if not {"x", "y", "z"} <= set(fields):
        raise ObjectLoadError(f"point cloud {path} has no x, y, z fields (FIELDS {fields})")
    sizes = [int(s) for s in header.get("SIZE", ["4"] * len(fields))]
    types = header.get("TYPE", ["F"] * len(fields))
    counts = [int(c) for c in header.get("COUNT", ["1"] * len(fields))]
    n = int(header.get("POINTS", header.get("WIDTH", ["0"]))[0])
    data = header["DATA"][0].lower() if header.get("DATA") else ""
    if data == "binary_compressed":
        raise ObjectLoadError(
            f"point cloud {path} is binary_compressed PCD, which shapebench does not read; "
            "re-save it uncompressed (Open3D: o3d.io.write_point_cloud(path, pcd, "
            "compressed=False); PCL: pcl_convert_pcd_ascii_binary in.pcd out.pcd 1)"
        )
    columns: list[tuple[str, str, tuple[int, ...]]] = []
    for name, size, kind, count in zip(fields, sizes, types, counts, strict=False):
        if (kind, size) not in _TYPES:
            raise ObjectLoadError(f"point cloud {path}: field {name} has TYPE {kind} SIZE {size}")
        columns.append((name, _TYPES[(kind, size)], (count,) if count > 1 else ()))
    if data == "ascii":
        text = body.decode("ascii", errors="replace").split()
        width = sum(max(c, 1) for c in counts)
        values = np.array(text[: n * width], dtype=np.float64).reshape(-1, width)
        index = {}
        at = 0
        for name, count in zip(fields, counts, strict=False):
            index[name] = at
            at += max(count, 1)
        xyz = values[:, [index["x"], index["y"], index["z"]]]
    elif data == "binary":
        dtype = np.dtype([(c[0], c[1], c[2]) if c[2] else (c[0], c[1]) for c in columns])
        if len(body) < n * dtype.itemsize:
            raise ObjectLoadError(
                f"point cloud {path} is truncated: {len(body)} bytes for {n} points of "
                f"{dtype.itemsize} bytes"
            )
        records = np.frombuffer(body[: n * dtype.itemsize], dtype=dtype, count=n)
        xyz = np.stack([records["x"], records["y"], records["z"]], axis=1).astype(np.float64)
    else:
        raise ObjectLoadError(f"point cloud {path}: unknown DATA {data!r} (ascii or binary)")
    xyz = xyz[np.isfinite(xyz).all(axis=1)]
    if len(xyz) == 0:
        raise ObjectLoadError(f"point cloud {path} holds no valid points")
    return xyz.astype(np.float32)


def write_pcd(path: Path | str, points: np.ndarray, binary: bool = True) -> None:
    """Write ``points`` (``(n, 3)``) as a PCD v0.7 file of float32 x, y, z (``DATA binary``, or
    ``ascii`` when ``binary`` is False), the way PCN's and Open3D's writers do."""
    pts = np.ascontiguousarray(points, dtype="<f4").reshape(-1, 3)
    n = len(pts)
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\n"
        "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
        f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\n"
        f"DATA {'binary' if binary else 'ascii'}\n"
    )
    body = (
        pts.tobytes()
        if binary
        else "".join(f"{x:.8g} {y:.8g} {z:.8g}\n" for x, y, z in pts).encode()
    )
    Path(path).write_bytes(header.encode("ascii") + body)
