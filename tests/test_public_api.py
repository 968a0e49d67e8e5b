"""Every name the README, the docs and the design's API contract use resolves (re-exports keep
the public API stable across layout changes)."""

import importlib
import pathlib
import re

import pytest

import vi_jax

ROOT = pathlib.Path(__file__).resolve().parent.parent
DOCUMENTS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
# The design's public API contract (../shared/DESIGN.md), named here so the test needs no file
# outside the repository.
CONTRACT = (
    "vj.models.UnderwaterVehicle", "vj.models.RigidBody", "vj.models.HeavyTop",
    "vj.models.GeometricallyExactBeam", "vj.models.clebsch", "vj.models.suris",
    "vj.simulate", "vj.ensemble", "vj.vary", "vj.Solution", "vj.NewtonFailure", "vj.State",
    "vj.System", "vj.AbstractSystem", "vj.fit", "vj.continuous.vector_field", "vj.enable_fast_cpu_loops",
)


def _documented_names():
    names = set(CONTRACT)
    pattern = re.compile(r"\b(?:vj|vi_jax)(?:\.[A-Za-z_][A-Za-z0-9_]*)+")
    for doc in DOCUMENTS:
        for match in pattern.findall(doc.read_text()):
            names.add("vj" + match[len("vi_jax"):] if match.startswith("vi_jax") else match)
    return sorted(names)


def _resolve(dotted):
    """Attribute access from ``vj``, importing submodules where attribute access alone would not."""
    obj, path = vi_jax, "vi_jax"
    for part in dotted.split(".")[1:]:
        path += "." + part
        if hasattr(obj, part):
            obj = getattr(obj, part)
        else:
            obj = importlib.import_module(path)
    return obj


@pytest.mark.parametrize("name", _documented_names())
def test_documented_name_resolves(name):
    _resolve(name)


def test_cli_entry_point_is_a_function():
    from vi_jax.cli import main

    assert callable(main)
