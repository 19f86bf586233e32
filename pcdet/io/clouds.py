"""Point-cloud files (PLY, PCD, XYZ/PTS/TXT) to numpy, keeping organisation when the file has it."""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError

CLOUD_SUFFIXES = {".ply", ".pcd", ".xyz", ".xyzn", ".pts", ".txt"}


@dataclass
class CloudData:
    """Points as read from a file.

    points : (N, 3) float64, as stored (may hold NaN for organized clouds).
    normals : (N, 3) float64 or None.
    colors : (N, 3) float64 in [0, 1] or None.
    shape : (H, W) when the file is organized (N == H * W), else None.
    """

    points: np.ndarray
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None
    shape: tuple[int, int] | None = None


def _pcd_header(path: Path) -> tuple[dict[str, list[str]], int]:
    """The header fields of a PCD file (``{"WIDTH": ["640"], ...}``, up to ``DATA``) and the byte offset where
    its data starts."""
    fields: dict[str, list[str]] = {}
    with open(path, "rb") as f:
        for _ in range(20):
            line = f.readline().decode("ascii", "replace").split()
            if line and not line[0].startswith("#"):
                fields[line[0].upper()] = line[1:]
                if line[0].upper() == "DATA":
                    break
        return fields, f.tell()


def _pcd_shape(path: Path) -> tuple[int, int] | None:
    fields, _ = _pcd_header(path)
    try:
        width, height = int(fields["WIDTH"][0]), int(fields["HEIGHT"][0])
    except (KeyError, IndexError, ValueError):
        return None
    if width and height and height > 1:
        return height, width
    return None


def _pcd_layout(path: Path) -> tuple[str, int, int, int]:
    """(data kind, points, bytes a point, data offset) of a PCD file whose header is whole and consistent (the
    FIELDS, SIZE, TYPE and COUNT lists of one length, sizes 1, 2, 4 or 8, types I, U or F, WIDTH x HEIGHT =
    POINTS, DATA ascii, binary or binary_compressed); ``InputError`` naming the file otherwise, before open3d's
    reader meets it (given a header cut short it fails to allocate, or reads garbage)."""
    fields, start = _pcd_header(path)
    missing = [k for k in ("FIELDS", "SIZE", "TYPE", "WIDTH", "HEIGHT", "DATA") if not fields.get(k)]
    if missing:
        raise InputError(f"PCD header lacks {', '.join(missing)} (or the header is cut short)", path)
    names, sizes, types = fields["FIELDS"], fields["SIZE"], fields["TYPE"]
    counts = fields.get("COUNT") or ["1"] * len(names)
    try:
        sizes_n, counts_n = [int(v) for v in sizes], [int(v) for v in counts]
        width, height = int(fields["WIDTH"][0]), int(fields["HEIGHT"][0])
        n = int(fields["POINTS"][0]) if fields.get("POINTS") else width * height
    except ValueError as e:
        raise InputError(f"PCD header holds a count that is not a whole number ({e})", path) from None
    kind = fields["DATA"][0].lower()
    if not len(names) == len(sizes_n) == len(types) == len(counts_n) or not {"x", "y", "z"} <= set(names):
        raise InputError("PCD header's FIELDS, SIZE, TYPE and COUNT disagree, or name no x, y, z", path)
    if any(v not in (1, 2, 4, 8) for v in sizes_n) or any(t.upper() not in ("I", "U", "F") for t in types) \
            or any(c < 1 for c in counts_n):
        raise InputError(f"PCD header has a size, type or count PCD does not define (SIZE {' '.join(sizes)}, "
                         f"TYPE {' '.join(types)}, COUNT {' '.join(counts)})", path)
    if width < 0 or height < 0 or n != width * height:
        raise InputError(f"PCD header declares {n} points but WIDTH x HEIGHT is {width} x {height}", path)
    if kind not in ("ascii", "binary", "binary_compressed"):
        raise InputError(f"PCD data kind {kind!r} is not ascii, binary or binary_compressed", path)
    return kind, n, sum(s * c for s, c in zip(sizes_n, counts_n)), start


