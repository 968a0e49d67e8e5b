"""Write the example telemetry file docs/telemetry_example.csv: 150 samples at irregular times
over 60 s of the position and attitude (quaternions) of the underwater vehicle's default run
(h = 0.01, order 4), with noise σ = 0.01 m and 0.01 rad, 5 rows without attitude and 3 without
x, y (a depth gauge alone).

    python benchmarks/make_telemetry_example.py [--out docs/telemetry_example.csv]
"""

import argparse
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import vi_jax as vj  # noqa: E402
from vi_jax.fitting._csv import write_telemetry  # noqa: E402
from vi_jax.fitting._telemetry import Telemetry, synthesize_telemetry  # noqa: E402

N_SAMPLES, DURATION = 150, 60.0


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent.parent / "docs" / "telemetry_example.csv")
    args = parser.parse_args()

    rng = np.random.default_rng(0)
    gaps = rng.uniform(0.1, 0.7, N_SAMPLES)
    t = np.round(np.cumsum(gaps) * DURATION / gaps.sum(), 3)
    model = vj.models.UnderwaterVehicle()
    sigma = {"position": 0.01, "attitude": 0.01}
    telemetry = synthesize_telemetry(model, model.initial_state(), t, sigma=sigma, h=0.01, order=4, seed=7)

    position = np.asarray(telemetry.values["position"]).copy()
    attitude = np.asarray(telemetry.values["attitude"]).copy()
    rows = rng.choice(N_SAMPLES, 8, replace=False)
    attitude[rows[:5]] = np.nan
    position[rows[5:], :2] = np.nan
    write_telemetry(args.out, Telemetry(t, sigma=sigma, position=position, attitude=attitude))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
