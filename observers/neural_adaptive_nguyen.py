r"""Neural adaptive observer of Nguyen, ch. 1, Sections 5-6 ((1.37)-(1.51)), trained online on the UIO.

Q. H. Nguyen, PhD thesis draft (Université de Lorraine, CRAN), ch. 1. Observer (1.37)/(1.62), forward
Euler (1.43)/(1.63) at ``dt_s`` (sub-steps of the runner's step):

.. math::

    \hat x_{k+1} = \hat x_k + \Delta t\big(A(\rho)\hat x_k + B_u u + B_\mu\mu_\theta(\hat x_k, \delta)
    + L_{NN}(y - C\hat x_k)\big),

``L_NN`` from Theorem 2 with the disk constraint (:mod:`roadtruth.observers.neural_adaptive_nguyen_design`).
``mu_theta``: a 4-32-32-2 tanh MLP (1282 parameters, last layer initialised x0.01) of the features
``((v_x - 15)/10, v_y, r/0.5, delta/0.1)`` (heading dropped: forces do not depend on it), output in kN.
The teacher is the regularised UIO (``uio_nguyen``) run on the same inputs: loss (1.42) with
``T_ref = 0`` (no reference trajectory in estimation), ``T_y = diag(1, 100, 100)``,
``T_uio = diag(1, 10, 0, 10)`` (psi weight 0: the two observers re-centre their heading at different
instants) and ``lambda_teacher = 1``. Gradient (1.45)-(1.47) with forward sensitivities
``S = d x_hat / d theta`` (1.48)-(1.50), the same Euler step as the state; Adam (lr ``learning_rate``)
on the gradient accumulated over ``accumulate`` steps ("loss accumulation", sec. 7.3.1; ``S`` reset
at each window start), or every step with a running ``S`` (``accumulate = 1``). Gradient norm
clipped at ``clip`` (Remark 4). Learning is frozen while ``v_x`` or ``r`` is missing.

Variant ``nao_nguyen_ensemble`` (Section 6, (1.51)): a queue of ``queue_size`` parameter snapshots,
one per Adam step; the prediction is ``sum_q w_q mu_q / sum_q w_q`` with ``w_q = exp(-age_q)`` (the
printed ``e^(i+1-p)`` grows without bound, read as a recency weight); only the newest network is
trained and used in the sensitivity.

``run()`` (what the harness calls) is the compiled whole-run loop of
:mod:`roadtruth.observers.neural_adaptive_nguyen_loop`, teacher included, equal bit for bit to stepping
``step()``, which stays the plain-Python reference (``ScalarLoopObserver.run(obs, t, Y)`` runs it over
a whole run).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from typing import Any

import numpy as np

from roadtruth.harness.errors import InputError
from roadtruth.harness.truth.tire import jit
from roadtruth.observers.base import EstimateTrack, ScalarLoopObserver
from roadtruth.observers.lmi import DesignResult, usable_gains
from roadtruth.observers.registry import register
from roadtruth.observers.uio_nguyen import TWO_PI, NguyenUIO
from roadtruth.observers.uio_nguyen_design import N_MU, N_X, vehicle_model

HIDDEN = 32
N_IN = 4
SIZES = (HIDDEN * N_IN, HIDDEN, HIDDEN * HIDDEN, HIDDEN, N_MU * HIDDEN, N_MU)
N_THETA = sum(SIZES)
FEATURE_SCALE = np.array([0.1, 1.0, 0.0, 2.0])  # d features / d x_hat (v_x, v_y, psi, r)


def init_theta(seed: int) -> np.ndarray:
    """Glorot-uniform weights, zero biases, last layer x0.01: (1282,) array."""
    rng = np.random.default_rng(seed)
    parts = []
    for fan_in, fan_out, scale in ((N_IN, HIDDEN, 1.0), (HIDDEN, HIDDEN, 1.0), (HIDDEN, N_MU, 0.01)):
        lim = math.sqrt(6.0 / (fan_in + fan_out))
        parts += [scale * rng.uniform(-lim, lim, fan_in * fan_out), np.zeros(fan_out)]
    return np.concatenate(parts)


@jit
def mlp(theta: np.ndarray, x: np.ndarray, delta: float, mu: np.ndarray, Jth: np.ndarray, Jx: np.ndarray,
        grads: bool) -> None:
    """``mu = mu_theta(x, delta)`` (2,) and, if ``grads``, ``Jth = d mu / d theta`` (2, 1282), ``Jx`` (2, 4)."""
    H = 32
    o1 = 0
    o2 = o1 + H * 4
    o3 = o2 + H
    o4 = o3 + H * H
    o5 = o4 + H
    o6 = o5 + 2 * H
    s = np.empty(4)
    s[0] = (x[0] - 15.0) * 0.1
    s[1] = x[1]
    s[2] = x[3] * 2.0
    s[3] = delta * 10.0
    h1 = np.empty(H)
    h2 = np.empty(H)
    for i in range(H):
        z = theta[o2 + i]
        for j in range(4):
            z += theta[o1 + i * 4 + j] * s[j]
        h1[i] = math.tanh(z)
    for i in range(H):
        z = theta[o4 + i]
        for j in range(H):
            z += theta[o3 + i * H + j] * h1[j]
        h2[i] = math.tanh(z)
    for o in range(2):
        z = theta[o6 + o]
        for j in range(H):
            z += theta[o5 + o * H + j] * h2[j]
        mu[o] = z
    if not grads:
        return
    Jth[:, :] = 0.0
    g2 = np.empty(H)
    g1 = np.empty(H)
    for o in range(2):
        for j in range(H):
            Jth[o, o5 + o * H + j] = h2[j]
        Jth[o, o6 + o] = 1.0
        for i in range(H):
            g2[i] = theta[o5 + o * H + i] * (1.0 - h2[i] * h2[i])
            Jth[o, o4 + i] = g2[i]
            for j in range(H):
                Jth[o, o3 + i * H + j] = g2[i] * h1[j]
        for j in range(H):
            acc = 0.0
            for i in range(H):
                acc += theta[o3 + i * H + j] * g2[i]
            g1[j] = acc * (1.0 - h1[j] * h1[j])
            Jth[o, o2 + j] = g1[j]
            for k in range(4):
                Jth[o, o1 + j * 4 + k] = g1[j] * s[k]
        ds = np.zeros(4)
        for j in range(H):
            for k in range(4):
                ds[k] += theta[o1 + j * 4 + k] * g1[j]
        Jx[o, 0] = ds[0] * 0.1
        Jx[o, 1] = ds[1]
        Jx[o, 2] = 0.0
        Jx[o, 3] = ds[2] * 2.0


@jit
def nao_step(x: np.ndarray, S: np.ndarray, g: np.ndarray, theta: np.ndarray, A: np.ndarray, Bu: np.ndarray,
             Bmu: np.ndarray, L: np.ndarray, y: np.ndarray, u: np.ndarray, x_t: np.ndarray, mu_t: np.ndarray,
             Ty: np.ndarray, Tu: np.ndarray, lam: float, dt: float, learn: bool, mu_out: np.ndarray,
             Jth: np.ndarray, Jx: np.ndarray) -> float:
    """One Euler step (1.63) of state ``x`` (4,) and sensitivity ``S`` (4, n_theta); accumulates the
    gradient of loss (1.42) into ``g`` (n_theta,) when ``learn``. Returns the loss at the step start.
    ``mu_out`` receives the network output used; the caller may overwrite it (ensemble) before."""
    mlp(theta, x, u[1], mu_out, Jth, Jx, learn)
    # residuals
    ey = np.empty(3)
    ey[0] = y[0] - x[0]
    ey[1] = y[1] - x[2]
    ey[2] = y[2] - x[3]
    loss = 0.0
    for i in range(3):
        loss += Ty[i] * ey[i] * ey[i]
    for i in range(4):
        d = x[i] - x_t[i]
        loss += Tu[i] * d * d
    for o in range(2):
        d = mu_out[o] - mu_t[o]
        loss += lam * d * d
    n = theta.shape[0]
    if learn:
        dLdx = np.empty(4)
        for i in range(4):
            dLdx[i] = 2.0 * Tu[i] * (x[i] - x_t[i])
        dLdx[0] -= 2.0 * Ty[0] * ey[0]
        dLdx[2] -= 2.0 * Ty[1] * ey[1]
        dLdx[3] -= 2.0 * Ty[2] * ey[2]
        dLdmu = np.empty(2)
        for o in range(2):
            dLdmu[o] = 2.0 * lam * (mu_out[o] - mu_t[o])
        # effective d L / d x including the network's dependence on x: dLdx + dLdmu Jx
        ex = np.empty(4)
        for i in range(4):
            ex[i] = dLdx[i] + dLdmu[0] * Jx[0, i] + dLdmu[1] * Jx[1, i]
        for k in range(n):
            gk = dLdmu[0] * Jth[0, k] + dLdmu[1] * Jth[1, k]
            for i in range(4):
                gk += ex[i] * S[i, k]
            g[k] += gk
        # S <- S + dt ((A + Bmu Jx - L C) S + Bmu Jth)
        Acl = A.copy()
        for i in range(4):
            for j in range(4):
                Acl[i, j] += Bmu[i, 0] * Jx[0, j] + Bmu[i, 1] * Jx[1, j]
            Acl[i, 0] -= L[i, 0]
            Acl[i, 2] -= L[i, 1]
            Acl[i, 3] -= L[i, 2]
        col = np.empty(4)
        for k in range(n):
            for i in range(4):
                s = Bmu[i, 0] * Jth[0, k] + Bmu[i, 1] * Jth[1, k]
                for j in range(4):
                    s += Acl[i, j] * S[j, k]
                col[i] = s
            for i in range(4):
                S[i, k] += dt * col[i]
    dx = np.empty(4)
    for i in range(4):
        s = Bu[i, 0] * u[0] + Bu[i, 1] * u[1] + Bmu[i, 0] * mu_out[0] + Bmu[i, 1] * mu_out[1]
        for j in range(4):
            s += A[i, j] * x[j]
        s += L[i, 0] * ey[0] + L[i, 1] * ey[1] + L[i, 2] * ey[2]
        dx[i] = s
    for i in range(4):
        x[i] += dt * dx[i]
    return loss


@jit
def adam_step(theta: np.ndarray, g: np.ndarray, m: np.ndarray, v: np.ndarray, t: int, lr: float, clip: float,
              scale: float) -> None:
    """Adam (beta = 0.9, 0.999) on ``g * scale`` clipped to norm ``clip``; ``t`` is the 1-based step."""
    n = theta.shape[0]
    nrm = 0.0
    for k in range(n):
        nrm += (g[k] * scale) ** 2
    nrm = math.sqrt(nrm)
    c = scale * (clip / nrm if nrm > clip else 1.0)
    b1, b2 = 0.9, 0.999
    for k in range(n):
        gk = g[k] * c
        m[k] = b1 * m[k] + (1 - b1) * gk
        v[k] = b2 * v[k] + (1 - b2) * gk * gk
        mh = m[k] / (1 - b1 ** t)
        vh = v[k] / (1 - b2 ** t)
        theta[k] -= lr * mh / (math.sqrt(vh) + 1e-8)


@register
class NeuralAdaptiveNguyen(ScalarLoopObserver):
    """Neural adaptive observer (Nguyen, Theorem 2, loss (1.42), sensitivity gradient + Adam), UIO teacher."""

    name = "nao_nguyen"
    citation = ("Q. H. Nguyen, PhD thesis draft, Univ. de Lorraine (CRAN), ch. 1, Sections 5-6, eqs. (1.37)-(1.50), "
                "(1.62)-(1.65); +I of (1.41) corrected, disk constraint for the Euler step added")
    inputs = ("vx_mps", "yaw_rate_radps", "ax_mps2", "delta_rad")
    states = ("vy_mps", "yaw_rate_radps", "beta_rad")
    variant = "accumulated"
    default_options: Mapping[str, Any] = {
        "dt_s": 0.01,                 # Euler step of (1.43) (sub-steps of the runner's step)
        "disk_radius": 0.95,          # Euler spectral radius bound (0.8 is infeasible on the sedan at 10 ms)
        "vx_range_mps": (5.0, 30.0),
        "grid_points": 101,
        "accumulate": 50,             # K of (1.44): steps per Adam update (1 = every step, running S)
        "learning_rate": 3e-3,
        "clip": 10.0,
        "teacher_weight": 1.0,        # lambda of (1.42)
        "queue_size": 0,              # > 0: ensemble queue of (1.51)
        "seed": 0,                    # network initialisation
        "hold_s": 0.1,
        "use_cache": True,
    }

    def _setup(self) -> None:
        o = self.options
        try:
            dt, K, lr, clip = float(o["dt_s"]), int(o["accumulate"]), float(o["learning_rate"]), float(o["clip"])
            p, lam = int(o["queue_size"]), float(o["teacher_weight"])
            lo, hi = (float(x) for x in o["vx_range_mps"])
        except (TypeError, ValueError) as exc:
            raise InputError(f"bad option value ({exc})", field=f"observer {self.name}") from exc
        if not (0.0 < dt <= 0.05) or K < 1 or lr <= 0 or clip <= 0 or p < 0 or lam < 0 or not (0 < lo < hi):
            raise InputError("bad options: need 0 < dt_s <= 0.05, accumulate >= 1, learning_rate > 0, clip > 0, "
                             "queue_size >= 0, teacher_weight >= 0", field=f"observer {self.name}")
        self._dt, self._K, self._lr, self._clip, self._p, self._lam = dt, K, lr, clip, p, lam
        self._vlo, self._vhi = lo, hi
        self._model = vehicle_model(self.vehicle)
        self._teacher = NguyenUIO(self.vehicle, vx_range_mps=(lo, hi), use_cache=bool(o["use_cache"]))
        self._L: np.ndarray | None = None
        self._Ty = np.array([1.0, 100.0, 100.0])
        self._Tu = np.array([1.0, 10.0, 0.0, 10.0])

    def _compute_design(self) -> DesignResult:
        from roadtruth.observers.neural_adaptive_nguyen_design import design_for
        self._teacher.design()
        return design_for(self.design_request())

    def _initial_state(self) -> list[float]:
        return [0.0, 0.0]

    def _internal_from_x0(self, z: list[float], x0: Mapping[str, float]) -> list[float]:
        for key, value in x0.items():
            if key not in ("vy_mps", "yaw_rate_radps"):
                raise InputError(f"cannot initialise state {key!r} (settable: vy_mps, yaw_rate_radps)",
                                 field=f"observer {self.name} x0")
            z[("vy_mps", "yaw_rate_radps").index(key)] = float(value)
        return z

    def _gain(self) -> np.ndarray:
        # Fetched on the first step, not at construction: creating the observer (to check a user's
        # options) must not solve its LMI, and a failed design then fails only this observer's run.
        if self._L is None:
            self._L = np.array(usable_gains(self.name, self.design(), ["L"])).reshape(N_X, 3)
        return self._L

    def _reset_extra(self) -> None:
        self._x = np.array([0.0, self._z[0], 0.0, self._z[1]])
        self._theta = init_theta(int(self.options["seed"]))
        self._S = np.zeros((N_X, N_THETA))
        self._g = np.zeros(N_THETA)
        self._m = np.zeros(N_THETA)
        self._v = np.zeros(N_THETA)
        self._adam_t = 0
        self._k = 0
        self._mu = np.zeros(N_MU)
        self._Jth = np.zeros((N_MU, N_THETA))
        self._Jx = np.zeros((N_MU, N_X))
        self._queue: deque[np.ndarray] = deque(maxlen=max(1, self._p))
        self._psi_m = 0.0
        self._r_prev, self._t_r_prev = math.nan, math.nan
        self._started = False
        self.loss_trace: list[float] = []
        self._teacher.reset(self._t, {"vy_mps": self._z[0], "yaw_rate_radps": self._z[1]})

    def run(self, t: np.ndarray, Y: np.ndarray, x0: Mapping[str, float] | None = None) -> EstimateTrack:
        """Compiled loop (:mod:`roadtruth.observers.neural_adaptive_nguyen_loop`), equal to stepping :meth:`step`.

        Without usable gains (a failed design) the run steps in Python, so that it fails exactly where
        stepping fails: at the first step that needs the gains.
        """
        from roadtruth.observers.neural_adaptive_nguyen_loop import run_compiled
        track = run_compiled(self, t, Y, x0)
        return track if track is not None else super().run(t, Y, x0)

    def _ensemble_mu(self, x: np.ndarray, delta: float) -> np.ndarray:
        out = np.zeros(N_MU)
        wsum = 0.0
        mu = np.zeros(N_MU)
        for age, th in enumerate(reversed(self._queue)):
            mlp(th, x, delta, mu, self._Jth, self._Jx, False)
            w = math.exp(-age)
            out += w * mu
            wsum += w
        return out / wsum

    def _advance(self, t_s: float, y: list[float]) -> None:
        self._teacher.step(t_s, np.asarray(y, dtype=float))
        h = self._tick(t_s, y)
        vx, r, ax, delta = self._u
        if not self._started:
            if vx != vx:
                return
            self._x[0] = vx
            self._started = True
        if self._fresh[1]:
            if self._r_prev == self._r_prev:
                self._psi_m += 0.5 * (t_s - self._t_r_prev) * (self._r_prev + r)
            self._r_prev, self._t_r_prev = r, t_s
        if self._psi_m > math.pi or self._psi_m < -math.pi:
            c = TWO_PI * round(self._psi_m / TWO_PI)
            self._psi_m -= c
            self._x[2] -= c
        if h <= 0.0:
            return
        tl = self._t_last
        live = r == r and vx == vx and t_s - min(tl[0], tl[1]) <= self.options["hold_s"]
        v = min(max(vx if vx == vx else self._x[0], self._vlo), self._vhi)
        A = self._model.A(v)
        L = self._gain() if live else np.zeros((N_X, 3))
        zt = self._teacher.zeta_hat()
        yv = np.array([vx if vx == vx else self._x[0], self._psi_m, r if r == r else self._x[3]])
        u = np.array([ax if ax == ax else 0.0, delta if delta == delta else 0.0])
        n = max(1, math.ceil(h / self._dt - 1e-9))
        dt = h / n
        for _ in range(n):
            if self._p > 0 and self._queue:
                # ensemble prediction in the state update; the newest network's gradient in S
                mu_e = self._ensemble_mu(self._x, u[1])
                loss = nao_step(self._x, self._S, self._g, self._theta, A, self._model.Bu, self._model.Bmu, L, yv, u,
                                zt[:4], zt[4:], self._Ty, self._Tu, self._lam, dt, live, self._mu, self._Jth, self._Jx)
                # replace the newest network's mu in the state update by the ensemble's
                self._x += dt * self._model.Bmu @ (mu_e - self._mu)
                self._mu = mu_e
            else:
                loss = nao_step(self._x, self._S, self._g, self._theta, A, self._model.Bu, self._model.Bmu, L, yv, u,
                                zt[:4], zt[4:], self._Ty, self._Tu, self._lam, dt, live, self._mu, self._Jth, self._Jx)
            if not live:
                continue
            self.loss_trace.append(loss)
            self._k += 1
            if self._k >= self._K:
                self._adam_t += 1
                adam_step(self._theta, self._g, self._m, self._v, self._adam_t, self._lr, self._clip, 1.0 / self._k)
                self._g[:] = 0.0
                self._k = 0
                if self._K > 1:
                    self._S[:] = 0.0  # truncated forward sensitivity per window
                if self._p > 0:
                    self._queue.append(self._theta.copy())

    def _values(self) -> list[float]:
        x = self._x
        vx = self._u[0]
        v = vx if vx == vx else float(x[0])
        return [float(x[1]), float(x[3]), math.atan2(float(x[1]), v) if v > 0.0 else 0.0]

    def unknown_input_N(self) -> np.ndarray:
        """Current learned ``mu_theta = (f_yf, f_yr)`` [N] (non-scored extra)."""
        return 1000.0 * self._mu

    def teacher(self) -> NguyenUIO:
        """The UIO whose estimate supervises the network."""
        return self._teacher


@register
class NeuralAdaptiveNguyenStepwise(NeuralAdaptiveNguyen):
    """Neural adaptive observer without loss accumulation (Adam every step, running sensitivity)."""

    name = "nao_nguyen_stepwise"
    citation = NeuralAdaptiveNguyen.citation + "; no loss accumulation"
    variant = "stepwise"
    default_options: Mapping[str, Any] = {**NeuralAdaptiveNguyen.default_options, "accumulate": 1}


@register
class NeuralAdaptiveNguyenEnsemble(NeuralAdaptiveNguyen):
    """Neural adaptive observer with the continuous-learning queue of (1.51) (5 snapshots, recency weights)."""

    name = "nao_nguyen_ensemble"
    citation = NeuralAdaptiveNguyen.citation + "; queue ensemble (1.51)"
    variant = "ensemble"
    default_options: Mapping[str, Any] = {**NeuralAdaptiveNguyen.default_options, "queue_size": 5}
