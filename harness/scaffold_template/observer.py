r"""A complementary sideslip observer: kinematic integration, anchored to the rear-axle steady state.

Lateral velocity from the kinematics of a rigid body in the plane (Kiencke & Nielsen, *Automotive
Control Systems*, 2000, sec. 7.3),

.. math:: \dot v_y = a_y - r\,v_x,

is exact but drifts with any accelerometer bias or road bank. The linear rear axle gives a second,
drift-free value in steady cornering: with :math:`F_{yr} = C_r\,\alpha_r`,
:math:`\alpha_r = -(v_y - l_r r)/v_x` and the rear share :math:`F_{yr} = m\,a_y\,l_f/L` of the lateral
force at :math:`a_y = v_x r`,

.. math:: v_{y,ss} = r\,\Bigl(l_r - \frac{m\,l_f\,v_x^2}{C_r\,L}\Bigr).

The observer integrates the kinematics and pulls the result towards :math:`v_{y,ss}` with the
documented gain :math:`1/\tau` (option ``tau_s``): fast motions come from the kinematics, the slow
part from the axle model, so a constant accelerometer bias :math:`b` leaves a bounded error
:math:`\tau b` instead of a growing one. The pull is applied exactly over each step
(:math:`e^{-h/\tau}`), so the step size does not change the gain.
"""

from __future__ import annotations

import math
from typing import Any

from roadtruth import ScalarLoopObserver

#: Below this reference speed [m/s] the axle model (1/v_x) is not used and the estimate decays to 0.
MIN_SPEED_MPS = 2.0


class ComplementarySideslip(ScalarLoopObserver):
    """Lateral velocity and sideslip angle from the IMU, wheel speeds and the rear-axle steady state."""

    name = "complementary_vy"
    citation = ("Kinematic model v_y' = a_y - r v_x (Kiencke & Nielsen 2000, sec. 7.3) blended with the "
                "linear rear-axle steady state")
    inputs = ("ay_mps2", "yaw_rate_radps", "vx_mps")
    states = ("vy_mps", "beta_rad")
    #: tau_s: time constant of the pull towards the steady state [s] (gain 1/tau_s).
    default_options: dict[str, Any] = {"tau_s": 0.5}

    def _setup(self) -> None:
        tau = float(self.options["tau_s"])
        if not (tau > 0.0 and math.isfinite(tau)):
            raise ValueError(f"tau_s must be a positive number of seconds (got {tau!r})")
        self._tau = tau
        v = self.vehicle
        self._lr = v.lr_m
        # m l_f / (C_r L) [s^2/m]: the speed-dependent part of the rear-axle steady state.
        self._k_us = v.mass_kg * v.lf_m / (v.cornering_stiffness_r_Npr * v.wheelbase_m)

    def _initial_state(self) -> list[float]:
        return [0.0, 0.0]  # [v_y (m/s), v_x held for beta (m/s)]

    def _advance(self, t_s: float, y: list[float]) -> None:
        h = self._tick(t_s, y)
        ay, r, vx = self._u
        if h <= 0.0 or ay != ay or r != r or vx != vx:
            return  # nothing new, or an input has never arrived: keep the estimate
        vy = self._z[0]
        if vx < MIN_SPEED_MPS:
            self._z[0] = vy * math.exp(-h / self._tau)
        else:
            vy_ss = r * (self._lr - self._k_us * vx * vx)
            vy = vy + h * (ay - r * vx)  # kinematics over the step (explicit Euler, h ~ 1 ms)
            self._z[0] = vy_ss + (vy - vy_ss) * math.exp(-h / self._tau)
        self._z[1] = vx

    def _values(self) -> list[float]:
        vy, vx = self._z
        return [vy, math.atan2(vy, vx) if vx >= MIN_SPEED_MPS else 0.0]
