"""The command line: absurd numbers and lists are named errors naming the option, malformed
YAML and a bad output path are clean errors, JSON output, version and help."""

import json

import pytest

from bogie_agents.cli import main as cli_main


def test_critical_speed_json_reports_a_stable_window(capsys):
    assert cli_main(["critical-speed", "--json", "--v-max-kmh", "200"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert payload["critical_speed_kmh"] is None and payload["stable_over_window"] is True
    assert payload["search_window_kmh"] == [50.0, 200.0] and payload["eigenvalue"] is None


@pytest.mark.parametrize(
    "argv, message",
    [(["ramp", "--accel", "1e9"], "argument --accel: '1e9' is not allowed; allowed: a number in (0, 10] m/s^2"),
     (["ramp", "--offset", "10"], "argument --offset: '10' is not allowed"),
     (["ramp", "--track-rms", "-0.001"], "argument --track-rms: '-0.001' is not allowed"),
     (["ramp", "--v-start-kmh", "-300"], "argument --v-start-kmh"),
     (["evaluate", "--policy", "passive", "--seed", "-1"], "argument --seed: '-1' is not allowed"),
     (["root-locus", "--n-speeds", "1"], "argument --n-speeds"),
     (["sensitivity", "--param", "Csy", "--workers", "0"], "argument --workers")],
)  # fmt: skip
def test_cli_rejects_absurd_numbers_naming_the_option(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli_main(argv)
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize(
    "argv, message",
    [(["bifurcation", "--rates", "1,x"], "--rates '1,x': every entry must be a number"),
     (["bifurcation", "--rates", "1,-2"], "--rates '1,-2': every entry must be a finite number > 0"),
     (["sensitivity", "--param", "Csy", "--scales", ""], "--scales '' is empty")],
)  # fmt: skip
def test_cli_list_options_are_named(argv, message, capsys):
    assert cli_main(argv) == 2
    assert message in capsys.readouterr().err


def test_cli_malformed_yaml_and_out_file_are_clean_errors(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("Csy: [1, 2\n")
    assert cli_main(["critical-speed", "--config", str(bad)]) == 2
    assert "is malformed" in capsys.readouterr().err
    bad.write_text("speed: {accel: 1}\nspeed: {accel: 2}\n")
    assert cli_main(["evaluate", "--policy", "passive", "--env-config", str(bad)]) == 2
    assert "duplicate key 'speed'" in capsys.readouterr().err
    out_file = tmp_path / "taken"
    out_file.write_text("x")
    assert cli_main(["results", "--policy", "passive", "--out", str(out_file)]) == 2
    assert "is an existing file" in capsys.readouterr().err
    assert cli_main(["ramp", "--v-start-kmh", "300", "--v-end-kmh", "301", "--accel", "10", "--out", str(out_file)]) == 2
    assert "bogie ramp: error:" in capsys.readouterr().err


def test_cli_version_and_help(capsys):
    with pytest.raises(SystemExit):
        cli_main(["--version"])
    from bogie_env import __version__

    assert capsys.readouterr().out.strip() == f"bogie {__version__}"
    for command in ("ramp", "evaluate", "bifurcation", "sensitivity", "train"):
        with pytest.raises(SystemExit):
            cli_main([command, "--help"])
        text = capsys.readouterr().out
        assert "``" not in text, command
    with pytest.raises(SystemExit):
        cli_main(["evaluate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "Protocol v2 (-v1 ids): critical, cost, margins (default: these three" in text and "robustness (default: all)" in text
