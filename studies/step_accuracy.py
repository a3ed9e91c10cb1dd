"""Accuracy of the RK4 step chosen from the spectrum: limit cycles and ramp onset at 2, 3, 8 substeps.

    python studies/step_accuracy.py

Prints the limit-cycle amplitude of y1 at 450 and 370 km/h, and the onset speed (1-s peak of
|y1 - track| above 4.5 mm) of a 1 m/s^2 ramp from 300 km/h on a 0.5 mm rms track, for 2, 3 and 8
RK4 substeps per 10 ms. docs/model.md (Section 8) quotes its output.
"""

import numpy as np

from bogie_env import BogieModel
from bogie_env.analysis.bifurcation import limit_cycle_state
from bogie_env.analysis.ramp import simulate
from bogie_env.track import alignment_profile


def main() -> None:
    model = BogieModel()
    for speed_kmh in (450.0, 370.0):
        start = limit_cycle_state(model, speed_kmh)
        for n_sub in (2, 3, 8):
            run = simulate(model, start, speed_kmh / 3.6, 0.0, 30.0, n_sub=n_sub)
            amplitude = np.abs(run.signal("y1")[-1000:]).max() * 1e3
            print(f"limit cycle at {speed_kmh:g} km/h, {n_sub} substeps: y1 amplitude {amplitude:.3f} mm")
    track = alignment_profile(5e-4)
    for n_sub in (2, 3, 8):
        x0 = model.equilibrium(300 / 3.6)
        x0[0] += 1e-3
        run = simulate(model, x0, 300 / 3.6, 1.0, 80.0, n_sub=n_sub, track=track)
        speeds, peaks = run.envelope("y1", 1.0)
        above = np.nonzero(peaks > 4.5e-3)[0]
        onset = f"{speeds[above[0]] * 3.6:.1f} km/h" if above.size else "none"
        print(f"ramp onset, {n_sub} substeps: {onset}")


if __name__ == "__main__":
    main()
