"""Files: atomic writes with normal permissions, and strict YAML (duplicate keys and syntax
errors are named, in every loader of the project)."""

import os
import stat

import pytest

from bogie_env.envs.config import make_config
from bogie_env.fileio import load_yaml, write_text_atomic
from bogie_env.params import BogieParams, ConfigError


def test_atomic_writes_have_normal_permissions(tmp_path):
    old = os.umask(0o022)
    try:
        write_text_atomic(tmp_path / "a.txt", "x")
        from bogie_env.analysis.plots import plt, save

        fig, _ = plt.subplots()
        save(fig, tmp_path / "f.png")
    finally:
        os.umask(old)
    for name in ("a.txt", "f.png"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o644, name
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "f.png"]  # no temporary left


def test_write_to_a_folder_is_a_named_error(tmp_path):
    with pytest.raises(ConfigError, match="is a folder"):
        write_text_atomic(tmp_path, "x")


@pytest.mark.parametrize(
    "text, message",
    [("a: 1\na: 2\n", "duplicate key 'a'"), ("speed: {accel: 1, accel: 2}\n", "duplicate key 'accel'"),
     ("a: [1, 2\n", "malformed"), ("a: !!python/object/apply:os.system ['true']\n", "malformed")],
)  # fmt: skip
def test_yaml_duplicates_and_syntax_errors(tmp_path, text, message):
    path = tmp_path / "c.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_yaml(path)


def test_every_project_yaml_loader_rejects_duplicates(tmp_path):
    from bogie_agents.training.train import load_run_config

    path = tmp_path / "dup.yaml"
    path.write_text("speed:\n  accel: 1.0\n  accel: 2.0\n")
    with pytest.raises(ConfigError, match="duplicate key 'accel'"):
        make_config(str(path))
    path.write_text("algo: ppo\nalgo: sac\n")
    with pytest.raises(ConfigError, match="duplicate key 'algo'"):
        load_run_config(path, None)
    from bogie_env.params import DEFAULT_BOGIE_CONFIG

    text = DEFAULT_BOGIE_CONFIG.read_text()
    first = next(line for line in text.splitlines() if line and not line.startswith((" ", "#")) and ":" in line)
    path.write_text(text + "\n" + first + "\n")
    with pytest.raises(ConfigError, match="duplicate key"):
        BogieParams.from_yaml(path)
    path.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="must hold a mapping"):
        make_config(str(path))
    with pytest.raises(ConfigError, match="must hold a mapping"):
        BogieParams.from_yaml(path)
