r"""Output-integrator dynamic-extension high-gain observer on radar (H. Bessafa, PhD thesis 2024, Thm 4.4.1).

H. Bessafa, "Advanced Estimation Algorithms for Connected and Autonomous Vehicle Applications", PhD
thesis, Université de Lorraine (CRAN), 2024, sec. 4.4, eqs. (4.67)-(4.97), on the radar relative
model of sec. 5.2 (state ``x = (d, d', a_L)``, ``y = d``, ``z = h(x) = d'``; see
:mod:`roadtruth.observers.high_gain_radar`).

A new output is made by integrating the measurements (4.67): ``mu' = alpha y + beta^2 z``, ``mu(0)``
known (here 0). The extended state ``xi = (mu, x)`` (4.73) has the Brunovsky-like chain ``A_xi`` (with
``alpha`` in its first row), the single output ``y_xi = mu`` and the observer (4.74)

.. math::

    \dot{\hat\xi} = A_\xi \hat\xi + B_f f(\hat x) + \beta^2 B_h \hat x_2 - e_3 a_E
    + T(\theta) K (\mu - \hat\mu),\quad T(\theta) = \mathrm{diag}(\theta, \dots, \theta^4).

The range and range rate reach the estimate only through their integral, so the range noise ``w``
enters the error dynamics as ``(alpha/theta) B_w w`` (4.75) instead of ``-K w`` (4.53). Gains and
certificate: :func:`roadtruth.observers.high_gain_radar_design.design_extension` (LMI (4.84); theta, beta and the
rate kappa from the ``varpi`` form (4.96)-(4.97), ``varpi = beta^2 theta^3``; ISS bound (4.87)).

Implementation: the two integrators ``mu`` and ``mu_hat`` are carried as their difference
``nu = mu - mu_hat`` (``mu`` grows like the integral of the range; the difference of two such numbers
would lose digits that the gain ``theta^4 K_4 ~ 1e8`` multiplies):
``nu' = alpha (y - d_hat) + beta^2 (z - d'_hat) - L_1 nu`` and ``(d, d', a_L)_hat' = chain + L_{2..4} nu``,
``L = T(theta) K``. The linear part is integrated exactly with the inputs as ramps (first-order hold,
as in :mod:`roadtruth.observers.high_gain_radar`); ``f(x_hat)`` is held over the step, evaluated on the box.

Missing samples (not stated in the thesis): a range (range-rate) sample older than ``hold_s`` is
replaced in ``mu'`` by its own estimate, i.e. its term of ``nu'`` is dropped; the observer then runs on
the information still measured. ``mu_hat(0) = mu(0)`` (``nu = 0``) at the first range sample, where
the state starts as in the other radar observers (``d``, ``d'`` measured, ``a_L = a_E``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from roadtruth.observers.high_gain_radar import _COMMON, HighGainRadarStandard, _check_extra
from roadtruth.observers.lmi import DesignFailed, DesignStatus
from roadtruth.observers.registry import register


@register
class HighGainRadarExtension(HighGainRadarStandard):
    """Dynamic-extension HGO (Thm 4.4.1): one output, the integral of alpha * range + beta^2 * range rate."""

    name = "hgo_radar_extension"
    citation = ("H. Bessafa, PhD thesis, Univ. Lorraine 2024, Thm 4.4.1, eqs. (4.67)-(4.97); "
                "radar model of sec. 5.2")
    variant = "extension"
    uses_rate = True
    # alpha of (4.67) (weight of the range in mu') and varpi = beta^2 theta^3 of (4.93)-(4.97)
    # (varpi = 0: the range rate is not used). The thesis gives no values.
    default_options = dict(_COMMON, ext_alpha=1.0, ext_varpi=1.0)

    def _setup(self) -> None:
        super()._setup()
        _check_extra(self, {"ext_alpha": lambda v: float(v) > 0.0, "ext_varpi": lambda v: float(v) >= 0.0})
        self._ext: tuple[float, ...] | None = None
        self._disc4: dict[tuple[float, bool, bool], tuple[tuple[float, ...], ...]] = {}

    def extension_gains(self) -> tuple[np.ndarray, float, float]:
        """``(L, alpha, beta)``: ``L = T(theta) K`` (4,) [1/s .. 1/s^4], the weights of ``mu'`` (4.67)."""
        d = self.design()
        if d.status not in (DesignStatus.CERTIFIED, DesignStatus.REJECTED) or "K" not in d.gains:
            raise DesignFailed(f"{self.name}: design {d.status.value}: {d.reason}")
        th = float(d.gain("theta")[0])
        L = np.array([th, th ** 2, th ** 3, th ** 4]) * d.gain("K")
        return L, float(d.gain("alpha")[0]), float(d.gain("beta")[0])

    def gains(self) -> tuple[np.ndarray, np.ndarray]:
        """Not a (L, M) observer: see :meth:`extension_gains`."""
        raise TypeError(f"{self.name} has extension gains (L, alpha, beta), not (L, M)")

    def _params(self) -> tuple[float, ...]:
        if self._ext is None:
            L, alpha, beta = self.extension_gains()
            self._ext = (*(float(x) for x in L), alpha, beta * beta)
        return self._ext

    def _discrete4(self, h: float, use_y: bool, use_z: bool) -> tuple[tuple[float, ...], ...]:
        """``(Phi, Gamma0, Gamma1)`` (16 floats each) of ``s' = F s + u0 + u1 t`` over a step ``h`` [s]."""
        key = (h, use_y, use_z)
        hit = self._disc4.get(key)
        if hit is not None:
            return hit
        from scipy.linalg import expm

        l1, l2, l3, l4, alpha, b2 = self._params()
        F = np.zeros((4, 4))
        F[:, 0] = (-l1, l2, l3, l4)
        F[0, 1] = -alpha if use_y else 0.0
        F[0, 2] = -b2 if use_z else 0.0
        F[1, 2] = F[2, 3] = 1.0
        aug = np.zeros((12, 12))
        aug[:4, :4], aug[:4, 4:8], aug[4:8, 8:] = F * h, np.eye(4) * h, np.eye(4) * h
        E = expm(aug)
        out = (tuple(E[:4, :4].reshape(-1).tolist()), tuple(E[:4, 4:8].reshape(-1).tolist()),
               tuple(E[:4, 8:].reshape(-1).tolist()))
        if len(self._disc4) > 64:
            self._disc4.clear()
        self._disc4[key] = out
        return out

    def _initial_state(self) -> list[float]:
        return [0.0, 0.0, 0.0, 0.0]   # (nu = mu - mu_hat, d, d', a_L)

    def _internal_from_x0(self, z: list[float], x0: Any) -> list[float]:
        tail = super()._internal_from_x0(z[1:], x0)
        return [0.0, *tail]

    def _advance(self, t_s: float, y: list[float]) -> None:
        prev_y, prev_z, prev_e = self._u[0], self._u[1], self._u[3]
        t_y, t_z, t_e = self._t_last[0], self._t_last[1], self._t_last[3]
        h = self._tick(t_s, y)
        if self._fresh[0]:
            dt = t_s - t_y
            self._slope_y = (self._u[0] - prev_y) / dt if 0.0 < dt <= self._hold else 0.0
        if self._fresh[1]:
            dt = t_s - t_z
            self._slope_z = (self._u[1] - prev_z) / dt if 0.0 < dt <= self._hold else 0.0
        if self._fresh[3]:
            dt = t_s - t_e
            self._slope_e = (self._u[3] - prev_e) / dt if 0.0 < dt <= self._hold else 0.0
        rng, rate, ve, ae = self._u
        if not self._started:
            if rng != rng:
                return
            self._z = [0.0, rng, rate if rate == rate else 0.0, ae if ae == ae else 0.0]
            self._started = True
            return
        if h <= 0.0:
            return
        tl = self._t_last
        use_y = t_s - tl[0] <= self._hold
        use_z = t_s - tl[1] <= self._hold
        nu, x1, x2, x3 = self._z
        ae = ae if ae == ae else 0.0
        sy = self._slope_y if self._fohs else 0.0
        sz = self._slope_z if self._fohs else 0.0
        y0 = rng - sy * (t_s - tl[0] + h)      # ramps through the last two samples (see module doc)
        z0 = rate - sz * (t_s - tl[1] + h)
        se = 0.0
        if self._fohs and t_s - tl[3] <= self._hold:
            se = self._slope_e
            ae = ae - se * (t_s - tl[3] + h)
        disc = self._disc4.get((h, use_y, use_z))
        Phi, Gam, Gam1 = disc if disc is not None else self._discrete4(h, use_y, use_z)
        _, _, _, _, alpha, b2 = self._ext if self._ext is not None else self._params()
        lo_v, hi_v, lo_a, hi_a = self._box
        v = x2 + (ve if ve == ve else 0.0)
        v = lo_v if v < lo_v else (hi_v if v > hi_v else v)
        a = lo_a if x3 < lo_a else (hi_a if x3 > hi_a else x3)
        km, dm, itau = self._fpar
        # inputs u0 + u1 s over the step: mu' terms (row 0), -a_E (row 2), f held (row 3)
        g0, g2, g3 = 0.0, -ae, -2.0 * km * v * a - (a + km * v * v + dm) * itau
        r0, r2 = 0.0, -se
        if use_y:
            g0 += alpha * y0
            r0 += alpha * sy
        if use_z:
            g0 += b2 * z0
            r0 += b2 * sz
        new = [Phi[k] * nu + Phi[k + 1] * x1 + Phi[k + 2] * x2 + Phi[k + 3] * x3
               + Gam[k] * g0 + Gam[k + 2] * g2 + Gam[k + 3] * g3 + Gam1[k] * r0 + Gam1[k + 2] * r2
               for k in (0, 4, 8, 12)]
        if all(q - q == 0.0 for q in new):
            self._z = new
        else:  # cannot happen with a certified design and finite inputs; stay finite
            self._z = [0.0, rng if rng - rng == 0.0 else 0.0, 0.0, 0.0]

    def _values(self) -> list[float]:
        return [self._z[1], self._z[2], self._z[3]]

    def lead_accel_mps2(self) -> float:
        return self._z[3]

    def internal_state(self) -> tuple[float, float, float]:
        """``(range [m], range rate [m/s], lead acceleration [m/s^2])`` estimates."""
        return (self._z[1], self._z[2], self._z[3])

    def integrator_error(self) -> float:
        """``nu = mu - mu_hat`` [m s]: the measured integral (4.67) minus its estimate."""
        return self._z[0]