def check_pcd_complete(path) -> None:
    """``InputError`` when a PCD file's header is not whole (``_pcd_layout``) or the file holds fewer points than
    its header's POINTS (a copy cut short): fewer data lines (ascii), fewer bytes than POINTS x the point size
    (binary). open3d's reader returns such a file's missing points undefined or none at all. Compressed data is
    left to the reader."""
    path = Path(path)
    kind, n, size, start = _pcd_layout(path)
    if kind == "ascii":
        have = _data_lines(path.read_bytes()[start:])
        if have < n:
            raise InputError(f"PCD file is truncated: its header declares {n} points (one line each); the file "
                             f"holds {have} lines after the header", path)
    elif kind == "binary" and (have := path.stat().st_size - start) < n * size:
        raise InputError(f"PCD file is truncated: its header declares {n} points of {size} bytes; the file holds "
                         f"{have} bytes after the header", path)


def _ply_head(path) -> tuple[list[bytes], int | None]:
    """The header lines of a PLY file (up to ``end_header``) and the byte offset where its data starts (None
    without an ``end_header`` line); ``InputError`` when the file is not PLY."""
    with open(path, "rb") as f:
        head = f.read(65536)
    if not head.startswith(b"ply"):
        raise InputError("not a PLY file (it does not start with 'ply')", path)
    end = head.find(b"end_header")
    if end < 0:
        return head.splitlines(), None
    return head[:end].splitlines(), head.find(b"\n", end) + 1 or len(head)


def _ply_layout(lines: list[bytes]) -> tuple[bytes, list[list]]:
    """The format (``b"ascii"``, ``b"binary_little_endian"``, ...) and the elements ``[name, count, bytes of its
    fixed-size properties, bytes of its list counts]``, in file order, of PLY header ``lines``."""
    fmt, elements = b"", []
    for ln in lines:
        w = ln.split()
        if len(w) >= 2 and w[0] == b"format":
            fmt = w[1]
        elif len(w) == 3 and w[0] == b"element" and w[2].isdigit():
            elements.append([w[1].decode("ascii", "replace"), int(w[2]), 0, 0])
        elif len(w) >= 3 and w[0] == b"property" and elements:
            if w[1] == b"list" and len(w) >= 5:
                elements[-1][3] += _PLY_SIZES.get(w[2], 1)
            else:
                elements[-1][2] += _PLY_SIZES.get(w[1], 0)
    return fmt, elements


def ply_elements(path) -> dict[str, int]:
    """``{element name: count}`` from a PLY header, in file order; ``InputError`` when the file is not PLY."""
    return {name: n for name, n, _, _ in _ply_layout(_ply_head(path)[0])[1]}


_PLY_SIZES = {b"char": 1, b"uchar": 1, b"int8": 1, b"uint8": 1, b"short": 2, b"ushort": 2, b"int16": 2,
              b"uint16": 2, b"int": 4, b"uint": 4, b"int32": 4, b"uint32": 4, b"float": 4, b"float32": 4,
              b"double": 8, b"float64": 8}


def _data_lines(data: bytes) -> int:
    """The lines of ``data`` that are not empty (a last line without its newline counts), at the speed of
    ``bytes.count``. Some empty lines of a run of three or more count too, so a complete file is never taken
    for a truncated one."""
    if not data:
        return 0
    return (data.count(b"\n") + (not data.endswith(b"\n")) - data.count(b"\n\n") - data.count(b"\n\r\n")
            - data.startswith((b"\n", b"\r\n")))


def check_ply_complete(path) -> None:
    """``InputError`` when a PLY file holds less data than its header declares (a copy cut short): a binary file
    smaller than its elements need (each list at least its count), an ASCII file with fewer data lines than
    elements. open3d's reader returns such a file's missing points undefined instead of failing."""
    path = Path(path)
    lines, start = _ply_head(path)
    if start is None:
        raise InputError("PLY header has no end_header line", path)
    fmt, elements = _ply_layout(lines)
    declared = ", ".join(f"{n} '{name}'" for name, n, _, _ in elements) + " elements"
    if fmt.startswith(b"binary"):
        need = sum(n * (fixed + lists) for _, n, fixed, lists in elements)
        have = path.stat().st_size - start
        if have < need:
            raise InputError(f"PLY file is truncated: its header declares {declared} ({need} bytes at least); "
                             f"the file holds {have} bytes after the header", path)
    elif fmt == b"ascii":
        need = sum(n for _, n, _, _ in elements)
        have = _data_lines(path.read_bytes()[start:])
        if have < need:
            raise InputError(f"PLY file is truncated: its header declares {declared} (one line each); the file "
                             f"holds {have} lines after the header", path)


