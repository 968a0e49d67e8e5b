"""A possible next step for the splitting (not used by the library): split the rotational kinetic
energy as ½|Π|²/I_a + Σ_{k≠a} ½(1/I_k − 1/I_a)Π_k² instead of one planar rotation per principal
axis. The first piece leaves Π fixed (|Π|² is a Casimir of so(3)*) and turns g, P about Π by
the angle t|Π|/I_a; it commutes with the rotation about an axis of equal moment, so for a
symmetric body only the kick and translation remain non-commuting.

Final-state error at T = 50 s of the order-6 composition (Blanes–Moan, 10 stages) against Dopri8
at rtol 1e-13, the pieces of the library against the sphere piece plus two planar rotations
(errors only: the sphere piece here is written with ``SO3().exp``, not tuned for speed).

    python benchmarks/splitting_sphere_piece.py
"""

import diffrax
import jax
import jax.numpy as jnp

import vi_jax as vj
from vi_jax import continuous
from vi_jax.discrete import _splitting as S
from vi_jax.discrete import _splitting_pieces as sp
from vi_jax.lie import SO3

jax.config.update("jax_enable_x64", True)


def sphere_flows(parts, a):
    """The library's kick and translation, the sphere piece with 1/I_a, and planar rotations
    about the other two axes with coefficients 1/I_k − 1/I_a."""
    flows = {k: f for k, f in sp.piece_flows(parts).items() if k in ("V", "T")}
    inv_a = parts.inv_inertia[a]

    def sphere(t, s):
        E = SO3().exp(t * inv_a * s.Pi)
        return sp.Phase(s.g @ E, s.q, s.Pi, None if s.P is None else E.T @ s.P)

    flows["S"] = sphere
    for k in (k for k in range(3) if k != a):
        def rotate(t, s, k=k):
            c, sn = jnp.cos(t * s.Pi[k] * (parts.inv_inertia[k] - inv_a)), jnp.sin(t * s.Pi[k] * (parts.inv_inertia[k] - inv_a))
            i, j = parts.planes[k]
            rows = jnp.concatenate([s.g, s.Pi[None]] + ([] if s.P is None else [s.P[None]]))
            rows = sp._turn_columns(rows, i, j, c, sn)
            return sp.Phase(rows[:3], s.q, rows[3], None if s.P is None else rows[4])

        flows[k] = rotate
    return flows


def final_state(model, h, n, flows, arrangement, parts):
    table = S.stage_table("blanes_moan10")
    pieces = S.arrange(tuple(flows), arrangement)
    phase = S.initial_phase(parts, model.initial_state())
    run = jax.jit(lambda p, h: S._steps(flows, pieces, table, h, S._first(flows, pieces, float(table[0, 0]), h, p), n))
    g, q, _, _ = S.from_phase(parts, run(phase, jnp.asarray(h)))
    return g, q


def error(model, g, q, ref):
    e = float(jnp.max(jnp.abs(g - ref[0])))
    return e if q is None else max(e, float(jnp.max(jnp.abs(q - ref[1])) / jnp.max(jnp.abs(ref[1]))))


def main(T=50.0):
    cases = (
        ("vehicle", vj.models.UnderwaterVehicle(), (1.0, 0.5, 0.25), ("V", "T", "R"), ("V", "T", "S", "R"), 1),
        ("heavy top", vj.models.HeavyTop(), (0.25, 0.125, 0.0625), ("V", "R"), ("V", "S", "R"), 0),
    )
    for name, model, steps, arrangement, sphere_arrangement, a in cases:
        y0 = continuous.initial_state(model, model.initial_state())
        sol = diffrax.diffeqsolve(continuous.vector_field(model), diffrax.Dopri8(), 0.0, T, None, y0,
                                  stepsize_controller=diffrax.PIDController(rtol=1e-13, atol=1e-13), max_steps=10**7)
        ref = (sol.ys[0][-1], None if sol.ys[2] is None else sol.ys[2][-1])
        parts = sp.separable_parts(model)
        print(f"{name}: moments {[round(float(1 / w), 3) for w in parts.inv_inertia]}, sphere piece on axis {a}")
        for h in steps:
            n = round(T / h)
            library = error(model, *final_state(model, h, n, sp.piece_flows(parts), arrangement, parts), ref)
            sphere = error(model, *final_state(model, h, n, sphere_flows(parts, a), sphere_arrangement, parts), ref)
            print(f"  h = {h:<7g} three planar rotations {library:.2e}   sphere + two planar {sphere:.2e}   ratio {library / sphere:.3g}")


if __name__ == "__main__":
    main()
