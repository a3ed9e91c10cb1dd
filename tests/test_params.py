"""Parameter loading and validation: every bad value names the field, value and range."""

import math

import pytest

from bogie_env.params import FIELDS, SENSITIVITY_PARAMS, BogieParams, ConfigError, load_params


def test_paper_preset_has_table1_values(paper_params):
    # Table 1 of the paper, in SI units (axle load as a force).
    expected = dict(mb=1610, Ibz=2820, mw=1570, Iwx=693, Iwy=121, Iwz=693, L1=1.5, L2=1.5, b1=1.02, b2=1.04,
                    b3=1.34, h1=0.42, h2=0.14, Wpa=1.5e5, e=0.7175, r0=0.46, lam=0.025, Kpx=5.8e7, Kpy=1.6e7,
                    Kpz=5.4e5, Cpx=0, Cpy=0, Cpz=5e3, Ksx=1e5, Ksy=1e5, Csx=1.3e4, Csy=3e4, Kr=1.617e7, delta=0.009)
    for name, value in expected.items():
        assert getattr(paper_params, name) == pytest.approx(value, rel=1e-12), name


def test_every_field_has_a_documented_range():
    for name, spec in FIELDS.items():
        assert spec.unit and spec.description and spec.low <= spec.high, name
    assert set(SENSITIVITY_PARAMS) <= set(FIELDS)


@pytest.mark.parametrize("value", [float("nan"), float("inf"), -1.0, "abc", True])
def test_bad_values_name_field_value_and_range(paper_params, value):
    with pytest.raises(ConfigError) as info:
        paper_params.replace(Csy=value)
    message = str(info.value)
    assert "Csy" in message and "allowed" in message


def test_out_of_range_message_has_the_range(paper_params):
    with pytest.raises(ConfigError, match=r"'Kpz' = -5 .*allowed: \(1000, 1e\+09\]"):
        paper_params.replace(Kpz=-5)


def test_unknown_keys_are_rejected_with_the_known_list(paper_params):
    values = paper_params.to_dict()
    values["Kpq"] = 1.0
    with pytest.raises(ConfigError, match="unknown bogie parameter.*'Kpq'.*known parameters: mb, Ibz"):
        BogieParams.from_dict(values)


def test_missing_keys_are_rejected(paper_params):
    values = paper_params.to_dict()
    del values["Csy"]
    with pytest.raises(ConfigError, match="missing bogie parameter.*Csy"):
        BogieParams.from_dict(values)


def test_params_are_immutable(paper_params):
    with pytest.raises(Exception):
        paper_params.Csy = 1.0  # type: ignore[misc]


def test_variants_scale_and_replace(paper_params):
    variant = paper_params.scaled(Csy=0.5, Kpz=2.5)
    assert variant.Csy == pytest.approx(1.5e4)
    assert variant.Kpz == pytest.approx(1.35e6)
    assert variant.Kpx == paper_params.Kpx
    assert paper_params.Csy == 3e4  # the original is untouched
    with pytest.raises(ConfigError, match="scale factor"):
        paper_params.scaled(Csy=float("nan"))
    with pytest.raises(ConfigError, match="unknown parameter 'Cs'"):
        paper_params.scaled(Cs=2.0)


def test_replace_checks_only_the_changes_and_builds_what_the_constructor_builds(paper_params):
    import dataclasses

    fast = paper_params.replace(Csy="45000", lam=0.2, f11=None, secondary_heights="printed")
    slow = dataclasses.replace(paper_params, Csy="45000", lam=0.2, f11=None, secondary_heights="printed")
    assert fast == slow and fast.to_dict() == slow.to_dict() and fast.source == slow.source
    assert type(fast.Csy) is float and hash(fast) == hash(slow)
    with pytest.raises(ConfigError, match="'lam' = -0.1 is out of range"):
        paper_params.replace(lam=-0.1)
    with pytest.raises(dataclasses.FrozenInstanceError):
        fast.Csy = 1.0


def test_cli_style_overrides_and_yaml_exponents(tmp_path, paper_params):
    params = load_params(None, ["Csy=45000", "Kpz = 1e6"])
    assert params.Csy == 45000 and params.Kpz == 1e6
    with pytest.raises(ConfigError, match="NAME=VALUE"):
        load_params(None, ["Csy"])
    # PyYAML reads 5.8e7 (no sign) as a string; the loader accepts it.
    text = (paper_params.source and open(paper_params.source).read()).replace("5.8e+7", "5.8e7")
    path = tmp_path / "bogie.yaml"
    path.write_text(text)
    assert BogieParams.from_yaml(path).Kpx == 5.8e7


def test_conical_wheel_may_be_infinite_but_others_not(paper_params):
    assert math.isinf(paper_params.Rwheel)
    with pytest.raises(ConfigError, match=r"'Rrail' = 0 is out of range.*\(0.01, 100\] or .inf"):
        paper_params.replace(Rrail=0.0)
    with pytest.raises(ConfigError, match="not finite"):
        paper_params.replace(Kpx=float("inf"))


def test_missing_file_is_a_clear_error(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        BogieParams.from_yaml(tmp_path / "nope.yaml")


def test_secondary_heights_setting(paper_params):
    assert paper_params.secondary_heights == "table1"
    assert paper_params.with_overrides(["secondary_heights=printed"]).secondary_heights == "printed"
    with pytest.raises(ConfigError, match=r"'secondary_heights' = 'both' is not allowed; allowed: table1, printed"):
        paper_params.replace(secondary_heights="both")
    with pytest.raises(ConfigError, match="secondary_heights"):
        BogieParams.from_dict({**paper_params.to_dict(), "secondary_heights": 1.0})
