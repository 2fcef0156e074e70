r"""Neuro-adaptive observers with concurrent learning (H. Bessafa, PhD thesis 2024, ch. 3).

H. Bessafa, "Advanced Estimation Algorithms for Connected and Autonomous Vehicle Applications", PhD
thesis, Université de Lorraine (CRAN), 2024, HAL tel-04744305:

* ``neuro_adaptive_cl``: the proposed neuro-adaptive LMI observer (sec. 3.4, Thm 3.4.1, (3.11),
  Algorithm 2) with gains from LMI (3.12) in the form that is feasible
  (:mod:`roadtruth.observers.neuro_adaptive_design`); ``neuro_adaptive_cl_printed``: the same with the printed
  gains L = 1e6 [0.0364, 0.5032, 5.6725], K = 3.169e7 (rejected at the printed lambda = 1e5).
* ``cl_aeo_ran_xie``: the concurrent-learning adaptive extended observer of Ran & Xie (sec. 3.3,
  (3.7)): high-gain extended observer ``[l_i / eps^i]``, saturated estimates, a *known* regressor
  (for (3.27): ``Phi = (v a, a, v^2, 1)``, so f = W^T Phi exactly).
* ``neuro_adaptive_chakrabarty``: the neuro-adaptive observer of Chakrabarty et al. (sec. 3.2, (3.4)):
  no extended state; the unknown term is ``W_hat^T sigma(x_hat)`` and the weights integrate the
  output error, ``W_hat' = l_w (y - C x_hat)``.

Observer (3.11) (typos corrected: derivative dots, ``L (y - C x_hat)``, two learning rates eta1, eta2
as in sec. 3.5.2), on ``z = (x_hat, x_hat_4)``, ``x_hat_4`` the lumped unknown term [m/s^3]::

    z'     = A~ z + L~ (y - C~ z) + b(t)                        (b: known inputs)
    W_hat' = eta1 s (x_hat_4 - W_hat^T s) + eta2 sum_j s_j (Lambda_j - W_hat^T s_j),  s = sigma(x_hat)

``sigma`` = three sigmoids of (x_1, x_2, x_3) with identity input weights and no bias (Fig 3.1).
History stack (Algorithm 2): columns ``s_j`` of Z (3 x p, p = 10) and ``Lambda_j = x_hat_4``; filled
in order, then a new point replaces the column whose replacement gives the largest minimum
singular value of Z, only if it increases it: the minimum singular value never decreases. A point
is offered every ``record_interval_s`` (the thesis does not say how often).

Integration (why not RK4): the LMI gains put one observer pole at -890 rad/s (printed gains:
-3.6e4 rad/s) and ``eta1 |s|^2`` makes the weight ODE stiff as well (up to ~3e3 /s). Explicit
schemes would need steps < 5e-5 s. Here the linear part ``A~ - L~ C~`` is integrated **exactly**
(matrix exponential of the step; the measured position and the known inputs as first-order holds
through their last two samples, so a ramp is integrated without error), which is stable for any
pole and any step, and the weight ODE, linear in W_hat for the frozen regressor, by a
**backward-Euler** step (one 3x3 solve: L-stable, and its fixed point is the exact least-squares
fixed point). The Chakrabarty baseline, whose right side is bilinear in (W_hat, sigma(x_hat)),
uses RK4 sub-steps sized to its (moderate) poles.

Harness application (the thesis's motivation, sec. 3.5: monitoring another vehicle in ACC): the
lead vehicle seen by radar, position = range. State ``x = (d, d', a_L)``: range [m], range rate
[m/s], lead acceleration [m/s^2]; ``d'' = a_L - a_E`` with the ego acceleration ``a_E`` (IMU
``ax_mps2``) as known input, and the lead's unknown drive in the lumped term ``x_4 = da_L/dt``. The
network sees ``(d, d' + v_E, a_L)`` (lead speed from the ego wheel speed ``vx_mps``). Only range
is used (position only, as in ch. 3); a range sample older than ``hold_s`` is not used (the
innovation is dropped). The first range sample initialises ``d``; ``d' = 0``, ``a_L = a_E``.

*Compiled.* ``step()``, ``run()`` and ``run_model()`` of all four observers call one numba kernel
(:mod:`roadtruth.observers.neuro_adaptive_loop`) with one sample or the whole log, on state arrays
carried between calls, so stepping and a whole run agree bit for bit.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from roadtruth.harness.errors import InputError
from roadtruth.observers import neuro_adaptive_design as nad
from roadtruth.observers.base import EstimateTrack, Observer, StepOutput
from roadtruth.observers.lmi import DesignResult, usable_gains
from roadtruth.observers.neuro_adaptive_loop import (
    MODE_CHAKRABARTY,
    MODE_CL,
    N_PAR,
    REG_M7C,
    REG_SIGMOID,
    learning_run,
)
from roadtruth.observers.registry import register

#: Most exact discretisations kept per observer (one per distinct step length; irregular stamps add more).
DISCRETISATION_CACHE = 4096


def exact_discretisation(Acl: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(Phi, Gamma0, Gamma1)`` (4, 4) for ``z' = Acl z + r0 + r1 s`` over a step ``h`` [s].

    ``z(h) = Phi z(0) + Gamma0 r0 + Gamma1 r1``, ``Gamma0 = int_0^h e^(Acl s) ds``,
    ``Gamma1 = int_0^h e^(Acl (h - s)) s ds`` (one exponential of a 12 x 12 block matrix).
    """
    from scipy.linalg import expm

    n = Acl.shape[0]
    aug = np.zeros((3 * n, 3 * n))
    aug[:n, :n], aug[:n, n:2 * n], aug[n:2 * n, 2 * n:] = Acl * h, np.eye(n) * h, np.eye(n) * h
    E = expm(aug)
    return E[:n, :n], E[:n, n:2 * n], E[:n, 2 * n:]


