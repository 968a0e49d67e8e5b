"""Telemetry CSV files (vi_jax/fitting/_csv.py): round trips, the two attitude forms against
rotations built independently (Rodrigues' formula, quaternion products), partial position
columns, the error messages and the example file docs/telemetry_example.csv."""

import re
from pathlib import Path

import numpy as np
import pytest

from vi_jax.fitting._csv import read_telemetry, write_telemetry
from vi_jax.fitting._telemetry import Telemetry

EXAMPLE = Path(__file__).resolve().parent.parent / "docs" / "telemetry_example.csv"
E = np.eye(3)


def rodrigues(axis, angle):
    """Rotation by ``angle`` about the unit vector ``axis``: I + sin θ K + (1 − cos θ) K²."""
    n = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    K = np.array([[0, -n[2], n[1]], [n[2], 0, -n[0]], [-n[1], n[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def axis_quaternion(axis, angle):
    n = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * n])


def hamilton(a, b):
    w1, v1, w2, v2 = a[0], a[1:], b[0], b[1:]
    return np.concatenate([[w1 * w2 - v1 @ v2], w1 * v2 + w2 * v1 + np.cross(v1, v2)])


def write_text(tmp_path, text, name="telemetry.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def random_telemetry(rng, m=40):
    t = np.cumsum(rng.uniform(0.05, 0.5, m))
    position = rng.normal(scale=10.0, size=(m, 3))
    position[rng.choice(m, 6, replace=False), :2] = np.nan
    position[rng.choice(m, 3, replace=False), 2] = np.nan
    attitude = np.stack([rodrigues(rng.normal(size=3), rng.uniform(0, np.pi)) for _ in range(m)])
    attitude[rng.choice(m, 5, replace=False)] = np.nan
    rates = rng.normal(size=(m, 3))
    rates[rng.choice(m, 4, replace=False), 1] = np.nan
    sigma = {"position": 0.01, "attitude": 0.02, "rates": 0.003}
    return Telemetry(t, sigma=sigma, position=position, attitude=attitude, rates=rates)


@pytest.mark.parametrize("form", ["quaternion", "euler"])
def test_round_trip(tmp_path, form):
    original = random_telemetry(np.random.default_rng(3))
    path = tmp_path / "round_trip.csv"
    write_telemetry(path, original, attitude=form)
    header = path.read_text().splitlines()[0]
    assert header == ("t,x,y,z,qw,qx,qy,qz,p,q,r" if form == "quaternion" else "t,x,y,z,roll,pitch,yaw,p,q,r")
    back = read_telemetry(path, sigma={**original.sigma, "velocity": 1.0})
    assert back.channels == original.channels and back.sigma == original.sigma
    np.testing.assert_array_equal(back.t, original.t)
    for c in original.channels:
        np.testing.assert_array_equal(back.mask[c], original.mask[c])
        np.testing.assert_allclose(back.values[c], original.values[c], rtol=1e-14, atol=1e-14)


def test_quaternions_are_written_with_nonnegative_scalar(tmp_path):
    R = np.stack([rodrigues([1.0, -2.0, 0.5], angle) for angle in (0.1, 3.0, np.pi, -3.1)])
    write_telemetry(tmp_path / "q.csv", Telemetry([0.0, 1.0, 2.0, 3.0], sigma={"attitude": 0.1}, attitude=R))
    rows = np.loadtxt(tmp_path / "q.csv", delimiter=",", skiprows=1)
    assert np.all(rows[:, 1] >= 0)
    np.testing.assert_allclose(np.linalg.norm(rows[:, 1:], axis=1), 1.0, atol=1e-15)


ANGLES = [(0.3, -0.4, 1.1), (-2.5, 1.2, -3.0), (1.0, np.pi / 2 - 1e-7, 0.2), (0.0, 0.0, np.pi - 1e-9)]


def test_euler_and_quaternion_columns_agree(tmp_path):
    expected, quaternions = [], []
    for roll, pitch, yaw in ANGLES:
        expected.append(rodrigues([0, 0, 1], yaw) @ rodrigues([0, 1, 0], pitch) @ rodrigues([1, 0, 0], roll))
        quaternions.append(hamilton(hamilton(axis_quaternion([0, 0, 1], yaw), axis_quaternion([0, 1, 0], pitch)),
                                    axis_quaternion([1, 0, 0], roll)))
    # a general axis too, and columns in another order
    expected.append(rodrigues([0.2, -0.7, 0.4], 2.2))
    quaternions.append(axis_quaternion([0.2, -0.7, 0.4], 2.2))
    euler_text = "t, yaw, pitch, roll\n" + "".join(f"{i}, {y!r}, {p!r}, {r!r}\n" for i, (r, p, y) in enumerate(ANGLES))
    quaternion_text = "qx,qy,qz,qw,t\n" + "".join(f"{x!r},{y!r},{z!r},{w!r},{i}\n" for i, (w, x, y, z) in enumerate(np.array(quaternions).tolist()))
    from_euler = read_telemetry(write_text(tmp_path, euler_text, "euler.csv"), sigma={"attitude": 0.1})
    from_quaternion = read_telemetry(write_text(tmp_path, quaternion_text, "quaternion.csv"), sigma={"attitude": 0.1})
    np.testing.assert_allclose(from_euler.values["attitude"], np.stack(expected[:-1]), atol=2e-15)
    np.testing.assert_allclose(from_quaternion.values["attitude"], np.stack(expected), atol=2e-15)


def test_depth_only_and_missing_cells(tmp_path):
    telemetry = read_telemetry(write_text(tmp_path, " t , z \n0, -1.5\n0.5,\n1.25 , -1.75\n"), sigma={"position": 0.05, "rates": 1.0})
    assert telemetry.channels == ("position",) and telemetry.sigma == {"position": 0.05}
    np.testing.assert_array_equal(telemetry.observed("position"), [False, False, True])
    np.testing.assert_array_equal(telemetry.mask["position"], [[0, 0, 1], [0, 0, 0], [0, 0, 1]])
    np.testing.assert_array_equal(telemetry.values["position"][:, 2], [-1.5, 0.0, -1.75])


def test_unnormalised_quaternion_is_normalised(tmp_path):
    telemetry = read_telemetry(write_text(tmp_path, "t,qw,qx,qy,qz\n0,1.0005,0,0,0\n1,0,0,0,0.9995\n"), sigma={"attitude": 0.1})
    np.testing.assert_allclose(telemetry.values["attitude"], [E, np.diag([-1.0, -1.0, 1.0])], atol=1e-15)


@pytest.mark.parametrize("text, match", [
    ("", r", line 1: expected a header row of column names, got an empty file"),
    ("\n0,1\n", r", line 1: expected a header row of column names, got an empty line"),
    ("t,x,depth\n0,1,2\n1,2,3\n", r", line 1: unknown column 'depth'; allowed columns: t, x, y, z, qw, qx"),
    ("t,x,x\n0,1,2\n1,2,3\n", r", line 1: duplicate column 'x'"),
    ("x,y\n0,1\n1,2\n", r", line 1: missing column 't'"),
    ("t\n0\n1\n", r", line 1: no data columns besides 't'"),
    ("t,qw,qx,qy\n0,1,0,0\n1,1,0,0\n", r", line 1: attitude columns qw, qx, qy, qz come together; missing qz"),
    ("t,qw,qx,qy,qz,roll,pitch,yaw\n0,1,0,0,0,0,0,0\n1,1,0,0,0,0,0,0\n", r", line 1: both quaternion .* and Euler angle .* columns"),
    ("t,x\n0,1\n1,2,3\n", r", line 3: expected 2 cells \(one per column\), got 3"),
    ("t,x\n0,1\n1,2\n2\n", r", line 4: expected 2 cells"),
    ("t,x\n0,1\n1,1.2.3\n", r", line 3, column 'x': expected a number or an empty cell, got '1.2.3'"),
    ("t,x\n0,nan\n1,2\n", r", line 2, column 'x': got 'nan'; a missing value is an empty cell"),
    ("t,x\n0,1\n1,-inf\n", r", line 3, column 'x': got '-inf'; a missing value is an empty cell"),
    ("t,x\n0,1\n,2\n", r", line 3, column 't': empty time"),
    ("t,x\n0,1\n2,2\n2,3\n", r", line 4: time t = 2.0 does not increase from t = 2.0 on line 3"),
    ("t,x\n0,1\n\n-1,2\n", r", line 4: time t = -1.0 does not increase from t = 0.0 on line 2"),
    ("t,qw,qx,qy,qz\n0,1,0,0,0\n1,1,,0,\n", r", line 3: attitude cells qw, qx, qy, qz are partly empty \(empty: qx, qz\)"),
    ("t,roll,pitch,yaw\n0,,,\n1,,0,\n", r", line 3: attitude cells roll, pitch, yaw are partly empty \(empty: roll, yaw\)"),
    ("t,qw,qx,qy,qz\n0,1,0,0,0\n1,1,0.1,0,0\n", r", line 3: quaternion norm 1.004\d* differs from 1 by more than 1e-3"),
    ("t,x\n0,1\n", r": expected at least 2 rows of data, got 1"),
    ("t,x\n", r": expected at least 2 rows of data, got 0"),
])
def test_errors_name_the_file_and_line(tmp_path, text, match):
    path = write_text(tmp_path, text)
    with pytest.raises(ValueError, match="^" + re.escape(str(path)) + match):
        read_telemetry(path, sigma={"position": 1.0, "attitude": 1.0})


def test_missing_sigma_names_the_channel(tmp_path):
    path = write_text(tmp_path, "t,z,p\n0,1,0.1\n1,2,0.2\n")
    with pytest.raises(ValueError, match=r"the file has channel 'rates' but sigma has no noise level for it"):
        read_telemetry(path, sigma={"position": 1.0, "attitude": 1.0})


def test_example_file():
    telemetry = read_telemetry(EXAMPLE, sigma={"position": 0.01, "attitude": 0.01, "velocity": 0.1})
    assert telemetry.t.shape == (150,) and telemetry.channels == ("position", "attitude")
    t = np.asarray(telemetry.t)
    assert t[0] > 0 and 55 < t[-1] <= 60 and np.all(np.diff(t) > 0)
    assert np.sum(np.asarray(telemetry.mask["attitude"])[:, 0] == 0) == 5
    np.testing.assert_array_equal(np.sum(np.asarray(telemetry.mask["position"]) == 0, axis=0), [3, 3, 0])
