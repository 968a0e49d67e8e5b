"""Telemetry CSV files: :func:`read_telemetry` builds a :class:`~._telemetry.Telemetry` from one,
:func:`write_telemetry` writes one.

A file is comma separated, UTF-8, with a header row of column names (line 1) and one row per
sample. Columns, in any order (spaces around names and values are ignored):

=====================  ==========================================================  ==============
columns                meaning                                                     channel
=====================  ==========================================================  ==============
``t``                  time [s]; required, strictly increasing, never empty        —
``x, y, z``            position [m], space frame                                   ``position``
``qw, qx, qy, qz``     unit quaternion body → space, scalar first                  ``attitude``
``roll, pitch, yaw``   Euler angles [rad], R = Rz(yaw)·Ry(pitch)·Rx(roll) (ZYX)    ``attitude``
``p, q, r``            body angular rates [rad/s]                                  ``rates``
``u, v, w``            body velocity [m/s]                                         ``velocity``
=====================  ==========================================================  ==============

- An empty cell is a missing sample; ``nan`` and ``inf`` are not allowed.
- Position, rates and velocity: any subset of a group's columns (``t,z`` is a depth gauge);
  an absent column is a component that is never observed.
- Attitude: either all four quaternion columns or all three Euler columns, not both; in each
  row the attitude cells are all filled or all empty. A quaternion is normalised on reading;
  one whose norm differs from 1 by more than 1e-3 is an error.
- At least 2 rows of data; blank lines are skipped.

A channel is in the file when one of its columns is; each needs a noise level in ``sigma``.
"""

import csv
import math

import numpy as np

from ._telemetry import Telemetry

QUATERNION = ("qw", "qx", "qy", "qz")
EULER = ("roll", "pitch", "yaw")
VECTOR_COLUMNS = {"position": ("x", "y", "z"), "rates": ("p", "q", "r"), "velocity": ("u", "v", "w")}
COLUMNS = ("t", *VECTOR_COLUMNS["position"], *QUATERNION, *EULER, *VECTOR_COLUMNS["rates"], *VECTOR_COLUMNS["velocity"])


