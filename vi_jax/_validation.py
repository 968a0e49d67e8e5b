"""Eager input validation at the API boundary: clear ``ValueError``s naming the argument, the
expectation and the value given. Checks on values run only when the values are concrete
(not traced: also constants closed over by a ``jit``-ed function, evaluated at trace time);
shape and dtype checks always run."""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np


def is_concrete(x) -> bool:
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(x))


def outside_transformations() -> bool:
    """Whether no transformation (``jit``, ``grad``, ``vmap``, …) is tracing the caller. False
    where this JAX no longer tells (callers then take their traced path, never wrongly the other)."""
    find = getattr(jax.extend.core, "find_top_trace", None)
    return find is not None and type(find(())).__name__ == "EvalTrace"


def is_eager(x) -> bool:
    """Whether a call with inputs ``x`` runs eagerly: ``x`` concrete and no transformation
    tracing the caller. Concrete inputs alone do not say so: a scene's function may close over
    a traced value (e.g. a Lagrangian closing over a parameter being differentiated)."""
    return is_concrete(x) and outside_transformations()


def converted(value, dtype):
    """``jnp.asarray(value, dtype)``, a concrete ``value`` (a step size, a step count) converted
    on the host: JAX converts by a program compiled on the first conversion of each kind (for a
    first ``vj.simulate``, two of 15–20 ms each). A traced or committed array is converted as
    ``jnp.asarray`` does (its placement kept)."""
    if isinstance(value, jax.core.Tracer) or getattr(value, "committed", False):
        return jnp.asarray(value, dtype)
    return jax.device_put(np.asarray(value, dtype))


def step_count(n):
    """A step or node count as a concrete int32 array: a loop program takes it as data, so
    another count compiles nothing (:func:`converted`)."""
    return converted(n, jnp.int32)


def is_batched(x) -> bool:
    """Whether a leaf of ``x`` is being batched by ``jax.vmap`` (a batch tracer)."""
    return any(isinstance(leaf, jax.core.Tracer) and hasattr(leaf, "batch_dim") for leaf in jax.tree_util.tree_leaves(x))


def _eager(check):
    """Evaluate a check at trace time when its inputs are concrete constants."""

    @functools.wraps(check)
    def wrapped(*args, **kwargs):
        with jax.ensure_compile_time_eval():
            return check(*args, **kwargs)

    return wrapped


def _short(value) -> str:
    if np.ndim(value) == 0 and not isinstance(value, str):
        try:
            return f"{np.asarray(value).item()!r}"
        except (TypeError, ValueError):
            return repr(value)
    text = np.array2string(np.asarray(value), precision=6, threshold=12)
    return text if len(text) < 200 else text[:197] + "..."


@_eager
def as_array(name, value, shape=None):
    try:
        # Numbers by a transfer: jnp.asarray compiles a program for them (same dtype, weak type).
        on_device = isinstance(value, (int, float, np.ndarray, np.generic))
        arr = value if isinstance(value, jax.Array) else jax.device_put(value) if on_device else jnp.asarray(value)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{name}: expected an array, got {value!r}") from err
    if not jnp.issubdtype(arr.dtype, jnp.number) or jnp.issubdtype(arr.dtype, jnp.complexfloating):
        raise ValueError(f"{name}: expected a real numeric array, got dtype {arr.dtype}")
    if shape is not None and arr.shape != tuple(shape):
        raise ValueError(f"{name}: expected shape {tuple(shape)}, got shape {arr.shape}")
    return arr


def _dtype(leaf):
    """The dtype of an array or a Python number (without ``jnp.result_type``'s type promotion
    machinery: these checks run at every concrete call)."""
    return leaf.dtype if hasattr(leaf, "dtype") else np.result_type(leaf)


def is_numeric(leaf) -> bool:
    """Whether ``leaf`` is a float array or a Python float."""
    return isinstance(leaf, (float, np.ndarray, jax.Array)) and jnp.issubdtype(_dtype(leaf), jnp.inexact)


def numeric_leaves(tree):
    """The float leaves (arrays or Python floats) of a pytree."""
    return [leaf for leaf in jax.tree_util.tree_leaves(tree) if is_numeric(leaf)]


@_eager
def check_finite(name, value):
    if is_concrete(value):
        for leaf in jax.tree_util.tree_leaves(value):
            if jnp.issubdtype(_dtype(leaf), jnp.inexact) and not np.isfinite(np.asarray(leaf)).all():
                raise ValueError(f"{name}: expected finite values, got {_short(leaf)}")
    return value


