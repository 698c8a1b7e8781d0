"""The core's table reader (``_core.read_tables``): the numeric rows of PLY, PCD and XYZ data.

The formats' readers parse and check their headers, describe the rows with :func:`spec` and read
them here; several files (the scans of a ``.conf``) are read in parallel by one call.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import _core

#: The core's errors for rows that end early or are not what the header says.
TruncatedData = _core.TruncatedData
MalformedData = _core.MalformedData

#: Core scalar type of each PLY type name.
PLY_SCALARS = {
    "char": "i8", "int8": "i8", "uchar": "u8", "uint8": "u8",
    "short": "i16", "int16": "i16", "ushort": "u16", "uint16": "u16",
    "int": "i32", "int32": "i32", "uint": "u32", "uint32": "u32",
    "float": "f32", "float32": "f32", "double": "f64", "float64": "f64",
}  # fmt: skip

#: Core scalar type of each PCD (TYPE, SIZE).
PCD_SCALARS = {
    ("I", 1): "i8", ("U", 1): "u8", ("I", 2): "i16", ("U", 2): "u16",
    ("I", 4): "i32", ("U", 4): "u32", ("F", 4): "f32", ("F", 8): "f64",
}  # fmt: skip


def spec(path: Path, *, offset: int, encoding: str, columns: list[str], rows: int,
         wanted: list[int], exact_columns: bool = True, commas: bool = False, affine=None,
         grid: tuple | None = None):
    """A ``_core.TableSpec``.

    Parameters
    ----------
    path : Path
    offset : int
        First byte of the rows.
    encoding : {"ascii", "binary_little_endian", "binary_big_endian"}
    columns : list of str
        Core scalar type names (``"f32"``, ``"u8"``, ...) of every column of a row, in order.
    rows : int
        Rows to read, or -1 (ASCII only) for every non-blank, non-comment line to the end.
    wanted : list of int
        Columns returned, in this order.
    exact_columns, commas : bool
        ASCII: rows must hold exactly ``len(columns)`` values (else at least); ``,`` and ``;``
        separate values too.
    affine : tuple of ((3, 3), (3,)) float, optional
        ``(m, t)``: positions ``p`` (rows) are returned as ``p @ m + t``.
    grid : (cells, columns) or (cells, columns, count type, index type), optional
        With a row count: the first ``cells`` lines (binary: records) after the rows are a PLY
        ``range_grid`` of ``columns`` cells per grid row, read into :attr:`TableData.grid`;
        binary records hold a count and that many row indices of the two core scalar types
        (default ``"u8"`` and ``"i32"``).
    """
    s = _core.TableSpec()
    s.path = str(path)
    s.offset = int(offset)
    s.encoding = getattr(_core.Encoding, encoding)
    s.columns = [getattr(_core.Scalar, c) for c in columns]
    s.rows = int(rows)
    s.wanted = [int(w) for w in wanted]
    s.exact_columns = bool(exact_columns)
    s.commas = bool(commas)
    if affine is not None:
        m, t = affine
        s.transform = True
        s.affine = [float(v) for v in np.asarray(m, dtype=np.float64).reshape(9)] + [
            float(v) for v in np.asarray(t, dtype=np.float64).reshape(3)]
    if grid is not None:
        s.grid_cells, s.grid_cols = int(grid[0]), int(grid[1])
        if len(grid) > 2:
            s.grid_count = getattr(_core.Scalar, grid[2])
            s.grid_index = getattr(_core.Scalar, grid[3])
    return s


@dataclass
class TableData:
    """The rows read for one spec.

    Attributes
    ----------
    values : (rows, len(wanted)) float64
    lines_after : int
        ASCII with a row count: the lines after the rows (the file's other elements).
    lo, hi, mean : (3,) float64
        Bounds and mean of the positions (the first three wanted columns) as read, before the
        spec's affine map, over the rows whose three values are finite (``finite`` of them).
    grid : (rows, 2) int32 or None
        With a spec's ``grid``: each row's grid row and column (-1: in no cell).
    """

    values: np.ndarray
    lines_after: int
    lo: np.ndarray
    hi: np.ndarray
    mean: np.ndarray
    finite: int
    grid: np.ndarray | None = None


def read(specs: list, threads: int = 0) -> list[TableData]:
    """Read every spec (in parallel when there are several).

    Raises
    ------
    TruncatedData, MalformedData
        The first failing spec's error (the caller names the file and the format).
    """
    return [_table_data(d, d["values"]) for d in _core.read_tables(list(specs), threads)]


def joinable(specs: list) -> bool:
    """Whether :func:`read_joined` can read these specs: each has a row count, and they all
    return the same number of columns."""
    return bool(specs) and all(s.rows >= 0 for s in specs) and len(
        {len(s.wanted) for s in specs}) == 1


def read_joined(specs: list, threads: int = 0) -> tuple[np.ndarray, list[TableData]]:
    """Read every spec as :func:`read` does, into one array: the rows of the specs one after
    the other (no copy to join them afterwards). The specs must be :func:`joinable`.

    Returns
    -------
    values : (total rows, columns) float64
    tables : list of TableData
        Per spec; each one's ``values`` is its block of ``values`` (a view).

    Raises
    ------
    TruncatedData, MalformedData
        As :func:`read`; TruncatedData also when a spec's row count is more than its file can
        hold (checked before anything is read).
    """
    values, dicts = _core.read_tables_joined(list(specs), threads)
    tables, at = [], 0
    for spec, d in zip(specs, dicts):
        tables.append(_table_data(d, values[at:at + spec.rows]))
        at += spec.rows
    return values, tables


def _table_data(d: dict, values: np.ndarray) -> TableData:
    n = int(d["finite"])
    return TableData(values, int(d["lines_after"]), np.array(d["lo"]), np.array(d["hi"]),
                     np.array(d["sum"]) / max(n, 1), n, d.get("grid"))