@dataclass(frozen=True)
class LearningTrack:
    """A run of the learning loop: ``z`` (n, 4) = (x_1, x_2, x_3, x_4 estimate), ``W`` (n, N) weights,
    ``f_nn`` (n,) the network ``W^T sigma(x_hat)`` [m/s^3], ``smin`` (n,) history-stack min singular value."""

    t_s: np.ndarray
    z: np.ndarray
    W: np.ndarray
    f_nn: np.ndarray
    smin: np.ndarray


_COMMON: dict[str, Any] = {
    "eta1": 1e3,                # learning rate of the current-data term (sec. 3.5.2)
    "eta2": 10.0,               # learning rate of the recorded-data term (sec. 3.5.2)
    "stack_size": 10,           # p of Algorithm 2 (sec. 3.5.2)
    "record_interval_s": 0.1,   # a point is offered to the history stack this often (not in the thesis)
    "hold_s": 0.12,             # a range sample is used for at most this long [s]
    "weights0": (0.0, 0.0, 0.0),
    "use_cache": True,
}


class _LearningObserver(Observer):
    """Shared run logic: radar relative model in the harness, design model through :meth:`run_model`."""

    inputs = ("range_m", "vx_mps", "ax_mps2")
    states = ("range_m", "range_rate_mps", "lead_accel_mps2")
    kind = REG_SIGMOID
    mode = MODE_CL

    def __init__(self, vehicle: Any, **options: Any) -> None:
        super().__init__(vehicle, **options)
        o = self.options
        try:
            self._eta = (float(o["eta1"]), float(o["eta2"]))
            self._p = int(o["stack_size"])
            self._rec = float(o["record_interval_s"])
            self._hold = float(o["hold_s"])
            self._W0 = np.asarray(o["weights0"], dtype=float).reshape(-1)
        except (TypeError, ValueError) as exc:
            raise InputError(f"bad option value ({exc})", field=f"observer {self.name}") from exc
        n_reg = 3 if self.kind == REG_SIGMOID else 4
        if not (min(self._eta) >= 0 and self._p >= n_reg and self._rec > 0 and self._hold > 0
                and self._W0.size == n_reg and np.all(np.isfinite(self._W0))):
            raise InputError(f"bad option: need eta1, eta2 >= 0, stack_size >= {n_reg}, record_interval_s, "
                             f"hold_s > 0 and {n_reg} finite weights0", field=f"observer {self.name}")
        # (Lt, par, sat, Acl): the kernel's constants, built at the first step (a failed design or a
        # bad gain option fails the run, not the construction)
        self._consts: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        self._disc: dict[float, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        # step()'s one-row buffers (column 2 of the kernel input, the known lead input, stays 0)
        self._t1, self._y1, self._hidx1 = np.zeros(1), np.zeros((1, 4)), np.zeros(1, dtype=np.int64)
        self._out1 = (np.empty((1, 4)), np.empty((1, self._W0.size)), np.empty(1), np.empty(1))
        self._dummy = np.zeros((1, 2, 4, 4))   # no step to discretise
        self.reset(0.0)

    def gains(self) -> np.ndarray:
        """``L~ = [L; K]`` (4,) [1/s, 1/s^2, 1/s^3, 1/s^4]."""
        d = self.design()
        return np.array(usable_gains(self.name, d, ("L", "K")))

    def saturation(self) -> np.ndarray:
        return np.full(4, np.inf)

    def _weight_gains(self, Lt: np.ndarray, z0: np.ndarray | None) -> np.ndarray:
        """Gains of an output-error weight law (mode 1 only); (N,)."""
        return np.zeros(self._W0.size)

    def _constants(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        if self._consts is None:
            Lt = np.ascontiguousarray(self.gains(), dtype=float)
            hmax = 0.2 / (4.0 * float(self.options["omega"])) if self.mode == MODE_CHAKRABARTY else 0.0
            par = np.array([self.mode, self.kind, self._eta[0], self._eta[1], self._rec, self._hold, hmax])
            assert par.shape == (N_PAR,)
            sat = np.ascontiguousarray(self.saturation(), dtype=float)
            self._consts = (Lt, par, sat, nad.A_EXT - Lt.reshape(4, 1) @ nad.C_EXT)
        return self._consts

    def _start(self, z0: np.ndarray | None) -> None:
        """Fresh kernel state; ``z0`` (4,) starts the observer there (else at the first range sample)."""
        N = self._W0.size
        self._z0 = None if z0 is None else np.array(z0, dtype=float).reshape(4)
        self._kz = np.zeros(4) if self._z0 is None else self._z0.copy()
        self._kW = self._W0.copy()
        self._kZ = np.zeros((N, self._p))      # history stack (Algorithm 2)
        self._kLam = np.zeros(self._p)
        self._klast = np.full(4, np.nan)       # latest sample of each channel, its time [s] and slope
        self._ktl = np.full(4, -np.inf)
        self._kslope = np.zeros(4)
        self._kst = np.array([0.0 if self._z0 is None else 1.0, np.nan, -np.inf, 0.0, 0.0])
        self._lw: np.ndarray | None = None

    def _matrices(self, key: float, Acl: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(PHI, G0, G1)`` (1, 2, 4, 4) of a step ``key`` [s] (closed loop, open chain), cached."""
        m = self._disc.get(key)
        if m is None:
            if len(self._disc) >= DISCRETISATION_CACHE:
                self._disc.clear()
            pairs = [exact_discretisation(A, key) for A in (Acl, nad.A_EXT)]
            m = tuple(np.array([[pr[i] for pr in pairs]]) for i in range(3))
            self._disc[key] = m
        return m

    def _discretisation(self, t: np.ndarray, Acl: np.ndarray) -> tuple[np.ndarray, ...]:
        """``(hidx, PHI, G0, G1)`` of the steps ending at ``t`` (the first from the kernel's last time).

        Steps are matched to 1e-12 s; a positive step that rounds to 0 gets the unit step's
        matrices, as the loop always has done."""
        n = t.shape[0]
        if self.mode != MODE_CL or n == 0:
            return np.zeros(n, dtype=np.int64), self._dummy, self._dummy, self._dummy
        if n == 1:   # step(): one scalar step, no array bookkeeping
            h = t[0] - self._kst[1]
            if not h > 0.0:
                return self._hidx1, self._dummy, self._dummy, self._dummy
            key = float(np.float64(h).round(12))   # the same rounding as np.round on an array
            return (self._hidx1, *self._matrices(key if key > 0.0 else 1.0, Acl))
        h = np.diff(t, prepend=self._kst[1])
        key = np.round(h, 12)
        key = np.where(key > 0.0, key, 1.0)
        pos = h > 0.0
        uniq, inv = np.unique(key[pos], return_inverse=True)
        hidx = np.zeros(n, dtype=np.int64)
        hidx[pos] = inv
        if len(uniq) == 0:
            return hidx, self._dummy, self._dummy, self._dummy
        mats = [self._matrices(k, Acl) for k in uniq.tolist()]
        PHI, G0, G1 = (np.concatenate([m[i] for m in mats]) for i in range(3))
        return hidx, PHI, G0, G1

    def _kernel(self, t: np.ndarray, Y: np.ndarray) -> LearningTrack:
        """Advance the kernel state through ``t`` (n,) [s], ``Y`` (n, 4) (kernel columns)."""
        Lt, par, sat, Acl = self._constants()
        # writeable C arrays: numba compiles a second copy of the kernel for read-only ones
        t, Y = (np.require(a, dtype=float, requirements=("C", "W")) for a in (t, Y))
        if self._lw is None:
            self._lw = np.ascontiguousarray(self._weight_gains(Lt, self._z0), dtype=float)
        hidx, PHI, G0, G1 = self._discretisation(t, Acl)
        n, N = t.shape[0], self._W0.size
        out_z, out_W, out_s, out_f = np.empty((n, 4)), np.empty((n, N)), np.empty(n), np.empty(n)
        learning_run(t, Y, hidx, PHI, G0, G1, Lt, self._lw, par, sat, self._kz, self._kW, self._kZ, self._kLam,
                     self._klast, self._ktl, self._kslope, self._kst, out_z, out_W, out_s, out_f)
        return LearningTrack(t, out_z, out_W, out_f, out_s)

    def run_model(self, t: np.ndarray, y: np.ndarray, u: np.ndarray, z0: np.ndarray,
                  bu: float = 1.0 / (nad.M7C["mass_kg"] * nad.M7C["tau_s"])) -> LearningTrack:
        """Design model (3.27): position ``y`` (n,) [m], input ``u`` (n,) [N], start ``z0`` (4,).

        Restarts the observer from ``z0`` (its state is then the end of this run)."""
        t = np.ascontiguousarray(t, dtype=float)
        Y = np.ascontiguousarray(np.column_stack([y, np.zeros(len(t)), bu * np.asarray(u, float), np.zeros(len(t))]))
        self._start(np.asarray(z0, dtype=float))
        return self._kernel(t, Y)

    # harness interface ------------------------------------------------------------------------
    def reset(self, t0_s: float, x0: Mapping[str, float] | None = None) -> None:
        """Restart; the clock starts at the first sample (a range sample starts the estimate unless ``x0``)."""
        self._t0 = t0_s
        bad = sorted(set(x0 or {}) - set(self.states))
        if bad:
            raise InputError(f"cannot initialise state {bad[0]!r} (settable: {', '.join(self.states)})",
                             field=f"observer {self.name} x0")
        self._start(None if not x0 else np.array([float(x0.get(s, 0.0)) for s in self.states] + [0.0]))

    def step(self, t_s: float, y: np.ndarray) -> StepOutput:
        """One sample through the compiled kernel (the code ``run()`` loops in, so the same bits)."""
        Lt, par, sat, Acl = self._constants()
        if self._lw is None:
            self._lw = np.ascontiguousarray(self._weight_gains(Lt, self._z0), dtype=float)
        t1, y1 = self._t1, self._y1
        t1[0] = t_s
        y = np.asarray(y, dtype=float)
        y1[0, 0], y1[0, 1], y1[0, 3] = y[0], -y[2], y[1]   # the columns of _relative_inputs
        hidx, PHI, G0, G1 = self._discretisation(t1, Acl)
        z, W, sm, f = self._out1
        learning_run(t1, y1, hidx, PHI, G0, G1, Lt, self._lw, par, sat, self._kz, self._kW, self._kZ, self._kLam,
                     self._klast, self._ktl, self._kslope, self._kst, z, W, sm, f)
        return StepOutput(z[0, :3].copy())

    @staticmethod
    def _relative_inputs(Y: np.ndarray) -> np.ndarray:
        # columns: range (y), -a_E (row 2 of the relative model), 0 (no known lead input), v_E
        Y = np.asarray(Y, dtype=float).reshape(-1, 3)
        return np.ascontiguousarray(np.column_stack([Y[:, 0], -Y[:, 2], np.zeros(len(Y)), Y[:, 1]]))

    def run(self, t: np.ndarray, Y: np.ndarray, x0: Mapping[str, float] | None = None) -> EstimateTrack:
        """Reset at ``t[0]`` and advance through the whole log in one compiled call (equal to stepping)."""
        t = np.ascontiguousarray(t, dtype=float)
        self.reset(float(t[0]) if len(t) else 0.0, x0)
        tr = self._kernel(t, self._relative_inputs(Y))
        self.last_learning = tr
        return EstimateTrack(self.name, tuple(self.states), t, tr.z[:, :3].copy())


@register
class NeuroAdaptiveCL(_LearningObserver):
    """Neuro-adaptive LMI observer with concurrent learning (Thm 3.4.1), gains from LMI (3.12) made feasible."""

    name = "neuro_adaptive_cl"
    citation = "H. Bessafa, PhD thesis, Univ. Lorraine 2024, sec. 3.4, Thm 3.4.1, (3.11)-(3.12), Algorithm 2"
    variant = "lmi"
    default_options = {**_COMMON, "p_floor": 1e-3}

    def _compute_design(self) -> DesignResult:
        return nad.cached(self.variant, float(self.options["p_floor"]), bool(self.options["use_cache"]))


@register
class NeuroAdaptiveCLPrinted(NeuroAdaptiveCL):
    """The same observer with the printed gains of sec. 3.5.2 (not certified at the printed lambda)."""

    name = "neuro_adaptive_cl_printed"
    citation = "H. Bessafa, PhD thesis, Univ. Lorraine 2024, sec. 3.5.2 (printed L, K)"
    variant = "printed"


@register
class CLAEORanXie(_LearningObserver):
    """Concurrent-learning adaptive extended observer (Ran & Xie, as recalled in Bessafa 2024, (3.7))."""

    name = "cl_aeo_ran_xie"
    citation = ("M. Ran, L. Xie et al., concurrent-learning adaptive extended observer, as recalled in "
                "H. Bessafa, PhD thesis, Univ. Lorraine 2024, sec. 3.3, (3.7)")
    variant = "cl_aeo"
    kind = REG_M7C
    default_options = {**_COMMON, "eta1": 1.0, "eta2": 1.0, "weights0": (0.0, 0.0, 0.0, 0.0), "eps": 0.1,
                       "saturation": (math.inf, 60.0, 15.0, 100.0)}

    def _compute_design(self) -> DesignResult:
        return DesignResult.not_applicable(self.variant, "high-gain extended observer: gains l_i/eps^i, no LMI")

    def gains(self) -> np.ndarray:
        eps = float(self.options["eps"])
        if not 0.0 < eps < 1.0:
            raise InputError("bad option: eps must be in (0, 1)", field=f"observer {self.name}")
        return nad.high_gain_eso_gains(eps)

    def saturation(self) -> np.ndarray:
        sat = np.asarray(self.options["saturation"], dtype=float).reshape(-1)
        if sat.size != 4 or np.any(~(sat > 0)):
            raise InputError("bad option: saturation needs 4 positive bounds", field=f"observer {self.name}")
        return sat


@register
class NeuroAdaptiveChakrabarty(_LearningObserver):
    """Neuro-adaptive observer of Chakrabarty et al. (Bessafa 2024, (3.4)): weights driven by the output error."""

    name = "neuro_adaptive_chakrabarty"
    citation = ("A. Chakrabarty, A. Zemouche, R. Rajamani, M. Benosman, robust data-driven neuro-adaptive "
                "observers, as recalled in H. Bessafa, PhD thesis, Univ. Lorraine 2024, sec. 3.2, (3.4)")
    variant = "chakrabarty"
    mode = MODE_CHAKRABARTY
    default_options = {**_COMMON, "omega": 10.0}

    def _compute_design(self) -> DesignResult:
        return DesignResult.not_applicable(self.variant, "gains of the original LMIs are not in the thesis; "
                                           "poles placed at -omega")

    def gains(self) -> np.ndarray:
        om = float(self.options["omega"])
        if not om > 0:
            raise InputError("bad option: omega must be > 0", field=f"observer {self.name}")
        return nad.chain_poles_gains(om)

    def _weight_gains(self, Lt: np.ndarray, z0: np.ndarray | None) -> np.ndarray:
        # L0 places (A - L0 C) like the first three chain gains; l_w spreads the fourth over the
        # weights so that, at the regressor of the start, the pair (x_hat, W^T s) has the gains of the
        # extended observer with all poles at -omega (the original LMIs of the paper are not given).
        x_start = np.zeros(3) if z0 is None else np.asarray(z0[:3], float)
        s0 = 1.0 / (1.0 + np.exp(-x_start))
        return Lt[3] * s0 / float(s0 @ s0)
