"""Env steps per second from Python (VecEnv.step, random actions) against the Rust engine
alone (the same batched step called in a Rust loop), for B = 1, 16, 256.

    python python/bench/throughput.py [--data DIR] [--seconds S] [--map R C]

Prints one row per B: env steps/s from Python, from Rust, and the per-call boundary overhead
(time per Python call minus time per Rust call).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import gman


def measure(b: int, seconds: float, data, grid) -> tuple:
    env = gman.make_vec_env(data=data, split="train", num_envs=b, seed=0, map=grid)
    env._core.warm_up()
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    # Calibrate the number of calls to about `seconds` of Python stepping.
    calls = 64
    acts = rng.integers(0, 6, size=(calls, b))
    while True:
        t0 = time.perf_counter()
        for a in acts:
            env.step(a)
        dt = time.perf_counter() - t0
        if dt >= seconds / 4 or calls >= 1 << 22:
            break
        calls *= 4
        acts = rng.integers(0, 6, size=(calls, b))
    best_py = float("inf")
    best_rs = float("inf")
    for rep in range(3):
        t0 = time.perf_counter()
        for a in acts:
            env.step(a)
        best_py = min(best_py, time.perf_counter() - t0)
        best_rs = min(best_rs, env._core.bench_steps(calls, rep))
    py_rate = calls * b / best_py
    rs_rate = calls * b / best_rs
    overhead_us = (best_py - best_rs) / calls * 1e6
    env.close()
    return calls, py_rate, rs_rate, overhead_us


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=None, help="GMAN data directory (default: the synthetic world)")
    ap.add_argument("--seconds", type=float, default=2.0, help="target seconds per measurement")
    ap.add_argument("--map", type=int, nargs=2, default=None, metavar=("R", "C"), help="also fill the spatial map")
    ap.add_argument("--sizes", type=int, nargs="+", default=[1, 16, 256])
    a = ap.parse_args()
    grid = tuple(a.map) if a.map else None
    print(f"world: {a.data or 'synthetic'}, map: {grid}, random actions, best of 3")
    print(f"{'B':>5} {'calls':>9} {'Python steps/s':>16} {'Rust steps/s':>16} {'Python/Rust':>12} {'overhead/call':>14}")
    for b in a.sizes:
        calls, py, rs, ov = measure(b, a.seconds, a.data, grid)
        print(f"{b:>5} {calls:>9} {py:>16,.0f} {rs:>16,.0f} {py / rs:>11.1%} {ov:>11.2f} us")


if __name__ == "__main__":
    main()
