"""Headless matplotlib figures for the analysis suite (the paper's Figs. 7-16 and more).

Every function takes a result object from the analysis modules and a path, and writes a
PNG atomically (to a temporary file, then renamed), so an interrupted run never leaves a
half-written figure behind.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..fileio import atomic_output  # noqa: E402
from ..stability import KMH  # noqa: E402

EN14363_KMH = 330.0  # EN 14363: stable to 30 km/h above the 300 km/h maximum running speed


def save(fig, path: str | Path, dpi: int = 130) -> Path:
    """Write a figure atomically and close it."""
    path = Path(path)
    try:
        with atomic_output(path, suffix=".png") as tmp:
            fig.savefig(tmp, dpi=dpi, bbox_inches="tight")
    finally:
        plt.close(fig)
    return path


def _mark_speeds(ax, linear_kmh: float | None = None, nonlinear_kmh: float | None = None, vertical: bool = True) -> None:
    line = ax.axvline if vertical else ax.axhline
    line(EN14363_KMH, color="tab:green", ls=":", lw=1.2, label="EN 14363 requirement 330 km/h")
    if linear_kmh is not None and np.isfinite(linear_kmh):
        line(linear_kmh, color="tab:red", ls="--", lw=1.2, label=f"linear critical speed {linear_kmh:.1f} km/h")
    if nonlinear_kmh is not None and np.isfinite(nonlinear_kmh):
        line(nonlinear_kmh, color="tab:purple", ls="-.", lw=1.2, label=f"nonlinear critical speed {nonlinear_kmh:.1f} km/h")


def param_label(name: str) -> str:
    """An axis label for a bogie parameter: its description, symbol and unit."""
    from ..params import FIELDS

    spec = FIELDS.get(name)
    return f"{spec.description} {name} ({spec.unit})" if spec and spec.unit else name


def root_locus_figure(locus, path, zoom: bool = False):
    """Figs. 7/8: eigenvalues in the complex plane from the lowest (triangle) to the highest speed (square).

    The full view shows the oscillatory modes near the imaginary axis (real part > -60 1/s,
    frequency < 150 rad/s), cropped to where they are; the zoom shows the hunting mode alone."""
    fig, ax = plt.subplots(figsize=(7, 5))
    ev = locus.eigenvalues
    v0, v1 = locus.speeds_kmh[0], locus.speeds_kmh[-1]
    shown = [j for j in range(ev.shape[1])
             if np.any((ev[:, j].real > -60) & (ev[:, j].imag > 0.5) & (ev[:, j].imag < 150))]  # fmt: skip
    for n, j in enumerate(shown):
        hunting = j == locus.hunting_mode
        ax.plot(ev[:, j].real, ev[:, j].imag, color="tab:blue" if hunting else "0.6", lw=2.0 if hunting else 0.8,
                zorder=3 if hunting else 1,
                label="hunting mode" if hunting else ("other modes" if n == 0 or (n == 1 and shown[0] == locus.hunting_mode) else None))  # fmt: skip
        first = n == 0
        ax.plot(ev[0, j].real, ev[0, j].imag, ">", color="k", ms=4, label=f"at {v0:.0f} km/h" if first else None)
        ax.plot(ev[-1, j].real, ev[-1, j].imag, "s", mfc="none", color="k", ms=4, label=f"at {v1:.0f} km/h" if first else None)
    ax.axvline(0.0, color="tab:red", lw=1, label="stability boundary (real part 0)")
    h = locus.hunting
    if zoom:
        ax.set_xlim(h.real.min() - 1, h.real.max() + 1)
        ax.set_ylim(min(h.imag.min(), 0) - 2, h.imag.max() + 2)
    else:
        pts = np.concatenate([ev[:, j] for j in shown]) if shown else h
        pts = pts[(pts.real > -60) & (pts.imag < 150)]
        re_lo, re_hi = min(pts.real.min(), 0.0), max(pts.real.max(), 0.0)
        im_hi = pts.imag.max()
        ax.set_xlim(re_lo - 0.08 * (re_hi - re_lo), re_hi + 0.08 * (re_hi - re_lo))
        ax.set_ylim(0, im_hi * 1.12)
    vc = locus.critical.speed_kmh
    ax.set_title(f"Root locus {locus.speeds_kmh[0]:.0f}-{locus.speeds_kmh[-1]:.0f} km/h; crossing at {vc:.1f} km/h")
    ax.set_xlabel("real part (1/s)")
    ax.set_ylabel("imaginary part (rad/s)")
    ax.legend(loc="best")
    ax.grid(alpha=0.3)
    return save(fig, path)


def real_parts_figure(locus, path):
    """Fig. 10: real parts of the tracked modes against speed, with a zoom on the crossing."""
    fig, (ax, zx) = plt.subplots(1, 2, figsize=(11, 4.5))
    v = locus.speeds_kmh
    for j in range(locus.eigenvalues.shape[1]):
        hunting = j == locus.hunting_mode
        for axis in (ax, zx):
            axis.plot(v, locus.eigenvalues[:, j].real, color="tab:blue" if hunting else "0.6",
                      lw=2 if hunting else 0.8, label="hunting mode" if hunting and axis is ax else None)  # fmt: skip
    vc = locus.critical.speed_kmh
    for axis in (ax, zx):
        axis.axhline(0, color="k", lw=0.8)
        _mark_speeds(axis, vc)
        axis.set_xlabel("speed (km/h)")
        axis.grid(alpha=0.3)
    ax.set_ylim(max(locus.eigenvalues.real.min(), -40), locus.eigenvalues.real.max() + 1)
    ax.set_ylabel("real part (1/s)")
    ax.legend(fontsize=8, loc="lower left")
    zx.set_xlim(vc - 25, vc + 25)
    zx.set_ylim(-3, 3)
    zx.set_title("zoom on the crossing")
    return save(fig, path)


def ramp_figure(result, path):
    """Fig. 9: lateral wheelset displacement against speed on the ramp, with a zoom on the onset."""
    traj = result.trajectory
    v = traj.speed_kmh
    y = traj.relative_lateral(1) * 1e3
    fig, (ax, zx) = plt.subplots(2, 1, figsize=(10, 7))
    ax.plot(v, y, lw=0.4, color="tab:blue")
    ax.set_ylabel("y1 relative to rail (mm)")
    ax.set_title(
        f"Ramp {v[0]:.0f}->{v[-1]:.0f} km/h at {result.accel:g} m/s^2, offset {result.initial_offset:g} m, "
        f"track rms {result.track_rms:g} m"
    )
    onset = result.onset_kmh
    for axis in (ax, zx):
        _mark_speeds(axis, result.linear_critical_speed_kmh)
        if onset is not None:
            axis.axvline(onset, color="tab:orange", lw=1.2, label=f"onset (> {result.onset_threshold * 1e3:g} mm) {onset:.1f} km/h")
        axis.grid(alpha=0.3)
        axis.set_xlabel("speed (km/h)")
    ax.legend(fontsize=8, loc="upper left")
    centre = onset if onset is not None else result.linear_critical_speed_kmh
    sel = (v > centre - 20) & (v < centre + 15)
    zx.plot(v[sel], y[sel], lw=0.6, color="tab:blue")
    zx.set_ylabel("y1 (mm), zoom")
    return save(fig, path)


def ramp_eigenvalue_figure(result, path):
    """Frozen eigenvalues along the ramp trajectory: largest real parts against speed."""
    fig, ax = plt.subplots(figsize=(8, 4.5))
    v = result.eigen_speeds * KMH
    real = np.sort(result.eigenvalues.real, axis=1)[:, ::-1]
    for k in range(min(4, real.shape[1])):
        ax.plot(v, real[:, k], lw=1.5 if k == 0 else 0.8, label="largest" if k == 0 else None)
    ax.axhline(0, color="k", lw=0.8)
    _mark_speeds(ax, result.linear_critical_speed_kmh)
    ax.set_ylim(-12, max(3, real[:, 0].max() + 1))
    ax.set_xlabel("speed (km/h)")
    ax.set_ylabel("real part (1/s)")
    ax.set_title("Frozen eigenvalues along the ramp trajectory (Jacobian at the current state)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    return save(fig, path)


def phase_portrait_figure(result, path, split_kmh: tuple[float, float] | None = None):
    """Fig. 11: phase portrait (y1, dy1), split into a lower and an upper speed range."""
    traj = result.trajectory
    v = traj.speed_kmh
    vc = result.linear_critical_speed_kmh
    lo_top, hi_bottom = split_kmh if split_kmh is not None else (vc + 25.0, vc)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    for ax, sel, title in (
        (axes[0], v <= lo_top, f"(a) {v[0]:.0f}-{lo_top:.0f} km/h"),
        (axes[1], v >= hi_bottom, f"(b) {hi_bottom:.0f}-{v[-1]:.0f} km/h"),
    ):
        ax.plot(traj.relative_lateral(1)[sel] * 1e3, traj.signal("dy1")[sel], lw=0.3)
        ax.set_xlabel("y1 (mm)")
        ax.set_ylabel("dy1/dt (m/s)")
        ax.set_title(title)
        ax.grid(alpha=0.3)
    return save(fig, path)


def onset_figure(rows: list[dict], linear_kmh: float, path):
    """How the ramp's visible onset moves with the initial offset and the track-noise floor."""
    fig, ax = plt.subplots(figsize=(7, 4.5))
    track = [r for r in rows if r["track_rms_m"] > 0]
    offsets = [r for r in rows if r["track_rms_m"] == 0]
    if track:
        ax.semilogx([r["track_rms_m"] for r in track], [r["onset_kmh"] or np.nan for r in track], "o-",
                    label="track alignment rms (no initial offset)")  # fmt: skip
    if offsets:
        ax.semilogx([r["initial_offset_m"] for r in offsets], [r["onset_kmh"] or np.nan for r in offsets], "s--",
                    label=f"initial offset at {offsets[0]['start_kmh']:g} km/h (perfect track)")  # fmt: skip
    ax.axhline(linear_kmh, color="tab:red", ls="--", label=f"linear critical speed {linear_kmh:.1f} km/h")
    ax.set_xlabel("noise level (m)")
    ax.set_ylabel("visible onset on the 0.1 m/s^2 ramp (km/h)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which="both")
    return save(fig, path)


def bifurcation_figure(diagram, nonlinear, path):
    """Limit-cycle amplitude against speed from small perturbations and from the limit cycle."""
    fig, ax = plt.subplots(figsize=(8, 5))
    v = diagram.speeds_kmh
    ax.plot(v, diagram.from_limit_cycle * 1e3, "s-", ms=3, label="started on the limit cycle")
    ax.plot(v, diagram.from_small * 1e3, "o", ms=3, mfc="none", label=f"started from {diagram.small_offset:g} m offset")
    ax.axhline(1e3 * diagram.threshold, color="0.5", lw=0.8, ls=":")
    _mark_speeds(ax, diagram.linear_critical_speed_kmh, None if nonlinear is None else nonlinear.fixed_speed_kmh)
    ax.set_xlabel("speed (km/h)")
    ax.set_ylabel("peak |y1| after settling (mm)")
    ax.set_title("Bifurcation diagram (fixed-speed runs)")
    ax.legend(fontsize=8, loc="upper left")
    ax.grid(alpha=0.3)
    return save(fig, path)


def ramp_down_figure(nonlinear, path):
    """Convergence of the ramp-down collapse speed as the ramp slows."""
    fig, ax = plt.subplots(figsize=(7, 4.5))
    rates = np.array(nonlinear.rates_kmh_per_s)
    collapse = np.array([np.nan if c is None else c for c in nonlinear.collapse_kmh])
    ax.semilogx(rates, collapse, "o-", label="ramp-down collapse speed")
    if nonlinear.fixed_speed_kmh is not None:
        ax.axhline(nonlinear.fixed_speed_kmh, color="tab:purple", ls="-.",
                   label=f"fixed-speed fold {nonlinear.fixed_speed_kmh:.1f} km/h")  # fmt: skip
    ax.axhline(nonlinear.linear_critical_speed_kmh, color="tab:red", ls="--",
               label=f"linear critical speed {nonlinear.linear_critical_speed_kmh:.1f} km/h")  # fmt: skip
    ax.set_xlabel("ramp-down rate (km/h per s)")
    ax.set_ylabel("speed (km/h)")
    ax.invert_xaxis()
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which="both")
    return save(fig, path)


