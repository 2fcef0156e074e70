r"""Reference sideslip estimator for production sensors: rear-axle tire inversion blended with kinematics.

``reference_beta`` estimates ``v_y`` and ``beta`` from what every stability-control car has: the yaw-rate
gyro, the lateral accelerometer and the speed (wheel speeds, or any speed the log has). It needs only
the basic vehicle parameters (mass, yaw inertia, ``l_f``, ``l_r``, rear-axle cornering stiffness and tire
shape, grip) and no steering angle, so steering-ratio, steering-offset and steering-compliance errors do
not enter.

Per step (filters on the held inputs; ``tau_f`` = option ``prefilter_s``):

1. **Axle force from the measured accelerations** (Newton-Euler of the single-track model, no tire
   model)::

       F_r = (l_f m a_y - I_z r') / L,        L = l_f + l_r

   with ``a_y`` and ``r`` low-passed by ``1/(tau_f s + 1)`` and ``r'`` from the same filter
   (``s/(tau_f s + 1)``), so both terms have the same phase.
2. **Grip the car shows.** The rear curve is the vehicle's Magic Formula axle curve with the peak
   scale ``k`` (peak ``k F_zr,static``, cornering stiffness kept, as in ``observers/tire_curves.py``);
   ``k >= headroom |a_y,lp| / g``: a measured lateral acceleration is a lower bound of the grip, so a
   car cornering harder than its configured grip raises the curve instead of saturating it. ``k``
   relaxes back to the configured grip with ``grip_recovery_s``.
3. **Rear slip by inverting the curve** on its rising branch, ``alpha_r = F_r^{-1}(F_r; k)``, and the
   model's lateral velocity from the rear slip definition (CONTRACT: ``alpha_r = -atan((v_y - l_r r)/v_x)``)::

       v_y,model = l_r r - v_x tan(alpha_r)

   In steady cornering with linear tires this is the textbook ``beta = l_r r / v_x - m l_f a_y / (L C_r)``
   (e.g. R. Rajamani, *Vehicle Dynamics and Control*, 2nd ed., 2012, sec. 3.2): the sideslip that the
   rear axle's force requires.
4. **Blend with the kinematic model** ``v_y' = a_y - v_x r`` (complementary filter, as in
   D. Piyabongkarn, R. Rajamani, J. A. Grogg, J. Y. Lew, "Development and experimental evaluation of a
   slip angle estimator for vehicle stability control", IEEE Trans. Control Syst. Technol. 17(1):78-88,
   2009: kinematics carry the fast part, the model the slow part, weighted by how valid the model is)::

       v_y <- v_y + h (a_y - v_x r);   v_y <- v_y + h / (tau + h) (v_y,model - v_y)

   ``tau`` grows from ``blend_min_s`` to ``blend_max_s`` as the rear axle uses its grip
   (``tau = tau_min + (tau_max - tau_min) (|F_r| / D_r)^2``): near the peak the inversion is
   ill-conditioned (a small force error is a large slip error), so kinematics weigh more. Both time
   constants stay short because the kinematic path integrates every accelerometer error (bias,
   gravity through roll and bank: 0.5 m/s^2 over 0.3 s is 0.15 m/s of v_y).

``beta = atan2(v_y, v_x)``; ``alpha_r_rad`` is the inverted rear slip. No option is tuned to a log:
the defaults are physical (filter and blend times of a production ESC estimator) and shared with the
EKF/UKF grip adaptation.

Limits: a road slipperier than the configured grip is seen only where the tires saturate (nothing in
``(r, a_y)`` shows it earlier); the static rear load ignores longitudinal load transfer (braking in a
corner lowers the rear curve's true peak); roll and bank leak into the accelerometer unmodelled.

The per-run loop is one compiled (numba) function; ``step`` runs the same function on one row.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from roadtruth.harness.errors import InputError
from roadtruth.harness.truth.tire import jit
from roadtruth.harness.truth.vehicle import G, VehicleParams
from roadtruth.observers.base import EstimateTrack, Observer, StepOutput
from roadtruth.observers.registry import register
from roadtruth.observers.tire_curves import inverse_magic_formula

STATES = ("vy_mps", "beta_rad", "alpha_r_rad")
INPUTS = ("vx_mps", "yaw_rate_radps", "ay_mps2")

# parameter array
(P_M, P_IZ, P_LF, P_LR, P_BYR, P_CYR, P_EYR, P_FZR, P_K0, P_TF, P_TMIN, P_TMAX, P_HEAD, P_TGF, P_TREC,
 P_KMAX, P_VMIN, N_PAR) = range(18)
# memory array: time, held inputs, filter states, estimate
(S_T, S_VX, S_R, S_AY, S_RF, S_AYF, S_AYLP, S_K, S_VY, S_AR, S_STARTED, N_MEM) = range(12)

_OPTIONS: dict[str, float] = {
    "prefilter_s": 0.05,       # low-pass of r and a_y before the force balance [s]
    "blend_min_s": 0.1,        # complementary-filter time constant with the rear axle far from its peak [s]
    "blend_max_s": 0.3,        # ... at its peak [s]
    "grip_headroom": 1.1,      # rear curve peak >= this x low-passed measured |a_y| (0: grip not adapted)
    "grip_filter_s": 0.2,      # time constant of that low-pass [s]
    "grip_recovery_s": 30.0,   # return of the curve to the configured grip [s]
    "grip_max": 3.0,           # largest peak scale the adaptation gives [1]
    "vx_min_mps": 2.0,         # v_x floor of the slip definition [m/s]
}


@jit
def reference_rows(t: np.ndarray, Y: np.ndarray, mem: np.ndarray, par: np.ndarray) -> np.ndarray:
    """Advance over rows ``t`` (n,) [s], ``Y`` (n, 3) = ``(v_x, r, a_y)`` (NaN = no new sample).

    ``mem`` (N_MEM,) is updated in place; returns the estimates (n, 3) in ``STATES`` order.
    """
    n = t.shape[0]
    out = np.empty((n, 3))
    lf, lr, m, iz = par[P_LF], par[P_LR], par[P_M], par[P_IZ]
    L = lf + lr
    for i in range(n):
        vx_new, r_new, ay_new = Y[i, 0], Y[i, 1], Y[i, 2]
        if vx_new == vx_new:
            mem[S_VX] = vx_new
        if r_new == r_new:
            mem[S_R] = r_new
        if ay_new == ay_new:
            mem[S_AY] = ay_new
        vx, r, ay = mem[S_VX], mem[S_R], mem[S_AY]
        h = t[i] - mem[S_T]
        if h < 0.0:
            h = 0.0
        mem[S_T] = t[i]
        if vx == vx and r == r and ay == ay:
            v = vx if vx > par[P_VMIN] else par[P_VMIN]
            first = mem[S_STARTED] == 0.0
            if first:
                # first complete sample: the filters start on it (no start-up transient from zero)
                mem[S_RF], mem[S_AYF], mem[S_AYLP] = r, ay, ay
                mem[S_STARTED] = 1.0
                h = 0.0
            tf = par[P_TF]
            a = h / (tf + h)
            rf = mem[S_RF] + a * (r - mem[S_RF])
            ayf = mem[S_AYF] + a * (ay - mem[S_AYF])
            rdot = (r - rf) / tf          # s/(tf s + 1) applied to r: the filtered yaw acceleration
            mem[S_RF], mem[S_AYF] = rf, ayf
            # grip floor from the measured lateral acceleration (as observers/kalman.py: adapt_grip)
            k0 = par[P_K0]
            k = mem[S_K]
            if par[P_HEAD] > 0.0:
                mem[S_AYLP] += h / (par[P_TGF] + h) * (ay - mem[S_AYLP]) if h > 0.0 else 0.0
                k += h / (par[P_TREC] + h) * (k0 - k) if h > 0.0 else 0.0
                k = max(k, par[P_HEAD] * abs(mem[S_AYLP]) / G, k0)
                k = min(k, max(par[P_KMAX], k0))
            mem[S_K] = k
            # rear-axle force from the measured motion, then its slip from the curve
            fr = (lf * m * ayf - iz * rdot) / L
            alpha_r, used = inverse_magic_formula(fr, par[P_BYR] / k, par[P_CYR], par[P_EYR], k * par[P_FZR])
            vy_model = lr * rf - v * math.tan(alpha_r)
            if first:
                vy = vy_model
            else:
                tau = par[P_TMIN] + (par[P_TMAX] - par[P_TMIN]) * used * used
                vy = mem[S_VY] + h * (ay - v * r)
                vy += h / (tau + h) * (vy_model - vy)
            mem[S_VY], mem[S_AR] = vy, alpha_r
            out[i, 0], out[i, 1], out[i, 2] = vy, math.atan2(vy, v), alpha_r
        elif mem[S_STARTED] > 0.0:
            v = vx if vx == vx and vx > par[P_VMIN] else par[P_VMIN]
            out[i, 0], out[i, 1], out[i, 2] = mem[S_VY], math.atan2(mem[S_VY], v), mem[S_AR]
        else:
            out[i, 0], out[i, 1], out[i, 2] = 0.0, 0.0, 0.0   # nothing measured yet: the neutral state
    return out


@register
class ReferenceSideslip(Observer):
    """Sideslip from production sensors: rear-axle Magic Formula inversion with an adaptive grip floor,
    blended with kinematic integration by how close the rear axle is to its peak."""

    name = "reference_beta"
    citation = ("Rear-axle tire inversion blended with kinematic integration (Piyabongkarn, Rajamani, Grogg "
                "& Lew, IEEE Trans. Control Syst. Technol. 17(1), 2009; Magic Formula: Pacejka, Tire and "
                "Vehicle Dynamics, 3rd ed., 2012, eq. 4.49)")
    inputs = INPUTS
    states = STATES
    default_options = dict(_OPTIONS)

    def __init__(self, vehicle: VehicleParams, **options: Any) -> None:
        super().__init__(vehicle, **options)
        o = {k: self._number(k) for k in _OPTIONS}
        if not (0.0 < o["prefilter_s"] <= 2.0 and 0.0 < o["blend_min_s"] <= o["blend_max_s"] <= 60.0):
            raise InputError("need 0 < prefilter_s <= 2 and 0 < blend_min_s <= blend_max_s <= 60",
                             field=f"observer {self.name} options")
        if not (o["grip_headroom"] == 0.0 or 1.0 <= o["grip_headroom"] <= 3.0):
            raise InputError(f"must be 0 (off) or in [1, 3] (got {o['grip_headroom']!r}): a curve below the "
                             "measured a_y cannot explain it", field=f"observer {self.name} option grip_headroom")
        if not (o["grip_filter_s"] >= 0.0 and o["grip_recovery_s"] >= 0.0 and o["grip_max"] > 0.0
                and o["vx_min_mps"] > 0.0):
            raise InputError("need grip_filter_s, grip_recovery_s >= 0 and grip_max, vx_min_mps > 0",
                             field=f"observer {self.name} options")
        rear = vehicle.tires.rear
        par = np.zeros(N_PAR)
        par[P_M], par[P_IZ], par[P_LF], par[P_LR] = (vehicle.mass_kg, vehicle.yaw_inertia_kgm2,
                                                     vehicle.lf_m, vehicle.lr_m)
        par[P_BYR], par[P_CYR], par[P_EYR] = rear.By, rear.Cy, min(rear.Ey, 1.0)
        par[P_FZR], par[P_K0] = vehicle.fz_rear_static_N, vehicle.tires.grip
        par[P_TF], par[P_TMIN], par[P_TMAX] = o["prefilter_s"], o["blend_min_s"], o["blend_max_s"]
        par[P_HEAD], par[P_TGF], par[P_TREC] = o["grip_headroom"], o["grip_filter_s"], o["grip_recovery_s"]
        par[P_KMAX], par[P_VMIN] = o["grip_max"], o["vx_min_mps"]
        self._par = par
        self.reset(0.0)

    def _number(self, key: str) -> float:
        value = self.options[key]
        if not (isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
                or value == math.inf):
            raise InputError(f"must be a number (got {value!r})", field=f"observer {self.name} option {key}")
        return float(value)

    def reset(self, t0_s: float, x0: Mapping[str, float] | None = None) -> None:
        if x0:
            raise InputError("starts from its first measurement; no state can be initialised",
                             field=f"observer {self.name} x0")
        mem = np.zeros(N_MEM)
        mem[S_T] = float(t0_s)
        mem[S_VX] = mem[S_R] = mem[S_AY] = math.nan
        mem[S_K] = self._par[P_K0]
        self._mem = mem

    def grip(self) -> float:
        """The rear curve's peak scale now, ``k`` [1] (peak force ``k F_zr,static``)."""
        return float(self._mem[S_K])

    def step(self, t_s: float, y: np.ndarray) -> StepOutput:
        Y = np.asarray(y, dtype=float).reshape(1, len(INPUTS))
        return StepOutput(reference_rows(np.array([float(t_s)]), Y, self._mem, self._par)[0])

    def run(self, t: np.ndarray, Y: np.ndarray, x0: Mapping[str, float] | None = None) -> EstimateTrack:
        t = np.ascontiguousarray(np.asarray(t, dtype=float))
        Y = np.ascontiguousarray(np.asarray(Y, dtype=float).reshape(len(t), len(INPUTS)))
        if len(t):
            self.reset(float(t[0]), x0)
        X = reference_rows(t, Y, self._mem, self._par) if len(t) else np.zeros((0, len(STATES)))
        return EstimateTrack(self.name, STATES, t, X)
