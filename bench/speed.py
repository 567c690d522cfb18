"""Speed of the estimator cascade, offline compensation and a whole session.

    .venv/bin/python bench/speed.py [--quick]

Prints, on this machine:
* the ``rls`` cascade (Algorithm 1) and ``kalman`` in µs per sample, median
  and p99 over blocks of 1, 7 and 1024 samples (a 1 kHz sensor read by a 1 kHz
  loop gives blocks of 1; a 7 kHz NetFT read by a 1 kHz loop, 7; offline,
  1024), each with both kernels side by side (``kernel = "numba"``, compiled,
  and ``"numpy"``, the reference); ``batch`` over 1, 7, 64 and 1024; and
  ``kalman`` with each of its model options (mount rotation, inertia, auto
  noise, bias rate, a late sensor stream), both kernels;
* ``compensate`` throughput in samples/s over a simulated CSV;
* a full simulated session (sensor → aligner → estimator → haptic command →
  MCAP) run as fast as possible: simulated seconds per wall second at 1 kHz
  and 7 kHz sensor rates (above 1.0 keeps up in real time).
Numbers vary with the machine and its load: quote them, never assert them.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from hapticlab.core.frames import quat_wxyz_from_matrix
from hapticlab.plugins.estimators.batch import BatchEstimator
from hapticlab.plugins.estimators.kalman import KalmanEstimator
from hapticlab.plugins.estimators.rls import RLSEstimator
from hapticlab.plugins.simworld import SimWorld
from hapticlab.sessions.bench.loop import per_sample_us
from hapticlab.sessions.bench.simulation import simulate
from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import build_session, run_session
from hapticlab.sessions.offline.compensate import compensate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller runs (a smoke test)")
    args = parser.parse_args()
    n = 4096 if args.quick else 20480
    # the simulated world: a 0.35 kg tool on a Gamma-class sensor (0.12 N, 0.01 N·m noise) on a random tour
    block, _ = simulate(SimWorld(seed=1, inertia=False), n / 1000.0, 1000.0)

    print(f"estimator µs per sample ({n} samples, second half timed; numba: compiled, numpy: the reference)")
    print(f"{'estimator':<10}{'block':>7}{'numba median':>14}{'p99':>9}{'numpy median':>14}{'p99':>9}")
    for name, factory in (("rls", RLSEstimator), ("kalman", KalmanEstimator)):
        for size in (1, 7, 1024):
            row = [
                per_sample_us(lambda kernel=kernel, factory=factory: factory(kernel=kernel), block, size)
                for kernel in ("numba", "numpy")
            ]
            print(f"{name:<10}{size:>7}{row[0][0]:>14.2f}{row[0][1]:>9.2f}{row[1][0]:>14.2f}{row[1][1]:>9.2f}")
    for size in (1, 7, 64, 1024):
        if size == 1 and not args.quick:
            continue  # minutes of pinv per sample; the baseline is not a live estimator
        med, p99 = per_sample_us(BatchEstimator, block, size)
        print(f"{'batch':<10}{size:>7}{'':>14}{'':>9}{med:>14.2f}{p99:>9.2f}")
    print(f"\nkalman options, µs per sample ({n} samples, second half timed)")
    print(f"{'option':<24}{'block':>7}{'numba median':>14}{'p99':>9}{'numpy median':>14}{'p99':>9}")
    options = {
        "mount_rotation = true": {"mount_rotation": True},
        "inertia = true": {"inertia": True},
        "noise = auto": {"noise_force": "auto", "noise_torque": "auto"},
        "bias_rate = true": {"bias_rate": True},
        "time_lag_s = -0.005": {"time_lag_s": -0.005},
    }
    for label, opts in options.items():
        for size in (1, 7, 64):
            row = [
                per_sample_us(lambda opts=opts, kernel=kernel: KalmanEstimator(kernel=kernel, **opts), block, size)
                for kernel in ("numba", "numpy")
            ]
            print(f"{label:<24}{size:>7}{row[0][0]:>14.2f}{row[0][1]:>9.2f}{row[1][0]:>14.2f}{row[1][1]:>9.2f}")

    with tempfile.TemporaryDirectory() as tmp:
        csv_path = Path(tmp) / "sim.csv"
        quat_BE = quat_wxyz_from_matrix(block.R_EB.transpose(0, 2, 1))
        table = np.column_stack([np.arange(n) * 1e-3, block.force_S, block.torque_S, quat_BE])
        np.savetxt(csv_path, table, delimiter=",", header="t,fx,fy,fz,tx,ty,tz,qw,qx,qy,qz", comments="")
        t0 = time.perf_counter()
        compensate(csv_path, Path(tmp) / "out.csv")
        dt = time.perf_counter() - t0
        print(f"\ncompensate (rls, CSV in and out): {n / dt:,.0f} samples/s ({n} rows in {dt:.2f} s)")

        duration = 2.0 if args.quick else 5.0
        print("\nfull simulated session, as fast as possible (recording every topic):")
        for rate in (1000, 7000):
            config, _ = load_config("demo")
            config = apply_overrides(config, ["session.realtime=false", f"sensor.rate_hz={rate}.0"])
            session = build_session(config)
            t0 = time.perf_counter()
            result = run_session(session, out=Path(tmp) / f"s{rate}.mcap", duration=duration)
            dt = time.perf_counter() - t0
            print(
                f"  sensor {rate:>5} Hz: {result.samples} samples, {duration / dt:.2f}× real time "
                f"({dt / result.samples * 1e6:.1f} µs per sample, loop at 1 kHz)"
            )


if __name__ == "__main__":
    main()
