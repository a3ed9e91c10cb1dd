"""Learning curves of trained rows: evaluation return against env steps, over training seeds.

    bogie results --out runs --curves ppo_scratch_v1='runs/ppo_scratch_v1/seed_*' --curves ...

Each training run records its periodic evaluations in ``RUN/eval/evaluations.npz`` (SB3's
``EvalCallback``: ``timesteps`` (n_eval,), ``results`` (n_eval, episodes) the undiscounted,
unnormalised episode returns on the ``eval_env`` task, ``ep_lengths``). With the agent config's
``eval.seed`` every evaluation of every training seed runs the same episodes (the eval env is
reseeded with it before each evaluation: :class:`SameEpisodesEvalCallback`), so the spread
over training seeds is the training's, not the evaluation sample's.

:func:`curves` reads the runs of each row (a name and the run folders, one per training seed),
:func:`curves_figure` draws ``learning_curves.png``: per row the mean over seeds of the
evaluation's mean return, and the band from the lowest to the highest seed. Rows must have
the same evaluation steps across their seeds (the same config and budget); a run cut short
is named in the error.
"""

from __future__ import annotations

import glob
import json
from pathlib import Path

import numpy as np

from bogie_env.params import ConfigError

FIGURE = "learning_curves.png"
DATA = "learning_curves.json"


def _eval_callback_class():
    from stable_baselines3.common.callbacks import EvalCallback

    class SameEpisodesEvalCallback(EvalCallback):
        """``EvalCallback`` that reseeds the eval env with ``seed`` before each evaluation (None: no reseeding)."""

        def __init__(self, *args, seed: int | None = None, **kwargs) -> None:
            super().__init__(*args, **kwargs)
            self.episode_seed = seed

        def _on_step(self) -> bool:
            if self.episode_seed is not None and self.eval_freq > 0 and self.n_calls % self.eval_freq == 0:
                self.eval_env.seed(self.episode_seed)
            return super()._on_step()

    return SameEpisodesEvalCallback


def eval_callback(*args, seed: int | None = None, **kwargs):
    """An SB3 ``EvalCallback`` whose evaluations all run the episodes of ``seed`` (None: SB3's own)."""
    return _eval_callback_class()(*args, seed=seed, **kwargs)


def parse_row(text: str) -> tuple[str, list[Path]]:
    """``NAME=GLOB`` (or ``NAME=DIR,DIR,...``) -> (NAME, run folders), sorted."""
    name, sep, pattern = text.partition("=")
    if not sep or not name or not pattern:
        raise ConfigError(f"--curves {text!r} is not allowed; allowed: NAME=GLOB or NAME=RUN,RUN,... "
                          "(e.g. ppo_scratch_v1='runs/ppo_scratch_v1/seed_*')")  # fmt: skip
    folders = sorted({Path(p) for part in pattern.split(",") for p in glob.glob(part) if Path(p).is_dir()})
    if not folders:
        raise ConfigError(f"--curves {text!r}: {pattern!r} matches no run folder")
    return name, folders


def read_run(folder: Path) -> dict:
    """One run's evaluation history: steps, per-evaluation mean return, its seed and command."""
    path = Path(folder) / "eval" / "evaluations.npz"
    if not path.is_file():
        raise ConfigError(f"{str(path)!r} does not exist: {str(folder)!r} is not a training run folder with evaluations")
    with np.load(path, allow_pickle=False) as data:
        steps, results = np.asarray(data["timesteps"], dtype=np.int64), np.asarray(data["results"], dtype=float)
    if not steps.size:
        raise ConfigError(f"{str(path)!r} holds no evaluation")
    config = {}
    if (Path(folder) / "config.json").is_file():
        config = json.loads((Path(folder) / "config.json").read_text())
    return {"run": str(folder), "seed": config.get("seed"), "source": config.get("source"),
            "eval_seed": (config.get("eval") or {}).get("seed"), "timesteps": steps,
            "mean_return": results.mean(axis=1), "episodes": int(results.shape[1])}  # fmt: skip


def curves(rows: list[tuple[str, list[Path]]]) -> list[dict]:
    """Per row: the evaluation steps, and the mean, lowest and highest over its runs of the mean return."""
    out = []
    for name, folders in rows:
        runs = [read_run(f) for f in folders]
        steps = runs[0]["timesteps"]
        for r in runs[1:]:
            if not np.array_equal(r["timesteps"], steps):
                raise ConfigError(f"--curves {name}: {r['run']!r} evaluated at steps {r['timesteps'].tolist()} but "
                                  f"{runs[0]['run']!r} at {steps.tolist()}; give runs of the same config and budget")  # fmt: skip
        returns = np.stack([r["mean_return"] for r in runs])
        out.append({"row": name, "runs": [r["run"] for r in runs], "seeds": [r["seed"] for r in runs],
                    "config": runs[0]["source"], "eval_seed": runs[0]["eval_seed"], "episodes": runs[0]["episodes"],
                    "timesteps": steps.tolist(), "mean": returns.mean(axis=0).tolist(),
                    "min": returns.min(axis=0).tolist(), "max": returns.max(axis=0).tolist(),
                    "per_seed": returns.tolist(),
                    "train_commands": [f"bogie train --config {r['source']} --seed {r['seed']} --out {r['run']}" for r in runs]})  # fmt: skip
    return out


def curves_figure(data: list[dict], path: Path) -> Path:
    """One panel per row (its own return axis; the rows' returns differ by far more than their
    spreads): mean evaluation return against env steps, the min-max band over its seeds, and
    each seed as a thin line."""
    from bogie_env.analysis.plots import plt, save

    fig, axes = plt.subplots(len(data), 1, figsize=(8, 1.2 + 2.2 * len(data)), sharex=True, squeeze=False)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for k, (row, ax) in enumerate(zip(data, axes[:, 0])):
        steps = np.asarray(row["timesteps"], dtype=float) / 1e6
        colour = colours[k % len(colours)]
        ax.fill_between(steps, row["min"], row["max"], color=colour, alpha=0.25, lw=0, label="min-max over seeds")
        for returns in row["per_seed"]:
            ax.plot(steps, returns, color=colour, lw=0.6, alpha=0.6)
        ax.plot(steps, row["mean"], color=colour, marker="o", ms=3, lw=1.8, label="mean over seeds")
        ax.set_title(f"{row['row']}: {len(row['runs'])} seeds ({', '.join(map(str, row['seeds']))}), "
                     f"{row['episodes']} episodes per evaluation", fontsize=9)  # fmt: skip
        ax.set_ylabel("evaluation return")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8, loc="lower right")
    axes[-1, 0].set_xlabel("env steps (millions)")
    same = all(row["eval_seed"] is not None for row in data)
    fig.suptitle("Learning curves: evaluation return (mean over episodes)"
                 + (", the same episodes at every evaluation and seed" if same else ""), fontsize=10)  # fmt: skip
    return save(fig, path)


def write_curves(specs: list[str], out: Path) -> dict:
    """``bogie results --curves NAME=GLOB ...``: ``out/learning_curves.png`` and ``out/learning_curves.json``."""
    from bogie_env.fileio import write_text_atomic

    data = curves([parse_row(s) for s in specs])
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    figure = curves_figure(data, out / FIGURE)
    import shlex

    command = " ".join(["bogie results --out", shlex.quote(str(out))] + [f"--curves {shlex.quote(s)}" for s in specs])
    write_text_atomic(out / DATA, json.dumps({"command": command, "rows": data}, indent=1))
    return {"figure": str(figure), "data": str(out / DATA), "command": command, "rows": [row["row"] for row in data]}
