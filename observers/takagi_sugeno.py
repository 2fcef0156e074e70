r"""Takagi-Sugeno observer with algebraic (camera) premises (Yacine et al. 2015).

Z. Yacine, D. Ichalal, N. Ait-Oufroukh, S. Mammar, S. Djennoune, "Takagi-Sugeno Observers:
Experimental Application for Vehicle Lateral Dynamics Estimation", IEEE Trans. Control Systems
Technology 23(2):754-761, 2015, doi:10.1109/TCST.2014.2327592.

Model S1 (eqs. (8), (12)-(13)), ``x = (v_y, r, (F_f + F_r)/m, (a_f F_f - a_r F_r)/I_z)`` with tire
relaxation ``tau = r_relax / v_x`` (``r_f = r_r``):

.. math::

    \dot x_1 = -v_x x_2 + x_3,\quad \dot x_2 = x_4,\quad
    \dot x_3 = -\tfrac{v_x}{r} x_3 + \tfrac{v_x}{m r}(F_f^S + F_r^S),\quad
    \dot x_4 = -\tfrac{v_x}{r} x_4 + \tfrac{v_x}{I_z r}(a_f F_f^S - a_r F_r^S),

``F^S = f(alpha) alpha`` in sector form (15)-(19) with the simplified slips (4)
``alpha_f = delta - (v_y + a_f r)/v_x``, ``alpha_r = -(v_y - a_r r)/v_x``; 8 rules (23)-(24).
Observer (31)-(32), typo ``h_i(x_hat)`` corrected to ``h_i(s_e)``:
``x_hat' = sum_i h_i(s_e) (A_i x_hat + B_i delta + L_i (r - x_hat_2))``, gains from Theorem 1
(:mod:`roadtruth.observers.takagi_sugeno_design`). Forces (46):
``F_f = (m a_r x_3 + I_z x_4)/(a_f + a_r)``, ``F_r = (m a_f x_3 - I_z x_4)/(a_f + a_r)``.

Premises (25)-(28), S2 (9): a Levant differentiator (:mod:`roadtruth.observers.levant_differentiator`, order 2
= the paper's "third-order" HOSMD) on each camera channel gives ``y_L'``, ``psi_L'``; then
``v_y,alg = y_L' - v_x psi_L - l_s psi_L'`` (26) feeds the slips of the weights only, and the road
curvature is algebraic (10)-(11): ``rho = (r - psi_L')/v_x`` (typo after (10) corrected).

Corrections implemented (printed equations that do not hold): Pacejka with the factor E (2)/(7); rule weight of
``A_jk`` is ``mu_fj mu_rk`` (the printed (22) swaps ``mu_2``/``mu_3``; option
``rule_order="as_printed"`` reproduces it, and it keeps the certificate — any convex weights do — but
makes the TS model inexact, see the tests); ``rho = (r - psi_L')/v_x``; ``h_i(s_e)`` in (32); the
error bound (34) as in (45). The paper prints no gains, so there is no "as printed" gain variant.

Harness choices (documented options):

* The TS vertices: ``tire_sectors="auto"`` uses the paper's ``M_f1, M_f2, M_r1, M_r2 = 4.2e4, 3.3e4,
  4.9e4, 3.3e4`` N/rad for its own car ``yacine2016`` and, for any other vehicle, the sector bounds
  ``[f_min, f_max]`` of ``f(alpha) = F(alpha)/alpha`` of the vehicle's Magic Formula axle curves
  (``roadtruth.observers.tire_curves.axle_curves`` at friction ``mu``) over ``|alpha| <= slip_max_rad``;
  ``"magic_formula"`` forces the latter, a 4-tuple gives them explicitly. The membership ``f`` of the
  premise is always the vehicle's Magic Formula secant (clipped into the sector).
* ``vx_range_mps`` (default (3, 40); the paper's (0.2, 17) is too low for highway scenarios): the
  measured ``v_x`` is clamped into it inside the model (the certificate then still holds, the model
  is inexact outside). ``relaxation_length_m`` 0.1 (the paper's ``r_f = r_r``).
* Sampling: the camera (e.g. 20 Hz) drives the differentiators at its own rate (irregular steps,
  ``tau`` = time since its previous sample); the observer runs at the runner's rate with an exact
  zero-order-hold step of the frozen closed loop ``exp(Phi h)`` (compiled): the quadratic Lyapunov
  function of Theorem 1 decreases across every step, whatever the step or the premise jumps.
* Camera missing: with no camera sample for ``camera_timeout_s`` the differentiators are reset and
  re-armed at the next sample; the algebraic premise is used only once they have run for
  ``differentiator_settle_s``. Meanwhile the premise falls back to the observer's own ``v_y``
  (``h_i(x_hat)``, the "unmeasured premise" form) and ``rho`` holds its last value (0 at start).
  Variant ``ts_yacine_xhat`` always uses ``h_i(x_hat)``.
* S2 convention (a correction for roadtruth's camera). (5)/(9) ``y_L' = v_y + v_x psi_L + l_s psi_L'``
  holds when ``psi_L`` is the heading relative to the road tangent at the CG (``y_L ~ y_CG + l_s
  psi_L``). roadtruth's camera (like a real one) reports ``psi_L`` relative to the road at the
  look-ahead point, ``psi_L,CG = psi_L + rho l_s``; then exactly ``y_L' = v_x sin psi_L + (v_y + l_s r)
  cos psi_L``, i.e. ``v_y = y_L' - v_x psi_L - l_s r`` (default ``lane_heading_at="lookahead"``,
  which also keeps the differentiated heading out of ``v_y``). The printed form differs by
  ``l_s v_x rho`` (0.08 m/s at 20 m/s on R = 120 m, as large as ``v_y``); ``"cg"`` keeps it.
* Differentiator tuning (``lipschitz_*``): on ``curvy_road`` the RMS error of ``y_L'`` is 0.008 m/s
  at L = 30 with a perfect 100 Hz camera but 0.08 m/s at best (L = 1) with the automotive camera
  (0.05 m offset noise at 20 Hz); ``psi_L'``: 0.0013 rad/s (L = 1-3) vs 0.012 rad/s (L = 0.3). The
  defaults are tuned for the automotive camera.
* The gyro corrects while its latest sample is younger than ``hold_s``; otherwise open loop.
* Compiled: the whole per-sample update (differentiators, premises, step, outputs) is one kernel
  (:mod:`roadtruth.observers.takagi_sugeno_loop`) that ``step()`` calls with one sample and ``run()``
  with the whole log: both give the same bits.
* Forces: ``fy_f_N`` of the truth is the axle force in the tire frame; (1) uses the body-frame force
  ``F_f = fy_f cos(delta) + fx_f sin(delta) ~ fy_f`` (small steer; 0.1 % at 3 deg). The estimate is
  reported as is, under the canonical name.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from roadtruth.harness.errors import InputError
from roadtruth.observers import takagi_sugeno_loop as loop
from roadtruth.observers.algebraic_vy_loop import levant_table
from roadtruth.observers.base import EstimateTrack, ScalarLoopObserver, StepOutput
from roadtruth.observers.levant_differentiator import LAMBDAS
from roadtruth.observers.lmi import DesignFailed, DesignResult, DesignStatus
from roadtruth.observers.registry import register
from roadtruth.observers.takagi_sugeno_design import (
    RULES,
    SEED_STIFFNESS_NPR,
    TSModel,
    sector_bounds,
)
from roadtruth.observers.takagi_sugeno_loop import expm_taylor, rule_weights, ts_step  # noqa: F401 (public)
from roadtruth.observers.tire_curves import axle_curves

# ---- observer ------------------------------------------------------------------------------------

_OPTIONS: dict[str, Any] = {
    "vx_range_mps": (3.0, 40.0),       # speed vertices of the TS model (seed: 0.2, 17)
    "relaxation_length_m": 0.1,        # r_f = r_r (seed Table I)
    "tire_sectors": "auto",            # "auto" | "seed" | "magic_formula" | (M_f1, M_f2, M_r1, M_r2) [N/rad]
    "slip_max_rad": 0.14,              # design slip range for the Magic Formula sectors (seed: 8 deg)
    "mu": 1.0,                         # road friction of the Magic Formula curves
    "decay_alpha": 0.001,              # alpha of Theorem 1 (seed)
    "state_scale": 0.1,                # LMI conditioning: x3, x4 scaled by this (else the solvers are inaccurate)
    "rule_order": "corrected",         # "corrected" | "as_printed" (eq. (22) as printed)
    "lookahead_m": 0.5,                # l_s (seed; roadtruth's default)
    "differentiator_order": 2,         # Levant k (the paper's "third-order" HOSMD)
    "lipschitz_y_lane": 1.0,           # bound on |y_L'''| [m/s^3] (noise/lag trade-off, see docstring)
    "lipschitz_psi_lane": 0.5,         # bound on |psi_L'''| [rad/s^3]
    "lane_heading_at": "lookahead",    # psi_L relative to the road at the look-ahead point | "cg" (as (26))
    "camera_timeout_s": 0.3,           # longer camera silence: reset the differentiators
    "differentiator_settle_s": 0.5,    # differentiator run time before its premise is trusted
    "hold_s": 0.1,                     # correct while the gyro sample is younger than this [s]
    "use_cache": True,
}


def _bad(name: str, value: Any, why: str) -> InputError:
    return InputError(f"option {name} = {value!r}: {why}", field="observer ts_yacine")


@register
class TakagiSugenoYacine(ScalarLoopObserver):
    """Takagi-Sugeno observer (8 rules, Theorem 1) with camera/HOSMD premises and algebraic curvature."""

    name = "ts_yacine"
    citation = ("Z. Yacine et al., IEEE Trans. Control Syst. Technol. 23(2):754-761, 2015, "
                "eqs. (10)-(13), (23)-(33), (46)")
    inputs = ("yaw_rate_radps", "delta_rad", "vx_mps", "y_lane_m", "psi_lane_rad")
    states = ("vy_mps", "yaw_rate_radps", "beta_rad", "fy_f_N", "fy_r_N", "rho_1pm")
    variant = "algebraic_premise"
    default_options = dict(_OPTIONS)
    premise_from_camera = True

    # ---- setup -----------------------------------------------------------------------------------
    def _setup(self) -> None:
        o, v = self.options, self.vehicle
        try:
            vlo, vhi = (float(a) for a in o["vx_range_mps"])
        except (TypeError, ValueError):
            raise _bad("vx_range_mps", o["vx_range_mps"], "needs two numbers") from None
        if not (0.0 < vlo < vhi <= 100.0):
            raise _bad("vx_range_mps", o["vx_range_mps"], "needs 0 < v_min < v_max <= 100 m/s")
        for key, lo, hi in (("relaxation_length_m", 1e-3, 5.0), ("slip_max_rad", 0.01, 0.5),
                            ("decay_alpha", 0.0, 50.0), ("state_scale", 1e-3, 1.0), ("lookahead_m", 0.0, 50.0),
                            ("lipschitz_y_lane", 1e-6, 1e6), ("lipschitz_psi_lane", 1e-6, 1e6),
                            ("camera_timeout_s", 1e-3, 10.0), ("differentiator_settle_s", 0.0, 10.0),
                            ("hold_s", 0.0, 10.0)):
            val = o[key]
            if not (isinstance(val, int | float) and math.isfinite(val) and lo <= val <= hi) or (
                    key == "decay_alpha" and val <= 0.0):
                raise _bad(key, val, f"needs a number in [{lo}, {hi}]")
        if o["rule_order"] not in ("corrected", "as_printed"):
            raise _bad("rule_order", o["rule_order"], "needs 'corrected' or 'as_printed'")
        if o["lane_heading_at"] not in ("lookahead", "cg"):
            raise _bad("lane_heading_at", o["lane_heading_at"], "needs 'lookahead' or 'cg'")
        self._heading_cg = o["lane_heading_at"] == "cg"
        if o["differentiator_order"] not in LAMBDAS:
            raise _bad("differentiator_order", o["differentiator_order"], f"needs one of {sorted(LAMBDAS)}")
        fc, rc = axle_curves(v, o["mu"])
        self._curves = (fc.B, fc.C, fc.E, fc.D, rc.B, rc.C, rc.E, rc.D)
        sectors = o["tire_sectors"]
        if sectors == "auto":
            sectors = "seed" if v.name == "yacine2016" else "magic_formula"
        if sectors == "seed":
            mf1, mf2, mr1, mr2 = SEED_STIFFNESS_NPR
        elif sectors == "magic_formula":
            mf2, mf1 = sector_bounds(fc.B, fc.C, fc.E, fc.D, float(o["slip_max_rad"]))
            mr2, mr1 = sector_bounds(rc.B, rc.C, rc.E, rc.D, float(o["slip_max_rad"]))
        else:
            try:
                mf1, mf2, mr1, mr2 = (float(a) for a in sectors)
            except (TypeError, ValueError):
                raise _bad("tire_sectors", sectors, "needs 'auto', 'seed', 'magic_formula' or 4 numbers") from None
            if not (0.0 < mf2 < mf1 and 0.0 < mr2 < mr1):
                raise _bad("tire_sectors", sectors, "needs 0 < M_f2 < M_f1 and 0 < M_r2 < M_r1")
        self.sector_source = sectors if isinstance(sectors, str) else "explicit"
        self.ts_model = TSModel(v.mass_kg, v.yaw_inertia_kgm2, v.lf_m, v.lr_m, float(o["relaxation_length_m"]),
                                (mf1, mf2), (mr1, mr2), (vlo, vhi))
        self._Av = np.array([self.ts_model.vertex(i)[0] for i in range(len(RULES))])
        self._Bv = np.array([self.ts_model.vertex(i)[1] for i in range(len(RULES))])
        self._Lv: np.ndarray | None = None
        self._w = np.zeros(len(RULES))
        self._x = np.zeros(4)
        self._printed = o["rule_order"] == "as_printed"
        # the kernel's constants (roadtruth.observers.takagi_sugeno_loop)
        tm = self.ts_model
        self._par = np.array([vlo, vhi, tm.af_m, tm.ar_m, tm.mf_Npr[0], tm.mf_Npr[1], tm.mr_Npr[0], tm.mr_Npr[1],
                              tm.mass_kg, tm.yaw_inertia_kgm2, float(o["lookahead_m"]), float(o["camera_timeout_s"]),
                              float(o["differentiator_settle_s"]), float(o["hold_s"]), float(self._heading_cg),
                              float(self._printed), float(self.premise_from_camera)])
        assert self._par.shape == (loop.N_PAR,)
        self._kcurves = np.array(self._curves, dtype=float)

    def _compute_design(self) -> DesignResult:
        from roadtruth.observers.takagi_sugeno_design import design_for
        result = design_for(self.design_request(self.ts_model))
        # Load/compile the kernel now, so the first estimation step is not charged with the JIT.
        k = int(self.options["differentiator_order"])
        loop.ts_run(np.empty(0), np.empty((0, 5)), np.zeros(5), np.zeros(4), np.zeros(7), np.zeros(k + 3),
                    np.zeros(k + 3), self._lev_table(), self._par, self._kcurves, self._Av, self._Bv,
                    np.zeros((len(RULES), 4)), np.zeros(len(RULES)), np.empty((0, 6)))
        return result

    def gains(self) -> np.ndarray:
        """(8, 4) vertex gains ``L_i``; raises :class:`DesignFailed` without usable gains."""
        if self._Lv is None:
            d = self.design()
            if d.status not in (DesignStatus.CERTIFIED, DesignStatus.REJECTED) or "L" not in d.gains:
                raise DesignFailed(f"{self.name}: design {d.status.value}: {d.reason}")
            self._Lv = np.ascontiguousarray(d.gain("L"), dtype=float)
        return self._Lv

    # ---- state -----------------------------------------------------------------------------------
    def _initial_state(self) -> list[float]:
        return [0.0, 0.0, 0.0, 0.0]  # x_hat(0) = 0 (seed section IV)

    def _internal_from_x0(self, z: list[float], x0: Any) -> list[float]:
        names = ("vy_mps", "yaw_rate_radps")
        for key, value in x0.items():
            if key not in names:
                raise InputError(f"cannot initialise state {key!r} (settable: {', '.join(names)})",
                                 field=f"observer {self.name} x0")
            z[names.index(key)] = float(value)
        return z

    def _lev_table(self) -> np.ndarray:
        o = self.options
        return levant_table(int(o["differentiator_order"]), float(o["lipschitz_y_lane"]), float(o["lipschitz_psi_lane"]))

    def _reset_extra(self) -> None:
        k = int(self.options["differentiator_order"])
        self._lev = self._lev_table()
        self._x = np.array(self._z, dtype=float)
        self._ku = np.full(5, math.nan)            # held (r, delta, v_x, y_L, psi_L)
        # (t_cur, t_cam, t_cam_start, v_y_alg, rho, premise_is_camera, t_gyro); see takagi_sugeno_loop
        self._ks = np.array([self._t, -math.inf, math.inf, math.nan, 0.0, 0.0, -math.inf])
        self._kdy, self._kdp = np.zeros(k + 3), np.zeros(k + 3)   # differentiators of y_L, psi_L
        self._last = self._outputs_now()

    def _outputs_now(self) -> np.ndarray:
        """The outputs of the current state, as the kernel writes them (before the first sample)."""
        x = self._x
        m, iz = self.ts_model.mass_kg, self.ts_model.yaw_inertia_kgm2
        af, ar = self.ts_model.af_m, self.ts_model.ar_m
        vx = self._ku[2]
        beta = math.atan2(x[0], vx) if vx == vx and vx > 0.1 else 0.0
        return np.array([x[0], x[1], beta, (m * ar * x[2] + iz * x[3]) / (af + ar),
                         (m * af * x[2] - iz * x[3]) / (af + ar), self._ks[4]])

    @property
    def premise_source(self) -> str:
        """Where the rule weights of the latest step came from: ``"camera"`` or ``"observer"``."""
        return "camera" if self._ks[5] != 0.0 else "observer"

    def premise_ready(self, t_s: float) -> bool:
        """The camera premise is usable: differentiators settled and the camera not silent."""
        o = self.options
        return bool(t_s - self._ks[2] >= o["differentiator_settle_s"] and t_s - self._ks[1] <= o["camera_timeout_s"])

    def _compiled(self, t: np.ndarray, Y: np.ndarray) -> np.ndarray:
        """Advance through ``t`` (n,) [s], ``Y`` (n, 5) in the shared kernel; outputs (n, 6)."""
        Lv = self._Lv if self._Lv is not None else self.gains()   # a failed design raises here
        out = np.empty((t.shape[0], 6))
        loop.ts_run(t, Y, self._ku, self._x, self._ks, self._kdy, self._kdp, self._lev, self._par, self._kcurves,
                    self._Av, self._Bv, Lv, self._w, out)
        if t.shape[0]:
            self._last = out[-1].copy()
        self._t = float(self._ks[0])
        self._z = self._x.tolist()
        return out

    def step(self, t_s: float, y: np.ndarray) -> StepOutput:
        """One sample through the compiled kernel (the same code ``run()`` loops in, so the same bits)."""
        out = self._compiled(np.array([float(t_s)]),
                             np.ascontiguousarray(np.asarray(y, dtype=float).reshape(1, 5)))
        return StepOutput(out[0])

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


@register
class TakagiSugenoYacineXhat(TakagiSugenoYacine):
    """Yacine et al. (2015) TS observer with unmeasured premises h_i(x_hat) (no camera in the weights)."""

    name = "ts_yacine_xhat"
    citation = ("Z. Yacine et al., IEEE Trans. Control Syst. Technol. 23(2):754-761, 2015, "
                "eqs. (31)-(33) with premises from the estimate")
    variant = "observer_premise"
    premise_from_camera = False
