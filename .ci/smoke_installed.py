"""Smoke test of a non-editable install; run from outside the repository so that the source tree
is not on sys.path: ``cd /tmp && VENV/bin/python - env < .ci/smoke_installed.py``.

- ``env``: the wheel alone (no extra). The env, the analysis command and the config files work;
  SB3 and torch are not installed, and ``bogie train`` says which extra it needs.
- ``agents``: after installing the ``[agents]`` extra. The shipped policy loads and acts.
"""

import importlib.util
import json
import shutil
import subprocess
import sys
from pathlib import Path

mode = sys.argv[1]
import bogie_env  # noqa: E402
from bogie_env.params import CONFIG_DIR  # noqa: E402

site = Path(bogie_env.__file__).resolve().parent.parent
assert site.name == "site-packages", f"bogie_env imported from {site}, not from an installed wheel"
assert CONFIG_DIR.resolve() == site / "bogie_env" / "configs", CONFIG_DIR
bogie = shutil.which("bogie", path=str(Path(sys.executable).parent))
assert bogie, "the bogie console script is not installed"

if mode == "env":
    for name in ("torch", "stable_baselines3"):
        assert importlib.util.find_spec(name) is None, f"{name} is installed without the [agents] extra"
    import gymnasium as gym

    env = gym.make("Bogie/HuntingPassive-v0", config={"speed": {"start_kmh": 300.0, "end_kmh": 302.0}})
    env.reset(seed=0)
    for _ in range(5):
        env.step(env.action_space.sample())
    envs = gym.make_vec("Bogie/Hunting-v0", num_envs=2, vectorization_mode="vector_entry_point")
    envs.reset(seed=0)
    envs.step(envs.action_space.sample())
    done = subprocess.run([bogie, "critical-speed", "--json"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    assert result["status"] == "crossing" and 300.0 < result["critical_speed_kmh"] < 450.0, result
    done = subprocess.run([bogie, "train", "--algo", "ppo", "--out", "runs/x"], capture_output=True, text=True)
    assert done.returncode == 2 and "bogie-env[agents]" in done.stderr, (done.returncode, done.stderr)
    print(f"installed env OK: critical speed {result['critical_speed_kmh']:.1f} km/h from {result['config']}")
elif mode == "agents":
    import gymnasium as gym
    import numpy as np

    from bogie_agents.controllers.policies import load_policy

    env = gym.make("Bogie/Hunting-v0")
    policy = load_policy("pretrained", env.unwrapped.config)
    obs, _ = env.reset(seed=0)
    policy.reset(1)
    action = np.asarray(policy.act(obs[None]))
    assert action.shape == (1, 4) and np.all(np.isfinite(action)), action
    env.step(action[0])
    print("installed agents OK: the pretrained policy loads and acts")
else:
    raise SystemExit(f"unknown mode {mode!r}; use env or agents")
