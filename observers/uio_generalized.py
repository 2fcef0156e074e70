r"""Generalized (output-derivative) unknown-input observer of Nguyen, ch. 1, Section 4 ((1.27)-(1.33)).

Q. H. Nguyen, PhD thesis draft (Université de Lorraine, CRAN), ch. 1 "Learning with Unknown Input
Observers for Robust Nonlinear Estimation", Section 4, on the vehicle of sec. 7.2. Model, corrections
and LMIs: :mod:`roadtruth.observers.uio_generalized_design`. Observer (1.32):

.. math::

    \dot\eta = P_\zeta\big(J(\rho)\hat\zeta + G(\rho)(u, \dot u)\big) + K(y_\chi - H\hat\zeta),\qquad
    \hat\zeta = \eta + Q_\zeta y_\chi,\qquad \zeta = (\chi_1, \chi_2, x, \mu),

with the stacked output ``y_chi = (y, C_chi y', y)`` and ``y = (v_x, psi_m, r)`` (``psi_m`` the
integrated gyro, as in ``uio_nguyen``). The derivative ``y'`` must be supplied (Table 1.1's
"estimated internally via chi_2" is circular when ``C_chi != 0``), and only causally:
``v_x' = a`` (the accelerometer, row 1 of (1.55)), ``psi' = r`` (the gyro) and ``r'`` plus the
input rates ``a'``, ``delta'`` from a causal differentiator (``differentiator="fd_lowpass"``:
backward difference + first-order low-pass with ``lowpass_s``; ``"levant"``: first-order Levant
differentiator with ``levant_lipschitz``). Per step the frozen affine ODE is integrated **exactly**
(zero-order-hold matrix exponential with first-order-held inputs; the gains are stiff, ``|K|`` up to
3e4, so explicit sub-stepping would cost hundreds of sub-steps).

Variants (Table 1.1, sec. 4.4, where they give distinct observers):

* ``uio_generalized`` (rank C B < rank B, the chapter's vehicle): ``mu = (f_yf, f_yr)`` [kN],
  ``C_chi = I``, ``delta_2 = 1`` (D of (1.58)), ``epsilon = 1e-3``: an H^1 bound, not exponential.
* ``uio_generalized_yaw_moment`` (rank C B = rank B, ``delta_2 = 0``): the unknown input is a yaw
  moment ``M_z`` [kN m] (``B_mu = e_r / I_z``); then the observer is exponential and *exact*: with
  exact ``y'`` the error vanishes whatever ``M_z(t)`` is (rate set by the stable invariant zero
  ``-(C_f + C_r)/(m v_x)`` of the v_y dynamics).
* ``C_chi = 0`` is the Section-3 UIO with redundant ``chi`` states (``uio_nguyen``), not registered.

States: ``vy_mps``, ``yaw_rate_radps``, ``beta_rad``; the unknown input is a non-scored extra
(:meth:`GeneralizedUIO.unknown_input`). Missing ``v_x`` / ``r`` older than ``hold_s``: the model
``x' = A x + B_u u + B_mu mu_hat`` predicts with ``mu_hat`` held; on resumption ``eta`` is re-seeded.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from roadtruth.harness.errors import InputError
from roadtruth.observers.base import EstimateTrack, ScalarLoopObserver, StepOutput
from roadtruth.observers.levant_differentiator import levant_gains
from roadtruth.observers.lmi import DesignResult, usable_gains
from roadtruth.observers.registry import register
from roadtruth.observers.uio_generalized_design import (
    N_BASIS,
    GeneralizedModel,
    generalized_model,
    unknown_input_matrix,
)
from roadtruth.observers.uio_generalized_loop import (
    HAVE_ZETA,
    PSI_M,
    UIOKernelState,
    balanced_constants,
    generalized_run,
    uio_update,
)
from roadtruth.observers.uio_nguyen_design import N_X, vehicle_model


@register
class GeneralizedUIO(ScalarLoopObserver):
    """Generalized UIO with output derivatives (Nguyen, Section 4, corrected), stacked output."""

    name = "uio_generalized"
    citation = ("Q. H. Nguyen, PhD thesis draft, Univ. de Lorraine (CRAN), ch. 1, Section 4, eqs. (1.27)-(1.33), "
                "Table 1.1; input-rate and LPV-rate terms added, E_bb block delta1 E - CB, stacked output")
    inputs = ("vx_mps", "yaw_rate_radps", "ax_mps2", "delta_rad")
    states = ("vy_mps", "yaw_rate_radps", "beta_rad")
    variant = "regularized_axle_forces"
    default_options: Mapping[str, Any] = {
        "unknown_input": "axle_forces",  # "axle_forces" (f_yf, f_yr) | "yaw_moment" (M_z)
        "delta2": 1.0,                  # output regularisation; 0 only if rank C B = rank B
        "epsilon": 0.001,               # S = epsilon P of Theorem 1
        "c_chi": 1.0,                   # C_chi = c_chi I (weight of y' in y_chi)
        "output_form": "stacked",       # "stacked" | "summed" ((1.27) as printed: PBH-infeasible)
        "vx_range_mps": (5.0, 30.0),
        "lmi_points": 11,               # v_x grid of the LMI
        "grid_points": 101,             # v_x grid of the certificate
        "differentiator": "fd_lowpass",  # "fd_lowpass" | "levant" (causal only)
        "lowpass_s": 0.02,              # low-pass time constant of fd_lowpass [s]
        "levant_lipschitz": 20.0,       # bound on |r''| for "levant" [rad/s^3]
        "hold_s": 0.1,
        "use_cache": True,
    }

    def _setup(self) -> None:
        o = self.options
        try:
            lo, hi = (float(x) for x in o["vx_range_mps"])
            d2, eps = float(o["delta2"]), float(o["epsilon"])
            float(o["c_chi"])
            npts, ngrid, hold, tlp, lip = (int(o["lmi_points"]), int(o["grid_points"]), float(o["hold_s"]),
                                           float(o["lowpass_s"]), float(o["levant_lipschitz"]))
        except (TypeError, ValueError) as exc:
            raise InputError(f"bad option value ({exc})", field=f"observer {self.name}") from exc
        if (not (0.0 < lo < hi) or d2 < 0.0 or eps <= 0.0 or npts < 2 or ngrid < 2 or hold <= 0.0 or tlp < 0.0
                or lip <= 0.0 or o["unknown_input"] not in ("axle_forces", "yaw_moment")
                or o["output_form"] not in ("stacked", "summed") or o["differentiator"] not in ("fd_lowpass", "levant")):
            raise InputError("bad options: need 0 < v_min < v_max, delta2 >= 0, epsilon > 0, unknown_input in "
                             "(axle_forces, yaw_moment), output_form in (stacked, summed), differentiator in "
                             "(fd_lowpass, levant), lowpass_s >= 0, levant_lipschitz > 0",
                             field=f"observer {self.name}")
        self._vlo, self._vhi, self._hold = lo, hi, hold
        self._model = vehicle_model(self.vehicle)
        self._Bmu = unknown_input_matrix(self._model, o["unknown_input"], self.vehicle.yaw_inertia_kgm2)
        self._nmu = self._Bmu.shape[1]
        self._gm: GeneralizedModel | None = None
        self._consts: tuple[np.ndarray, ...] | None = None
        self._kernel: tuple[Any, ...] | None = None  # arguments of generalized_run that never change

    def generalized_model(self) -> GeneralizedModel:
        """(1.27)-(1.31) for this observer's options (raises InputError if Assumption 5 fails)."""
        if self._gm is None:
            o = self.options
            try:
                self._gm = generalized_model(self._model, self._Bmu, float(o["c_chi"]) * np.eye(3), float(o["delta2"]),
                                             summed=o["output_form"] == "summed")
            except ValueError as exc:
                raise InputError(str(exc), field=f"observer {self.name}") from exc
        return self._gm

    def _compute_design(self) -> DesignResult:
        from roadtruth.observers.uio_generalized_design import design_for
        return design_for(self.design_request(self.generalized_model()))

    def constants(self) -> tuple[np.ndarray, ...]:
        """``(Fs, Gws, Q, Mp, Gp)``: basis of ``eta' = F eta + G (y_chi, u, u')`` and the prediction model."""
        if self._consts is None:
            gm = self.generalized_model()
            nz = gm.n_zeta
            d = self.design()
            K = np.array(usable_gains(self.name, d, ["K"])).reshape(nz, -1)
            P, Q, H = gm.P_zeta, gm.Q_zeta, gm.H
            Fs = np.array([P @ gm.Js[k] - (K @ H if k == 0 else 0.0) for k in range(N_BASIS)])
            Gws = np.array([np.hstack([Fs[k] @ Q + (K if k == 0 else 0.0), P @ gm.Gs[k]]) for k in range(N_BASIS)])
            mdl, nxm = self._model, N_X + self._nmu
            Mp = np.zeros((3, nxm, nxm))
            for i, Ai in enumerate((mdl.A0, mdl.A1, mdl.A2)):
                Mp[i, :N_X, :N_X] = Ai
            Mp[0, :N_X, N_X:] = self._Bmu
            Gp = np.zeros((3, nxm, 2))
            Gp[0, :N_X] = mdl.Bu
            self._consts = (np.ascontiguousarray(Fs), np.ascontiguousarray(Gws), np.ascontiguousarray(Q), Mp, Gp)
        return self._consts

    def kernel_constants(self) -> tuple[Any, ...]:
        """The constant arguments of :func:`~roadtruth.observers.uio_generalized_loop.generalized_run`.

        ``(Fb, Gb, d, Q, Mp, Gp, C_chi, dpsi, par, summed, levant)``: the basis balanced by the powers of
        two ``d``, ``Q_zeta``, the prediction model, ``D_bar[k0 + 1]`` (the psi row, zero when summed),
        ``par = (v_lo, v_hi, hold_s, lowpass_s, g0, g1, delta2)``. A failed design raises here.
        """
        if self._kernel is None:
            Fs, Gws, Q, Mp, Gp = self.constants()
            gm = self.generalized_model()
            Fb, Gb, dbal = balanced_constants(Fs, Gws, 0.5 * (self._vlo + self._vhi))
            o = self.options
            levant = o["differentiator"] == "levant"
            g0, g1 = levant_gains(1, float(o["levant_lipschitz"])) if levant else (0.0, 0.0)
            par = np.array([self._vlo, self._vhi, self._hold, float(o["lowpass_s"]), g0, g1, gm.delta2])
            k0 = 2 * gm.n_y
            dpsi = np.zeros(gm.n_mu) if gm.summed else np.ascontiguousarray(gm.D_bar[k0 + 1], dtype=float)
            self._kernel = (Fb, Gb, dbal, np.ascontiguousarray(Q), np.ascontiguousarray(Mp),
                            np.ascontiguousarray(Gp), np.ascontiguousarray(gm.C_chi, dtype=float), dpsi, par,
                            bool(gm.summed), levant)
        return self._kernel

    def _initial_state(self) -> list[float]:
        return [0.0, 0.0]  # (v_y, r) of the initial estimate

    def _reset_extra(self) -> None:
        n_out = 3 if self.options["output_form"] == "summed" else 9
        self._ks = UIOKernelState.initial(self._t, 2 * 3 + N_X + self._nmu, n_out, float(self._z[0]),
                                          float(self._z[1]))
        self._last = np.array([float(self._z[0]), float(self._z[1]), 0.0])

    def _compiled(self, t: np.ndarray, Y: np.ndarray) -> np.ndarray:
        """Advance through ``t`` (n,) [s], ``Y`` (n, 4) in the shared kernel; the (n, 3) estimates."""
        Fb, Gb, dbal, Q, Mp, Gp, cchi, dpsi, par, summed, levant = self.kernel_constants()
        ks = self._ks
        out = np.empty((t.shape[0], 3))
        generalized_run(t, Y, Fb, Gb, dbal, Q, Mp, Gp, cchi, dpsi, ks.u, ks.fresh, ks.tl, ks.zeta, ks.eta,
                        ks.w_prev, ks.dst, ks.state, par, summed, levant, out)
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

    # ---- core step (also used with exact derivatives by the tests) ---------------------------------
    def advance_with_derivatives(self, h: float, y: np.ndarray, ydot: np.ndarray, u: np.ndarray, udot: np.ndarray,
                                 v: float) -> None:
        """One UIO step of ``h`` [s] to measurements ``y`` (3,), ``y'`` (3,), ``u = (a, delta)``, ``u'``
        (2,), at speed ``v`` (clamped into the design range), with the derivatives given instead of
        differentiated. The first call seeds ``eta``."""
        Fb, Gb, dbal, Q, _, _, cchi, _, par, summed, _ = self.kernel_constants()
        ks = self._ks
        N = ks.zeta.shape[0] + 2
        uio_update(float(h), np.asarray(y, dtype=float), np.asarray(ydot, dtype=float), float(u[0]), float(u[1]),
                   float(udot[0]), float(udot[1]), float(v), Fb, Gb, dbal, Q, cchi, ks.zeta, ks.eta, ks.w_prev,
                   ks.state, par, summed, np.zeros((9, N, N)), np.zeros(N, dtype=np.int64))

    @property
    def psi_m(self) -> float:
        """The integrated gyro heading pseudo-output [rad], kept in [-pi, pi]."""
        return float(self._ks.state[PSI_M])

    def zeta_hat(self) -> np.ndarray:
        """Copy of ``zeta_hat = (chi_1, chi_2, x, mu)``: (2 n_y + 4 + n_mu,) array (mu in kN or kN m)."""
        return self._ks.zeta.copy() if self._ks.state[HAVE_ZETA] else np.zeros(0)

    def unknown_input(self) -> np.ndarray:
        """Current unknown-input estimate: ``(f_yf, f_yr)`` [N] or ``(M_z,)`` [N m] (non-scored extra)."""
        if not self._ks.state[HAVE_ZETA]:
            return np.zeros(self._nmu)
        return 1000.0 * self._ks.zeta[2 * 3 + N_X:]


@register
class GeneralizedUIOYawMoment(GeneralizedUIO):
    """Generalized UIO, Table 1.1 exact case: unknown yaw moment, rank C B = rank B, delta2 = 0."""

    name = "uio_generalized_yaw_moment"
    citation = ("Q. H. Nguyen, PhD thesis draft, Univ. de Lorraine (CRAN), ch. 1, Section 4, (1.27)-(1.33), "
                "Table 1.1 case rank(CB) = rank(B), unknown yaw moment")
    variant = "exact_yaw_moment"
    default_options: Mapping[str, Any] = {**GeneralizedUIO.default_options, "unknown_input": "yaw_moment",
                                          "delta2": 0.0, "epsilon": 0.01}