def curves_figure(curves, nominal_kmh: float, path, title: str = ""):
    """Figs. 12-14: critical speed against each parameter's scale."""
    n = len(curves)
    cols = min(n, 2)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(5.5 * cols, 3.8 * rows), squeeze=False)
    for ax, curve in zip(axes.ravel(), curves):
        ax.plot(curve.values, curve.critical_speed_kmh, "o-", ms=3, label="linear critical speed")
        ax.axhline(nominal_kmh, color="0.5", lw=0.8, ls="--", label=f"nominal bogie {nominal_kmh:.1f} km/h")
        ax.axhline(EN14363_KMH, color="tab:green", lw=0.8, ls=":", label=f"EN 14363 requirement {EN14363_KMH:.0f} km/h")
        ax.set_xlabel(param_label(curve.param))
        ax.set_ylabel("critical speed (km/h)")
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize=7)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return save(fig, path)


def grids_figure(grids, path, title: str = ""):
    """Figs. 15-16: critical speed over two-parameter grids (heatmaps, maximum marked)."""
    n = len(grids)
    cols = min(n, 2)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(5.8 * cols, 4.5 * rows), squeeze=False)
    for ax, grid in zip(axes.ravel(), grids):
        x, y = np.array(grid.values[1]), np.array(grid.values[0])
        mesh = ax.pcolormesh(x, y, grid.critical_speed_kmh, shading="nearest", cmap="viridis")
        ax.contour(x, y, grid.critical_speed_kmh, levels=[EN14363_KMH], colors="w", linewidths=1)
        best = grid.maximum()
        ax.plot(best["values"][1], best["values"][0], "r*", ms=12,
                label=f"maximum {best['critical_speed_kmh']} km/h")  # fmt: skip
        ax.plot([], [], color="w", lw=1, label=f"{EN14363_KMH:.0f} km/h contour (EN 14363)")
        ax.set_xlabel(param_label(grid.params[1]))
        ax.set_ylabel(param_label(grid.params[0]))
        legend = ax.legend(loc="lower right", fontsize=7, facecolor="0.3", labelcolor="w", framealpha=0.8)
        legend.get_frame().set_edgecolor("0.3")
        fig.colorbar(mesh, ax=ax, label="critical speed (km/h)")
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return save(fig, path)
