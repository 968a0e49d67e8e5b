"""Explicit splitting of separable reduced Lagrangians: compositions of the exact flows of
``_splitting_pieces`` (potential kick "V", translation "T", the sphere piece "S" on SO(3), one
rotation per remaining principal axis).

Every method is a composition Φ*_{α_s h}∘Φ_{β_s h}∘…∘Φ*_{α_1 h}∘Φ_{β_1 h} of the Lie–Trotter map
Φ_t = X_m(t)∘…∘X_1(t) of the pieces X_1 (outermost) … X_m and its adjoint Φ*_t = X_1(t)∘…∘X_m(t)
(Hairer, Lubich & Wanner, *Geometric Numerical Integration*, 2nd ed., §II.5, §V.3; the order
conditions do not depend on the number of pieces). Strang's splitting is Φ*_{h/2}∘Φ_{h/2}, and a
symmetric composition of it with fractions γ_i has α_i = β_i = γ_i/2. Adjacent flows of the same
piece are merged (X(a)∘X(b) = X(a + b)), and across the steps between two saved nodes the last
flow of a step is merged with the first of the next; the stages of a composition run as a rolled
loop (an unrolled order-8 step has ~140 flows: compiling it took minutes).

The state is the continuous one, (g, q, Π = Jξ, P = Mν), started from the continuous Legendre
map: for a splitting method the momenta are the state, and the velocities at the nodes are
ξ = J⁻¹Π, ν = M⁻¹P exactly.
"""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _validation as val
from .._saved_nodes import checkpointed, default_cpu_loops, each_step_rematerialised, scan_saved_nodes, step_block
from .._system import State
from ..lie import SO3
from ._splitting_pieces import from_phase, piece_flows, separable_parts, to_phase, velocities

# --- composition coefficients (each checked for its order by tests/test_splitting.py) -------------
# HLW: Hairer, Lubich & Wanner, Geometric Numerical Integration, 2nd ed. (2006).
_Y1 = 1.0 / (2.0 - 2.0 ** (1.0 / 3.0))
_S5 = 1.0 / (4.0 - 4.0 ** (1.0 / 3.0))
_R19 = math.sqrt(19.0)


def _symmetric(half):
    """γ₁ … γ_k … γ₁ from its first half (the middle one included)."""
    return (*half, *reversed(half[:-1]))


def _with_middle(half):
    """γ₁ … γ_k, 1 − 2Σγ_i, γ_k … γ₁."""
    return _symmetric((*half, 1.0 - 2.0 * sum(half)))


def _from_gammas(gammas):
    """Symmetric composition of Strang's splitting: α_i = β_i = γ_i/2."""
    return tuple(c for g in gammas for c in (0.5 * g, 0.5 * g))


def _from_palindrome(a, b):
    """(β₁, α₁, β₂, …) of a symmetric two-piece splitting X(a₁)Y(b₁)X(a₂)…Y(b₁)X(a₁) (a has one
    more entry than b): β₁ = a₁, α_i = b_i − β_i, β_{i+1} = a_{i+1} − α_i."""
    out, carry = [], 0.0
    for ai, bi in zip(a, b):
        beta = ai - carry
        carry = bi - beta
        out += [beta, carry]
    return tuple(out)


_BM4_A = (0.0792036964311957, 0.353172906049774, -0.0420650803577195)
_BM4_B = (0.209515106613362, -0.143851773179818)
_BM6_A = (0.0502627644003922, 0.413514300428344, 0.0450798897943977, -0.188054853819569, 0.541960678450780)
_BM6_B = (0.148816447901042, -0.132385865767784, 0.067307604692185, 0.432666402578175)


def _bm(a, b):
    a = (*a, 1.0 - 2.0 * sum(a))
    b = (*b, 0.5 - sum(b))
    return _from_palindrome(_symmetric(a), (*b, *reversed(b)))


_MCLACHLAN_ALPHA = ((146 + 5 * _R19) / 540, (-2 + 10 * _R19) / 135, 1 / 5, (-23 - 20 * _R19) / 270, (14 - _R19) / 108)

