"""Track geometry: routes (tangent, clothoid transition, circular curve, cant ramps), their YAML
validation and the compiled sampler."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bogie_env.route import (
    CANT_BASE_M, RouteError, available_routes, equilibrium_cant_m, load_route, route_from_dict,
)  # fmt: skip
from bogie_env.track import (
    ALIGNMENT_WHEELSET1, CANT_FRAME, CANT_WHEELSET1, CANT_WHEELSET2, CURVATURE_FRAME, CURVATURE_WHEELSET1,
    CURVATURE_WHEELSET2, N_TRACK_SAMPLES, TrackInput, sample_track,
)  # fmt: skip

SHIPPED = ("conventional-1500", "high-speed-7000", "s-curve")


def test_shipped_routes_load_with_design_speed_and_sources():
    assert set(SHIPPED) <= set(available_routes())
    for name in SHIPPED:
        route = load_route(name)
        assert route.design_speed_kmh and route.sources and route.length > 1000


def test_high_speed_route_geometry_clothoid_and_cant_ramp():
    route = load_route("high-speed-7000")
    # tangent 200, transition 400, curve 1200, transition 400, tangent 300
    assert route.length == 2500
    assert route.curvature(100.0) == 0.0 and route.cant(100.0) == 0.0
    s = np.linspace(200.0, 600.0, 9)
    # clothoid: curvature linear in distance, cant ramps linearly along it
    np.testing.assert_allclose(route.curvature(s), (s - 200.0) / 400.0 / 7000.0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(route.cant(s), 0.165 * (s - 200.0) / 400.0, rtol=0, atol=1e-15)
    assert route.curvature(1200.0) == pytest.approx(1 / 7000.0) and route.cant(1200.0) == pytest.approx(0.165)
    assert route.curvature(2000.0) == pytest.approx(0.5 / 7000.0) and route.curvature(2300.0) == 0.0
    assert route.curvature(5000.0) == 0.0  # held beyond the end


def test_s_curve_reverses_through_zero_and_right_curves_are_negative():
    route = load_route("s-curve")
    # curve left ends at 1050, reverse transition 1050-1550, right curve from 1550
    assert route.curvature(800.0) == pytest.approx(1 / 3000.0) and route.cant(800.0) == pytest.approx(0.16)
    assert route.curvature(1300.0) == pytest.approx(0.0, abs=1e-15) and route.cant(1300.0) == pytest.approx(0.0, abs=1e-15)
    assert route.curvature(1800.0) == pytest.approx(-1 / 3000.0) and route.cant(1800.0) == pytest.approx(-0.16)
    assert load_route("conventional-1500").curvature(600.0) == pytest.approx(-1 / 1500.0)


def test_equilibrium_cant_is_en13803s_11_8_v2_over_r():
    """EN 13803's engineering formula D_eq = 11.8 V^2 / R (mm, km/h, m) over a 1500 mm base: the
    small-angle form of tan(theta) = V^2 / (g R), so equal to within theta^2 / 2 (+ the rounding
    of 11.8)."""
    for v, r in ((350.0, 7000.0), (180.0, 1500.0), (160.0, 3000.0), (300.0, 9000.0), (80.0, 2000.0)):
        theta = math.atan((v / 3.6) ** 2 / (9.81 * r))
        assert 1e3 * equilibrium_cant_m(v, r) == pytest.approx(11.8 * v * v / r, rel=0.5 * theta**2 + 2e-3)
    assert CANT_BASE_M == 1.5


def test_compiled_sampler_equals_the_route_under_each_wheelset_and_the_frame():
    route = load_route("s-curve")
    track = TrackInput(route=route)
    compiled = track.compiled()
    L1 = 1.5
    out = np.empty(N_TRACK_SAMPLES)
    for s in (-50.0, 0.0, 201.3, 449.0, 1049.9, 1300.0, 1551.0, 2149.0, 2400.0, 9000.0):
        sample_track(compiled, s, L1, out)
        assert out[CURVATURE_WHEELSET1] == pytest.approx(route.curvature(s + L1), abs=1e-15)
        assert out[CURVATURE_WHEELSET2] == pytest.approx(route.curvature(s - L1), abs=1e-15)
        assert out[CURVATURE_FRAME] == pytest.approx(route.curvature(s), abs=1e-15)
        for k, offset in ((CANT_WHEELSET1, L1), (CANT_WHEELSET2, -L1), (CANT_FRAME, 0.0)):
            assert out[k] == pytest.approx(math.asin(route.cant(s + offset) / 1.5), abs=1e-15)
        np.testing.assert_allclose(out, track.under_wheelsets(s, L1), rtol=0, atol=1e-15)
    # no route: exact zeros
    TrackInput().compiled()
    sample_track(TrackInput().compiled(), 123.0, L1, out)
    assert np.all(out == 0.0) and out[ALIGNMENT_WHEELSET1] == 0.0


def _segments(*items):
    return {"name": "t", "segments": list(items)}


@pytest.mark.parametrize(
    "data, message",
    [
        (_segments({"type": "spiral", "length": 10}), "segments[0].type = 'spiral'"),
        (_segments({"type": "tangent", "length": -1}), "segments[0].length = -1"),
        (_segments({"type": "tangent"}), "segments[0].length is required"),
        (_segments({"type": "curve", "length": 10, "radius": 50, "direction": "left"}), "segments[0].radius = 50"),
        (_segments({"type": "curve", "length": 10, "radius": 900, "direction": "up"}), "segments[0].direction = 'up'"),
        (_segments({"type": "curve", "length": 10, "radius": 900, "direction": "left", "cant": 0.5}), "segments[0].cant = 0.5"),
        (_segments({"type": "curve", "length": 10, "radius": "big", "direction": "left"}), "segments[0].radius = 'big' is not a number"),
        (_segments({"type": "tangent", "length": 10, "radius": 3}), "unknown key(s) radius"),
        (_segments({"type": "transition", "length": 10}, {"type": "tangent", "length": 10}), "segments[0]: a transition"),
        (_segments({"type": "tangent", "length": 10},
                   {"type": "curve", "length": 10, "radius": 900, "direction": "left", "cant": 0.1}), "cant jumps"),
        ({"segments": []}, "'segments' = [] must be a non-empty list"),
        ({"segments": [{"type": "tangent", "length": 1}], "speed": 3}, "unknown key(s) speed"),
    ],
)
def test_bad_routes_fail_with_named_errors(data, message):
    with pytest.raises(RouteError) as error:
        route_from_dict(data)
    assert message in str(error.value)


def test_route_files_load_safely_and_unknown_names_list_the_shipped_routes(tmp_path):
    evil = tmp_path / "evil.yaml"
    evil.write_text("!!python/object/apply:os.system ['echo pwned']\n")
    with pytest.raises(RouteError, match="not valid YAML"):
        load_route(evil)
    good = tmp_path / "mine.yaml"
    good.write_text("segments:\n  - {type: curve, length: 100, radius: 2000, cant: 0.05, direction: right}\n")
    assert load_route(good).curvature(50.0) == pytest.approx(-1 / 2000.0)
    with pytest.raises(RouteError, match="shipped routes: .*high-speed-7000"):
        load_route("no-such-route")
