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
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from roadtruth.harness.errors import InputError
from roadtruth.harness.truth.tire import jit
from roadtruth.observers import neuro_adaptive_design as nad
from roadtruth.observers.base import EstimateTrack, Observer
from roadtruth.observers.lmi import DesignResult, usable_gains
from roadtruth.observers.registry import register

REG_SIGMOID = 0   # sigma(x) of (3.29): three sigmoids
REG_M7C = 1       # known regressor of (3.27): (v a, a, v^2, 1)
IOTA = 0.01       # saturation overshoot of rho (Ran & Xie: rho(inf) = 1 + iota)


def _regressor(kind: int, x1: float, x2: float, x3: float, out: np.ndarray) -> None:
    if kind == REG_SIGMOID:
        out[0] = 1.0 / (1.0 + math.exp(-x1))
        out[1] = 1.0 / (1.0 + math.exp(-x2))
        out[2] = 1.0 / (1.0 + math.exp(-x3))
    else:
        out[0] = x2 * x3
        out[1] = x3
        out[2] = x2 * x2
        out[3] = 1.0


def _rho(v: float, m: float) -> float:
    """``M rho(v / M)``: identity inside ``|v| <= M``, smooth saturation to ``(1 + iota) M`` outside."""
    if not m < math.inf:
        return v
    q = v / m
    if abs(q) <= 1.0:
        return v
    s = 1.0 if q > 0 else -1.0
    return m * s * (1.0 + IOTA * math.tanh((abs(q) - 1.0) / IOTA))


def _smin(Z: np.ndarray) -> float:
    ev = np.linalg.eigvalsh(Z @ Z.T)
    return math.sqrt(max(ev[0], 0.0))


def _cl_loop(t: np.ndarray, Y: np.ndarray, hidx: np.ndarray, PHI: np.ndarray, G0: np.ndarray, G1: np.ndarray,
             Lt: np.ndarray, kind: int, sat: np.ndarray, eta1: float, eta2: float, p: int, rec_dt: float,
             hold: float, z0: np.ndarray, W0: np.ndarray, started0: bool,
             out_z: np.ndarray, out_W: np.ndarray, out_smin: np.ndarray, out_fnn: np.ndarray) -> None:
    """Loop of (3.11)/(3.7). ``Y`` (n, 4): y, b_2, b_3 (known inputs of rows 2, 3), v_offset; NaN = none.

    ``PHI, G0, G1`` (nh, 2, 4, 4): exact discretisation per distinct step (index ``hidx`` (n,)), with
    [0] the closed loop ``A~ - L~ C~`` and [1] the open chain (no position sample within ``hold``).
    """
    n = t.shape[0]
    N = W0.shape[0]
    z = z0.copy()
    W = W0.copy()
    Z = np.zeros((N, p))
    Lam = np.zeros(p)
    k = 0
    smin = 0.0
    s = np.zeros(N)
    last = np.full(4, np.nan)      # latest sample of each channel
    tl = np.full(4, -np.inf)        # its time
    slope = np.zeros(4)             # its slope (from the two latest samples)
    started = started0
    t_rec = -np.inf
    tprev = t[0]
    rhs0 = np.zeros(4)
    rhs1 = np.zeros(4)
    for i in range(n):
        ti = t[i]
        for c in range(4):
            v = Y[i, c]
            if v == v:
                dt = ti - tl[c]
                slope[c] = (v - last[c]) / dt if (dt > 0.0 and dt <= hold and last[c] == last[c]) else 0.0
                last[c] = v
                tl[c] = ti
        h = ti - tprev
        tprev = ti
        if not started:
            if last[0] == last[0]:
                z[0] = last[0]
                z[1] = 0.0
                z[2] = 0.0 if last[1] != last[1] else -last[1]  # a_L = a_E (b_2 = -a_E)
                z[3] = 0.0
                started = True
        elif h > 0.0:
            use_y = (ti - tl[0]) <= hold
            j = 0 if use_y else 1
            hi = hidx[i]
            # input lines over [t - h, t]: value at t - h and slope (extrapolated while held)
            for r in range(4):
                rhs0[r] = 0.0
                rhs1[r] = 0.0
            for c in (1, 2):
                if last[c] == last[c]:
                    sc = slope[c] if ti - tl[c] <= hold else 0.0
                    rhs0[c] += last[c] + sc * (ti - h - tl[c])
                    rhs1[c] += sc
            if use_y:
                y0 = last[0] + slope[0] * (ti - h - tl[0])
                for r in range(4):
                    rhs0[r] += Lt[r] * y0
                    rhs1[r] += Lt[r] * slope[0]
            zn = PHI[hi, j] @ z + G0[hi, j] @ rhs0 + G1[hi, j] @ rhs1
            ok = True
            for r in range(4):
                if not (zn[r] - zn[r] == 0.0):
                    ok = False
            if ok:
                z = zn
            # weights: backward Euler of W' = -(eta1 s s^T + eta2 Z Z^T) W + eta1 s x4 + eta2 Z Lam
            voff = last[3] if last[3] == last[3] else 0.0
            _regressor(kind, _rho(z[0], sat[0]), _rho(z[1] + voff, sat[1]), _rho(z[2], sat[2]), s)
            x4 = _rho(z[3], sat[3])
            M = np.eye(N) + h * (eta1 * np.outer(s, s) + eta2 * (Z @ Z.T))
            b = W + h * (eta1 * s * x4 + eta2 * (Z @ Lam))
            W = np.linalg.solve(M, b)
            if ti - t_rec >= rec_dt - 1e-12:
                t_rec = ti
                if k < p:
                    Z[:, k] = s
                    Lam[k] = x4
                    k += 1
                    smin = _smin(Z)
                else:
                    best = -1.0
                    jbest = -1
                    for jj in range(p):
                        old = Z[:, jj].copy()
                        Z[:, jj] = s
                        sj = _smin(Z)
                        Z[:, jj] = old
                        if sj > best:
                            best = sj
                            jbest = jj
                    if best > smin:
                        Z[:, jbest] = s
                        Lam[jbest] = x4
                        smin = best
        for r in range(4):
            out_z[i, r] = z[r]
        voff = last[3] if last[3] == last[3] else 0.0
        _regressor(kind, _rho(z[0], sat[0]), _rho(z[1] + voff, sat[1]), _rho(z[2], sat[2]), s)
        out_fnn[i] = W @ s
        for r in range(N):
            out_W[i, r] = W[r]
        out_smin[i] = smin


