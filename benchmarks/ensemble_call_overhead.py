"""Fixed cost of a concrete ``vj.ensemble`` call (the host work around its compiled programs):
the vehicle, 1024 members, h = 0.01, float64, the final node saved, at 4 and at 1000 steps, one
group of members per core. Peers: the same call with its input values checked leaf by leaf as
before ``check_values`` (``vi_jax/_validation.py``): a transfer to the host per leaf, then the
members' group membership by its own program; the same call with the groups' program lowered and
compiled anew at every call, as before programs were kept (``vi_jax/engine/_kept_programs.py``),
and with that and the host work of the version before it too (``a42d569``): member 0 sliced by
one program per leaf for the input checks, which also checked its group membership before the
check of every member, and each group's members sliced and padded on the host, one transfer per
leaf and group. All timed in one process, alternately (41 timings each).

    python benchmarks/ensemble_call_overhead.py [--fast-loops]
"""

import statistics
import time

from _timing import parse_args_with_fast_loops, write_config_json

ARGS = parse_args_with_fast_loops()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
import numpy as np  # noqa: E402

import vi_jax as vj  # noqa: E402
from _generated import perturbed_states  # noqa: E402
from vi_jax import _validation  # noqa: E402
from vi_jax.engine import _ensemble, _member_groups  # noqa: E402
from vi_jax.engine._member_split import pad_members  # noqa: E402

MEMBERS, REPEATS = 1024, 41


def per_leaf_member(tree, axes, index):
    return jax.tree.map(lambda ax, x: x if ax is None else x[index], axes, tree, is_leaf=lambda x: x is None)


def per_leaf_groups(program, dynamic, axes, n_members, steps_per_node, *args, **kwargs):
    """``on_cores`` with each group's members sliced and padded on the host, leaf by leaf."""
    size = -(-n_members // min(_member_groups.cores(), n_members // _member_groups.MIN_GROUP))

    def group(start):
        def take(ax, x):
            return x if ax is None or x is None else jax.numpy.asarray(pad_members(np.asarray(x)[start : start + size], size))

        return jax.tree.map(take, axes, dynamic, is_leaf=lambda x: x is None)

    groups = [group(start) for start in range(0, n_members, size)]
    compiled = program.lower(groups[0], *args, n_members=size, **kwargs).compile()
    parts = list(_member_groups._workers(len(groups)).map(lambda g: jax.block_until_ready(compiled(g, *args, n_members=size, **kwargs)), groups))
    return _member_groups._joined_on_device(parts, n_members)


def per_leaf_checks(named, group, g, g_batched=False, tol=1e-6):
    """The checks as ``vj.ensemble`` made them before ``check_values``."""
    for name, x, _ in named:
        _validation.check_finite(name, x)
    if not float(_validation.membership_error(group, g)) <= tol:
        raise ValueError("x0.g: expected elements of the group for every member")


def compiled_each_call(program, *args, **kwargs):
    return program.lower(*args, **kwargs).compile()


def main():
    current = dict(take_member=_ensemble.take_member, on_cores=_ensemble.on_cores, validate_scheme=_ensemble.validate_scheme,
                   compiled_program=_member_groups.compiled_program, check_values=_validation.check_values)
    leaf_checks = dict(current, check_values=per_leaf_checks)
    before = dict(leaf_checks, compiled_program=compiled_each_call)
    per_leaf = dict(before, take_member=per_leaf_member, on_cores=per_leaf_groups,
                    validate_scheme=lambda *args, values: current["validate_scheme"](*args, values=True))
    modules = dict(take_member=_ensemble, on_cores=_ensemble, validate_scheme=_ensemble, compiled_program=_member_groups, check_values=_validation)
    model = vj.models.UnderwaterVehicle()
    states = perturbed_states(model.initial_state(), MEMBERS)
    assert _member_groups.cores() >= 2, "one group per core needs two cores"
    rows = []
    for steps in (4, 1000):
        samples = {"this version": [], "values checked leaf by leaf (before)": [], "and compiled each call (two before)": [],
                   "and per-leaf host work (three before)": []}
        variants = dict(zip(samples, (current, leaf_checks, before, per_leaf)))
        for _ in range(1 + REPEATS):  # the first round compiles
            for name, variant in variants.items():
                for key, fn in variant.items():
                    setattr(modules[key], key, fn)
                start = time.perf_counter()
                jax.block_until_ready(vj.ensemble(model, states, 0.01, steps, save_every=steps, throw=False).q)
                samples[name].append(time.perf_counter() - start)
        for key, fn in current.items():
            setattr(modules[key], key, fn)
        medians = {k: statistics.median(v[1:]) for k, v in samples.items()}
        fastest = {k: min(v[1:]) for k, v in samples.items()}
        ours, *peers = samples
        rows.append(dict(steps=steps, median_ms={k: 1e3 * v for k, v in medians.items()}, fastest_ms={k: 1e3 * v for k, v in fastest.items()},
                         saved_ms_median={k: 1e3 * (medians[k] - medians[ours]) for k in peers},
                         saved_ms_fastest={k: 1e3 * (fastest[k] - fastest[ours]) for k in peers}))
        print(f"{steps:5d} steps: this version {1e3 * medians[ours]:.2f} ms (fastest {1e3 * fastest[ours]:.2f})", flush=True)
        for k in peers:
            print(f"             {k}: {1e3 * medians[k]:.2f} ms ({1e3 * fastest[k]:.2f}): {1e3 * (medians[k] - medians[ours]):.2f} ms "
                  f"less by medians, {1e3 * (fastest[k] - fastest[ours]):.2f} by the fastest", flush=True)
    write_config_json("ensemble_call_overhead", ARGS.fast_loops, members=MEMBERS, rows=rows)


if __name__ == "__main__":
    main()
