"""The shared conventions, pinned down against geometry worked out by hand."""
import math

import numpy as np
import pytest

from board import conventions as C
from board.errors import InvalidInputError


def test_azimuth_is_clockwise_from_grid_north():
    assert C.az_from_en_deg(0.0, 1.0) == 0.0
    assert C.az_from_en_deg(1.0, 0.0) == pytest.approx(90.0)   # east
    assert C.az_from_en_deg(0.0, -1.0) == pytest.approx(180.0)
    assert C.az_from_en_deg(-1.0, 0.0) == pytest.approx(270.0)  # west
    e, n = C.en_from_az_deg(90.0)
    assert (e, n) == pytest.approx((1.0, 0.0), abs=1e-12)


def test_wrap_and_round_trip_az_el():
    assert C.wrap_az_deg(-1e-17) == 0.0 and C.wrap_az_deg(360.0) == 0.0 and C.wrap_az_deg(-90) == 270.0
    np.testing.assert_allclose(C.wrap_deg180([190.0, -190.0, 10.0]), [-170.0, 170.0, 10.0])
    rng = np.random.default_rng(1)
    az, el = rng.uniform(0, 360, 100), rng.uniform(-89, 89, 100)
    az2, el2 = C.az_el_from_enu_deg(C.enu_from_az_el_deg(az, el))
    np.testing.assert_allclose(C.wrap_deg180(az2 - az), 0, atol=1e-9)
    np.testing.assert_allclose(el2, el, atol=1e-9)


def test_horizon_dip_matches_tangent_geometry():
    # the tangent from height h to a sphere of radius R touches at distance sqrt(2Rh + h^2); its dip is atan(d/R)
    R, h = 3_389_500.0, 2.0
    d = math.sqrt(2 * R * h + h * h)
    assert C.horizon_dip_deg(h, R) == pytest.approx(math.degrees(math.atan2(d, R)), rel=1e-9)
    # curvature drop d^2/2R: 15 m at 10 km on Mars (DESIGN.md)
    assert float(C.curvature_drop_m(10_000.0, C.BODIES["mars"].radius_m)) == pytest.approx(14.75, abs=0.01)


def test_rotation_heading_pitch_roll():
    fwd, left, up = np.eye(3)
    R = C.rotation_enu_from_camera(90.0)
    np.testing.assert_allclose(R @ fwd, [1, 0, 0], atol=1e-12)   # heading 90: forward is east
    np.testing.assert_allclose(R @ left, [0, 1, 0], atol=1e-12)  # left is north
    R = C.rotation_enu_from_camera(0.0, pitch_deg=10.0)
    az, el = C.az_el_from_enu_deg(R @ fwd)
    assert el == pytest.approx(10.0)                              # nose up
    R = C.rotation_enu_from_camera(0.0, roll_deg=10.0)
    right = -left
    _, el = C.az_el_from_enu_deg(R @ right)
    assert el == pytest.approx(-10.0)                             # right side down
    Rall = C.rotation_enu_from_camera(37.0, 4.0, -6.0)
    np.testing.assert_allclose(Rall @ Rall.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(Rall) == pytest.approx(1.0)


def test_bodies_and_refusals():
    assert C.body_from_name("Mars").radius_m == 3_389_500.0
    assert C.body_from_name("2000000").radius_m == 2e6
    with pytest.raises(InvalidInputError, match="unknown body"):
        C.body_from_name("pluto-ish")
    with pytest.raises(InvalidInputError, match="implausible"):
        C.body_from_name(5.0)


def test_parse_xy_names_the_option():
    from board.cliargs import parse_xy

    assert parse_xy("1.5,-2", "--center") == (1.5, -2.0)
    with pytest.raises(InvalidInputError, match="--center must be X,Y"):
        parse_xy("1.5", "--center")
    with pytest.raises(InvalidInputError, match="finite"):
        parse_xy("nan,2", "--at")


def test_body_radii_and_the_curvature_coefficient_are_defined_once():
    """No body radius literal and no hand-written ``(1 - k) / 2R`` outside board/conventions.py (issue 13)."""
    import re
    from pathlib import Path

    repo = Path(__file__).resolve().parents[2]
    radii = [f"{b.radius_m:_.1f}".rstrip("0").rstrip(".") for b in C.BODIES.values()]
    literal = re.compile(r"(?<![\w.])(%s)(?:\.0)?(?![\w])" % "|".join(
        re.escape(r) + "|" + re.escape(r.replace("_", "")) for r in radii))
    coeff = re.compile(r"\(1(?:\.0)? - [\w.]*refraction_k\) / \(2(?:\.0)? \*|\*\* ?2 / \(2(?:\.0)? \* [\w.]*radius")
    bad = []
    for pkg in ("board", "blender_addon", "render_service", "skyloc", "benchmarks"):
        for f in sorted((repo / pkg).rglob("*.py")):
            if f.name == "conventions.py" and f.parent.name == "board":
                continue
            for i, line in enumerate(f.read_text().splitlines(), 1):
                code = line.split("#", 1)[0]
                if literal.search(code) or coeff.search(code):
                    bad.append(f"{f.relative_to(repo)}:{i}: {line.strip()}")
    assert not bad, "\n".join(bad)