METHODS = {
    # name: (order, (β₁, α₁, β₂, α₂, …), source)
    "strang": (2, (0.5, 0.5), "Strang 1968"),
    "triple_jump": (4, _from_gammas((_Y1, 1 - 2 * _Y1, _Y1)), "Yoshida 1990 (triple jump); HLW §II.4, eq. (4.4)"),
    "suzuki5": (4, _from_gammas((_S5, _S5, 1 - 4 * _S5, _S5, _S5)), "Suzuki 1990 (five-stage fractal); HLW §II.4"),
    "mclachlan5": (
        4,
        tuple(c for beta, alpha in zip(reversed(_MCLACHLAN_ALPHA), _MCLACHLAN_ALPHA) for c in (beta, alpha)),
        "McLachlan 1995; HLW §V.3, eq. (3.6)",
    ),
    "blanes_moan6": (4, _bm(_BM4_A, _BM4_B), "Blanes & Moan 2002, J. Comput. Appl. Math. 142, Table 2 (PRK, s = 6, order 4)"),
    "yoshida7": (
        6,
        _from_gammas(_symmetric((0.78451361047755726381949763, 0.23557321335935813368479318,
                                 -1.17767998417887100694641568, 1.31518632068391121888424973))),
        "Yoshida 1990 (solution A); HLW §V.3.2",
    ),
    "kahan_li9": (
        6,
        _from_gammas(_with_middle((0.39216144400731413928, 0.33259913678935943860,
                                   -0.70624617255763935981, 0.082213596293550800230))),
        "Kahan & Li 1997; HLW §V.3.2, eq. (3.12)",
    ),
    "blanes_moan10": (6, _bm(_BM6_A, _BM6_B), "Blanes & Moan 2002, J. Comput. Appl. Math. 142, Table 2 (PRK, s = 10, order 6)"),
    "suzuki_umeno15": (
        8,
        _from_gammas(_symmetric((0.74167036435061295344822780, -0.40910082580003159399730010,
                                 0.19075471029623837995387626, -0.57386247111608226665638773,
                                 0.29906418130365592384446354, 0.33462491824529818378495798,
                                 0.31529309239676659663205666, -0.79688793935291635401978884))),
        "Suzuki & Umeno 1993, McLachlan 1995; HLW §V.3.2",
    ),
    "kahan_li17": (
        8,
        _from_gammas(_symmetric((0.13020248308889008087881763, 0.56116298177510838456196441,
                                 -0.38947496264484728640807860, 0.15884190655515560089621075,
                                 -0.39590389413323757733623154, 0.18453964097831570709183254,
                                 0.25837438768632204729397911, 0.29501172360931029887096624,
                                 -0.60550853383003451169892108))),
        "Kahan & Li 1997; HLW §V.3.2, eq. (3.14)",
    ),
}

# Pieces are named "V" (potential kick), "T" (translation), "S" (sphere, SO(3) only) and 0, 1, …
# (rotation axes); an arrangement lists them from the outermost to the innermost, "R" standing
# for the axes it does not list, by index. Method per order: the fastest to final-state errors
# 1e-4 … 1e-10 on the vehicle at T = 50 (benchmarks/splitting_compositions.py, the same choice
# with and without the XLA:CPU loop option; within an order the methods differ by up to 3×).
# Arrangements (benchmarks/splitting_sphere_piece.py [--fast-loops]): with the sphere piece the
# error at equal step is 66–20,000× smaller on the symmetric heavy top at orders 4–8 (its free
# motion is then exact) and 1–3.6× smaller on the vehicle, for 2–21 % more per step with the
# loop option (20–38 % without). Time to equal error, sphere ÷ planar: heavy top 0.17–0.77
# (loop option) and 0.20–0.97 (default flags); vehicle 0.89–1.14 and 0.95–1.32. Each order
# takes the sphere arrangement with the smallest vehicle error.
DEFAULTS = {
    2: ("strang", ("V", "S", "R", "T")),
    4: ("blanes_moan6", ("V", "T", "S", "R")),
    6: ("blanes_moan10", ("V", "T", "S", "R")),
    8: ("suzuki_umeno15", ("V", "S", "R", "T")),
}
ORDERS = tuple(DEFAULTS)


