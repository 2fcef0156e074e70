r"""Generalized (output-derivative) unknown-input observer of Nguyen, ch. 1, Section 4 ((1.27)-(1.33)).

Q. H. Nguyen, PhD thesis draft (Université de Lorraine, CRAN), ch. 1 "Learning with Unknown Input
Observers for Robust Nonlinear Estimation", Section 4, on the vehicle of sec. 7.2. Model, corrections
and LMIs: :mod:`observers.uio_generalized_design`. Observer (1.32):

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

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from harness.errors import InputError
from harness.tire import jit
from observers.base import EstimateTrack, ScalarLoopObserver
from observers.levant_differentiator import LevantDifferentiator
from observers.lmi import DesignResult, usable_gains
from observers.registry import register
from observers.takagi_sugeno import expm_taylor
from observers.uio_generalized_design import (
    N_BASIS,
    GeneralizedModel,
    basis,
    generalized_model,
    unknown_input_matrix,
)
from observers.uio_nguyen import SUBSTEP_RATE, TWO_PI, affine_rk4
from observers.uio_nguyen_design import N_X, vehicle_model


@jit
def exact_affine_step(z: np.ndarray, Fs: np.ndarray, Gs: np.ndarray, c: np.ndarray, w0: np.ndarray,
                      w1: np.ndarray, h: float) -> None:
    """Advance ``z' = F z + G w(t)`` by ``h`` [s] exactly, in place.

    ``F = sum_k c_k Fs[k]`` (Fs: (nb, n, n)), ``G`` likewise (Gs: (nb, n, m)); ``w`` linear from
    ``w0`` to ``w1`` over the step. Uses ``exp`` of the (n + 2)-square augmented matrix
    ``[[F h, b0 h, db h], [0, 0, 0], [0, 1, 0]]`` acting on ``(z, 1, 0)``.
    """
    n, m, nb = z.shape[0], w0.shape[0], c.shape[0]
    M = np.zeros((n + 2, n + 2))
    for i in range(n):
        b0 = 0.0
        b1 = 0.0
        for k in range(nb):
            ck = c[k]
            if ck == 0.0:
                continue
            for j in range(n):
                M[i, j] += ck * Fs[k, i, j] * h
            for j in range(m):
                g = ck * Gs[k, i, j]
                b0 += g * w0[j]
                b1 += g * w1[j]
        M[i, n] = b0 * h
        M[i, n + 1] = (b1 - b0) * h
    M[n + 1, n] = 1.0
    E = expm_taylor(M)
    out = np.empty(n)
    for i in range(n):
        s = E[i, n]
        for j in range(n):
            s += E[i, j] * z[j]
        out[i] = s
    for i in range(n):
        z[i] = out[i]


class CausalDerivative:
    """Causal derivative of an irregularly sampled signal: ``"fd_lowpass"`` or ``"levant"``.

    ``fd_lowpass``: backward difference ``(f_k - f_(k-1)) / tau`` through a first-order low-pass with
    time constant ``lowpass_s`` [s] (exact discretisation ``exp(-tau / T)``); delay about ``T + tau/2``.
    ``levant``: first-order Levant differentiator with Lipschitz constant ``lipschitz`` (bound on ``|f''|``).
    """

    def __init__(self, kind: str, lowpass_s: float, lipschitz: float) -> None:
        self.kind, self.T = kind, float(lowpass_s)
        self._lev = LevantDifferentiator(1, lipschitz) if kind == "levant" else None
        self.reset()

    def reset(self) -> None:
        self.value = 0.0
        self._prev = math.nan
        if self._lev is not None:
            self._lev.reset()

    def update(self, f: float, tau: float) -> float:
        """Feed ``f`` taken ``tau`` [s] after the previous sample; returns the derivative estimate."""
        if self._lev is not None:
            self._lev.update(f, tau)
            self.value = self._lev.z[1]
            return self.value
        if self._prev == self._prev and tau > 0.0:
            raw = (f - self._prev) / tau
            a = math.exp(-tau / self.T) if self.T > 0.0 else 0.0
            self.value = a * self.value + (1.0 - a) * raw
        self._prev = f
        return self.value


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
        self._balanced: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # see uio_generalized_loop

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
        from observers.uio_generalized_design import design_for
        return design_for(self)

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

    def _initial_state(self) -> list[float]:
        return [0.0, 0.0]  # (v_y, r) of the initial estimate

    def _reset_extra(self) -> None:
        o = self.options
        self._diff = [CausalDerivative(o["differentiator"], o["lowpass_s"], o["levant_lipschitz"]) for _ in range(3)]
        self._zeta: np.ndarray | None = None
        self._eta: np.ndarray | None = None
        self._psi_m = 0.0
        self._r_prev, self._t_r_prev = math.nan, math.nan
        self._t_prev = math.nan
        self._w_prev: np.ndarray | None = None
        self._tracking = False

    def run_compiled(self, t: np.ndarray, Y: np.ndarray, x0: Mapping[str, float] | None = None) -> EstimateTrack:
        """``run()`` as one compiled loop (:mod:`observers.uio_generalized_loop`), ~4x faster.

        Equal to ``run()`` / stepping :meth:`step` to ~1e-11 of each state's scale, not bit-equal (the
        loop evaluates the same exact step by a Padé exponential acting on the state vector), which is
        why ``run()`` still steps the plain-Python reference: the harness promises ``step() == run()``
        to the bit.
        """
        from observers.uio_generalized_loop import run_compiled
        return run_compiled(self, t, Y, x0)

    # ---- core step (also used with exact derivatives by the tests) ---------------------------------
    def advance_with_derivatives(self, h: float, y: np.ndarray, ydot: np.ndarray, u: np.ndarray, udot: np.ndarray,
                                 v: float) -> None:
        """One UIO step of ``h`` [s] to measurements ``y`` (3,), ``y'`` (3,), ``u = (a, delta)``, ``u'``
        (2,), at speed ``v`` (clamped into the design range). The first call seeds ``eta``."""
        Fs, Gws, Q, _, _ = self._consts if self._consts is not None else self.constants()
        gm = self._gm
        assert gm is not None
        ychi = gm.output(y, ydot)
        w1 = np.concatenate([ychi, u, udot])
        if self._eta is None or self._w_prev is None or not self._tracking:
            if self._zeta is None:
                z = np.zeros(gm.n_zeta)
                ny = gm.n_y
                z[:ny], z[ny:2 * ny] = y, ydot
                z[2 * ny:2 * ny + N_X] = [y[0], self._z[0], y[1], self._z[1]]
                self._zeta = z
            self._eta = self._zeta - Q @ ychi
            self._w_prev = w1
            self._v_prev = self._vlo if v < self._vlo else (self._vhi if v > self._vhi else v)
            self._a_prev = float(u[0])
            self._tracking = True
            return
        v = self._vlo if v < self._vlo else (self._vhi if v > self._vhi else v)
        a = float(u[0])
        if h > 0.0:
            # schedule at the step's midpoint (second order in h; the end point leaves O(h v'))
            vm, am = 0.5 * (v + self._v_prev), 0.5 * (a + self._a_prev)
            exact_affine_step(self._eta, Fs, Gws, basis(vm, am), self._w_prev, w1, h)
        self._w_prev = w1
        self._v_prev, self._a_prev = v, a
        self._zeta = self._eta + Q @ ychi

    def _advance(self, t_s: float, y: list[float]) -> None:
        h = self._tick(t_s, y)
        if self._consts is None:
            self.constants()
        vx, r, ax, delta = self._u
        if vx != vx:
            return
        a = ax if ax == ax else 0.0
        d = delta if delta == delta else 0.0
        tau = t_s - self._t_prev if self._t_prev == self._t_prev else 0.0
        self._t_prev = t_s
        if self._fresh[1]:
            if self._r_prev == self._r_prev and self._tracking:
                self._psi_m += 0.5 * (t_s - self._t_r_prev) * (self._r_prev + r)
            self._r_prev, self._t_r_prev = r, t_s
        rd = self._diff[0].update(r, tau) if r == r and tau > 0.0 else self._diff[0].value
        ad = self._diff[1].update(a, tau) if tau > 0.0 else 0.0
        dd = self._diff[2].update(d, tau) if tau > 0.0 else 0.0
        tl = self._t_last
        live = r == r and t_s - min(tl[0], tl[1]) <= self._hold
        gm = self._gm
        assert gm is not None
        k0 = 2 * gm.n_y
        if not live:
            if self._zeta is not None and h > 0.0:
                _, _, _, Mp, Gp = self._consts  # type: ignore[misc]
                xm = self._zeta[k0:].copy()
                v = min(max(vx, self._vlo), self._vhi)
                uu = np.array([a, d])
                affine_rk4(xm, Mp, Gp, uu, uu, v, 1.0 / v, h, max(1, math.ceil(h * 200.0 / SUBSTEP_RATE)))
                self._zeta[k0:] = xm
            self._tracking = False
            return
        if not self._tracking and self._zeta is not None:
            # restart where the model's psi is (the psi output carries delta2 D mu, see uio_nguyen)
            self._psi_m = float(self._zeta[k0 + 2] + gm.delta2 * (gm.D_bar[k0 + 1] @ self._zeta[k0 + N_X:])
                                if not gm.summed else self._zeta[k0 + 2])
        if self._psi_m > math.pi or self._psi_m < -math.pi:
            c = TWO_PI * round(self._psi_m / TWO_PI)
            self._psi_m -= c
            if self._eta is not None and self._w_prev is not None and self._zeta is not None:
                # psi has a zero column in J: shift every psi slot and the measured psi together
                shift = np.zeros(gm.n_zeta)
                shift[1] = shift[k0 + 2] = c
                wshift = np.zeros_like(self._w_prev)
                yshift = gm.output(np.array([0.0, c, 0.0]), np.zeros(3))
                wshift[:yshift.size] = yshift
                self._zeta -= shift
                self._w_prev -= wshift
                self._eta = self._zeta - self._consts[2] @ self._w_prev[:yshift.size]  # type: ignore[index]
        yv = np.array([vx, self._psi_m, r])
        ydot = np.array([a, r, rd])
        self.advance_with_derivatives(h, yv, ydot, np.array([a, d]), np.array([ad, dd]), vx)

    def _values(self) -> list[float]:
        if self._zeta is None:
            return [float(self._z[0]), float(self._z[1]), 0.0]
        k0 = 2 * 3
        vy, r, vx = float(self._zeta[k0 + 1]), float(self._zeta[k0 + 3]), float(self._zeta[k0])
        v = self._u[0] if self._u[0] == self._u[0] else vx
        return [vy, r, math.atan2(vy, v) if v > 0.0 else 0.0]

    def zeta_hat(self) -> np.ndarray:
        """Copy of ``zeta_hat = (chi_1, chi_2, x, mu)``: (2 n_y + 4 + n_mu,) array (mu in kN or kN m)."""
        return np.zeros(0) if self._zeta is None else self._zeta.copy()

    def unknown_input(self) -> np.ndarray:
        """Current unknown-input estimate: ``(f_yf, f_yr)`` [N] or ``(M_z,)`` [N m] (non-scored extra)."""
        return np.zeros(self._nmu) if self._zeta is None else 1000.0 * self._zeta[2 * 3 + N_X:]


@register
class GeneralizedUIOYawMoment(GeneralizedUIO):
    """Generalized UIO, Table 1.1 exact case: unknown yaw moment, rank C B = rank B, delta2 = 0."""

    name = "uio_generalized_yaw_moment"
    citation = ("Q. H. Nguyen, PhD thesis draft, Univ. de Lorraine (CRAN), ch. 1, Section 4, (1.27)-(1.33), "
                "Table 1.1 case rank(CB) = rank(B), unknown yaw moment")
    variant = "exact_yaw_moment"
    default_options: Mapping[str, Any] = {**GeneralizedUIO.default_options, "unknown_input": "yaw_moment",
                                          "delta2": 0.0, "epsilon": 0.01}
