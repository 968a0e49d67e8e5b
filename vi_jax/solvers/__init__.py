"""Small dense Newton solves with implicit-function gradients, and their result codes."""

from ._newton import (
    CHORD_ITERATIONS as CHORD_ITERATIONS,
    MAX_ITERATIONS as MAX_ITERATIONS,
    NONFINITE as NONFINITE,
    NOT_SEPARABLE as NOT_SEPARABLE,
    RESULT_MESSAGES as RESULT_MESSAGES,
    SINGULAR_DIFFERENCE_MAP as SINGULAR_DIFFERENCE_MAP,
    SUCCESS as SUCCESS,
    LUFactors as LUFactors,
    NewtonStats as NewtonStats,
    dense_solve as dense_solve,
    lu_factor as lu_factor,
    lu_solve as lu_solve,
    newton_root as newton_root,
)