def arrange(names, arrangement):
    """The pieces ``names`` of a scene, outermost first, in the order of ``arrangement``."""
    axes = tuple(sorted(p for p in names if isinstance(p, int) and p not in arrangement))
    order = []
    for p in arrangement:
        order += list(axes) if p == "R" else [p] if p in names else []
    missing = set(names) - set(order)
    if missing:
        raise ValueError(f"arrangement: {arrangement!r} leaves out the pieces {sorted(map(str, missing))}")
    return tuple(order)


def resolve(order, method=None, arrangement=None, sphere=True):
    """(method, arrangement) for ``order``: the defaults of ``DEFAULTS`` where not given; without
    ``sphere`` (scenes off SO(3)) a default arrangement drops the sphere piece "S"."""
    val.check_choice("order", order, ORDERS)
    if method is not None:
        val.check_choice("method", method, tuple(METHODS))
        if METHODS[method][0] != order:
            raise ValueError(f"method: {method!r} has order {METHODS[method][0]}, but order={order!r} was asked for")
    if arrangement is None:
        arrangement = tuple(p for p in DEFAULTS[order][1] if p != "S" or sphere)
    return method or DEFAULTS[order][0], tuple(arrangement)


def resolved_parts(system, dtype, order, method=None, arrangement=None, *, throw=True):
    """(method, arrangement, ``separable_parts``) of a run: the sphere piece by default on SO(3),
    the parts' frame prepared for it when the arrangement has it."""
    method, arrangement = resolve(order, method, arrangement, isinstance(system.group, SO3))
    return method, arrangement, separable_parts(system, dtype, throw=throw, sphere="S" in arrangement)


# --- states --------------------------------------------------------------------------------------
class SplittingState(eqx.Module):
    """(g, q, Π, P) at a node: the variables of the DEP engine's ``StepState`` (M = Π), continuous
    body momenta."""

    g: jax.Array
    q: jax.Array | None
    M: jax.Array
    P: jax.Array | None


class SplittingNodes(eqx.Module):
    """Saved nodes (leading axis: n_steps // save_every + 1 rows, the initial state first):
    g, q, body momenta M = Π and P, body velocities ξ = J⁻¹Π and ν = M⁻¹P."""

    g: jax.Array
    q: jax.Array | None
    M: jax.Array
    P: jax.Array | None
    xi: jax.Array
    nu: jax.Array | None


def splitting_initial_state(system, x0: State) -> SplittingState:
    """Continuous Legendre map (Π, P) = (ℓ_ξ, ℓ_ν) at the initial data; ν₀ = ρ_Q(g₀)⁻¹q̇₀."""
    nu0 = system.configuration_action.act_inverse(x0.g, x0.qdot) if system.has_additional else None
    mu, p = system.momenta(x0.xi, system.body_configuration(x0.g, x0.q), nu0, system.body_advected(x0.g))
    dtype = x0.g.dtype
    return SplittingState(x0.g, x0.q, mu.astype(dtype), None if p is None else p.astype(dtype))


# --- the step ------------------------------------------------------------------------------------
# With pieces X₀ (outermost) … X_m, stage i of Φ*_{α_i}∘Φ_{β_i} after its first flow X₀(β_i) is
#   X₁(β_i) … X_{m−1}(β_i) X_m(β_i + α_i) X_{m−1}(α_i) … X₁(α_i) X₀(next_i),
# next_i = α_i + β_{i+1} merging X₀ into the next stage (next_s = α_s + β₁ into the next step,
# or α_s at the end). The stages run as a rolled loop: one copy of the stage to compile.
def _stage(flows, order, h, s, coefficients):
    beta, alpha, following = coefficients
    for piece in order[1:-1]:
        s = flows[piece](beta * h, s)
    s = flows[order[-1]]((beta + alpha) * h, s)
    for piece in reversed(order[1:-1]):
        s = flows[piece](alpha * h, s)
    return flows[order[0]](following * h, s)


