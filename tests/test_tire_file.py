"""Reading .tir files: the shipped file round-trips, bad files are one clear line, defaults are documented."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_tire_mf61 import reference

from roadtruth.harness.errors import VehicleError
from roadtruth.harness.truth.tire_file import (
    MF61_INDEX,
    N_MF61_COEF,
    SCALING_NAMES,
    read_tire_file,
    shipped_tire_path,
    tire_file_from_text,
)
from roadtruth.harness.truth.tire_mf61 import mf61_forces

TIR = shipped_tire_path("mf61_205_60R15")

MINIMAL = """\
$ a minimal MF 6.1 file: only the required keys and a few others
[UNITS]
LENGTH = 'meter'
FORCE = 'newton'
ANGLE = 'radian'
[MODEL]
FITTYP = 61          $ Magic Formula 6.1
[DIMENSION]
unloaded_radius = 0.31   ! lower-case key, '!' comment
[VERTICAL]
FNOMIN = 4.0D+03
[LONGITUDINAL_COEFFICIENTS]
PCX1 = 1.6
PDX1 = 1.1
PKX1 = 20.0
[LATERAL_COEFFICIENTS]
PCY1 = 1.3
PDY1 = 0.9
PKY1 = -15.0
PKY2 = 1.7
"""


def test_shipped_file_round_trips():
    tire = read_tire_file(TIR)
    assert tire.fittyp == 61 and tire.coef.shape == (N_MF61_COEF,)
    assert tire.fnomin_N == 4000.0 and tire.unloaded_radius_m == 0.3135
    assert tire.vertical_stiffness_Npm == 209651.0 and tire.vertical_damping_Nspm == 50.0
    assert (tire.longvl_mps, tire.vxlow_mps) == (16.7, 1.0)
    assert (tire.nompres_Pa, tire.inflpres_Pa) == (200000.0, 200000.0) and tire.coefficient("DPI") == 0.0
    assert (tire.fzmin_N, tire.fzmax_N, tire.kpumin, tire.kpumax) == (100.0, 10000.0, -1.0, 1.0)
    assert (tire.alpmin_rad, tire.alpmax_rad, tire.cammin_rad, tire.cammax_rad) == (-0.5, 0.5, -0.2, 0.2)
    assert tire.coefficient("PKY1") == -15.324 and tire.coefficient("QDZ6") == 0.0017015
    assert tire.scaling["LMUY"] == 1.0
    with pytest.raises(ValueError):
        tire.coef[0] = 1.0  # the kernel's vector is read-only
    rng = np.random.default_rng(3)
    for _ in range(30):
        fz = float(rng.uniform(tire.fzmin_N, 9000.0))
        kappa, alpha = float(rng.uniform(-0.5, 0.5)), float(rng.uniform(-0.4, 0.4))
        gamma = float(rng.uniform(-0.15, 0.15))
        got = mf61_forces(tire.coef, fz, kappa, alpha, gamma, 15.0, 1.0, 1.0)
        np.testing.assert_allclose(got, reference(tire, fz, kappa, alpha, gamma), rtol=1e-9, atol=1e-9)


def test_minimal_file_gets_documented_defaults(tmp_path):
    path = tmp_path / "minimal.tir"
    path.write_text(MINIMAL)
    tire = read_tire_file(path)
    assert tire.name == "minimal" and tire.unloaded_radius_m == 0.31 and tire.fnomin_N == 4000.0
    for name in SCALING_NAMES:
        assert tire.coefficient(name) == 1.0
    assert tire.coefficient("PKY4") == 2.0  # MF-Tyre 6.1 default
    for name in ("PDX2", "PEX1", "PHX1", "PVY1", "PKY6", "RBX1", "RCY1", "QBZ1", "QDZ1", "SSZ1", "DPI"):
        assert tire.coefficient(name) == 0.0
    assert (tire.longvl_mps, tire.vxlow_mps) == (16.7, 1.0)
    assert tire.nompres_Pa is None and tire.vertical_stiffness_Npm is None
    assert tire.fzmin_N == 0.0 and math.isinf(tire.fzmax_N) and math.isinf(tire.alpmax_rad)
    # no shifts and no combined-slip reduction coefficients: F_y(α) odd, F_y unaffected by κ (G_yκ = 1)
    fy = mf61_forces(tire.coef, 4000.0, 0.0, 0.05, 0.0, 20.0, 1.0, 1.0)[1]
    assert fy > 0.0 and mf61_forces(tire.coef, 4000.0, 0.0, -0.05, 0.0, 20.0, 1.0, 1.0)[1] == pytest.approx(-fy, rel=1e-12)
    assert mf61_forces(tire.coef, 4000.0, 0.1, 0.05, 0.0, 20.0, 1.0, 1.0)[1] == pytest.approx(fy, rel=1e-12)
    # K_yα = PKY1 F_z0 sin(2 atan(F_z/(PKY2 F_z0))) → slope at α = 0
    h = 1e-7
    slope = (mf61_forces(tire.coef, 4000.0, 0.0, h, 0.0, 20.0, 1.0, 1.0)[1]
             - mf61_forces(tire.coef, 4000.0, 0.0, -h, 0.0, 20.0, 1.0, 1.0)[1]) / (2 * h)
    assert slope == pytest.approx(15.0 * 4000.0 * math.sin(2.0 * math.atan(1.0 / 1.7)), rel=1e-6)


def test_fittyp_spellings():
    for spelling, version in (("61", 61), ("62", 62), ("6.1", 61), ("6.2", 62), ("'62'", 62)):
        assert tire_file_from_text(MINIMAL.replace("FITTYP = 61", f"FITTYP = {spelling}")).fittyp == version


def _error(text: str, tmp_path) -> str:
    path = tmp_path / "bad.tir"
    path.write_text(text)
    with pytest.raises(VehicleError) as info:
        read_tire_file(path)
    message = str(info.value)
    assert "\n" not in message and str(path) in message
    return message


@pytest.mark.parametrize(("edit", "expected"), [
    (("FITTYP = 61", "FITTYP = 52"), ":7: FITTYP: 52 is not supported"),
    (("FITTYP = 61", "FITTYP = 6"), ":7: FITTYP: 6 is not supported"),
    (("[MODEL]\nFITTYP = 61          $ Magic Formula 6.1\n", ""), "MODEL: section [MODEL] missing"),
    (("PDY1 = 0.9", "PDY1 = zero.9"), ":18: PDY1: value 'zero.9' is not a number"),
    (("ANGLE = 'radian'", "ANGLE = 'degree'"), ":5: ANGLE: unit 'degree' is not supported"),
    (("LENGTH = 'meter'", "LENGTH = 'mm'"), ":3: LENGTH: unit 'mm' is not supported"),
    (("FORCE = 'newton'", "FORCE = 'kN'"), ":4: FORCE: unit 'kN' is not supported"),
    (("PKY2 = 1.7\n", ""), "PKY2: required coefficient missing"),
    (("PCY1 = 1.3", "PCY1 = 1.3\nPCY1 = 1.4"), ":18: PCY1: defined twice in [LATERAL_COEFFICIENTS] (first on line 17)"),
    (("PCX1 = 1.6", "PCX1 1.6"), ":13: expected 'NAME = value'"),
    (("FNOMIN = 4.0D+03", "FNOMIN = -4000"), ":11: FNOMIN: must be positive"),
])
def test_bad_files_are_one_line_naming_key_and_line(tmp_path, edit, expected):
    old, new = edit
    assert old in MINIMAL
    assert expected in _error(MINIMAL.replace(old, new), tmp_path)


def test_missing_fittyp_and_unreadable_file(tmp_path):
    assert "FITTYP: missing in [MODEL]" in _error(MINIMAL.replace("FITTYP = 61          $ Magic Formula 6.1\n", "USE_MODE = 4\n"), tmp_path)
    with pytest.raises(VehicleError, match="cannot read tire file"):
        read_tire_file(tmp_path / "absent.tir")
    with pytest.raises(VehicleError, match="no shipped tire file 'nope'"):
        shipped_tire_path("nope")


def test_index_constants_match_the_kernel_layout():
    import roadtruth.harness.truth.tire_mf61 as k
    for name, index in MF61_INDEX.items():
        assert getattr(k, "R0" if name == "UNLOADED_RADIUS" else name) == index
