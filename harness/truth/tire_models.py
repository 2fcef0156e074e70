"""The truth's tire models per vehicle: a .tir file (MF 6.1/6.2) or a Fiala brush tire, and the
per-axle Magic Formula fitted to either for the observers' bicycle view.

``tires.model`` in a vehicle file selects the model the stepping loop evaluates (docs/VEHICLES.md,
docs/PHYSICS.md): ``magic_formula`` (the per-axle shapes of the file), ``mf61`` (``tires.file``: a
shipped name such as ``mf61_205_60R15`` or a path, relative to the vehicle file) or ``fiala``
(``tires.front`` / ``tires.rear``: ``cornering_stiffness_Npr`` and ``longitudinal_stiffness_N`` of the
axle, ``half_length_m`` of the contact patch, optional ``camber_stiffness`` per unit load and radian).
For mf61 and fiala the ``AxleTire`` shapes the observers use are FITTED to the truth model's pure-slip
curves at the axle's static wheel load (``roadtruth.harness.truth.tire_fit``); the observers' model is then as close
to the truth's as a per-axle Magic Formula gets, and no closer.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import numpy as np

from roadtruth.harness.errors import VehicleError
from roadtruth.harness.truth.tire_fiala import fiala_coefficients, fiala_forces
from roadtruth.harness.truth.tire_file import read_tire_file, shipped_tire_path
from roadtruth.harness.truth.tire_fit import fit_axle_magic_formula, pure_slip_curves
from roadtruth.harness.truth.tire_mf61 import N_MF61_COEF, camber_stiffness, mf61_forces
from roadtruth.harness.truth.vehicle import AxleTire

#: Columns of the per-wheel coefficient table the stepping loop reads (the longest model's).
N_TIRE_COEF = max(N_MF61_COEF, 4)
#: Loop codes of the tire models.
TIRE_MODEL_CODES = {"magic_formula": 0, "mf61": 1, "fiala": 2}


def resolve_tire_file(name_or_path: str, vehicle_source: str) -> Path:
    """A path (absolute, or relative to the vehicle file's folder) or the name of a shipped tire file."""
    p = Path(name_or_path)
    local = p if p.is_absolute() else Path(vehicle_source).parent / p
    if local.is_file():
        return local
    try:
        return shipped_tire_path(name_or_path)
    except VehicleError as exc:
        raise VehicleError(f"tire file {str(name_or_path)!r} not found next to the vehicle file ({local}) nor "
                           f"shipped ({str(exc).split('(shipped: ', 1)[-1].rstrip(')')})", source=vehicle_source,
                           field="tires.file") from None


@functools.lru_cache(maxsize=32)
def _mf61_axle(path: str, fz: float) -> AxleTire:
    tf = read_tire_file(path)
    coef = np.ascontiguousarray(tf.coef)
    fit = fit_axle_magic_formula(*pure_slip_curves(
        lambda f, k, a, g: mf61_forces(coef, f, k, a, g, 20.0, 1.0, 1.0), fz), fz)
    # Pneumatic trail at small slip from the odd part of the curves (ply-steer/conicity offsets cancel).
    a = np.radians(0.5)
    _, fy_p, mz_p = mf61_forces(coef, fz, 0.0, a, 0.0, 20.0, 1.0, 1.0)
    _, fy_m, mz_m = mf61_forces(coef, fz, 0.0, -a, 0.0, 20.0, 1.0, 1.0)
    trail = -(mz_p - mz_m) / (fy_p - fy_m)
    # The observers' Magic Formula has D = grip mu F_z and keeps B C F_z as the slope: B is stated at
    # grip 1 (B_fit mu_fit), and the vehicle's grip is the file's peak ratio (``file_grip``).
    return AxleTire(By=fit.By * fit.mu_y, Cy=fit.Cy, Ey=fit.Ey, Bx=fit.Bx * fit.mu_x, Cx=fit.Cx, Ex=fit.Ex,
                    stiffness_source=f"fitted to {Path(path).name} at {fz:.0f} N",
                    camber_stiffness=abs(camber_stiffness(tf, fz)) / fz, trail_m=float(trail))


@functools.lru_cache(maxsize=32)
def file_grip(path: str, fz: float) -> float:
    """Peak lateral F_y/F_z of a tire file at load ``fz`` on its own road (the observers' ``grip``)."""
    coef = np.ascontiguousarray(read_tire_file(path).coef)
    fy, _ = pure_slip_curves(lambda f, k, a, g: mf61_forces(coef, f, k, a, g, 20.0, 1.0, 1.0), fz)
    return float(np.max(np.abs(fy(np.radians(np.linspace(-25.0, 25.0, 201))))) / fz)


@functools.lru_cache(maxsize=32)
def _fiala_axle(coef_t: tuple[float, ...], fz: float) -> AxleTire:
    coef = np.asarray(coef_t, dtype=np.float64)
    fit = fit_axle_magic_formula(*pure_slip_curves(lambda f, k, a, g: fiala_forces(coef, f, k, a, g, 1.0), fz), fz)
    return AxleTire(By=fit.By, Cy=fit.Cy, Ey=fit.Ey, Bx=fit.Bx, Cx=fit.Cx, Ex=fit.Ex,
                    stiffness_source="fitted to the Fiala tire at static load",
                    camber_stiffness=coef_t[3] / fz, trail_m=coef_t[2] / 3.0)


def fitted_axle_tires(model: str, t: Any, source: str, fz_front_axle_N: float, fz_rear_axle_N: float
                      ) -> tuple[str, tuple[tuple[float, ...], tuple[float, ...]], tuple[AxleTire, AxleTire]]:
    """(tire file path, Fiala per-wheel coefficients (front, rear), fitted AxleTires (front, rear)).

    ``t`` is the vehicle file's ``tires`` field reader (``roadtruth.harness.truth.vehicle._AllFields``); its errors are
    collected like every other field's.
    """
    wheel_f, wheel_r = fz_front_axle_N / 2.0, fz_rear_axle_N / 2.0
    if model == "mf61":
        name = t.string("file")
        if not name:
            return "", ((), ()), (_nan_axle(), _nan_axle())
        try:
            path = str(resolve_tire_file(name, source))
            return path, ((), ()), (_mf61_axle(path, wheel_f), _mf61_axle(path, wheel_r))
        except VehicleError as exc:
            t._record(f"{t._name('file')}: {str(exc).split(': ', 1)[-1]}")
            return "", ((), ()), (_nan_axle(), _nan_axle())
    coefs, axles = [], []
    for key, fz_wheel in (("front", wheel_f), ("rear", wheel_r)):
        a = t.sub(key)
        c_alpha = a.number("cornering_stiffness_Npr", lo=1e3, hi=1e6) / 2.0
        c_kappa = a.number("longitudinal_stiffness_N", lo=1e3, hi=2e6) / 2.0
        half = a.number("half_length_m", lo=0.01, hi=0.5)
        c_gamma = a.number("camber_stiffness", 0.0, lo=0.0, hi=5.0) * fz_wheel
        a.done()
        coef = tuple(float(x) for x in fiala_coefficients(c_alpha, c_kappa, half, c_gamma))
        coefs.append(coef)
        axles.append(_fiala_axle(coef, fz_wheel) if np.all(np.isfinite(coef)) else _nan_axle())
    return "", (coefs[0], coefs[1]), (axles[0], axles[1])


def _nan_axle() -> AxleTire:
    nan = float("nan")
    return AxleTire(nan, nan, nan, nan, nan, nan, "not read")


def wheel_coefficients(tires: Any) -> np.ndarray:
    """(4, N_TIRE_COEF) coefficient table of the loop for wheels fl, fr, rl, rr (zeros for magic_formula)."""
    out = np.zeros((4, N_TIRE_COEF))
    if tires.model == "mf61":
        coef = read_tire_file(tires.file).coef
        out[:, : coef.shape[0]] = coef
    elif tires.model == "fiala":
        for i, c in enumerate((tires.fiala_front, tires.fiala_front, tires.fiala_rear, tires.fiala_rear)):
            out[i, : len(c)] = c
    return out
