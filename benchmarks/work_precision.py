"""Error against compiled run time: every vi_jax scheme against diffrax's solvers on the
underwater vehicle and the heavy top (work precision at T = 50 s), a long-horizon run on a
bounded motion (energy, Kelvin–Noether and group-constraint drift) and energy error against
time. The measurement lives in ``vi_jax/studies/work_precision.py`` (also ``vi-jax compare``). Like the command
line, it compiles small-step loops into single XLA:CPU kernels (``vi_jax/engine/_cpu_tuning.py``), for
every peer alike; set XLA_FLAGS=--xla_backend_extra_options= to measure XLA's default instead.

    python benchmarks/work_precision.py [--quick] [--repeats 5] [--out DIR] [--no-progress]
"""

import argparse

from vi_jax.cli.compare import add_compare_arguments, run_compare
from vi_jax.engine._cpu_tuning import enable_fast_cpu_loops

if __name__ == "__main__":
    enable_fast_cpu_loops()
    run_compare(add_compare_arguments(argparse.ArgumentParser(description=__doc__.splitlines()[0])).parse_args())