def stage_table(method):
    """Rows (β_i, α_i, next_i) of ``method``, next_i = α_i + β_{i+1} and next_s = α_s + β₁."""
    c = np.asarray(METHODS[method][1], dtype=np.float64)
    beta, alpha = c[0::2], c[1::2]
    return np.stack([beta, alpha, alpha + np.roll(beta, -1)], axis=1)


def _steps(flows, order, table, h, s, n, remat_block=None):
    """``n`` steps from a state whose first flow X₀(β₁h) has been applied; the last step ends
    with X₀(α_s h), the others with X₀((α_s + β₁)h). One loop over the n·s stages: a single
    copy of the stage to compile (unrolling it measured slower on CPU, with and without the loop
    option, and compiles longer). Leading rows of zeros in ``table`` are exact no-ops (every
    piece's flow over time 0 is the identity to the bit: cos 0 = 1, sin 0 = 0, kicks by 0).
    ``remat_block``: reverse mode rematerialises each stage by itself, in blocks of as many
    stages (:func:`~vi_jax._saved_nodes.each_step_rematerialised`; a program that does not
    differentiate runs one loop: :func:`~vi_jax._saved_nodes.checkpointed`)."""
    table = jnp.asarray(table, h.dtype)
    n_stages = table.shape[0]

    def body(i, s):
        row = table[i % n_stages]
        row = jnp.where(i == n * n_stages - 1, row.at[2].set(row[1]), row)
        return _stage(flows, order, h, s, row)

    if isinstance(n, int) and n * n_stages == 1:
        return body(0, s)
    if remat_block:

        def program(stage, carry, checkpoint):
            if checkpoint:
                return each_step_rematerialised(stage, carry, n * n_stages, remat_block)
            return jax.lax.scan(stage, carry, None, length=n * n_stages)[0]

        stage = lambda carry, _: ((carry[0] + 1, body(*carry)), None)  # noqa: E731
        return checkpointed(program, stage, (jnp.asarray(0, jnp.int32), s))[1]
    return jax.lax.fori_loop(0, n * n_stages, body, s)


def _first(flows, order, beta1, h, s):
    return flows[order[0]](beta1 * h, s)


def splitting_step(parts, h, state: SplittingState, order: int = 2, *, method=None, arrangement=None) -> SplittingState:
    """One step of the splitting method of ``order`` (or the named ``method``, pieces in
    ``arrangement``) on the body-frame state; ``parts`` from ``separable_parts(system)``."""
    method, arrangement = resolve(order, method, arrangement, parts.sphere)
    if ("S" in arrangement) != parts.sphere:
        raise ValueError(f"arrangement: {arrangement!r} needs separable_parts(..., sphere={'S' in arrangement})")
    flows = piece_flows(parts)
    pieces = arrange(tuple(flows), arrangement)
    h = jnp.asarray(h, state.M.dtype)
    table = stage_table(method)
    s = _first(flows, pieces, float(table[0, 0]), h, to_phase(parts, state.g, state.q, state.M, state.P))
    return SplittingState(*from_phase(parts, _steps(flows, pieces, table, h, s, 1)))


