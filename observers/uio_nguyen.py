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
integrated by RK4 with sub-steps ``|lambda| h_sub <= 0.5``. The whole per-sample update is one compiled
kernel (:func:`roadtruth.observers.uio_nguyen_loop.nguyen_run`) shared by ``step()`` and ``run()``.

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
from roadtruth.observers.base import EstimateTrack, ScalarLoopObserver, StepOutput
from roadtruth.observers.lmi import DesignFailed, DesignResult, DesignStatus
from roadtruth.observers.registry import register
from roadtruth.observers.uio_nguyen_design import MU_SCALE_N, N_X, N_ZETA, scheduling_points, vehicle_model
from roadtruth.observers.uio_nguyen_loop import (  # noqa: F401  (affine_rk4, SUBSTEP_RATE: re-exported)
    N_STATE,
    PSI_M,
    R_PREV,
    STARTED,
    SUBSTEP_RATE,
    T_CUR,
    T_R_PREV,
    TRACKING,
    TWO_PI,
    affine_rk4,
    nguyen_run,
)


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
        # the kernel's carried state (roadtruth.observers.uio_nguyen_loop.nguyen_run), updated in place
        self._ku, self._kfresh, self._ktl = np.full(4, math.nan), np.zeros(4, dtype=np.bool_), np.full(4, -math.inf)
        self._eta = np.zeros(N_ZETA)
        self._zeta = np.array(self._z, dtype=float)
        self._w_prev = np.zeros(5)  # (y, u) at the previous step (first-order hold)
        self._u_prev = np.zeros(2)
        self._ks = np.zeros(N_STATE)
        self._ks[T_CUR] = self._t
        self._ks[R_PREV] = self._ks[T_R_PREV] = math.nan
        z = self._zeta
        self._last = np.array([z[1], z[3], 0.0])
        self._par: np.ndarray | None = None

    # the scalars of the carried state, by name (read by the neural adaptive observer's teacher)
    @property
    def _psi_m(self) -> float:
        return float(self._ks[PSI_M])

    @property
    def _r_prev(self) -> float:
        return float(self._ks[R_PREV])

    @property
    def _t_r_prev(self) -> float:
        return float(self._ks[T_R_PREV])

    @property
    def _tracking(self) -> bool:
        return bool(self._ks[TRACKING])

    @property
    def _started(self) -> bool:
        return bool(self._ks[STARTED])

    def _compiled(self, t: np.ndarray, Y: np.ndarray) -> np.ndarray:
        """Advance through ``t`` (n,) [s], ``Y`` (n, 4) in the shared kernel; the (n, 3) estimates."""
        Fs, Gs, Qz, Ms, Gp, bounds = self._consts if self._consts is not None else self.constants()
        if self._par is None:
            self._par = np.array([self._vlo, self._vhi, self._hold, self._d2])
        out = np.empty((t.shape[0], 3))
        nguyen_run(t, Y, self._ku, self._kfresh, self._ktl, self._eta, self._zeta, self._w_prev, self._u_prev,
                   self._ks, Fs, Gs, Qz, Ms, Gp, bounds, self._par, out)
        if t.shape[0]:
            self._last = out[-1].copy()
        return out

    def step(self, t_s: float, y: np.ndarray) -> StepOutput:
        """One sample through the compiled kernel (the same code ``run()`` loops in, so the same bits)."""
        x = self._compiled(np.array([float(t_s)]), np.ascontiguousarray(np.asarray(y, dtype=float).reshape(1, 4)))
        return StepOutput(x[0])

    def run(self, t: np.ndarray, Y: np.ndarray, x0: Mapping[str, float] | None = None) -> EstimateTrack:
        """Reset at ``t[0]`` and advance through the whole log in one compiled call (equal to stepping)."""
        t = np.ascontiguousarray(t, dtype=float)
        Y = np.ascontiguousarray(np.asarray(Y, dtype=float).reshape(len(t), len(self.inputs)))
        if len(t):
            self.reset(float(t[0]), x0)
        return EstimateTrack(self.name, tuple(self.states), t, self._compiled(t, Y))

    def _advance(self, t_s: float, y: list[float]) -> None:
        self.step(t_s, np.array(y, dtype=float))

    def _values(self) -> list[float]:
        return self._last.tolist()

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
