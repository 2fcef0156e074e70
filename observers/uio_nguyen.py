r"""Regularised H^1 unknown-input observer (Q. H. Nguyen, thesis draft, ch. 1, Section 3 and sec. 7.2.2).

Q. H. Nguyen, PhD thesis draft (Université de Lorraine, CRAN), ch. 1 "Learning with Unknown Input
Observers for Robust Nonlinear Estimation", Section 3 (eqs. (1.5)-(1.26)) and the vehicle of
sec. 7.2 (eqs. (1.52)-(1.61)), **with corrections of printed equations that do not hold** (``D_bar = [0, -D]``,
``E_cal = P_zeta E_bar - ...``, ``D_cal = (I - H Q_zeta) D_bar``, ``+I`` in (1.26), vertices
``n_x x n_zeta``). Model and LMIs: :mod:`roadtruth.observers.uio_nguyen_design`.

Observer (1.10), ``zeta = (v_x, v_y, psi, r, f_yf, f_yr)`` (forces in kN):

.. math::

    \dot\eta = P_\zeta(A_\zeta(\rho)\hat\zeta + B_u u) + K(y - H\hat\zeta),\qquad \hat\zeta = \eta + Q_\zeta y,

scheduled on the measured ``rho = (v_x, 1/v_x)`` (``v_x`` clamped into the design range so that rho
stays in the certified polytope). Per step the inputs are first-order held and the affine ODE in ``eta`` is
integrated by RK4 with sub-steps ``|lambda| h_sub <= 0.5`` (a compiled kernel with a plain-Python twin).

Measurements: ``v_x <- vx_mps``, ``r <- yaw_rate_radps``, ``a <- ax_mps2`` (the accelerometer's
specific force; (1.52a)'s ``r v_y`` and ``mu g`` are not in the printed row 1, and ``v_x`` only feeds
``v_x``), ``delta <- delta_rad``. **Heading**: a car's ESC cluster does not measure psi, so the psi
output is the integrated gyro ``psi_m = int r_m dt`` (trapezoid). It carries no information beyond
``r``: ``psi_m - psi_hat = int (r_m - r_hat) dt`` turns the psi channel into an integral action on the
r residual. The observer stays well posed: with the psi row ``(A, C)`` has observability rank 4
(3 without it: psi is an integrator nothing else sees, so the psi row only makes psi itself
observable and adds nothing about ``v_y``, which is seen through ``r' = a42 v_y + ...`` alone), (1.4)
holds whatever psi is, and the true heading obeys ``psi_m = psi + int (r_m - r) dt``: the measurement
is ``C x`` plus the integrated gyro noise, a noise the certificate's model does not see separately.
A gyro bias ``b`` becomes a ramp ``b t`` in psi_m that the model explains consistently by
``psi_hat`` following ``r_hat`` (same effect as the bias on r alone). GNSS course is not used: it is
``psi + beta``, so ``course - beta_hat`` feeds the observer's own estimate back into its output and
the certified error dynamics no longer apply; a course output needs an LPV ``C(rho)`` (another design).
psi is re-centred to (-pi, pi] exactly (psi_m, psi_hat and eta shifted together: the psi column of A is 0).

Missing samples: while ``v_x`` and ``r`` are younger than ``hold_s`` the observer runs on held values;
otherwise it predicts ``x' = A x + B_u u + B_mu mu_hat`` with ``mu_hat`` held, and on resumption
re-seeds ``eta = zeta_hat - Q_zeta y`` with ``psi_m`` restarted at ``psi_hat + delta2 f_yf_hat``.

States: ``vy_mps``, ``yaw_rate_radps``, ``beta_rad = atan2(v_y, v_x)``. Note that the
regularised output ``y_r = r + delta2 f_yr - delta2 f_yr`` makes the UIO split the measured yaw rate:
in practice ``r_hat = r_m - delta2 f_yr_hat`` (to < 1e-4 rad/s RMS on MuJoCo runs), so ``r_hat`` is
worse than the gyro whenever the tire-force residual is large. The unknown input is not a
canonical signal: with ``y = (v_x, psi, r)`` only its effect on ``r'`` is identifiable (
``rank C B_mu = 1``, normal rank of ``C (sI - A)^-1 B_mu`` is 1), so ``mu_hat`` (per axle, N) and the
yaw-moment residual ``l_f f_yf - l_r f_yr`` are exposed as non-scored extras
(:meth:`NguyenUIO.unknown_input_N`), not as states. The neural adaptive observer of the same chapter
(Sections 5-6) is not implemented here.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from roadtruth.harness.errors import InputError
from roadtruth.harness.truth.tire import jit
from roadtruth.observers.base import ScalarLoopObserver
from roadtruth.observers.lmi import DesignFailed, DesignResult, DesignStatus
from roadtruth.observers.registry import register
from roadtruth.observers.uio_nguyen_design import MU_SCALE_N, N_X, N_ZETA, scheduling_points, vehicle_model

TWO_PI = 2.0 * math.pi
SUBSTEP_RATE = 0.5  # largest ||M|| h_sub of one RK4 sub-step


@jit
def affine_rk4(z: np.ndarray, Ms: np.ndarray, Gs: np.ndarray, w0: np.ndarray, w1: np.ndarray, rho1: float,
               rho2: float, h: float, nsub: int) -> None:
    """Advance ``z' = M z + G w(t)`` by ``h`` [s] in place with ``nsub`` RK4 sub-steps.

    ``M = Ms[0] + rho1 Ms[1] + rho2 Ms[2]``: Ms (3, n, n); ``G`` likewise from Gs (3, n, m); the input
    is first-order held, ``w(t)`` linear from w0 (m,) at the start to w1 (m,) at the end of the step.
    """
    n = z.shape[0]
    m = w0.shape[0]
    M = np.empty((n, n))
    b0 = np.empty(n)
    db = np.empty(n)
    for i in range(n):
        s0 = 0.0
        s1 = 0.0
        for j in range(m):
            g = Gs[0, i, j] + rho1 * Gs[1, i, j] + rho2 * Gs[2, i, j]
            s0 += g * w0[j]
            s1 += g * w1[j]
        b0[i] = s0
        db[i] = s1 - s0
        for j in range(n):
            M[i, j] = Ms[0, i, j] + rho1 * Ms[1, i, j] + rho2 * Ms[2, i, j]
    k = np.empty((4, n))
    zt = np.empty(n)
    for sub in range(nsub):
        for stage in range(4):
            # stage times 0, 1/2, 1/2, 1 of the sub-step, as a fraction of the whole step
            frac = (sub + (0.0 if stage == 0 else (1.0 if stage == 3 else 0.5))) / nsub
            for i in range(n):
                if stage == 0:
                    zt[i] = z[i]
                elif stage == 3:
                    zt[i] = z[i] + (h / nsub) * k[2, i]
                else:
                    zt[i] = z[i] + 0.5 * (h / nsub) * k[stage - 1, i]
            for i in range(n):
                s = b0[i] + frac * db[i]
                for j in range(n):
                    s += M[i, j] * zt[j]
                k[stage, i] = s
        for i in range(n):
            z[i] += (h / nsub) / 6.0 * (k[0, i] + 2.0 * k[1, i] + 2.0 * k[2, i] + k[3, i])


@register
class NguyenUIO(ScalarLoopObserver):
    """Regularised H^1 unknown-input observer (Nguyen, Theorem 1, corrected), LPV in (v_x, 1/v_x)."""

    name = "uio_nguyen"
    citation = ("Q. H. Nguyen, PhD thesis draft (undated), Univ. de Lorraine (CRAN), ch. 1, Section 3, "
                "eqs. (1.5)-(1.26), vehicle (1.52)-(1.61); signs of D_bar and D_cal, P_zeta in E_cal "
                "and the +I of (1.26) corrected")
    inputs = ("vx_mps", "yaw_rate_radps", "ax_mps2", "delta_rad")
    states = ("vy_mps", "yaw_rate_radps", "beta_rad")
    variant = "regularized"
    default_options: Mapping[str, Any] = {
        "delta1": 0.0,                 # state-side regularisation (1.5); 0 as in the chapter's vehicle
        "delta2": 0.1,                 # output-side regularisation; below 0.1 the LMIs are infeasible
        "epsilon": 0.01,               # S = epsilon P of Theorem 1; above 0.01 the LMIs are infeasible
        "vx_range_mps": (5.0, 30.0),   # design domain of v_x; v_x is clamped into it
        "grid_points": 101,            # v_x grid of the certificate
        "hold_s": 0.1,                 # correct only while v_x and r are younger than this [s]
        "use_cache": True,
    }

    def _setup(self) -> None:
        o = self.options
        try:
            lo, hi = (float(x) for x in o["vx_range_mps"])
            d1, d2, eps = float(o["delta1"]), float(o["delta2"]), float(o["epsilon"])
            ngrid, hold = int(o["grid_points"]), float(o["hold_s"])
        except (TypeError, ValueError) as exc:
            raise InputError(f"bad option value ({exc})", field=f"observer {self.name}") from exc
        if not (0.0 < lo < hi) or d1 < 0.0 or d2 < 0.0 or eps <= 0.0 or ngrid < 2 or hold <= 0.0:
            raise InputError(f"bad options vx_range_mps={o['vx_range_mps']}, delta1={d1}, delta2={d2}, "
                             f"epsilon={eps}, grid_points={ngrid}, hold_s={hold}", field=f"observer {self.name}")
        self._vlo, self._vhi, self._hold, self._d2 = lo, hi, hold, d2
        self._model = vehicle_model(self.vehicle)
        self._lf, self._lr = self.vehicle.lf_m, self.vehicle.lr_m
        self._consts: tuple[np.ndarray, ...] | None = None

    def _compute_design(self) -> DesignResult:
        from roadtruth.observers.uio_nguyen_design import design_for
        return design_for(self.design_request())

    def constants(self) -> tuple[np.ndarray, ...]:
        """``(Fs, Gs, Q, Ms, Gp, bounds)`` of the two affine ODEs; raises DesignFailed without gains.

        UIO: ``eta' = F(rho) eta + G(rho) (y, u)``, ``F = P A_zeta - K H``, ``G = [F Q + K, P B_u]``.
        Prediction: ``zeta' = M(rho) zeta + [B_u; 0] u``, ``M = [[A, B_mu], [0, 0]]``.
        ``bounds`` = (2,) largest spectral norms of F and M on the design domain [1/s].
        """
        if self._consts is None:
            d = self.design()
            if d.status not in (DesignStatus.CERTIFIED, DesignStatus.REJECTED) or "K" not in d.gains:
                raise DesignFailed(f"{self.name}: design {d.status.value}: {d.reason}")
            K, Pz, Qz, H = (d.gain(k) for k in ("K", "P_zeta", "Q_zeta", "H"))
            mdl = self._model
            Az = [np.hstack([Ai, mdl.Bmu if i == 0 else np.zeros_like(mdl.Bmu)])
                  for i, Ai in enumerate((mdl.A0, mdl.A1, mdl.A2))]
            Fs = np.array([Pz @ Az[i] - (K @ H if i == 0 else 0.0) for i in range(3)])
            Gs = np.array([np.hstack([Fs[i] @ Qz + (K if i == 0 else 0.0), Pz @ mdl.Bu if i == 0 else
                                      np.zeros((N_ZETA, 2))]) for i in range(3)])
            Ms = np.zeros((3, N_ZETA, N_ZETA))
            Ms[:, :N_X, :] = np.array(Az)
            Gp = np.zeros((3, N_ZETA, 2))
            Gp[0, :N_X] = mdl.Bu
            _, grid = scheduling_points((self._vlo, self._vhi), 41)
            bounds = np.array([max(np.linalg.norm(S[0] + r1 * S[1] + r2 * S[2], 2) for r1, r2 in grid)
                               for S in (Fs, Ms)])
            self._consts = (Fs, Gs, np.ascontiguousarray(Qz), Ms, Gp, bounds)
        return self._consts

    def _initial_state(self) -> list[float]:
        return [0.0] * N_ZETA  # zeta_hat = (v_x, v_y, psi, r, f_yf, f_yr [kN])

    def _internal_from_x0(self, z: list[float], x0: Mapping[str, float]) -> list[float]:
        slots = {"vy_mps": 1, "yaw_rate_radps": 3}
        for key, value in x0.items():
            if key not in slots:
                raise InputError(f"cannot initialise state {key!r} (settable: {', '.join(slots)})",
                                 field=f"observer {self.name} x0")
            z[slots[key]] = float(value)
        return z

    def _reset_extra(self) -> None:
        self._eta = np.zeros(N_ZETA)
        self._zeta = np.array(self._z, dtype=float)
        self._psi_m = 0.0
        self._r_prev, self._t_r_prev = math.nan, math.nan
        self._tracking = False  # eta is seeded and the UIO is running
        self._w_prev = np.zeros(5)  # (y, u) at the previous step (first-order hold)
        self._u_prev: np.ndarray | None = None
        self._started = False

    def _advance(self, t_s: float, y: list[float]) -> None:
        h = self._tick(t_s, y)
        Fs, Gs, Qz, Ms, Gp, bounds = self._consts if self._consts is not None else self.constants()
        vx, r, ax, delta = self._u
        zeta = self._zeta
        if not self._started:
            if vx != vx:
                return
            zeta[0] = vx
            self._started = True
        if self._fresh[1]:
            # Heading pseudo-measurement: trapezoidal integral of the gyro between its samples.
            if self._r_prev == self._r_prev and self._tracking:
                self._psi_m += 0.5 * (t_s - self._t_r_prev) * (self._r_prev + r)
            self._r_prev, self._t_r_prev = r, t_s
        v = vx if vx == vx else zeta[0]
        v = self._vlo if v < self._vlo else (self._vhi if v > self._vhi else v)
        u1 = np.array([ax if ax == ax else 0.0, delta if delta == delta else 0.0])
        u0 = self._u_prev if self._u_prev is not None else u1
        self._u_prev = u1
        tl = self._t_last
        live = r == r and vx == vx and t_s - min(tl[0], tl[1]) <= self._hold
        if not live:
            self._tracking = False
            if h > 0.0:
                nsub = max(1, math.ceil(h * bounds[1] / SUBSTEP_RATE))
                affine_rk4(zeta, Ms, Gp, u0, u1, v, 1.0 / v, h, nsub)
            return
        if not self._tracking:
            # (Re)start: the integrated gyro restarts where the model's psi is, eta = zeta - Q y.
            self._psi_m = zeta[2] + self._d2 * zeta[4]
            self._tracking = True
            self._w_prev = np.array([vx, self._psi_m, r, u1[0], u1[1]])
            self._eta = zeta - Qz @ self._w_prev[:3]
            return
        if self._psi_m > math.pi or self._psi_m < -math.pi:
            c = TWO_PI * round(self._psi_m / TWO_PI)
            self._psi_m -= c
            self._eta[2] -= c
            self._eta += c * Qz[:, 1]
            self._w_prev[1] -= c
        ym = np.array([vx, self._psi_m, r])
        w1 = np.array([vx, self._psi_m, r, u1[0], u1[1]])
        if h > 0.0:
            nsub = max(1, math.ceil(h * bounds[0] / SUBSTEP_RATE))
            affine_rk4(self._eta, Fs, Gs, self._w_prev, w1, v, 1.0 / v, h, nsub)
        self._w_prev = w1
        self._zeta = zeta = self._eta + Qz @ ym

    def _values(self) -> list[float]:
        zeta = self._zeta
        vy, r = float(zeta[1]), float(zeta[3])
        vx = self._u[0]
        v = vx if vx == vx else float(zeta[0])
        return [vy, r, math.atan2(vy, v) if v > 0.0 else 0.0]

    def zeta_hat(self) -> np.ndarray:
        """Copy of the current ``zeta_hat = (v_x, v_y, psi_hat, r, f_yf [kN], f_yr [kN])``: (6,) array."""
        return self._zeta.copy()

    def unknown_input_N(self) -> tuple[float, float, float]:
        """Current ``(f_yf, f_yr, l_f f_yf - l_r f_yr)`` estimate [N, N, N m] (non-scored extra).

        Per-axle values are structurally non-identifiable from ``(v_x, psi, r)`` and attenuated by
        the regularisation (on the chapter's protocol: regression slope ~0.06-0.16 at delta2 = 0.1).
        """
        f, rr = float(self._zeta[4]) * MU_SCALE_N, float(self._zeta[5]) * MU_SCALE_N
        return f, rr, self._lf * f - self._lr * rr
