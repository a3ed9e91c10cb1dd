"""Is the v1 integration step converged? Spectrum errors and closed-loop critical speeds.

1. RK4's error on the lightly damped modes (damping ratio < 0.5) over v1's speed range, per
   number of substeps per 10 ms step: the relative error of the decay rate and of the
   frequency (``bogie_env.integrate.eigenvalue_errors``), for nominal and worn wheels.
2. Measured: the onset speed of hunting on v1's ramp (100 -> 600 km/h at 1.5 m/s^2, alert-level
   track, one step of loop delay, rate limits) for the passive bogie and the gain-scheduled LQR
   (``bogie_agents.controllers.lqr.LQRController``, full-state observation, designed for the
   episode's conicity without regard to the delay), with the v0 step (stability only), the v1
   step and half the v1 step. Same seeds, same track positions and noise in every run: the
   differences are the integration's.

    python studies/step_convergence.py            # the figures in docs/environment.md
    python studies/step_convergence.py --quick    # fewer seeds and conicities
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bogie_agents.controllers.lqr import LQRController
from bogie_env.dynamics import BogieModel
from bogie_env.envs.config import make_config
from bogie_env.envs.task import HuntingTask
from bogie_env.integrate import eigenvalue_errors, spectrum, stable_substep
from bogie_env.params import BogieParams

KMH = 3.6


def spectral_table(conicities: list[float], n_subs: list[int]) -> None:
    print("RK4 relative errors of the lightly damped modes, v1 speed range 100-600 km/h, dt = 10 ms")
    print("conicity  " + "  ".join(f"n_sub={n:<2d}(decay, freq)" for n in n_subs))
    base = BogieParams.paper()
    for lam in conicities:
        model = BogieModel(base.replace(lam=lam))
        eig = spectrum(model, np.linspace(100 / KMH, 600 / KMH, 7)).ravel()
        cells = [eigenvalue_errors(eig, 0.01 / n) for n in n_subs]
        print(f"{lam:<9g} " + "  ".join(f"{d:8.3f} {f:8.4f}      " for d, f in cells))
    stable = stable_substep(BogieModel(base), 300 / KMH, 600 / KMH, 0.01).n_sub
    print(f"v0's step (stability only, 300-600 km/h): {stable} substeps")


def onset_speeds(controller: str, conicity: float, n_sub: int, delay_steps: int, seeds: list[int], method: str = "rk4") -> np.ndarray:
    """Hunting onset (km/h) of each seed on the v1 ramp with the env's integrator ``method``
    (``integration.method``) at ``n_sub`` substeps; 600 where none was detected."""
    acts = {"delay_steps": delay_steps}
    config = {
        "randomize": {},
        "integration": {"n_sub": n_sub, "method": method},
        "actuators": {name: acts for name in ("frame_lateral", "frame_yaw", "wheelset1_yaw", "wheelset2_yaw")},
    }
    if controller == "lqr":
        config.update(observation={"type": "state"}, sensors={"enabled": False})
    cfg = make_config(config, variant="v1_passive" if controller == "passive" else "v1")
    task = HuntingTask(len(seeds), cfg)
    task.seed_rows(np.arange(len(seeds)), seeds)
    task.reset_rows(np.arange(len(seeds)), {"conicity": conicity})
    policy = None
    if controller == "lqr":
        policy = LQRController(cfg, model=BogieModel(task.base_params.replace(lam=conicity)))
        policy.reset(len(seeds))
    done = np.zeros(len(seeds), dtype=bool)
    while not np.all(done):
        actions = policy.act(task.obs) if policy else np.zeros((len(seeds), task.action_dim))
        task.step(actions)
        done |= task.done
    onset = task.onset_speed_kmh.copy()
    return np.where(np.isnan(onset), cfg["speed"]["end_kmh"], onset)


def measured_table(conicities: list[float], seeds: list[int]) -> None:
    v1_sub = HuntingTask(1, make_config(variant="v1")).n_sub
    n_subs = [2, v1_sub, 2 * v1_sub]
    print(f"\nHunting onset on the v1 ramp, mean over seeds {seeds} (km/h); v1 step: {v1_sub} substeps")
    print(f"{'controller':<10} {'conicity':>8} {'delay':>5}  " + "  ".join(f"n_sub={n:<3d}" for n in n_subs)
          + "  |v1 - half| |v0 - half|")  # fmt: skip
    for controller, delays in (("passive", [1]), ("lqr", [1, 2])):
        for lam in conicities:
            for delay in delays:
                t0 = time.perf_counter()
                means = [float(np.mean(onset_speeds(controller, lam, n, delay, seeds))) for n in n_subs]
                print(f"{controller:<10} {lam:>8g} {delay * 10:>3d}ms  " + "  ".join(f"{m:9.1f}" for m in means)
                      + f"  {abs(means[1] - means[2]):10.2f} {abs(means[0] - means[2]):10.2f}"
                      + f"   ({time.perf_counter() - t0:.0f} s)", flush=True)  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2 seeds, conicities 0.025 and 0.1")
    args = parser.parse_args()
    conicities = [0.025, 0.1] if args.quick else [0.025, 0.05, 0.1, 0.2, 0.3]
    seeds = [0, 1] if args.quick else [0, 1, 2, 3]
    spectral_table([0.025, 0.1, 0.3], [2, 3, 4, 6, 8, 10, 12, 16, 20])
    measured_table(conicities, seeds)


if __name__ == "__main__":
    main()
