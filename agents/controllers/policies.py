"""Policies by name or path: the classical controllers and trained SB3 agents, one interface.

``load_policy(spec, env_config, trusted=False)`` returns an object with ``observation_type``,
``reset(n, rows)`` and ``act(obs) -> actions``:

- ``passive``, ``skyhook``, ``lqr``, ``lqg``: :mod:`bogie_agents.controllers.lqr`;
- ``robust_damping``: :mod:`bogie_agents.controllers.robust` (the robust classical baseline for v1, docs/controllers.md);
- ``robust_steering``: ``robust_damping`` plus the curving assist of :mod:`bogie_agents.controllers.curving_assist`;
- ``pretrained``: the policy shipped for the env's version, ``agents/pretrained/v0/`` or
  ``agents/pretrained/v1/`` (see docs/results.md), checked against the SHA-256 sums in that
  folder's ``SHA256SUMS`` before anything in it is loaded. The version is the env id's
  (``env_id=``, e.g. ``Bogie/Hunting-v1``) or, without one, the config's: v1 when the v1 sensor
  model is on (``sensors.enabled``), else v0 (:func:`env_version`). Each folder's
  ``config.json`` names the env id it was trained on;
- ``distilled``: the sensor-only student shipped for the env's version
  (``agents/pretrained/distilled_v1/``: DAgger from the privileged reference as a correction on
  ``robust_steering``, docs/studies/distillation.md), plain arrays and JSON, checked against its
  folder's ``SHA256SUMS`` as ``pretrained`` is;
- ``distilled_mpc``: the sensor-only student of the MPC reference, its linearised loops held to
  issue 25's margin floors (``agents/pretrained/distilled_mpc_v1/``: a plain network on the
  sensor history, DAgger from ``privileged_mpc``, docs/studies/distillation.md), checked as
  ``distilled`` is;
- ``distilled_mpc_washout``: the same student and penalty on the robust filter bank's washed-out
  signals instead of the raw sensors (``agents/pretrained/distilled_mpc_washout_v1/``: zero
  command for any constant observation, so none in a steady curve), checked as ``distilled`` is;
- a path to a training run folder (``runs/NAME``) or to an SB3 ``.zip``: the saved model and,
  if present beside it, its ``vecnormalize.json`` observation statistics.

**A policy file is code.** An SB3 ``.zip`` holds pickled Python objects, and loading it runs
whatever they say; so does a ``vecnormalize.pkl``. Load such files only from sources you trust:
a path is loaded only with ``trusted=True`` (``bogie evaluate --trust-policy``). The observation
statistics are read from ``vecnormalize.json`` (plain numbers, no code); a legacy
``vecnormalize.pkl`` is read only when trusted, and :func:`convert_vecnormalize` turns it
into the JSON form.
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import numpy as np

from bogie_env.fileio import write_text_atomic
from bogie_env.params import ConfigError

from .classical import CLASSICAL
#: The shipped policies, one folder per env version (``v0``, ``v1``).
PRETRAINED_DIR = Path(__file__).resolve().parent.parent / "pretrained"
#: Shipped policies by name: each one's folder under :data:`PRETRAINED_DIR` for an env version.
SHIPPED = {"pretrained": "{version}", "distilled": "distilled_{version}", "distilled_mpc": "distilled_mpc_{version}",
           "distilled_mpc_washout": "distilled_mpc_washout_{version}"}
ALGORITHMS = ("ppo", "sac", "td3", "recurrent_ppo")
NORMALISATION_FILE = "vecnormalize.json"
LEGACY_NORMALISATION_FILE = "vecnormalize.pkl"
MANIFEST_FILE = "SHA256SUMS"
NORMALISATION_FORMAT = "bogie-vecnormalize-1"
TRUST_HINT = ("an SB3 model file is code (loading it unpickles Python objects, which can run anything); "
              "load it only if you trust its source, with --trust-policy (load_policy(..., trusted=True))")  # fmt: skip


class SB3Policy:
    """A trained SB3 model acting deterministically on normalised observations.

    With memory (:mod:`bogie_agents.controllers.memory`) it keeps it per row: the last ``frame_stack``
    normalised observations, or a recurrent model's LSTM state; ``reset(n, rows)`` starts the
    given rows (all without ``rows``) afresh."""

    observation_type = "sensors"

    def __init__(self, model, obs_mean: np.ndarray | None, obs_var: np.ndarray | None, clip_obs: float, epsilon: float,
                 name: str, env_config: dict | None = None, frame_stack: int = 1) -> None:  # fmt: skip
        from .memory import ObservationHistory, RecurrentState, is_recurrent

        self.model = model
        self.frame_stack = int(frame_stack)
        self.history = ObservationHistory(self.frame_stack) if self.frame_stack > 1 else None
        self.recurrent = RecurrentState() if is_recurrent(model) else None
        # one observation's shape (the model's input is frame_stack of them side by side)
        shape = model.observation_space.shape
        self.frame_shape = (shape[0] // self.frame_stack,) + tuple(shape[1:])
        self.obs_mean, self.obs_var = obs_mean, obs_var
        self.clip_obs, self.epsilon = clip_obs, epsilon
        self.name = name
        self.env_config = env_config or {}
        self.observation_type = self.env_config.get("observation", {}).get("type", "sensors")

    def reset(self, n_envs: int, rows=None) -> None:
        for memory in (self.history, self.recurrent):
            if memory is not None:
                memory.reset(n_envs, rows)

    def normalise(self, obs: np.ndarray) -> np.ndarray:
        if self.obs_mean is None:
            return obs
        scaled = (obs - self.obs_mean) / np.sqrt(self.obs_var + self.epsilon)
        return np.clip(scaled, -self.clip_obs, self.clip_obs).astype(np.float32)

    def act(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs, dtype=np.float32)
        expected = self.frame_shape
        if obs.shape[-len(expected):] != expected:
            raise ConfigError(f"policy {self.name!r} takes observations of shape {expected}; got {obs.shape[1:]}")
        x = self.normalise(obs)
        if self.history is not None:
            x = self.history(x.reshape(-1, *expected)).reshape(*obs.shape[:-1], -1)
        if self.recurrent is not None:
            actions = self.recurrent.predict(self.model, x.reshape(-1, x.shape[-1]))
            return np.asarray(actions, dtype=np.float32).reshape(*obs.shape[:-1], -1)
        actions, _ = self.model.predict(x, deterministic=True)
        return np.asarray(actions, dtype=np.float32)


def sha256_file(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def write_manifest(folder: str | Path, names: list[str]) -> Path:
    """Write ``folder/SHA256SUMS`` (``sha256sum`` format) for the given files."""
    folder = Path(folder)
    lines = [f"{sha256_file(folder / name)}  {name}\n" for name in sorted(names)]
    write_text_atomic(folder / MANIFEST_FILE, "".join(lines))
    return folder / MANIFEST_FILE


def verify_manifest(folder: str | Path, model_suffix: str = ".zip") -> list[str]:
    """Check every file listed in ``folder/SHA256SUMS``; returns the names checked.

    A model file (``model_suffix``: an SB3 ``.zip``, a distilled student's ``.npz``) must be
    listed, and no other ``.zip``/``.pkl``/``.json``/``.npz`` may sit in the folder unlisted (it
    could be picked up instead)."""
    folder = Path(folder)
    manifest = folder / MANIFEST_FILE
    if not manifest.is_file():
        raise ConfigError(f"{str(manifest)!r} is missing: the pretrained policy cannot be verified; reinstall it")
    listed: dict[str, str] = {}
    for number, line in enumerate(manifest.read_text().splitlines(), start=1):
        parts = line.split()
        if len(parts) != 2 or len(parts[0]) != 64:
            raise ConfigError(f"{str(manifest)!r} line {number} is not '<sha256>  <file>': {line!r}")
        listed[parts[1].lstrip("*")] = parts[0].lower()
    for name, expected in listed.items():
        path = folder / name
        if "/" in name or not path.is_file():
            raise ConfigError(f"{str(manifest)!r} lists {name!r}, which is not a file in {str(folder)!r}")
        if sha256_file(path) != expected:
            raise ConfigError(f"{str(path)!r} does not match its SHA-256 in {MANIFEST_FILE}: the file was changed "
                              "or damaged; refusing to load it (a policy file is code). Reinstall the package.")  # fmt: skip
    unlisted = [p.name for p in folder.iterdir() if p.suffix in (".zip", ".pkl", ".json", ".npz") and p.name not in listed]
    if unlisted:
        raise ConfigError(f"{str(folder)!r} holds files not in {MANIFEST_FILE}: {', '.join(sorted(unlisted))}; "
                          "refusing to load an unverified policy")  # fmt: skip
    if not any(name.endswith(model_suffix) for name in listed):
        raise ConfigError(f"{str(manifest)!r} lists no model {model_suffix}")
    return sorted(listed)


def save_normalisation(vec_normalize, path: str | Path) -> None:
    """Write a VecNormalize's observation statistics as plain JSON (exact float64 round trip)."""
    if vec_normalize.norm_obs:
        rms = vec_normalize.obs_rms
        mean, var, count = np.asarray(rms.mean, dtype=float), np.asarray(rms.var, dtype=float), float(rms.count)
    else:  # no observation statistics (norm_obs false): the identity, recorded as such
        size = int(np.prod(vec_normalize.observation_space.shape))
        mean, var, count = np.zeros(size), np.ones(size), 0.0
    payload = {
        "format": NORMALISATION_FORMAT,
        "obs_mean": [float(v) for v in mean.ravel()],
        "obs_var": [float(v) for v in var.ravel()],
        "count": count,
        "clip_obs": float(vec_normalize.clip_obs),
        "epsilon": float(vec_normalize.epsilon),
        "norm_obs": bool(vec_normalize.norm_obs),
    }
    write_text_atomic(Path(path), json.dumps(payload, indent=1))


def load_normalisation(path: str | Path) -> dict:
    """Read and check a ``vecnormalize.json``: arrays of equal length, finite, variances >= 0."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ConfigError(f"observation statistics {str(path)!r} are not readable JSON: {error}") from None
    if not isinstance(data, dict) or data.get("format") != NORMALISATION_FORMAT:
        raise ConfigError(f"{str(path)!r} is not a {NORMALISATION_FORMAT!r} file (its 'format' key)")
    try:
        mean = np.array(data["obs_mean"], dtype=float)
        var = np.array(data["obs_var"], dtype=float)
        clip_obs, epsilon = float(data["clip_obs"]), float(data["epsilon"])
        norm_obs = bool(data.get("norm_obs", True))
        count = float(data.get("count", math.nan))
    except (KeyError, TypeError, ValueError) as error:
        raise ConfigError(f"{str(path)!r}: missing or non-numeric entry ({error}); needs obs_mean, obs_var, "
                          "clip_obs, epsilon") from None  # fmt: skip
    if mean.ndim != 1 or mean.shape != var.shape or not mean.size:
        raise ConfigError(f"{str(path)!r}: obs_mean and obs_var must be lists of the same length")
    if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(var)) and np.all(var >= 0)):
        raise ConfigError(f"{str(path)!r}: obs_mean must be finite and obs_var finite and >= 0")
    if not (clip_obs > 0 and epsilon > 0 and math.isfinite(clip_obs) and math.isfinite(epsilon)):
        raise ConfigError(f"{str(path)!r}: clip_obs and epsilon must be finite and > 0")
    return {"mean": mean if norm_obs else None, "var": var if norm_obs else None, "clip_obs": clip_obs,
            "epsilon": epsilon, "count": count}  # fmt: skip


def apply_normalisation(vec_normalize, stats: dict) -> None:
    """Set a VecNormalize's observation statistics from :func:`load_normalisation`'s result."""
    if stats["mean"] is None:
        vec_normalize.norm_obs = False
    else:
        vec_normalize.obs_rms.mean, vec_normalize.obs_rms.var = stats["mean"].copy(), stats["var"].copy()
        vec_normalize.obs_rms.count = stats["count"]
    vec_normalize.clip_obs, vec_normalize.epsilon = stats["clip_obs"], stats["epsilon"]


def _load_legacy_pickle(path: Path) -> dict:
    """A VecNormalize pickle (code: only called when trusted)."""
    import pickle

    try:
        with path.open("rb") as handle:
            stats = pickle.load(handle)  # noqa: S301 - trusted by the caller's explicit flag
        rms = stats.obs_rms
        return {"mean": np.asarray(rms.mean, dtype=float) if stats.norm_obs else None,
                "var": np.asarray(rms.var, dtype=float) if stats.norm_obs else None,
                "clip_obs": float(stats.clip_obs), "epsilon": float(stats.epsilon), "count": float(rms.count)}  # fmt: skip
    except Exception as error:  # noqa: BLE001 - a corrupt or foreign pickle
        raise ConfigError(f"{str(path)!r} is not a readable VecNormalize pickle: {type(error).__name__}: {error}") from None


def convert_vecnormalize(pickle_path: str | Path, json_path: str | Path | None = None) -> Path:
    """Turn a trusted ``vecnormalize.pkl`` into a data-only ``vecnormalize.json`` (same numbers)."""
    import pickle

    pickle_path = Path(pickle_path)
    json_path = Path(json_path) if json_path else pickle_path.with_name(NORMALISATION_FILE)
    with pickle_path.open("rb") as handle:
        stats = pickle.load(handle)  # noqa: S301 - the caller vouches for the file
    save_normalisation(stats, json_path)
    return json_path


def _find_model(path: Path) -> tuple[Path, Path | None, Path | None]:
    """(model .zip, statistics file or None, run config.json or None) from a folder or a zip."""
    if path.is_dir():
        candidates = [path / "best_model.zip", path / "final_model.zip", path / "model.zip"]
        candidates += sorted(path.glob("*.zip"))
        for candidate in candidates:
            if candidate.is_file():
                zip_path = candidate
                break
        else:
            raise ConfigError(f"policy folder {str(path)!r} holds no SB3 model (.zip)")
        folder = path
    elif path.is_file() and path.suffix == ".zip":
        zip_path, folder = path, path.parent
    else:
        raise ConfigError(
            f"policy {str(path)!r} is neither a known name ({', '.join(list(CLASSICAL) + list(SHIPPED))}), "
            "a training run folder, nor an SB3 .zip file"
        )
    norm = folder / NORMALISATION_FILE
    if not norm.is_file():
        norm = folder / LEGACY_NORMALISATION_FILE
    config = folder / "config.json"
    return zip_path, norm if norm.is_file() else None, config if config.is_file() else None


def load_sb3_policy(path: str | Path, trusted: bool = False, env_config: dict | None = None):
    """Load a trained model and its observation statistics. ``trusted`` must be True (see the module doc).

    A run whose config has a ``residual`` section (:mod:`bogie_agents.controllers.residual`) loads as the
    composite :class:`~bogie_agents.controllers.residual.ResidualPolicy`; its classical baseline is built
    for ``env_config`` (default: the run's own env config)."""
    if not trusted:
        raise ConfigError(f"refusing to load {str(path)!r}: {TRUST_HINT}")
    from stable_baselines3 import PPO, SAC, TD3

    zip_path, norm_path, config_path = _find_model(Path(path))
    try:
        run_config = json.loads(config_path.read_text()) if config_path else {}
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ConfigError(f"run config {str(config_path)!r} is not readable JSON: {error}") from None
    if not isinstance(run_config, dict):
        raise ConfigError(f"run config {str(config_path)!r} must hold a JSON object")
    algo = str(run_config.get("algo", "")).lower()
    classes = {"ppo": PPO, "sac": SAC, "td3": TD3}
    if algo == "recurrent_ppo":
        from sb3_contrib import RecurrentPPO

        classes["recurrent_ppo"] = RecurrentPPO
    order = [classes[algo]] if algo in classes else [PPO, SAC, TD3]
    model, errors = None, []
    for cls in order:
        try:
            model = cls.load(str(zip_path), device="cpu")
            break
        except Exception as error:  # noqa: BLE001 - try the next algorithm class
            errors.append(f"{cls.__name__}: {type(error).__name__}: {str(error)[:200]}")
    if model is None:
        names = [c.__name__ for c in order]
        names = " or ".join([", ".join(names[:-1]), names[-1]] if len(names) > 1 else names)
        raise ConfigError(f"could not load {str(zip_path)!r} as a {names} model ({'; '.join(errors)})")
    from .memory import check_frame_stack

    frame_stack = check_frame_stack(run_config.get("frame_stack") or 1, f"{str(config_path)!r}")
    frame = (model.observation_space.shape[0] // frame_stack,)
    stats = {"mean": None, "var": None, "clip_obs": 10.0, "epsilon": 1e-8}
    if norm_path is not None:
        stats = load_normalisation(norm_path) if norm_path.suffix == ".json" else _load_legacy_pickle(norm_path)
        if stats["mean"] is not None and stats["mean"].shape != frame:
            raise ConfigError(f"{str(norm_path)!r} has statistics for {stats['mean'].size} observations but the model "
                              f"{str(zip_path)!r} takes {frame} (per frame)")  # fmt: skip
    run_env = run_config.get("env", {}) if isinstance(run_config.get("env", {}), dict) else {}
    network = SB3Policy(model, stats["mean"], stats["var"], stats["clip_obs"], stats["epsilon"], name=str(path),
                        env_config=run_env, frame_stack=frame_stack)  # fmt: skip
    if run_config.get("residual") is None:
        return network
    from .residual import ResidualPolicy, WashedOutFeatures, check_residual_config

    residual = check_residual_config(run_config["residual"], where=f"{str(config_path)!r}: 'residual'")
    config = env_config if env_config is not None else run_env
    features = WashedOutFeatures(config) if residual["features"] == "washed_out" else None
    return ResidualPolicy(CLASSICAL[residual["baseline"]](config), network, residual["scale"], name=str(path),
                          features=features)  # fmt: skip


def check_shapes(policy, env_config: dict) -> None:
    """An SB3 policy's observation and action shapes must match the env it will drive."""
    model = getattr(policy, "model", None)
    frames = getattr(policy, "frames", None)  # a distilled student's frame history
    if model is None and frames is None:
        return
    from bogie_env.envs.config import merge_config
    from bogie_env.envs.task import HuntingTask

    task = HuntingTask(1, merge_config(env_config, {"observation": {"type": policy.observation_type}}))
    if model is None:
        pairs = [("observation", (frames.obs_dim,), task.observation_space.shape),
                 ("action", (frames.action_dim,), task.action_space.shape)]  # fmt: skip
    else:
        frame = getattr(getattr(policy, "network", policy), "frame_shape", model.observation_space.shape)  # one of frame_stack
        pairs = [("observation", frame, task.observation_space.shape),
                 ("action", model.action_space.shape, task.action_space.shape)]  # fmt: skip
    if getattr(policy, "features", None) is not None:  # a residual on features: its filters take the env's observation
        pairs = pairs[1:]
        if getattr(getattr(policy.features, "filters", None), "n_obs", task.observation_space.shape[0]) != task.observation_space.shape[0]:
            raise ConfigError(f"policy {policy.name!r}: its feature filters take {policy.features.filters.n_obs} "
                              f"observations but the env config gives {task.observation_space.shape}")  # fmt: skip
    for what, model_shape, env_shape in pairs:
        if tuple(model_shape) != tuple(env_shape):
            raise ConfigError(
                f"policy {policy.name!r} expects {what}s of shape {tuple(model_shape)} but the env config gives "
                f"{tuple(env_shape)}; evaluate it with the env config it was trained on (its run's config.json: "
                "actuator modes and observation settings)"
            )


def env_version(env_config: dict | None = None, env_id: str | None = None) -> str:
    """The env version a policy is for: the id's suffix (``Bogie/Hunting-v1`` -> ``v1``) or, with no
    id, the config's: ``v1`` when the v1 sensor model is on (``sensors.enabled``), else ``v0``."""
    if env_id is not None:
        from bogie_env.envs.registration import IDS

        if env_id not in IDS:
            raise ConfigError(f"env id {env_id!r} is not a bogie-env id; known ids: {', '.join(IDS)}")
        return env_id.rsplit("-", 1)[-1]
    sensors = (env_config or {}).get("sensors") or {}
    return "v1" if sensors.get("enabled") else "v0"


def shipped_dir(spec: str, env_config: dict | None = None, env_id: str | None = None) -> Path:
    """The folder of the shipped policy ``spec`` (a key of :data:`SHIPPED`) for the env's version (:func:`env_version`)."""
    return PRETRAINED_DIR / SHIPPED[spec].format(version=env_version(env_config, env_id))


def pretrained_dir(env_config: dict | None = None, env_id: str | None = None) -> Path:
    """The folder of the policy shipped for the env's version (:func:`env_version`)."""
    return shipped_dir("pretrained", env_config, env_id)


def load_policy(spec: str, env_config: dict, trusted: bool = False, env_id: str | None = None):
    """A policy by name (a classical controller of :data:`CLASSICAL`, or a shipped one of :data:`SHIPPED`) or path.

    ``pretrained`` is the policy shipped for the env's version (``env_id``, or the config's:
    :func:`env_version`), verified against its SHA-256 manifest; a path is loaded only when
    ``trusted`` is True, since an SB3 model file is code."""
    if spec in CLASSICAL:
        return CLASSICAL[spec](env_config)
    if spec == "pretrained":
        folder = pretrained_dir(env_config, env_id)
        if not folder.is_dir() or not list(folder.glob("*.zip")):
            shipped = sorted(p.name for p in PRETRAINED_DIR.iterdir() if p.is_dir()) if PRETRAINED_DIR.is_dir() else []
            raise ConfigError(f"no pretrained policy for env version {folder.name!r} in {folder} (shipped: "
                              f"{', '.join(shipped) or 'none'}); train one (docs/results.md)")  # fmt: skip
        verify_manifest(folder)
        policy = load_sb3_policy(folder, trusted=True, env_config=env_config)
    elif spec in SHIPPED:  # a distilled student: plain arrays and JSON
        folder = shipped_dir(spec, env_config, env_id)
        if not folder.is_dir():
            shipped = sorted(p.name for p in PRETRAINED_DIR.glob(f"{spec}_*") if p.is_dir())
            raise ConfigError(f"no {spec} student for env version {env_version(env_config, env_id)!r} in {folder} "
                              f"(shipped: {', '.join(shipped) or 'none'}); distil one (docs/studies/distillation.md)")  # fmt: skip
        verify_manifest(folder, model_suffix=".npz")
        from .distilled import load_student

        policy = load_student(folder)
    else:
        path = Path(spec)
        if not path.exists():
            raise ConfigError(
                f"policy {spec!r} not found: give one of {', '.join(list(CLASSICAL) + list(SHIPPED))} "
                "or the path of a training run folder or SB3 .zip"
            )
        from .distilled import is_student, load_student

        if is_student(path):  # plain arrays and JSON: no code, no trust needed
            policy = load_student(path)
        elif not trusted:
            raise ConfigError(f"policy {spec!r} is a path: {TRUST_HINT}")
        else:
            policy = load_sb3_policy(path, trusted=True, env_config=env_config)
    check_shapes(policy, env_config)
    return policy
