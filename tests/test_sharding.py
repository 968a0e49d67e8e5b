"""An ensemble sharded over four (forced host) CPU devices equals the single-device run, for
the generated batched step (the vehicle and the rigid body) and the vmap path, and a concrete sharded run of another
length (same saved-node capacity) compiles nothing new.

The device count must be fixed before JAX initialises, so the check runs in a fresh Python
process with ``XLA_FLAGS=--xla_force_host_platform_device_count=4``.
"""

import json
import os
import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent(
    """
    import json
    import logging
    import jax
    jax.config.update("jax_enable_x64", True)
    import numpy as np
    import vi_jax as vj
    from vi_jax.engine._ensemble import ensemble, vary

    MESSAGES = []  # jax logs every compile at DEBUG level
    class Collect(logging.Handler):
        def emit(self, record):
            MESSAGES.append(record.getMessage())
    logging.getLogger("jax").addHandler(Collect())
    logging.getLogger("jax").setLevel(logging.DEBUG)

    assert jax.device_count() == 4, jax.devices()
    mesh = jax.make_mesh((4,), ("members",))
    rng = np.random.default_rng(0)
    report, recompiled = {}, []
    vehicle, body = vj.models.UnderwaterVehicle(), vj.models.RigidBody()
    cases = (
        ("batched", 7, vary(vehicle, mass=123.8 + rng.uniform(-5, 5, size=7)), vehicle.initial_state()),
        ("vmap", 8, vary(body, inertia=np.diag([0.5, 0.6, 1.0]) * rng.uniform(0.9, 1.1, size=(8, 1, 1))), body.initial_state()),
        ("batched", 6, vary(body, inertia=np.diag([0.5, 0.6, 1.0]) * rng.uniform(0.9, 1.1, size=(6, 1, 1))), body.initial_state()),
    )
    for method, n, models, x0 in cases:
        states = vary(x0, xi=np.asarray(x0.xi) + 0.3 * rng.normal(size=(n, 3)))
        kwargs = dict(system_axes=0, method=method, save_every=5)
        single = ensemble(models, states, 0.02, 100, **kwargs)
        sharded = ensemble(models, states, 0.02, 100, mesh=mesh, **kwargs)
        fields = {}
        for name in ("t", "g", "xi", "q", "nu", "M", "P", "energy", "kelvin_noether", "newton_iterations", "result"):
            if getattr(single, name) is None:  # the rigid body has no additional dynamics
                continue
            a, b = np.asarray(getattr(single, name)), np.asarray(getattr(sharded, name))
            fields[name] = dict(
                shapes_equal=a.shape == b.shape,
                identical=bool(np.array_equal(a, b)),
                max_rel=float(np.max(np.abs(a - b)) / max(np.max(np.abs(a)), 1e-300)),
            )
        fields["newton_residual_max"] = float(np.max(np.asarray(sharded.newton_residual)))
        MESSAGES.clear()  # 24 saved nodes below: the same capacity (32) as the 20 above
        longer = ensemble(models, states, 0.02, 120, mesh=mesh, **kwargs)
        recompiled += [m for m in MESSAGES if m.startswith("Compiling jit(_sharded)")]
        report[f"{method}-{n}"] = dict(
            fields=fields, devices=len(sharded.g.sharding.device_set), longer_rows=longer.q.shape[1] if longer.q is not None else longer.g.shape[1],
        )
    report["recompiled"] = recompiled
    print(json.dumps(report))
    """
)


def test_sharded_ensemble_equals_single_device():
    flags = f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=4".strip()
    env = dict(os.environ, XLA_FLAGS=flags, JAX_PLATFORMS="cpu")
    run = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    report = json.loads(run.stdout.strip().splitlines()[-1])
    # Concrete runs take traced step counts: another n_steps with the same capacity compiles nothing.
    assert report.pop("recompiled") == []
    for case in report.values():
        assert case["longer_rows"] == 25
        assert all(f["shapes_equal"] for k, f in case["fields"].items() if k != "newton_residual_max")
        assert case["fields"]["newton_residual_max"] <= 64 * 2.0**-52
        assert case["fields"]["newton_iterations"]["identical"] and case["fields"]["result"]["identical"]
    # The generated batched step is elementwise over members: sharding (7 or 6 members padded
    # to 8 over 4 devices) changes no arithmetic of the vehicle's Cayley steps (states bitwise
    # equal); the rigid body's exp map evaluates sin and cos in a one-kernel loop
    # (vi_jax/_one_kernel.py) whose vector and scalar parts depend on the members per device,
    # and may round differently there (not bitwise equal since the loops are one kernel): its
    # states, as the node diagnostics (under vmap), are held to the bound below.
    states = {"batched-7": ("t", "g", "q", "M", "P"), "batched-6": ("t", "g", "M")}  # the vehicle, the rigid body
    assert all(report["batched-7"]["fields"][k]["identical"] for k in states["batched-7"])
    # jax.vmap of vj.simulate (a free rigid body: the generic path, any system): XLA may order a
    # reduction differently for 2 members per device than for 8 (≲ a few ulps per step), and a
    # difference grows at most linearly over 100 steps of this bounded motion: 8 ulps per step.
    bound = 8 * 100 * 2.0**-52
    for case in ("vmap-8", *states):
        assert all(f["max_rel"] <= bound for k, f in report[case]["fields"].items() if k != "newton_residual_max"), case
    assert report["vmap-8"]["devices"] == 4  # a multiple of the devices stays sharded