def advance(parts, method, arrangement, h, phase, n_saved, save_every, checkpoint=False):
    """``n_saved`` nodes of ``save_every`` steps; returns the saved principal-frame states.
    ``checkpoint``: reverse mode stores the states at the saved nodes and block boundaries only
    and recomputes the steps between them (memory ∝ saved nodes, not steps × stages).

    On XLA:CPU's default loop plan (:func:`~vi_jax._saved_nodes.step_block`) every step saved
    runs in blocks of ``step_block`` nodes, each node rematerialised, not its block; with a node
    every few steps each stage is rematerialised by itself instead of the node (``python
    benchmarks/reverse_mode_plan.py``, 4,000 steps under ``jit``, µs a step against the plan of
    blocks of 128 nodes, each node rematerialised): vehicle, Strang, every node saved: forward
    4.85 → 1.24, gradient 18.1 → 6.3; a node every 10 steps: gradient 16.4 → 6.7 (the heavy
    top 12.6 → 3.5). The stages' blocks are seen by differentiation only
    (:func:`~vi_jax._saved_nodes.checkpointed`): a program that does not differentiate runs them
    in one loop (the heavy top, a node every 10 steps: 0.40 µs a step, 0.38 with
    ``checkpoint=False``; 0.45 while its forward pass ran the blocks too)."""
    flows = piece_flows(parts)
    pieces = arrange(tuple(flows), arrangement)
    table = stage_table(method)
    default_loops = default_cpu_loops()
    each_stage = checkpoint and default_loops and save_every > 1
    remat_block = step_block(phase, power_of_two=False) if each_stage else None

    def node(s, _):
        s = _steps(flows, pieces, table, h, _first(flows, pieces, float(table[0, 0]), h, s), save_every, remat_block)
        return s, s

    if default_loops and save_every == 1:  # blocks of steps; each node rematerialised, not its block
        return scan_saved_nodes(node, phase, n_saved, checkpoint, step_block(phase), blocks=False)[1]
    return scan_saved_nodes(node, phase, n_saved, checkpoint, nodes=not each_stage)[1]


def advance_loop(parts, method, arrangement, h, phase, n_saved, save_every, capacity):
    """:func:`advance` with traced ``n_saved`` (≤ ``capacity``) and ``save_every``: one program
    for every run length (forward only). Rows past ``n_saved`` repeat the initial state."""
    flows = piece_flows(parts)
    pieces = arrange(tuple(flows), arrangement)
    table = stage_table(method)
    rows = jax.tree.map(lambda x: jnp.broadcast_to(x, (capacity,) + x.shape), phase)

    def node(k, carry):
        s, rows = carry
        s = _steps(flows, pieces, table, h, _first(flows, pieces, float(table[0, 0]), h, s), save_every)
        return s, jax.tree.map(lambda buf, x: buf.at[k].set(x), rows, s)

    return jax.lax.fori_loop(0, n_saved, node, (phase, rows))[1]


def initial_phase(parts, x0: State):
    """The principal-frame state of the continuous initial data."""
    state0 = splitting_initial_state(parts.system, x0)
    return to_phase(parts, state0.g, state0.q, state0.M, state0.P)


def nodes(parts, phase0, saved) -> SplittingNodes:
    """The initial and saved principal-frame states as body-frame nodes."""
    phases = jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), phase0, saved)
    g, q, M, P = from_phase(parts, phases)
    xi, nu = velocities(parts, phases)
    return SplittingNodes(g, q, M, P, xi, nu)


@eqx.filter_jit
def _run(parts, x0, h, n_saved, save_every, method, arrangement, checkpoint):
    phase0 = initial_phase(parts, x0)
    return nodes(parts, phase0, advance(parts, method, arrangement, h, phase0, n_saved, save_every, checkpoint))


def splitting_run(
    system, x0: State, h, n_steps: int, order: int = 2, save_every: int = 1, *,
    method=None, arrangement=None, checkpoint=False,
) -> SplittingNodes:
    """Integrate a separable scene from continuous initial data ``x0`` with the splitting method
    of ``order`` ∈ {2, 4, 6, 8} (or the named ``method`` of ``METHODS``, pieces in
    ``arrangement``; defaults in ``DEFAULTS``); saves every ``save_every`` steps. Jittable,
    vmappable, differentiable by plain reverse mode (``checkpoint``: see :func:`advance`); the
    working dtype is that of (x0.g, x0.xi, h)."""
    n_steps, save_every = val.check_steps(n_steps, save_every)
    dtype = jnp.result_type(x0.g, x0.xi, h)
    if not jnp.issubdtype(dtype, jnp.floating):
        dtype = jnp.result_type(float)
    cast = lambda x: None if x is None else jnp.asarray(x, dtype)  # noqa: E731
    x0 = State(cast(x0.g), cast(x0.xi), cast(x0.q), cast(x0.qdot))
    method, arrangement, parts = resolved_parts(system, dtype, order, method, arrangement)
    return _run(parts, x0, jnp.asarray(h, dtype), n_steps // save_every, save_every, method, arrangement, bool(checkpoint))