_PLY_DTYPES = {b"char": "i1", b"uchar": "u1", b"int8": "i1", b"uint8": "u1", b"short": "i2", b"ushort": "u2",
               b"int16": "i2", b"uint16": "u2", b"int": "i4", b"uint": "u4", b"int32": "i4", b"uint32": "u4",
               b"float": "f4", b"float32": "f4", b"double": "f8", b"float64": "f8"}
_PLY_ORDER = {b"binary_little_endian": "<", b"binary_big_endian": ">"}
_FLOAT_TYPES = (b"float", b"float32", b"double", b"float64")


def _vertex_columns(table, names: list[bytes], types: list[bytes]):
    """(points (N, 3), normals (N, 3) or None, colours (N, 3) in [0, 1] or None), float64, from a vertex table
    whose columns ``table(name)`` are named ``names`` and typed ``types`` (PLY type names)."""
    def columns(*want: bytes) -> np.ndarray | None:
        if not all(c in names for c in want):
            return None
        with np.errstate(invalid="ignore"):  # non-finite values are dropped by the caller, not warned about
            return np.stack([np.asarray(table(c), np.float64).reshape(-1) for c in want], axis=1)

    col = columns(b"red", b"green", b"blue")
    if col is not None and types[names.index(b"red")] not in _FLOAT_TYPES:
        col = col / 255.0  # integer colours are 0-255
    return columns(b"x", b"y", b"z"), columns(b"nx", b"ny", b"nz"), col


def _ply_vertex_header(path: Path):
    """(format, vertex count, [(name, type)] of the vertex properties, data offset) of a PLY whose first element is
    ``vertex`` with scalar properties of known types including x, y and z: the layout numpy reads directly (every
    scan of the Stanford repository, the clouds open3d and PCL write). None for any other layout."""
    lines, start = _ply_head(path)
    if start is None:
        return None
    fmt = next((ln.split()[1] for ln in lines if ln.startswith(b"format ") and len(ln.split()) >= 2), b"")
    elements = [i for i, ln in enumerate(lines) if ln.startswith(b"element ")]
    if not elements or len(lines[elements[0]].split()) != 3:
        return None
    _, name, count = lines[elements[0]].split()
    if name != b"vertex" or not count.isdigit():
        return None
    props = []
    for ln in lines[elements[0] + 1:]:
        w = ln.split()
        if not w or w[0] in (b"comment", b"obj_info"):
            continue
        if w[0] != b"property":
            break
        if len(w) != 3 or w[1] not in _PLY_DTYPES:
            return None  # a list property, or a type numpy is not told here
        props.append((w[2], w[1]))
    names = [n for n, _ in props]
    if not {b"x", b"y", b"z"} <= set(names) or len(set(names)) != len(names):
        return None
    return fmt, int(count), props, start


def _numpy_ply_vertices(path: Path):
    """The vertex element of a PLY in the layout of ``_ply_vertex_header``, read with numpy (binary: one
    ``frombuffer`` over the header's record layout; ASCII: the numbers of the vertex lines), else None."""
    head = _ply_vertex_header(path)
    if head is None:
        return None
    fmt, n, props, start = head
    names, types = [p for p, _ in props], [t for _, t in props]
    if fmt in _PLY_ORDER:
        dtype = np.dtype([(p.decode("ascii", "replace"), _PLY_ORDER[fmt] + _PLY_DTYPES[t]) for p, t in props])
        with open(path, "rb") as f:
            f.seek(start)
            data = f.read(n * dtype.itemsize)
        if len(data) < n * dtype.itemsize:
            raise InputError(f"PLY file is truncated: {n} vertices need {n * dtype.itemsize} bytes, the file holds "
                             f"{len(data)}", path)
        rec = np.frombuffer(data, dtype, count=n)
        return _vertex_columns(lambda c: rec[c.decode("ascii", "replace")], names, types)
    if fmt == b"ascii":
        with open(path, "rb") as f:
            f.seek(start)
            rows = b"".join(f.readline() for _ in range(n))
        try:
            a = np.array(rows.split(), dtype=np.float64)
        except ValueError as e:  # a token that is not a number
            raise InputError(f"vertex list holds a value that is not a number ({e})", path) from None
        if a.size != n * len(props):
            raise InputError(f"vertex list holds {a.size} numbers, expected {n} x {len(props)}", path)
        a = a.reshape(n, len(props))
        return _vertex_columns(lambda c: a[:, names.index(c)], names, types)
    return None


