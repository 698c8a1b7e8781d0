"""Small valid point files (bytes) for the robustness tests to break: PLY, PCD, XYZ and LAS.

Each builder returns the file's bytes for the given (n, 3) points, so a test can truncate, mutate
or lie about them before writing them to ``tmp_path``.
"""

from __future__ import annotations

import io

import numpy as np


def sample_points(n: int = 40, seed: int = 0) -> np.ndarray:
    """(n, 3) float32 points on a jittered unit sphere (enough neighbours for estimation)."""
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    return p.astype(np.float32)


def ply_header(n: int, fmt: str = "binary_little_endian", normals: bool = False) -> bytes:
    props = "property float x\nproperty float y\nproperty float z\n"
    if normals:
        props += "property float nx\nproperty float ny\nproperty float nz\n"
    return f"ply\nformat {fmt} 1.0\nelement vertex {n}\n{props}end_header\n".encode()


def ply_binary(points: np.ndarray, normals: np.ndarray | None = None) -> bytes:
    data = points if normals is None else np.hstack([points, normals])
    return ply_header(len(points), normals=normals is not None) + data.astype("<f4").tobytes()


def ascii_rows(points: np.ndarray) -> bytes:
    return "".join(" ".join(repr(float(v)) for v in row) + "\n" for row in points).encode()


def ply_ascii(points: np.ndarray) -> bytes:
    return ply_header(len(points), "ascii") + ascii_rows(points)


def ply_mesh(vertices: np.ndarray, faces: np.ndarray) -> bytes:
    head = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(vertices)}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    ).encode()
    body = vertices.astype("<f4").tobytes()
    for f in faces:
        body += bytes([3]) + np.asarray(f, dtype="<i4").tobytes()
    return head + body


def ply_mesh_ascii(vertices: np.ndarray, faces) -> bytes:
    """An ASCII PLY mesh whose faces carry a scalar before their index list (as the Armadillo's
    do) and polygons of any size."""
    head = (
        "ply\nformat ascii 1.0\n"
        f"element vertex {len(vertices)}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {len(faces)}\nproperty uchar flags\n"
        "property list uchar int vertex_indices\nend_header\n"
    ).encode()
    rows = "".join(f"7 {len(f)} " + " ".join(map(str, f)) + "\n" for f in faces)
    return head + ascii_rows(vertices) + rows.encode()


def obj_text(vertices: np.ndarray, faces) -> bytes:
    """An OBJ: vertices, a texture coordinate, and faces in the v/vt and v//vn forms."""
    lines = ["# fuzz seed", "o seed"] + [f"v {x:.6g} {y:.6g} {z:.6g}" for x, y, z in vertices]
    lines += ["vt 0 0", "vn 0 0 1"]
    lines += ["f " + " ".join(f"{i + 1}/1" if k % 2 else f"{i + 1}//1" for k, i in enumerate(f))
              for f in faces]
    return ("\n".join(lines) + "\n").encode()


def stl_binary(vertices: np.ndarray, faces) -> bytes:
    corners = np.asarray(vertices, "<f4")[np.asarray(faces)]
    rec = np.zeros(len(corners), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
    rec["v"] = corners
    return b"solid fuzz".ljust(80) + np.uint32(len(rec)).tobytes() + rec.tobytes()


def stl_ascii(vertices: np.ndarray, faces) -> bytes:
    out = ["solid fuzz"]
    for f in faces:
        out += ["facet normal 0 0 1", "outer loop"]
        out += [f"vertex {x:.6g} {y:.6g} {z:.6g}" for x, y, z in np.asarray(vertices)[f]]
        out += ["endloop", "endfacet"]
    return ("\n".join(out + ["endsolid fuzz"]) + "\n").encode()


def pcd_header(n: int, data: str = "binary", width: int | None = None) -> bytes:
    width = n if width is None else width
    return (
        "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
        f"WIDTH {width}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n"
    ).encode()


def pcd_binary(points: np.ndarray) -> bytes:
    return pcd_header(len(points)) + points.astype("<f4").tobytes()


def pcd_ascii(points: np.ndarray) -> bytes:
    return pcd_header(len(points), "ascii") + ascii_rows(points)


def xyz_text(points: np.ndarray) -> bytes:
    return ascii_rows(points)


def las_bytes(points: np.ndarray, scale: float = 1e-4) -> bytes:
    """LAS 1.2, point format 3, written by laspy to memory."""
    import laspy

    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = [scale] * 3
    header.offsets = [0.0, 0.0, 0.0]
    las = laspy.LasData(header)
    las.x, las.y, las.z = np.asarray(points, dtype=np.float64).T
    buf = io.BytesIO()
    las.write(buf)
    return buf.getvalue()


#: Byte offsets of fields in the LAS 1.2 public header.
LAS_OFFSET_TO_POINTS = 96
LAS_N_VLRS = 100
LAS_LEGACY_COUNT = 107