def _quaternion_to_matrix(q):
    """Rotation matrices (m, 3, 3) of unit quaternions q = (w, x, y, z) (m, 4), scalar first,
    Hamilton convention: R v = q ⊗ (0, v) ⊗ q̄."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def _matrix_to_quaternion(R):
    """Unit quaternions (m, 4), scalar first with w ≥ 0, of rotation matrices R (m, 3, 3): the
    inverse of :func:`_quaternion_to_matrix` (Shepperd's method: each row of ``c`` is 4·q_k·q
    for one k, and the one with the largest q_k² is used)."""
    d = np.diagonal(R, axis1=-2, axis2=-1)
    tr = d.sum(-1)
    a, b, e = R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]
    f, g, h = R[:, 0, 1] + R[:, 1, 0], R[:, 0, 2] + R[:, 2, 0], R[:, 1, 2] + R[:, 2, 1]
    c = np.stack([
        np.stack([1 + tr, a, b, e], -1),
        np.stack([a, 1 + 2 * d[:, 0] - tr, f, g], -1),
        np.stack([b, f, 1 + 2 * d[:, 1] - tr, h], -1),
        np.stack([e, g, h, 1 + 2 * d[:, 2] - tr], -1),
    ], 1)
    q = c[np.arange(len(R)), np.argmax(np.diagonal(c, axis1=1, axis2=2), axis=1)]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[:, :1] < 0, -q, q)


def _euler_to_matrix(angles):
    """Rotation matrices (m, 3, 3) R = Rz(yaw) Ry(pitch) Rx(roll) of ZYX Euler angles
    (m, 3) = (roll, pitch, yaw) [rad] (body → space: roll about x, then pitch about y, then yaw
    about z, all about the space axes)."""
    (cr, cp, cy), (sr, sp, sy) = np.cos(angles).T, np.sin(angles).T
    return np.stack([
        np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
        np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
        np.stack([-sp, cp * sr, cp * cr], -1),
    ], -2)


def _matrix_to_euler(R):
    """ZYX Euler angles (m, 3) = (roll, pitch, yaw), pitch in [−π/2, π/2], of rotation matrices R
    (m, 3, 3): the inverse of :func:`_euler_to_matrix`. Yaw and pitch are read off
    R·Rx(roll)ᵀ = Rz(yaw)·Ry(pitch), which stays accurate near pitch = ±π/2."""
    roll = np.arctan2(R[:, 2, 1], R[:, 2, 2])
    M = R @ np.swapaxes(_euler_to_matrix(np.stack([roll, 0 * roll, 0 * roll], -1)), -1, -2)
    return np.stack([roll, np.arctan2(-M[:, 2, 0], M[:, 2, 2]), np.arctan2(-M[:, 0, 1], M[:, 1, 1])], -1)


def _number(path, line, name, cell):
    """The value of a cell (NaN if empty)."""
    if not cell:
        return math.nan
    try:
        value = float(cell)
    except ValueError:
        raise ValueError(f"{path}, line {line}, column {name!r}: expected a number or an empty cell, got {cell!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"{path}, line {line}, column {name!r}: got {cell!r}; a missing value is an empty cell")
    return value


def _check_header(path, names):
    for name in names:
        if name not in COLUMNS:
            raise ValueError(f"{path}, line 1: unknown column {name!r}; allowed columns: {', '.join(COLUMNS)}")
        if names.count(name) > 1:
            raise ValueError(f"{path}, line 1: duplicate column {name!r}")
    if "t" not in names:
        raise ValueError(f"{path}, line 1: missing column 't' (time [s])")
    for group in (QUATERNION, EULER):
        missing = [n for n in group if n not in names]
        if 0 < len(missing) < len(group):
            raise ValueError(f"{path}, line 1: attitude columns {', '.join(group)} come together; missing {', '.join(missing)}")
    if QUATERNION[0] in names and EULER[0] in names:
        raise ValueError(f"{path}, line 1: both quaternion ({', '.join(QUATERNION)}) and Euler angle ({', '.join(EULER)}) columns; give one of them")
    if names == ["t"]:
        raise ValueError(f"{path}, line 1: no data columns besides 't'")


def read_telemetry(path, *, sigma) -> Telemetry:
    """The :class:`~._telemetry.Telemetry` in the CSV file ``path`` (format: the module
    docstring), with noise levels ``sigma`` {channel: σ} for the channels in the file (entries
    for other channels are ignored)."""
    with open(path, newline="", encoding="utf-8-sig") as f:
        reader = csv.reader(f)
        header = next(reader, None)
        if not header:
            raise ValueError(f"{path}, line 1: expected a header row of column names, got {'an empty file' if header is None else 'an empty line'}")
        names = [name.strip() for name in header]
        _check_header(path, names)
        rows, lines = [], []
        for row in reader:
            if not row:
                continue
            if len(row) != len(names):
                raise ValueError(f"{path}, line {reader.line_num}: expected {len(names)} cells (one per column), got {len(row)}")
            rows.append([_number(path, reader.line_num, n, cell.strip()) for n, cell in zip(names, row)])
            lines.append(reader.line_num)
    if len(rows) < 2:
        raise ValueError(f"{path}: expected at least 2 rows of data, got {len(rows)}")
    data = np.array(rows, dtype=np.float64)
    column = {n: data[:, j] for j, n in enumerate(names)}
    t = column["t"]
    if np.any(np.isnan(t)):
        raise ValueError(f"{path}, line {lines[int(np.argmax(np.isnan(t)))]}, column 't': empty time")
    if np.any(np.diff(t) <= 0):
        i = int(np.argmax(np.diff(t) <= 0))
        raise ValueError(f"{path}, line {lines[i + 1]}: time t = {float(t[i + 1])!r} does not increase from t = {float(t[i])!r} on line {lines[i]}")

    channels = {c: np.stack([column.get(n, np.full(len(t), np.nan)) for n in group], -1)
                for c, group in VECTOR_COLUMNS.items() if any(n in names for n in group)}
    for group in (QUATERNION, EULER):
        if group[0] not in names:
            continue
        values = np.stack([column[n] for n in group], -1)
        empty = np.isnan(values)
        partial = np.any(empty, 1) & ~np.all(empty, 1)
        if np.any(partial):
            i = int(np.argmax(partial))
            raise ValueError(f"{path}, line {lines[i]}: attitude cells {', '.join(group)} are partly empty "
                             f"(empty: {', '.join(n for n, e in zip(group, empty[i]) if e)}); give all of them or none")
        if group is QUATERNION:
            norm = np.linalg.norm(values, axis=-1, keepdims=True)
            bad = np.abs(norm[:, 0] - 1) > 1e-3
            if np.any(bad):
                i = int(np.argmax(bad))
                raise ValueError(f"{path}, line {lines[i]}: quaternion norm {float(norm[i, 0])!r} differs from 1 by more than 1e-3")
            channels["attitude"] = _quaternion_to_matrix(values / norm)
        else:
            channels["attitude"] = _euler_to_matrix(values)

    if not isinstance(sigma, dict):
        raise ValueError(f"sigma: expected a dict {{channel: noise level}}, got {sigma!r}")
    for c in channels:
        if c not in sigma:
            raise ValueError(f"{path}: the file has channel {c!r} but sigma has no noise level for it (sigma = {sigma!r})")
    return Telemetry(t, sigma={c: sigma[c] for c in channels}, **channels)


def write_telemetry(path, telemetry, *, attitude="quaternion"):
    """Write ``telemetry`` (a :class:`~._telemetry.Telemetry`) to the CSV file ``path`` (format:
    the module docstring): the columns with any observed sample, missing samples as empty cells,
    floats with repr precision (``read_telemetry`` gives the values back to round-off); the
    attitude as quaternions with qw ≥ 0 (``attitude="quaternion"``) or ZYX Euler angles
    (``"euler"``). The noise levels are not written."""
    if attitude not in ("quaternion", "euler"):
        raise ValueError(f"attitude: expected 'quaternion' or 'euler', got {attitude!r}")
    columns = {"t": np.asarray(telemetry.t, dtype=np.float64)}
    for c in telemetry.channels:
        values, mask = np.asarray(telemetry.values[c], dtype=np.float64), np.asarray(telemetry.mask[c]) > 0
        if c == "attitude":
            names = QUATERNION if attitude == "quaternion" else EULER
            values = _matrix_to_quaternion(values) if attitude == "quaternion" else _matrix_to_euler(values)
            mask = np.repeat(mask[:, :1], len(names), axis=1)
        else:
            names = VECTOR_COLUMNS[c]
        for j, name in enumerate(names):
            if np.any(mask[:, j]):
                columns[name] = np.where(mask[:, j], values[:, j], np.nan)
    with open(path, "w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f, lineterminator="\n")
        writer.writerow(columns)
        writer.writerows(["" if math.isnan(v) else repr(float(v)) for v in row] for row in zip(*columns.values()))