@_eager
def check_positive_scalar(name, value):
    arr = as_array(name, value, ())
    if is_concrete(arr) and not (np.isfinite(np.asarray(arr)) and float(arr) > 0):
        raise ValueError(f"{name}: expected a finite number > 0, got {_short(arr)}")
    return arr


def check_int(name, value, minimum):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name}: expected an integer ≥ {minimum}, got {value!r}")
    return int(value)


def check_steps(n_steps, save_every):
    """``n_steps`` ≥ 1 and ``save_every`` ≥ 1 dividing it."""
    n_steps = check_int("n_steps", n_steps, 1)
    save_every = check_int("save_every", save_every, 1)
    if n_steps % save_every:
        raise ValueError(f"save_every: expected a divisor of n_steps={n_steps}, got {save_every}")
    return n_steps, save_every


def check_choice(name, value, choices):
    if value not in choices:
        raise ValueError(f"{name}: expected one of {tuple(choices)}, got {value!r}")
    return value


@eqx.filter_jit  # one program per group and shape: op by op, a check compiles a dozen (0.3–0.5 s)
def membership_error(group, g):
    """The largest membership error of ``g``: a group element, or a batch of them (leading axes)."""
    return jnp.max(jax.vmap(group.membership_error)(jnp.reshape(g, (-1,) + jnp.shape(g)[-2:])))


def check_values(named, group, g, g_batched=False, tol=1e-6):
    """``named`` (name, leaf, whether the leaf carries an ensemble's member axis) finite and ``g``
    (x0.g) on ``group`` (one element per member where ``g_batched``), the error naming the
    members at fault. The array leaves are reduced where they are, by one program, and a flag per
    leaf comes to the host (an accelerator's ensemble is not copied to the host to be checked; on
    CPU as fast as a check per leaf: ``python benchmarks/ensemble_call_overhead.py``), the error
    messages of a leaf or ``g`` without the member axis those of :func:`check_finite` and
    :func:`check_on_group`. Python numbers are checked on the host, the arrays only where they
    are concrete (as every check here)."""
    arrays = [entry for entry in named if isinstance(entry[1], (np.ndarray, jax.Array))]
    for name, x, _ in named:
        if not isinstance(x, (np.ndarray, jax.Array)):
            check_finite(name, x)
    if not is_concrete([x for _, x, _ in arrays] + [g]):
        return
    with jax.ensure_compile_time_eval():
        finite, err = jax.device_get(_value_summary(group, [x for _, x, _ in arrays], g))
    for (name, x, batched), ok in zip(arrays, finite):
        if not ok and batched:
            bad = np.flatnonzero(~np.isfinite(np.asarray(x)).reshape(np.shape(x)[0], -1).all(axis=1))
            raise ValueError(f"{name}: expected finite values for every member, got non-finite values in members {_first(bad)}")
        if not ok:
            check_finite(name, x)
    if not err <= tol and g_batched:
        errors = np.asarray(jax.vmap(membership_error, in_axes=(None, 0))(group, g))
        raise ValueError(
            f"x0.g: expected elements of {type(group).__name__} for every member, got membership error {float(err):.3g} "
            f"in members {_first(np.flatnonzero(~(errors <= tol)))}"
        )
    if not err <= tol:
        check_on_group("x0.g", group, g, tol)


def _first(indices) -> str:
    return f"{indices[:10].tolist()}{' …' if indices.size > 10 else ''}"


@functools.partial(jax.jit, static_argnums=0)
def _value_summary(group, leaves, g):
    finite = jnp.stack([jnp.all(jnp.isfinite(x)) for x in leaves]) if leaves else jnp.zeros(0, bool)
    return finite, membership_error(group, g)


@_eager
def check_on_group(name, group, g, tol=1e-6):
    if is_concrete(g):
        err = float(membership_error(group, g))
        if not err <= tol:
            raise ValueError(
                f"{name}: expected an element of {type(group).__name__} (membership error ≤ {tol:g}), "
                f"got membership error {err:.3g} for {_short(g)}"
            )
    return g


@_eager
def check_spd(name, value, tol=0.0):
    arr = as_array(name, value)
    if is_concrete(arr):
        mat = np.asarray(arr, dtype=float)
        if mat.ndim == 1:
            ok = bool(np.all(np.isfinite(mat)) and np.all(mat > tol))
        else:
            ok = bool(
                mat.shape[0] == mat.shape[1]
                and np.all(np.isfinite(mat))
                and np.allclose(mat, mat.T, rtol=1e-10, atol=1e-12)
                and np.all(np.linalg.eigvalsh(0.5 * (mat + mat.T)) > tol)
            )
        if not ok:
            raise ValueError(f"{name}: expected symmetric positive definite values, got {_short(arr)}")
    return arr
