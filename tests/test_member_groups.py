"""``vj.ensemble``'s concrete CPU runs with the members in one group per core, the groups run at
the same time from worker threads: equal to the run in one group, whatever the path."""

import threading

import numpy as np
import pytest

import vi_jax as vj
from vi_jax.engine import _member_groups

FIELDS = ["g", "xi", "M", "energy", "kelvin_noether", "newton_iterations", "result"]


@pytest.mark.parametrize(
    "scene, method, order",
    [("HeavyTop", "batched", 1), ("UnderwaterVehicle", "batched", 1), ("RigidBody", "vmap", 2)],
    ids=["generated step", "generated step, nu solved first", "vmap"],
)
def test_groups_on_cores_equal_one_group(scene, method, order, monkeypatch):
    """Seven members on three "cores" (groups of at least two): groups of three, the last
    padded with copies of its last member, each run by a worker thread; every field
    equals the one-group run's. Both run the same scheme on the same members; XLA may vectorise
    a 3-member and a 7-member program differently (a few ε per step over 200 steps: bound
    1e-12 relative), and Newton's statistics are equal."""
    model = getattr(vj.models, scene)()
    x0 = model.initial_state()
    states = vj.vary(x0, xi=np.asarray(x0.xi) + 0.1 * np.random.default_rng(1).normal(size=(7, 3)))
    run = lambda: vj.ensemble(model, states, 0.01, 200, save_every=20, order=order, method=method)  # noqa: E731

    monkeypatch.setattr(_member_groups, "cores", lambda: 1)
    one = run()
    workers = []

    class Recording(_member_groups.ThreadPoolExecutor):
        def map(self, fn, *iterables):
            def recorded(group):
                workers.append(threading.current_thread())
                return fn(group)

            return super().map(recorded, *iterables)

    monkeypatch.setattr(_member_groups, "cores", lambda: 3)
    monkeypatch.setattr(_member_groups, "MIN_GROUP", 2)
    monkeypatch.setattr(_member_groups, "_workers", Recording)
    grouped = run()
    assert len(workers) == 3 and threading.main_thread() not in workers  # an idle worker may take a second group
    for name in FIELDS:
        ours, theirs = np.asarray(getattr(grouped, name)), np.asarray(getattr(one, name))
        assert ours.shape == theirs.shape == (7,) + theirs.shape[1:], name
        assert np.max(np.abs(ours - theirs)) <= 1e-12 * max(np.max(np.abs(theirs)), 1.0), name


@pytest.mark.parametrize("few", ["members", "steps per node"])
def test_one_group_below_the_minimums(few, monkeypatch):
    """Fewer than two groups' worth of members, or a node saved more often than every
    ``MIN_STEPS_PER_NODE`` steps: a plain call, no worker thread."""
    monkeypatch.setattr(_member_groups, "cores", lambda: 8)
    monkeypatch.setattr(_member_groups, "_workers", None)  # would fail if used
    model = vj.models.RigidBody()
    x0 = model.initial_state()
    n = 2 * _member_groups.MIN_GROUP - (1 if few == "members" else 0)
    save_every = _member_groups.MIN_STEPS_PER_NODE - (1 if few == "steps per node" else 0)
    states = vj.vary(x0, xi=np.asarray(x0.xi) + 0.1 * np.random.default_rng(2).normal(size=(n, 3)))
    sol = vj.ensemble(model, states, 0.01, 4 * save_every, save_every=save_every)
    assert sol.g.shape == (n, 5, 3, 3)


def test_worker_threads_start_once_per_process(monkeypatch):
    """Calls reuse one pool of worker threads; a forked child (another pid) gets its own, the
    parent's threads not existing there."""
    pool = _member_groups._workers(2)
    assert _member_groups._workers(2) is pool
    monkeypatch.setattr(_member_groups.os, "getpid", lambda: -1)
    child = _member_groups._workers(2)
    assert child is not pool
    assert list(child.map(lambda x: 2 * x, [1, 2])) == [2, 4]