def _chak_rhs(x: np.ndarray, W: np.ndarray, y: float, b2: float, b3: float, voff: float, L0: np.ndarray,
              lw: np.ndarray, use_y: bool, s: np.ndarray, dx: np.ndarray, dW: np.ndarray) -> None:
    _regressor(REG_SIGMOID, x[0], x[1] + voff, x[2], s)
    e = (y - x[0]) if use_y else 0.0
    dx[0] = x[1] + L0[0] * e
    dx[1] = x[2] + b2 + L0[1] * e
    dx[2] = W @ s + b3 + L0[2] * e
    for r in range(W.shape[0]):
        dW[r] = lw[r] * e


def _chak_loop(t: np.ndarray, Y: np.ndarray, L0: np.ndarray, lw: np.ndarray, hmax: float, hold: float,
               x0: np.ndarray, W0: np.ndarray, started0: bool, out_z: np.ndarray, out_W: np.ndarray,
               out_fnn: np.ndarray) -> None:
    """Chakrabarty et al. (3.4) with RK4 sub-steps of at most ``hmax`` [s]; inputs as in ``_cl_loop``."""
    n = t.shape[0]
    N = W0.shape[0]
    x = x0.copy()
    W = W0.copy()
    last = np.full(4, np.nan)
    tl = np.full(4, -np.inf)
    slope = np.zeros(4)
    started = started0
    tprev = t[0]
    s = np.zeros(N)
    k1x, k2x, k3x, k4x = np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3)
    k1w, k2w, k3w, k4w = np.zeros(N), np.zeros(N), np.zeros(N), np.zeros(N)
    for i in range(n):
        ti = t[i]
        for c in range(4):
            v = Y[i, c]
            if v == v:
                dt = ti - tl[c]
                slope[c] = (v - last[c]) / dt if (dt > 0.0 and dt <= hold and last[c] == last[c]) else 0.0
                last[c] = v
                tl[c] = ti
        h = ti - tprev
        tprev = ti
        if not started:
            if last[0] == last[0]:
                x[0] = last[0]
                x[1] = 0.0
                x[2] = 0.0 if last[1] != last[1] else -last[1]
                started = True
        elif h > 0.0:
            use_y = (ti - tl[0]) <= hold
            m = int(math.ceil(h / hmax))
            hs = h / m
            voff = last[3] if last[3] == last[3] else 0.0
            for q in range(m):
                ta = ti - h + q * hs
                vals = np.zeros(3)
                sl = np.zeros(3)
                for c in range(3):
                    if last[c] == last[c]:
                        sc = slope[c] if (c == 0 or ti - tl[c] <= hold) else 0.0
                        vals[c] = last[c] + sc * (ta - tl[c])
                        sl[c] = sc
                _chak_rhs(x, W, vals[0], vals[1], vals[2], voff, L0, lw, use_y, s, k1x, k1w)
                hh = 0.5 * hs
                _chak_rhs(x + hh * k1x, W + hh * k1w, vals[0] + hh * sl[0], vals[1] + hh * sl[1],
                          vals[2] + hh * sl[2], voff, L0, lw, use_y, s, k2x, k2w)
                _chak_rhs(x + hh * k2x, W + hh * k2w, vals[0] + hh * sl[0], vals[1] + hh * sl[1],
                          vals[2] + hh * sl[2], voff, L0, lw, use_y, s, k3x, k3w)
                _chak_rhs(x + hs * k3x, W + hs * k3w, vals[0] + hs * sl[0], vals[1] + hs * sl[1],
                          vals[2] + hs * sl[2], voff, L0, lw, use_y, s, k4x, k4w)
                xn = x + (hs / 6.0) * (k1x + 2.0 * k2x + 2.0 * k3x + k4x)
                Wn = W + (hs / 6.0) * (k1w + 2.0 * k2w + 2.0 * k3w + k4w)
                if np.all(np.isfinite(xn)) and np.all(np.isfinite(Wn)):
                    x, W = xn, Wn
        voff = last[3] if last[3] == last[3] else 0.0
        _regressor(REG_SIGMOID, x[0], x[1] + voff, x[2], s)
        f = W @ s
        out_z[i, 0], out_z[i, 1], out_z[i, 2], out_z[i, 3] = x[0], x[1], x[2], f
        out_fnn[i] = f
        for r in range(N):
            out_W[i, r] = W[r]


