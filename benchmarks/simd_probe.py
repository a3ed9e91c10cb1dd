"""The RK4 interval in SIMD lane blocks against one row at a time, on the calling thread.

    python benchmarks/simd_probe.py [--rows 512] [--seconds 5] [--variant v1_route]

Both run the library's own code (``bogie_env.simulator._advance_block``, one compilation per
block width): blocks of ``bogie_env.lanes.LANES`` rows, and blocks of one row (scalar code: what
``advance_rows`` does with the rows that do not fill a block, e.g. a single env's). Rows: the
Bogie/Hunting-v0 task's (or another env config variant's, e.g. ``v1_route``: v1's rate limits
and delays, routes with curves and cant), with random states, commands and coefficients
(+-5 %) per row. Prints

- whether both give the same bits after 20 intervals (all row arrays compared);
- rows/s of each (CPU time, best of half-second batches), twice, and the ratio; and for the
  interval's right-hand sides alone (``dynamics._rhs_lanes`` at the rows' states), in blocks
  of LANES rows and in blocks of one lane (scalar code), with their share of the interval;
- the packed double-precision instructions in the machine code of the 8-lane block
  (``inspect_asm``: zmm/ymm registers, and the scalar ones), and whether any FMA was emitted.

It compiles into a fresh temporary numba cache (``NUMBA_CACHE_DIR``; numba shows no machine code
for kernels loaded from a cache): about a minute of compilation first.
"""

from __future__ import annotations

import argparse
import os
import re
import tempfile
import time
import timeit

os.environ.setdefault("NUMBA_CACHE_DIR", tempfile.mkdtemp(prefix="bogie_numba_cache_"))

import numpy as np  # noqa: E402
from numba import njit  # noqa: E402

from bogie_env.actuators import N_CHANNELS, lag_weights  # noqa: E402
from bogie_env.dynamics import N_COEFFICIENTS, N_INPUTS, N_STATES, _cant_trig, _rhs_lanes  # noqa: E402
from bogie_env.envs.task import HuntingTask  # noqa: E402
from bogie_env.lanes import LANES, stack_array  # noqa: E402
from bogie_env.simulator import M_SPEED, ROW_ARRAYS, _advance_block  # noqa: E402
from bogie_env.track import N_TRACK_SAMPLES  # noqa: E402

ROUNDS = 2


@njit(inline="always")
def _run_width(lanes, rows, channels, track, dt, n_sub):
    """One interval of every row in blocks of ``lanes`` rows (the row count a multiple of it)."""
    weights = np.empty((3 * n_sub + 1, N_CHANNELS))
    lag_weights(channels, dt, n_sub, weights)
    stop = rows[0].shape[0]
    for n0 in range(0, stop, lanes):
        _advance_block(lanes, n0, stop, rows, channels, track, dt, n_sub, np.empty(0), weights)  # no stage divisors: RK4


@njit
def _run_lanes(rows, channels, track, dt, n_sub):
    _run_width(LANES, rows, channels, track, dt, n_sub)


@njit
def _run_single(rows, channels, track, dt, n_sub):
    _run_width(1, rows, channels, track, dt, n_sub)


@njit(inline="always")
def _rhs_only(lanes, x, speed, track_sample, coefficients, out, n_sub):
    """The right-hand side alone, as often as an interval of n_sub substeps evaluates it (4 n_sub
    times a row), in blocks of ``lanes`` rows at the rows' current states, without inputs."""
    xb = stack_array((N_STATES, lanes))
    ob = stack_array((N_STATES, lanes))
    pb = stack_array((N_COEFFICIENTS, lanes))
    yt = stack_array((N_TRACK_SAMPLES, lanes))
    trig = stack_array((6, lanes))
    q = stack_array((N_INPUTS, lanes))
    v = stack_array((lanes,))
    frame = stack_array((2, lanes))
    for n0 in range(0, x.shape[0], lanes):
        for lane in range(lanes):
            n = n0 + lane
            xb[:, lane] = x[n]
            pb[:, lane] = coefficients[n]
            yt[:, lane] = track_sample[n]
            q[:, lane] = 0.0
            v[lane] = speed[n]
            cos_sin = _cant_trig(yt[:, lane])
            for k in range(6):
                trig[k, lane] = cos_sin[k]
        for _ in range(4 * n_sub):
            _rhs_lanes(xb, v, q, yt, trig, pb, ob, frame)
        for lane in range(lanes):
            out[n0 + lane] = ob[:, lane]


