r"""Finite-time and interval estimation of ``(beta, r)`` for the discrete LPV bicycle (Bessafa 2024, ch. 2).

H. Bessafa, *Advanced Estimation Algorithms for Connected and Autonomous Vehicle Applications*, PhD
thesis, Université de Lorraine, 2024, ch. 2. Model (2.32)–(2.37) (:mod:`roadtruth.observers.finite_time_interval_design`):
``x_{k+1} = A_N(rho_k) x_k + B_u(rho_k) u_k + v_k``, ``y_k = r_k``, ``u = delta``,
``rho = (1/v_x, 1/v_x^2)``, ``v_k = Delta A(rho_k) x_k + Delta B(rho_k) u_k`` from the unknown
cornering-stiffness error ``|Delta c_i| <= u c_iN``.

* ``finite_time_chaibdraa`` — two LPV Luenberger observers (2.11a,b) with gains ``L(rho)``, ``K(rho)``
  combined algebraically (2.10)–(2.11c) (Chaib-Draa et al., as recalled in thesis §2.3):
  ``x_hat_k = E_m^-1 [Phi_L^-1 zeta_k - Phi_K^-1 eta_k + eta_{k-m} - zeta_{k-m}]``,
  ``E_m = Phi_L^-1 - Phi_K^-1``, ``Phi_L(k) = M_L(k-1) ... M_L(k-m)``, ``M_L = A_N - L C``; exact for
  ``k >= m = 2`` on the nominal model, whatever the initial states.
* ``flpv_interval_bessafa`` — the thesis's estimator (§2.4, (2.18)–(2.25)): the same ``x_hat_k`` plus
  ``x_k = x_hat_k + sum_j G_j(k) v_{k-j}`` with
  ``G_j = E_m^-1 [Phi_L^-1 Pi^L_{<j} - Phi_K^-1 Pi^K_{<j}]`` (2.22) (for m = 2: ``G_1 = I``,
  ``G_2 = E_2^-1 [M_L(k-2)^-1 - M_K(k-2)^-1]``), and the bounds (2.24)–(2.25) with the corrected
  upper bound ``G^+ v_hi - G^- v_lo``. Each ``v_{k-j}`` is bounded separately (the author's code
  bounded the sum with one box, valid only for constant ``v``). The bound of ``v_j`` uses the
  measured ``r_j, delta_j, rho_j`` and an a-priori ``|beta| <= beta_bound_rad``; ``v`` is linear in
  ``(Delta c_f, Delta c_r)``, so ``|v_i| <= sum_c Delta c |d v_i / d c|`` is exact for the box.
  ``flpv_interval_bessafa_printed`` runs the same equations with the gains printed in §2.4.2.
* ``interval_efimov_lpv`` — the Efimov et al. interval observer for discrete LPV systems (thesis §2.2,
  (2.3)–(2.5)), read with the measured scheduling: ``A_0 = A_N(rho_k)`` (known), ``Delta A(rho_k)`` in
  the interval matrix of the stiffness box, ``d = Delta B u`` bounded with the measured ``u``, and a
  constant gain making ``A_N(rho) - L C`` nonnegative on the box (cooperativity: inclusion).

*Sampling.* The estimators are discrete-time: each runs its own fixed step ``sample_time_s`` on the
latest held samples of ``yaw_rate_radps``, ``delta_rad``, ``vx_mps`` (the harness feeds them at the
sensor rates) and holds its estimate between ticks. The Euler model is the thesis's; its error
against a continuous truth is ``O(T_s^2)`` and is *not* covered by the bounds.

*Outside the model* (``v_x`` out of ``vx_range_mps``, stale inputs older than ``hold_s``): the
window restarts; until ``m`` valid steps have passed the bounds are the a-priori box
``|beta| <= beta_bound_rad`` and ``r`` = the measurement ``± yaw_rate_error_bound_radps`` (the thesis
reports 0 for ``k < m``; the harness needs a sound value). With ``yaw_rate_error_bound_radps = nu > 0``
the bounds also cover a measurement error ``|w| <= nu`` on ``y = r`` (our extension: it enters the
error dynamics through ``L w`` and ``K w`` and the ``v`` bound through the measured ``r``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from roadtruth.harness.errors import InputError
from roadtruth.observers.base import EstimateTrack, ScalarLoopObserver
from roadtruth.observers.bicycle import axle_stiffness
from roadtruth.observers.finite_time_interval_design import (
    BicycleLPV,
    FlpvOptions,
    cached,
    design_efimov,
    design_flpv,
)
from roadtruth.observers.lmi import DesignResult, SolverSettings, usable_gains
from roadtruth.observers.registry import register

M2 = tuple[float, float, float, float]  # row-major 2x2
#: Yaw-rate bracket before the first sample [rad/s] (a car does not exceed it).
R_PRIOR_RADPS = 2.0

_COMMON: dict[str, Any] = {
    "sample_time_s": 0.05,            # the estimator's own step T_s [s]
    "vx_range_mps": (1.0 / 0.06, 100.0),   # rho1 in [0.01, 0.06] (thesis §2.4.2)
    "stiffness_uncertainty": 0.1,     # |Delta c_i| <= u c_iN (thesis: 0.05 and 0.1)
    "beta_bound_rad": 0.15,           # a-priori |beta| bound: v bounds and the bracket before m steps
    "yaw_rate_error_bound_radps": 0.0,  # bound on the error of the measured r (0 = the thesis)
    "hold_s": 0.2,                    # inputs older than this restart the window
    "use_cache": True,
}


def _mul(a: M2, b: M2) -> M2:
    return (a[0] * b[0] + a[1] * b[2], a[0] * b[1] + a[1] * b[3], a[2] * b[0] + a[3] * b[2], a[2] * b[1] + a[3] * b[3])


def _inv(a: M2) -> M2:
    d = a[0] * a[3] - a[1] * a[2]
    return (a[3] / d, -a[1] / d, -a[2] / d, a[0] / d)


def _sub(a: M2, b: M2) -> M2:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2], a[3] - b[3])


def _mv(a: M2, x: tuple[float, float]) -> tuple[float, float]:
    return (a[0] * x[0] + a[1] * x[1], a[2] * x[0] + a[3] * x[1])


def _solve(a: M2, x: tuple[float, float]) -> tuple[float, float]:
    d = a[0] * a[3] - a[1] * a[2]
    return ((a[3] * x[0] - a[1] * x[1]) / d, (-a[2] * x[0] + a[0] * x[1]) / d)


class _BicycleLPVObserver(ScalarLoopObserver):
    """Shared setup: the model of the vehicle, the fixed-step clock and the validity checks."""

    inputs = ("yaw_rate_radps", "delta_rad", "vx_mps")
    states = ("beta_rad", "yaw_rate_radps")
    has_bounds = True
    default_options = dict(_COMMON)

    def _setup(self) -> None:
        o, f = self.options, f"observer {self.name}"
        try:
            ts, vlo, vhi = float(o["sample_time_s"]), *(float(x) for x in o["vx_range_mps"])
        except (TypeError, ValueError):
            raise InputError("sample_time_s must be a number and vx_range_mps a pair (lo, hi)", field=f) from None
        if not (0.0 < ts <= 1.0 and 0.0 < vlo < vhi and math.isfinite(vhi)):
            raise InputError(f"need 0 < sample_time_s <= 1 and 0 < lo < hi in vx_range_mps, got {ts!r}, "
                             f"{o['vx_range_mps']!r}", field=f)
        self._unc = float(o["stiffness_uncertainty"])
        self._bmax = float(o["beta_bound_rad"])
        self._nu = float(o["yaw_rate_error_bound_radps"])
        if not (0.0 <= self._unc < 1.0 and self._bmax > 0.0 and self._nu >= 0.0):
            raise InputError("need 0 <= stiffness_uncertainty < 1, beta_bound_rad > 0, "
                             "yaw_rate_error_bound_radps >= 0", field=f)
        v = self.vehicle
        cf, cr = axle_stiffness(v)
        self.model = BicycleLPV.from_speed_range(v.mass_kg, v.yaw_inertia_kgm2, v.lf_m, v.lr_m, cf, cr, ts, (vlo, vhi))
        self._ts, self._vlo, self._vhi, self._hold = ts, vlo, vhi, float(o["hold_s"])
        self._dcf, self._dcr = self._unc * cf, self._unc * cr
        self._gains: tuple[float, ...] | None = None

    def _initial_state(self) -> list[float]:
        return []   # the internal state lives in attributes; it is not settable (finite-time: no x0 needed)

    def _reset_extra(self) -> None:
        self._next = -math.inf   # time of the next discrete step [s]
        self._count = 0          # valid steps since the last restart
        self._prior(math.nan)

    def run(self, t: np.ndarray, Y: np.ndarray, x0: Mapping[str, float] | None = None) -> EstimateTrack:
        """Compiled loop (:mod:`roadtruth.observers.finite_time_interval_loop`), equal to stepping :meth:`step`."""
        from roadtruth.observers.finite_time_interval_loop import run_compiled
        return run_compiled(self, t, Y, x0)

    def _advance(self, t_s: float, y: list[float]) -> None:
        self._tick(t_s, y)
        r, delta, vx = self._u
        if t_s < self._next - 1e-6 * self._ts:   # tolerance: the clock accumulates T_s in floating point
            return
        self._next = t_s + self._ts if self._next == -math.inf else self._next + self._ts
        if self._next <= t_s:  # a long gap: re-anchor the clock instead of replaying the held samples
            self._next = t_s + self._ts
        tl = self._t_last
        if (r != r or delta != delta or vx != vx or t_s - min(tl) > self._hold
                or not self._vlo <= vx <= self._vhi):
            self._count = 0
            self._prior(r)
            return
        self._discrete_step(r, delta, 1.0 / vx, 1.0 / (vx * vx))

    def _prior(self, r: float) -> None:
        """The a-priori bracket (no certified estimate yet)."""
        b, nu = self._bmax, self._nu
        if r != r:   # no yaw-rate sample yet
            self._lo, self._hi, self._x = [-b, -R_PRIOR_RADPS], [b, R_PRIOR_RADPS], [0.0, 0.0]
        else:
            self._lo, self._hi, self._x = [-b, r - nu], [b, r + nu], [0.0, r]

    def _a(self, rho1: float, rho2: float) -> M2:
        A = self.model.a(rho1, rho2)
        return (float(A[0, 0]), float(A[0, 1]), float(A[1, 0]), float(A[1, 1]))

    def _b(self, rho1: float) -> tuple[float, float]:
        B = self.model.b(rho1)
        return float(B[0]), float(B[1])

    def _discrete_step(self, r: float, delta: float, rho1: float, rho2: float) -> None:
        raise NotImplementedError

    def _values(self) -> list[float]:
        return self._x

    def _bounds(self) -> tuple[list[float], list[float]]:
        return self._lo, self._hi


class _FiniteTime(_BicycleLPVObserver):
    """Two LPV observers and their algebraic combination over m = 2 steps (thesis (2.11), (2.24))."""

    bounded = True

    def _compute_design(self) -> DesignResult:
        opts = FlpvOptions()
        return cached("finite_time_interval", self.model, self.variant, {"flpv": opts.__dict__},
                      bool(self.options["use_cache"]),
                      lambda: design_flpv(self.model, self.variant, opts, SolverSettings()))

    def gains(self) -> tuple[np.ndarray, np.ndarray]:
        """Vertex gains ``L``, ``K`` (4, 2) each; raises :class:`DesignFailed` without usable gains."""
        if self._gains is None:
            self._gains = usable_gains(self.name, self.design(), ("L", "K"))
            g = np.array(self._gains)
            self._LK = (g[:8].reshape(4, 2), g[8:].reshape(4, 2))
        return self._LK

    def _reset_extra(self) -> None:
        super()._reset_extra()
        self._zeta = (0.0, 0.0)
        self._eta = (0.0, 0.0)
        self._hist: list[tuple[Any, ...]] = []   # per past step j: zeta_j, eta_j, M_L, M_K, L_j, K_j, vbar_j

    def _vbar(self, r: float, delta: float, rho1: float, rho2: float) -> tuple[float, float]:
        """Bound of ``|v|`` at this step. ``v`` is linear in (Delta c_f, Delta c_r) with coefficients
        affine in beta: ``|c + a beta| <= max over the two ends of the beta interval`` (the current
        bounds intersected with ``|beta| <= beta_bound_rad``; sound by induction over the steps,
        since the bounds at this step were computed from earlier ``v`` bounds). ``|dr| <= nu``."""
        m, iz, lf, lr, ts = (self.model.mass_kg, self.model.yaw_inertia_kgm2, self.model.lf_m, self.model.lr_m,
                             self.model.ts_s)
        nu, dcf, dcr = self._nu, self._dcf, self._dcr
        blo, bhi = max(self._lo[0], -self._bmax), min(self._hi[0], self._bmax)

        def mx(c: float, a: float) -> float:
            return max(abs(c + a * blo), abs(c + a * bhi))

        v1 = ts / m * (dcf * (mx(rho1 * delta - lf * rho2 * r, -rho1) + lf * rho2 * nu)
                       + dcr * (mx(lr * rho2 * r, -rho1) + lr * rho2 * nu))
        v2 = ts / iz * (dcf * (mx(lf * delta - lf * lf * rho1 * r, -lf) + lf * lf * rho1 * nu)
                        + dcr * (mx(-lr * lr * rho1 * r, lr) + lr * lr * rho1 * nu))
        return v1, v2

    def _discrete_step(self, r: float, delta: float, rho1: float, rho2: float) -> None:
        Lv, Kv = self.gains()
        xi = self.model.weights(rho1, rho2)
        l1, l2 = (float(x) for x in xi @ Lv)
        k1, k2 = (float(x) for x in xi @ Kv)
        A = self._a(rho1, rho2)
        b1, b2 = self._b(rho1)
        ML: M2 = (A[0], A[1] - l1, A[2], A[3] - l2)   # A - L C with C = [0, 1]
        MK: M2 = (A[0], A[1] - k1, A[2], A[3] - k2)
        if self._count == 0:
            self._hist = []
        zeta, eta = self._zeta, self._eta
        self._hist.append((zeta, eta, ML, MK, (l1, l2), (k1, k2), (0.0, 0.0)))
        if len(self._hist) > 3:
            self._hist.pop(0)
        if self._count >= 2:
            self._combine(r)
        else:
            self._prior(r)
        self._hist[-1] = self._hist[-1][:6] + (self._vbar(r, delta, rho1, rho2),)
        # (2.11a,b): the observers advance with y_k = r_k
        z1, z2 = _mv(ML, zeta)
        e1, e2 = _mv(MK, eta)
        self._zeta = (z1 + b1 * delta + l1 * r, z2 + b2 * delta + l2 * r)
        self._eta = (e1 + b1 * delta + k1 * r, e2 + b2 * delta + k2 * r)
        self._count += 1

    def _combine(self, r: float) -> None:
        """(2.11c) and the bounds (2.24)–(2.25) at step k from the steps k-1, k-2 (``_hist[-3:-1]``)."""
        zk, ek = self._hist[-1][0], self._hist[-1][1]
        z2, e2, ML2, MK2, L2, K2, v2 = self._hist[-3]   # step k-2
        _, _, ML1, MK1, L1, K1, v1 = self._hist[-2]      # step k-1
        iPL, iPK = _inv(_mul(ML1, ML2)), _inv(_mul(MK1, MK2))
        E = _sub(iPL, iPK)
        a = _mv(iPL, zk)
        c = _mv(iPK, ek)
        xh = _solve(E, (a[0] - c[0] + e2[0] - z2[0], a[1] - c[1] + e2[1] - z2[1]))
        if not self.bounded:
            self._x, self._lo, self._hi = [xh[0], xh[1]], [xh[0], xh[1]], [xh[0], xh[1]]
            return
        iE = _inv(E)
        G2 = _mul(iE, _sub(_inv(ML2), _inv(MK2)))   # G_1 = I
        w = [v1[0] + abs(G2[0]) * v2[0] + abs(G2[1]) * v2[1], v1[1] + abs(G2[2]) * v2[0] + abs(G2[3]) * v2[1]]
        nu = self._nu
        if nu > 0.0:   # measurement error on y: H_j = -E^-1 [Phi_L^-1 Pi_<j L_{k-j} - Phi_K^-1 Pi_<j K_{k-j}]
            h1 = _mv(iE, _sub2(_mv(iPL, L1), _mv(iPK, K1)))
            h2 = _mv(iE, _sub2(_solve(ML2, L2), _solve(MK2, K2)))
            w[0] += (abs(h1[0]) + abs(h2[0])) * nu
            w[1] += (abs(h1[1]) + abs(h2[1])) * nu
        # (2.24)-(2.25), intersected with what is known for sure: |beta| <= beta_bound, r = y +- nu
        # (the measured r is exact on the model; the thesis's bounds on r ignore it).
        lo = [max(xh[0] - w[0], -self._bmax), max(xh[1] - w[1], r - nu)]
        hi = [min(xh[0] + w[0], self._bmax), min(xh[1] + w[1], r + nu)]
        if lo[0] > hi[0] or lo[1] > hi[1]:   # disjoint: the model does not hold; keep the model's bounds
            lo, hi = [xh[0] - w[0], xh[1] - w[1]], [xh[0] + w[0], xh[1] + w[1]]
        self._x = [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])]
        self._lo, self._hi = lo, hi


def _sub2(a: tuple[float, float], b: tuple[float, float]) -> tuple[float, float]:
    return (a[0] - b[0], a[1] - b[1])


@register
class FlpvIntervalBessafa(_FiniteTime):
    """FLPV finite-time interval estimator of (beta, r) from the yaw rate, fresh Algorithm 1 design."""

    name = "flpv_interval_bessafa"
    citation = "H. Bessafa, PhD thesis, Univ. Lorraine 2024, sec. 2.4, eqs. (2.18)-(2.25), Algorithm 1"
    variant = "fresh"


@register
class FlpvIntervalBessafaPrinted(_FiniteTime):
    """FLPV interval estimator with the gains printed in the thesis (not certified: unstable vertices)."""

    name = "flpv_interval_bessafa_printed"
    citation = "H. Bessafa, PhD thesis, Univ. Lorraine 2024, sec. 2.4.2 (printed gains L_i, K_i)"
    variant = "printed"


@register
class FiniteTimeChaibDraa(_FiniteTime):
    """Exact finite-time estimate of (beta, r) by two combined LPV observers (no bounds)."""

    name = "finite_time_chaibdraa"
    citation = ("Chaib-Draa et al., two combined observers, as recalled in H. Bessafa, PhD thesis 2024, sec. 2.3, "
                "eqs. (2.10)-(2.17)")
    variant = "fresh"
    has_bounds = False
    bounded = False


@register
class IntervalEfimovLPV(_BicycleLPVObserver):
    """Efimov et al. interval observer for discrete LPV systems on the (beta, r) bicycle (cooperative gain)."""

    name = "interval_efimov_lpv"
    citation = "Efimov et al., discrete LPV interval observer, as recalled in H. Bessafa, PhD thesis 2024, eqs. (2.3)-(2.5)"
    variant = "efimov"

    def _compute_design(self) -> DesignResult:
        return cached("interval_efimov_lpv", self.model, self.variant, {"uncertainty": self._unc},
                      bool(self.options["use_cache"]),
                      lambda: design_efimov(self.model, (self._dcf, self._dcr), SolverSettings()))

    def _reset_extra(self) -> None:
        super()._reset_extra()
        self._box: list[float] | None = None   # [beta_lo, r_lo, beta_hi, r_hi]

    def _discrete_step(self, r: float, delta: float, rho1: float, rho2: float) -> None:
        if self._gains is None:
            self._gains = usable_gains(self.name, self.design(), ("L",))
        l1, l2 = self._gains
        nu = self._nu
        if self._count == 0 or self._box is None:
            self._box = [-self._bmax, r - nu, self._bmax, r + nu]
        xl, xh = self._box[:2], self._box[2:]
        self._lo, self._hi = list(xl), list(xh)
        self._x = [0.5 * (xl[0] + xh[0]), 0.5 * (xl[1] + xh[1])]
        A = self._a(rho1, rho2)
        b1, b2 = self._b(rho1)
        M = (A[0], A[1] - l1, A[2], A[3] - l2)
        hi_m = self.model
        h = (hi_m.ts_s * np.array([[(self._dcf + self._dcr) / hi_m.mass_kg * rho1,
                                    (self._dcr * hi_m.lr_m + self._dcf * hi_m.lf_m) / hi_m.mass_kg * rho2],
                                   [(self._dcr * hi_m.lr_m + self._dcf * hi_m.lf_m) / hi_m.yaw_inertia_kgm2,
                                    (self._dcr * hi_m.lr_m**2 + self._dcf * hi_m.lf_m**2) / hi_m.yaw_inertia_kgm2
                                    * rho1]])).reshape(-1).tolist()
        # (2.3) with Delta A in [-h, h]: upper bracket h x_hi^+ + h x_lo^-, lower -(h x_hi^+ + h x_lo^-)
        s = [max(xh[i], 0.0) + max(-xl[i], 0.0) for i in range(2)]
        up = (h[0] * s[0] + h[1] * s[1], h[2] * s[0] + h[3] * s[1])
        dB = (self.model.ts_s * self._dcf * abs(delta) * rho1 / self.model.mass_kg,
              self.model.ts_s * self._dcf * abs(delta) * self.model.lf_m / self.model.yaw_inertia_kgm2)
        ml, mh = _mv(M, (xl[0], xl[1])), _mv(M, (xh[0], xh[1]))
        base = (b1 * delta + l1 * r, b2 * delta + l2 * r)
        n1, n2 = abs(l1) * nu, abs(l2) * nu
        self._box = [ml[0] + base[0] - up[0] - dB[0] - n1, ml[1] + base[1] - up[1] - dB[1] - n2,
                     mh[0] + base[0] + up[0] + dB[0] + n1, mh[1] + base[1] + up[1] + dB[1] + n2]
        self._count += 1