_regressor = jit(_regressor)
_rho = jit(_rho)
_smin = jit(_smin)
_cl_loop = jit(_cl_loop)
_chak_rhs = jit(_chak_rhs)
_chak_loop = jit(_chak_loop)


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
        self._track: EstimateTrack | None = None

    def gains(self) -> np.ndarray:
        """``L~ = [L; K]`` (4,) [1/s, 1/s^2, 1/s^3, 1/s^4]."""
        d = self.design()
        return np.array(usable_gains(self.name, d, ("L", "K")))

    def saturation(self) -> np.ndarray:
        return np.full(4, np.inf)

    def _run(self, t: np.ndarray, Y: np.ndarray, z0: np.ndarray | None) -> LearningTrack:
        t = np.ascontiguousarray(t, dtype=float)
        Y = np.ascontiguousarray(Y, dtype=float)
        n = len(t)
        Lt = self.gains()
        hs = np.diff(t) if n > 1 else np.zeros(0)
        key = np.round(hs, 12)
        uniq, inv = np.unique(key, return_inverse=True) if n > 1 else (np.zeros(1), np.zeros(0, dtype=np.int64))
        uniq = np.where(uniq > 0, uniq, 1.0)
        hidx = np.zeros(n, dtype=np.int64)
        hidx[1:] = inv
        PHI = np.empty((len(uniq), 2, 4, 4))
        G0 = np.empty_like(PHI)
        G1 = np.empty_like(PHI)
        Acl = nad.A_EXT - Lt.reshape(4, 1) @ nad.C_EXT
        for q, h in enumerate(uniq):
            for j, A in enumerate((Acl, nad.A_EXT)):
                PHI[q, j], G0[q, j], G1[q, j] = exact_discretisation(A, float(h))
        N = self._W0.size
        out_z, out_W = np.empty((n, 4)), np.empty((n, N))
        out_s, out_f = np.empty(n), np.empty(n)
        z_init = np.zeros(4) if z0 is None else np.asarray(z0, dtype=float)
        _cl_loop(t, Y, hidx, PHI, G0, G1, Lt, self.kind, self.saturation(), self._eta[0], self._eta[1], self._p,
                 self._rec, self._hold, z_init, self._W0.copy(), z0 is not None, out_z, out_W, out_s, out_f)
        return LearningTrack(t, out_z, out_W, out_f, out_s)

    def run_model(self, t: np.ndarray, y: np.ndarray, u: np.ndarray, z0: np.ndarray,
                  bu: float = 1.0 / (nad.M7C["mass_kg"] * nad.M7C["tau_s"])) -> LearningTrack:
        """Design model (3.27): position ``y`` (n,) [m], input ``u`` (n,) [N], start ``z0`` (4,)."""
        Y = np.column_stack([y, np.zeros(len(t)), bu * np.asarray(u, float), np.zeros(len(t))])
        return self._run(np.asarray(t, float), Y, z0)

    # harness interface ------------------------------------------------------------------------
    def reset(self, t0_s: float, x0: Mapping[str, float] | None = None) -> None:
        self._t0 = t0_s
        bad = sorted(set(x0 or {}) - set(self.states))
        if bad:
            raise InputError(f"cannot initialise state {bad[0]!r} (settable: {', '.join(self.states)})",
                             field=f"observer {self.name} x0")
        self._x0 = None if not x0 else np.array([float(x0.get(s, 0.0)) for s in self.states] + [0.0])
        self._hist_t: list[float] = []
        self._hist_y: list[np.ndarray] = []

    def step(self, t_s: float, y: np.ndarray) -> Any:
        """Step-by-step use reruns the compiled loop on the history (the harness calls :meth:`run`)."""
        from roadtruth.observers.base import StepOutput
        self._hist_t.append(float(t_s))
        self._hist_y.append(np.asarray(y, dtype=float))
        tr = self._run(np.array(self._hist_t), self._relative_inputs(np.array(self._hist_y)), self._x0)
        return StepOutput(tr.z[-1, :3].copy())

    @staticmethod
    def _relative_inputs(Y: np.ndarray) -> np.ndarray:
        # columns: range (y), -a_E (row 2 of the relative model), 0 (no known lead input), v_E
        Y = np.asarray(Y, dtype=float).reshape(-1, 3)
        return np.column_stack([Y[:, 0], -Y[:, 2], np.zeros(len(Y)), Y[:, 1]])

    def run(self, t: np.ndarray, Y: np.ndarray, x0: Mapping[str, float] | None = None) -> EstimateTrack:
        self.reset(float(t[0]) if len(t) else 0.0, x0)
        tr = self._run(np.asarray(t, float), self._relative_inputs(Y), self._x0)
        self.last_learning = tr
        return EstimateTrack(self.name, tuple(self.states), np.asarray(t, float), tr.z[:, :3].copy())


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
    default_options = {**_COMMON, "omega": 10.0}

    def _compute_design(self) -> DesignResult:
        return DesignResult.not_applicable(self.variant, "gains of the original LMIs are not in the thesis; "
                                           "poles placed at -omega")

    def gains(self) -> np.ndarray:
        om = float(self.options["omega"])
        if not om > 0:
            raise InputError("bad option: omega must be > 0", field=f"observer {self.name}")
        return nad.chain_poles_gains(om)

    def _run(self, t: np.ndarray, Y: np.ndarray, z0: np.ndarray | None) -> LearningTrack:
        t = np.ascontiguousarray(t, dtype=float)
        Y = np.ascontiguousarray(Y, dtype=float)
        n = len(t)
        g = self.gains()
        # L0 places (A - L0 C) like the first three chain gains; l_w spreads the fourth over the
        # weights so that, at the regressor of the start, the pair (x_hat, W^T s) has the gains of the
        # extended observer with all poles at -omega (the original LMIs of the paper are not given).
        x_start = np.zeros(3) if z0 is None else np.asarray(z0[:3], float)
        s0 = 1.0 / (1.0 + np.exp(-x_start))
        lw = g[3] * s0 / float(s0 @ s0)
        out_z, out_W, out_f = np.empty((n, 4)), np.empty((n, 3)), np.empty(n)
        _chak_loop(t, Y, g[:3].copy(), lw, 0.2 / (4.0 * float(self.options["omega"])), self._hold,
                   x_start, self._W0.copy(), z0 is not None, out_z, out_W, out_f)
        return LearningTrack(t, out_z, out_W, out_f, np.zeros(n))