def _ply_with_plyfile(path: Path):
    """(points (N, 3), normals (N, 3) or None, colours (N, 3) in [0, 1] or None) of a PLY's vertex element in any
    other layout (vertex after another element, list properties beside it), read with plyfile."""
    import plyfile

    try:
        data = plyfile.PlyData.read(str(path))
        vertex = data["vertex"]
    except KeyError:
        raise InputError("PLY file has no vertex element", path) from None
    except Exception as e:  # plyfile raises its own and numpy's errors for malformed files: the file's problem
        raise InputError(f"cannot parse PLY ({type(e).__name__}: {e})", path) from None
    props = {p.name.encode(): p for p in vertex.properties}
    names = list(props)
    types = [str(getattr(p, "val_dtype", "")).encode() for p in props.values()]
    types = [b"float" if t.startswith((b"f", b"d")) else b"int" for t in types]
    try:
        return _vertex_columns(lambda c: vertex[c.decode()], names, types)
    except (ValueError, TypeError) as e:
        raise InputError(f"cannot parse PLY vertex element ({e})", path) from None


def read_ply_vertices(path) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """(points (N, 3), normals (N, 3) or None, colours (N, 3) in [0, 1] or None), float64, of a PLY's vertex
    element: numpy on the header's layout where the vertices come first (binary or ASCII; ``nan`` and ``inf``
    read as such), plyfile otherwise. ``InputError`` naming the file for anything unreadable."""
    path = Path(path)
    rows = _numpy_ply_vertices(path)
    pts, nrm, col = rows if rows is not None else _ply_with_plyfile(path)
    if pts is None:
        raise InputError("PLY vertex element has no x, y, z properties", path)
    return pts, nrm, col


def read_cloud(path, keep_invalid: bool = False) -> CloudData:
    """Read a point cloud file.

    Non-finite points are dropped unless ``keep_invalid`` (then an organized cloud keeps its H x W layout).
    Raises ``InputError`` when the file holds no finite point.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: point cloud not found")
    suffix = path.suffix.lower()
    if suffix not in CLOUD_SUFFIXES:
        raise InputError(f"unknown point-cloud format {suffix!r}; expected one of {sorted(CLOUD_SUFFIXES)}", path)
    shape = None
    if path.stat().st_size == 0:
        raise InputError("point cloud is empty (0 bytes)", path)
    if suffix in (".xyz", ".xyzn", ".pts", ".txt"):
        try:
            with warnings.catch_warnings():  # a file without numbers is refused below, in pcdet's words
                warnings.simplefilter("ignore", UserWarning)
                a = np.loadtxt(path, ndmin=2, dtype=float)
        except ValueError as e:
            raise InputError(f"cannot parse as whitespace-separated numbers ({e})", path) from None
        if a.size == 0:
            raise InputError("point cloud is empty", path)
        if a.shape[1] < 3:
            raise InputError(f"expected at least 3 columns (x y z), got {a.shape[1]}", path)
        pts = a[:, :3]
        nrm = a[:, 3:6] if a.shape[1] >= 6 else None
        col = None
    else:
        if suffix == ".ply":
            check_ply_complete(path)
            pts, nrm, col = read_ply_vertices(path)
        else:
            from .._o3d import o3d  # only PCD needs open3d: its import costs about a second of every command

            check_pcd_complete(path)
            pc = o3d.io.read_point_cloud(str(path), remove_nan_points=False, remove_infinite_points=False)
            pts = np.asarray(pc.points, dtype=np.float64)
            nrm = np.asarray(pc.normals, dtype=np.float64) if pc.has_normals() else None
            col = np.asarray(pc.colors, dtype=np.float64) if pc.has_colors() else None
        if len(pts) == 0:
            raise InputError("point cloud is empty or could not be parsed", path)
        if suffix == ".pcd":
            shape = _pcd_shape(path)
            if shape and shape[0] * shape[1] != len(pts):
                shape = None
    finite = np.isfinite(pts).all(axis=1)
    if nrm is not None:
        nrm = np.where(np.isfinite(nrm), nrm, 0.0)
    if not finite.any():
        raise InputError("point cloud holds no finite point", path)
    if not keep_invalid and not finite.all():
        pts, shape = pts[finite], None
        nrm = nrm[finite] if nrm is not None else None
        col = col[finite] if col is not None else None
    return CloudData(pts, nrm, col, shape)