@njit(error_model="numpy")  # as the library's kernels: no division-by-zero checks
def _rhs_only_lanes(x, speed, track_sample, coefficients, out, n_sub):
    _rhs_only(LANES, x, speed, track_sample, coefficients, out, n_sub)


@njit(error_model="numpy")
def _rhs_only_single(x, speed, track_sample, coefficients, out, n_sub):
    _rhs_only(1, x, speed, track_sample, coefficients, out, n_sub)


def _rows(n: int, variant: str | None):
    task = HuntingTask(n, variant=variant, num_threads=1)
    task.reset_rows(np.arange(n))
    sim = task.sim
    rng = np.random.default_rng(1)
    sim.x[:] += rng.normal(scale=2e-3, size=sim.x.shape)
    sim.command[:] = rng.normal(scale=3e3, size=sim.command.shape)
    sim.coefficients[:] *= 1.0 + 0.05 * rng.uniform(-1, 1, size=sim.coefficients.shape)
    return sim


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=512)
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--variant", default=None, help="env config variant (bogie_env.envs.config.VARIANTS); default v0's")
    args = parser.parse_args()
    n = args.rows - args.rows % LANES
    sim = _rows(n, args.variant)
    fixed = (sim.channels, sim._track, sim.dt, sim.n_sub)
    base = tuple(a.copy() for a in sim.rows)
    lanes_rows, single_rows = tuple(a.copy() for a in base), tuple(a.copy() for a in base)
    for _ in range(20):
        _run_lanes(lanes_rows, *fixed)
        _run_single(single_rows, *fixed)
    differ = [name for name, a, b in zip(ROW_ARRAYS, lanes_rows, single_rows) if a.tobytes() != b.tobytes()]
    print(f"{n} rows, 20 intervals: blocks of {LANES} rows and of 1 row give the same bits: {not differ}"
          + (f" (differ: {', '.join(differ)})" if differ else ""))  # fmt: skip

    def rate(kernel, *inputs) -> float:
        """Rows/s of kernel(*inputs): CPU time, best of ``--seconds`` worth of half-second batches."""
        kernel(*inputs)
        calls = max(1, int(0.5 / max(timeit.timeit(lambda: kernel(*inputs), timer=time.process_time, number=1), 1e-6)))
        batches = max(1, int(args.seconds / 0.5))
        return n * calls / min(timeit.repeat(lambda: kernel(*inputs), timer=time.process_time, number=calls, repeat=batches))

    rhs_inputs = (sim.x.copy(), sim.motion[:, M_SPEED].copy(), sim.track_sample.copy(), sim.coefficients.copy(), np.empty_like(sim.x), sim.n_sub)
    for _ in range(ROUNDS):
        single = rate(_run_single, tuple(a.copy() for a in base), *fixed)
        lanes = rate(_run_lanes, tuple(a.copy() for a in base), *fixed)
        print(f"interval, rows/s: blocks of 1 row (scalar) {single:.4g}, of {LANES} rows {lanes:.4g}: ratio {lanes / single:.2f}")
        rhs_single, rhs_lanes = rate(_rhs_only_single, *rhs_inputs), rate(_rhs_only_lanes, *rhs_inputs)
        print(f"  its {4 * sim.n_sub} right-hand sides alone, rows/s: 1 lane (scalar) {rhs_single:.4g}, {LANES} lanes {rhs_lanes:.4g}: "
              f"ratio {rhs_lanes / rhs_single:.2f}; share of the interval in blocks of {LANES} rows: {lanes / rhs_lanes:.0%}")  # fmt: skip
    signature = next(s for s in _advance_block.signatures if str(s[0]) == f"Literal[int]({LANES})")
    asm = _advance_block.inspect_asm(signature)
    count = {label: len(re.findall(pattern, asm)) for label, pattern in (
        ("packed zmm", r"\tv\w+pd\t[^\n]*%zmm"), ("packed ymm", r"\tv\w+pd\t[^\n]*%ymm"),
        ("scalar", r"\tv\w+sd\t"), ("vdivpd", r"\tvdivpd"), ("vsqrtpd", r"\tvsqrtpd"), ("fma", r"\tvfn?m(add|sub)"))}  # fmt: skip
    print(f"instructions in the block of {LANES} lanes: " + ", ".join(f"{k} {v}" for k, v in count.items()))


if __name__ == "__main__":
    main()
