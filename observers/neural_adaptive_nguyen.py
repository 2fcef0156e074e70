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

*Compiled.* ``step()`` and ``run()`` call the same numba kernel
(:mod:`roadtruth.observers.neural_adaptive_nguyen_loop`, teacher included) with one sample or the
whole log, on state arrays carried between calls, so they agree bit for bit.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from roadtruth.harness.errors import InputError
from roadtruth.observers.base import EstimateTrack, ScalarLoopObserver, StepOutput
from roadtruth.observers.lmi import DesignFailed, DesignResult, usable_gains
from roadtruth.observers.neural_adaptive_nguyen_loop import N_PAR, N_STATE, nao_run
from roadtruth.observers.registry import register
from roadtruth.observers.uio_nguyen import NguyenUIO
from roadtruth.observers.uio_nguyen_design import N_MU, N_X, vehicle_model
from roadtruth.observers.uio_nguyen_loop import T_CUR

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
        self._kconst: tuple[np.ndarray, ...] | None = None   # the kernel's constants, built at the first step
        self._t1, self._y1 = np.zeros(1), np.zeros((1, N_IN))

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
        # Everything the kernel carries between calls (roadtruth.observers.neural_adaptive_nguyen_loop).
        self._x = np.array([0.0, self._z[0], 0.0, self._z[1]])   # (v_x, v_y, psi, r)
        self._theta = init_theta(int(self.options["seed"]))
        self._S = np.zeros((N_X, N_THETA))     # d x_hat / d theta
        self._g = np.zeros(N_THETA)            # accumulated loss gradient
        self._m = np.zeros(N_THETA)            # Adam moments
        self._v = np.zeros(N_THETA)
        self._mu = np.zeros(N_MU)              # mu_theta used in the last sub-step [kN]
        self._ring = np.zeros((max(1, self._p), N_THETA))   # ensemble snapshots (ring buffer)
        self._kstate = np.zeros(N_STATE)       # (psi_m, r_prev, t_r_prev, started, adam_t, k, count, head, -)
        self._kstate[1:3] = math.nan
        self._klatch = np.array([self._t])     # t_cur [s]
        self._ku = np.full(N_IN, math.nan)     # held (v_x, r, a_x, delta) and their arrival times [s]
        self._kfresh = np.zeros(N_IN, dtype=np.bool_)
        self._ktl = np.full(N_IN, -math.inf)
        self.loss_trace: list[float] = []
        self._out = np.array([self._z[0], self._z[1], 0.0])   # last estimates (vy, r, beta)
        # the teacher's own state arrays, advanced in place by the kernel (its latch is this observer's)
        self._teacher.reset(self._t, {"vy_mps": self._z[0], "yaw_rate_radps": self._z[1]})

    def _constants(self) -> tuple[np.ndarray, ...]:
        """The kernel's constant arrays; raises DesignFailed if the teacher's design has no gains."""
        if self._kconst is None:
            teacher = self._teacher
            Fs, Gs, Qz, Ms, Gp, bounds = teacher.constants()
            try:
                L, has_gain = np.ascontiguousarray(self._gain(), dtype=float), 1.0
            except DesignFailed:
                # fail only at the first step that needs the gain (the kernel stops there)
                L, has_gain = np.zeros((N_X, 3)), 0.0
            mdl = self._model
            cap = max(1, self._p)
            self._kconst = (
                np.ascontiguousarray(np.array([mdl.A0, mdl.A1, mdl.A2], dtype=float)),
                np.ascontiguousarray(mdl.Bu, dtype=float), np.ascontiguousarray(mdl.Bmu, dtype=float), L,
                self._Ty, self._Tu, np.array([math.exp(-age) for age in range(cap)]),
                np.array([self._dt, self._K, self._lr, self._clip, self._p, self._lam, self._vlo, self._vhi,
                          float(self.options["hold_s"]), has_gain]),
                Fs, Gs, Qz, Ms, Gp, bounds,
                np.array([teacher._vlo, teacher._vhi, teacher._hold, teacher._d2]))
            assert self._kconst[7].shape == (N_PAR,)
        return self._kconst

    def _compiled(self, t: np.ndarray, Y: np.ndarray) -> np.ndarray:
        """Advance through ``t`` (n,) [s], ``Y`` (n, 4) in the shared kernel; the (n, 3) estimates."""
        model, Bu, Bmu, L, Ty, Tu, weights, par, Fs, Gs, Qz, Ms, Gp, bounds, tpar = self._constants()
        if t is not self._t1:
            # writeable C arrays: numba compiles a second copy of the kernel for read-only ones
            t, Y = (np.require(a, dtype=float, requirements=("C", "W")) for a in (t, Y))
        te = self._teacher
        X, losses = nao_run(t, Y, self._klatch, self._ku, self._kfresh, self._ktl, self._x, self._theta, self._S,
                            self._g, self._m, self._v, self._mu, self._ring, self._kstate, model, Bu, Bmu, L, Ty, Tu,
                            weights, par, te._eta, te._zeta, te._w_prev, te._u_prev, te._ks, Fs, Gs, Qz, Ms, Gp,
                            bounds, tpar)
        if losses.shape[0]:
            self.loss_trace.extend(losses.tolist())
        if self._kstate[8]:
            self._gain()   # a step needed the gain of a failed design: raises DesignFailed
        self._t = float(self._klatch[0])
        if len(t):
            self._out = X[-1].copy()
        return X

    def step(self, t_s: float, y: np.ndarray) -> StepOutput:
        """One sample through the compiled kernel (the code ``run()`` loops in, so the same bits)."""
        t1, y1 = self._t1, self._y1   # writeable one-row buffers (one compiled specialisation)
        t1[0] = t_s
        y1[0] = y
        return StepOutput(self._compiled(t1, y1)[0])

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
        return self._out.tolist()

    def ensemble_queue(self) -> list[np.ndarray]:
        """Copies of the ensemble's parameter snapshots (1.51), oldest first (empty without a queue)."""
        if self._p == 0:
            return []
        count, head, cap = int(self._kstate[6]), int(self._kstate[7]), self._ring.shape[0]
        return [self._ring[(head - count + i) % cap].copy() for i in range(count)]

    @property
    def adam_steps(self) -> int:
        """Number of Adam updates of the network so far."""
        return int(self._kstate[4])

    def unknown_input_N(self) -> np.ndarray:
        """Current learned ``mu_theta = (f_yf, f_yr)`` [N] (non-scored extra)."""
        return 1000.0 * self._mu

    def teacher(self) -> NguyenUIO:
        """The UIO whose estimate supervises the network, at this observer's state (it shares the samples).

        The kernel advances the teacher's own state arrays; its latch and last estimate are copied in
        here, so that stepping the returned UIO continues from where this observer is.
        """
        te = self._teacher
        te._ku[:], te._kfresh[:], te._ktl[:] = self._ku, self._kfresh, self._ktl
        te._ks[T_CUR] = te._t = float(self._klatch[0])
        z, vx = te._zeta, self._ku[0]
        v = vx if vx == vx else z[0]
        te._last = np.array([z[1], z[3], math.atan2(z[1], v) if v > 0.0 else 0.0])
        return te


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
