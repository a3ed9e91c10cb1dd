"""Loading a policy safely: the shipped policy's manifest, a path only with the trust flag,
data-only observation statistics, and named errors for tampered, corrupt or mismatched files."""

import json
import pickle
import shutil

import numpy as np
import pytest

import bogie_agents.controllers.policies as policies
from bogie_agents.controllers.policies import (
    MANIFEST_FILE,
    NORMALISATION_FILE,
    PRETRAINED_DIR as PRETRAINED_ROOT,
    load_normalisation,
    load_policy,
    load_sb3_policy,
    verify_manifest,
)
from bogie_agents.cli import main as cli_main
from bogie_env.envs.config import make_config
from bogie_env.params import ConfigError


PRETRAINED_DIR = PRETRAINED_ROOT / "v0"  # the v0 policy (these tests use v0's default config)


class _RunsCode:
    """A pickle that runs code when loaded: it creates a marker file."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


@pytest.fixture(scope="module")
def env_config():
    return make_config()


def _pretrained_copy(tmp_path, monkeypatch):
    root = tmp_path / "pretrained"
    shutil.copytree(PRETRAINED_ROOT, root)
    monkeypatch.setattr(policies, "PRETRAINED_DIR", root)
    return root / "v0"


def test_shipped_policy_has_a_manifest_and_data_only_statistics():
    names = verify_manifest(PRETRAINED_DIR)
    assert {"best_model.zip", NORMALISATION_FILE, "config.json"} <= set(names)
    assert not list(PRETRAINED_DIR.glob("*.pkl")), "the shipped statistics must not be a pickle"
    stats = load_normalisation(PRETRAINED_DIR / NORMALISATION_FILE)
    assert stats["mean"].shape == (11,) and np.all(stats["var"] > 0) and stats["count"] > 1e6


def test_tampered_pretrained_policy_is_refused(tmp_path, monkeypatch, env_config):
    folder = _pretrained_copy(tmp_path, monkeypatch)
    data = bytearray((folder / "best_model.zip").read_bytes())
    data[-10] ^= 0xFF
    (folder / "best_model.zip").write_bytes(bytes(data))
    with pytest.raises(ConfigError, match="does not match its SHA-256"):
        load_policy("pretrained", env_config)


def test_unlisted_file_beside_the_pretrained_policy_is_refused(tmp_path, monkeypatch, env_config):
    folder = _pretrained_copy(tmp_path, monkeypatch)
    (folder / "vecnormalize.pkl").write_bytes(pickle.dumps(_RunsCode(tmp_path / "ran")))
    with pytest.raises(ConfigError, match="not in SHA256SUMS: vecnormalize.pkl"):
        load_policy("pretrained", env_config)
    assert not (tmp_path / "ran").exists()
    (folder / "vecnormalize.pkl").unlink()
    (folder / MANIFEST_FILE).unlink()
    with pytest.raises(ConfigError, match="SHA256SUMS' is missing"):
        load_policy("pretrained", env_config)


def test_a_policy_path_needs_the_trust_flag_and_runs_nothing_without_it(tmp_path, env_config):
    run = tmp_path / "run"
    shutil.copytree(PRETRAINED_DIR, run)
    (run / NORMALISATION_FILE).unlink()
    (run / "vecnormalize.pkl").write_bytes(pickle.dumps(_RunsCode(tmp_path / "ran")))
    for spec in (str(run), str(run / "best_model.zip")):
        with pytest.raises(ConfigError, match="--trust-policy"):
            load_policy(spec, env_config)
        with pytest.raises(ConfigError, match="code"):
            load_sb3_policy(spec)
    assert not (tmp_path / "ran").exists()


def test_cli_names_the_trust_flag(tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(PRETRAINED_DIR, run)
    assert cli_main(["evaluate", "--policy", str(run), "--parts", "critical"]) == 2
    err = capsys.readouterr().err
    assert "--trust-policy" in err and "code" in err


def test_data_only_statistics_match_the_model_and_are_checked(tmp_path, env_config):
    run = tmp_path / "run"
    shutil.copytree(PRETRAINED_DIR, run)
    trusted = load_policy(str(run), env_config, trusted=True)
    shipped = load_policy("pretrained", env_config)
    obs = np.random.default_rng(0).uniform(-1, 1, (4, 11)).astype(np.float32)
    assert np.array_equal(trusted.act(obs), shipped.act(obs))
    stats = json.loads((run / NORMALISATION_FILE).read_text())
    for key, value, message in [("obs_var", [-1.0] * 11, "obs_var finite and >= 0"),
                                ("obs_mean", [0.0] * 3, "same length"),
                                ("format", "pickle", "is not a 'bogie-vecnormalize-1' file"),
                                ("clip_obs", "ten", "non-numeric")]:  # fmt: skip
        (run / NORMALISATION_FILE).write_text(json.dumps({**stats, key: value}))
        with pytest.raises(ConfigError, match=message):
            load_policy(str(run), env_config, trusted=True)
    (run / NORMALISATION_FILE).write_text("{not json")
    with pytest.raises(ConfigError, match="not readable JSON"):
        load_policy(str(run), env_config, trusted=True)


def test_corrupt_model_zip_is_a_named_error(tmp_path, env_config, capsys):
    bad = tmp_path / "model.zip"
    bad.write_bytes(b"PK\x03\x04 this is not a zip")
    with pytest.raises(ConfigError, match="could not load .* as a PPO, SAC or TD3 model"):
        load_policy(str(bad), env_config, trusted=True)
    assert cli_main(["evaluate", "--trust-policy", "--policy", str(bad), "--parts", "critical"]) == 2
    assert "could not load" in capsys.readouterr().err


def test_corrupt_legacy_pickle_is_a_named_error(tmp_path, env_config):
    run = tmp_path / "run"
    shutil.copytree(PRETRAINED_DIR, run)
    (run / NORMALISATION_FILE).unlink()
    (run / "vecnormalize.pkl").write_bytes(b"\x80\x04garbage")
    with pytest.raises(ConfigError, match="not a readable VecNormalize pickle"):
        load_policy(str(run), env_config, trusted=True)


def test_policy_env_shape_mismatch_fails_at_load(tmp_path, env_config):
    passive_env = make_config({"actuators": {"frame_lateral": {"mode": "off"}}})
    with pytest.raises(ConfigError, match=r"expects observations of shape \(11,\) but the env config gives \(10,\)"):
        load_policy("pretrained", passive_env)
    policy = load_policy("pretrained", env_config)
    with pytest.raises(ConfigError, match=r"takes observations of shape \(11,\); got \(7,\)"):
        policy.act(np.zeros((2, 7), dtype=np.float32))


@pytest.mark.parametrize("name, residual", [("distilled", True), ("distilled_mpc", False), ("distilled_mpc_washout", True)])
def test_a_shipped_student_is_verified_before_loading(tmp_path, monkeypatch, name, residual):
    """``distilled`` (a correction on ``robust_steering``), ``distilled_mpc`` (a plain student) and
    ``distilled_mpc_washout`` (a student on washed-out signals) load their ``NAME_v1`` folder (v1 ids only) after its manifest; a changed weight or an unlisted
    file beside it is refused, as for ``pretrained``."""
    from bogie_agents.controllers.distilled import DistilledPolicy
    from bogie_env.envs.registration import IDS

    v1 = make_config(variant=IDS["Bogie/Hunting-v1"])
    policy = load_policy(name, v1, env_id="Bogie/Hunting-v1")
    assert isinstance(policy, DistilledPolicy) and policy.residual == residual
    with pytest.raises(ConfigError, match=f"no {name} student for env version 'v0'"):
        load_policy(name, make_config())
    folder = _pretrained_copy(tmp_path, monkeypatch).parent / f"{name}_v1"
    (folder / "extra.json").write_text("{}")
    with pytest.raises(ConfigError, match="not in SHA256SUMS: extra.json"):
        load_policy(name, v1, env_id="Bogie/Hunting-v1")
    (folder / "extra.json").unlink()
    data = bytearray((folder / "student.npz").read_bytes())
    data[-100] ^= 0xFF
    (folder / "student.npz").write_bytes(bytes(data))
    with pytest.raises(ConfigError, match="does not match its SHA-256"):
        load_policy(name, v1, env_id="Bogie/Hunting-v1")


def test_the_washed_out_student_commands_nothing_for_a_constant_observation():
    """A steady curve, a constant sensor bias: any constant observation. ``distilled_mpc_washout``'s
    signals are washed out, so once its filters have settled (the observation is a step from
    rest, and the washouts are at 0.5 Hz) it commands nothing; the plain ``distilled_mpc`` on the
    same observation holds a steady command (the check can fail)."""
    from bogie_env.envs.registration import IDS
    from bogie_env.envs.task import SPEED_SCALE_KMH, speed_index

    v1 = make_config(variant=IDS["Bogie/Hunting-v1"])
    commands = {}
    for name in ("distilled_mpc_washout", "distilled_mpc"):
        policy = load_policy(name, v1, env_id="Bogie/Hunting-v1")
        obs = np.full((2, policy.frames.obs_dim), 0.3, dtype=np.float32)
        obs[1] *= -1.0  # the mirrored curve
        obs[:, speed_index(v1["observation"]["type"])] = 250.0 / SPEED_SCALE_KMH
        policy.reset(2)
        commands[name] = np.array([policy.act(obs) for _ in range(1000)])[-100:]  # the last second of 10
    assert np.abs(commands["distilled_mpc_washout"]).max() < 1e-4
    assert np.abs(commands["distilled_mpc"]).min(axis=0).max() > 0.05


def test_the_policy_help_names_every_controller_and_shipped_policy():
    """``--policy --help`` lists every name ``load_policy`` takes (a new controller must be added there)."""
    import re

    from bogie_agents.controllers import POLICY_HELP
    from bogie_agents.controllers.classical import CLASSICAL
    from bogie_agents.controllers.policies import SHIPPED

    named = set(re.findall(r"[a-z_0-9]+", POLICY_HELP))
    assert set(CLASSICAL) | set(SHIPPED) <= named, sorted(set(CLASSICAL) | set(SHIPPED) - named)
