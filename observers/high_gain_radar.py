r"""Radar relative longitudinal high-gain observers (H. Bessafa, PhD thesis 2024, ch. 4-5).

H. Bessafa, "Advanced Estimation Algorithms for Connected and Autonomous Vehicle Applications", PhD
thesis, Université de Lorraine (CRAN), 2024, HAL tel-04744305: Thm 4.3.1 (standard HGO, SHGO),
Thm 4.3.2 (Method 1: range-rate gain of bounded norm), Thm 4.3.3 (Method 2: range-rate gain from the
mean-value vertices of h), Thm 4.3.4 (generalized multi-output HGO), applied in sec. 5.2 (radar
longitudinal tracking). The dynamic-extension observer of Thm 4.4.1 is in :mod:`roadtruth.observers.high_gain_methods`.

Model (M7d: (1.35) for the lead, written relative to the ego car, (5.1)-(5.3)). State
``x = (d, d', a_L)``: range [m], range rate [m/s], lead acceleration [m/s^2]; ego speed ``v_E`` and
acceleration ``a_E`` are known inputs, lead speed ``v_L = d' + v_E``:

.. math::

    \dot x = A x + B f(x) - e_2 a_E,\quad y = C x = d,\quad z = h(x) = x_2 = d',\\
    f = -(2K_d/m) v_L a_L - (1/\tau)(a_L + (K_d/m) v_L^2 + d_m/m)

(the known ``-e_2 a_E`` cancels in the error dynamics). Observer (4.45)-(4.46):
``x_hat' = A x_hat + B f(x_hat) - e_2 a_E + T(theta) K (y - C x_hat) + T(theta) N / theta^3 (z - x_hat_2)``
with ``T(theta) = diag(theta, theta^2, theta^3)``; the SHGO (4.15)-(4.16) is the same with ``N = 0``.
Methods 1 and 2 (4.24) inject ``M (z - x_hat_2)`` with ``M`` given by their designs in state
coordinates: Method 1 ``||M||`` bounded by (4.33), Method 2 ``M = T(theta) P^-1 Z^T`` (corrected).
Gains and certificate: :mod:`roadtruth.observers.high_gain_radar_design` (LMIs (4.20), (4.57), conditions
(4.21), (4.58); decay rate ``kappa`` of (4.60)).

CORRECTIONS implemented (printed statements that do not hold): Thm 4.3.3/4.3.4 print ``M = P^-1 Z^T``; the derivation gives
``M = T(theta) N / theta^n`` with ``N = P^-1 Z^T`` (used here). sec. 5.2.2(a) cites Thm 4.3.2 for the
standard HGO; it is Thm 4.3.1. ``k_f`` is recomputed from the lead box (about 2.0 for the
thesis's lead parameters) rather than taken as printed.

Discretisation: exact integration of the linear part ``A - L C - M e_2^T`` (any theta is stable)
with the inputs as ramps over the step (first-order hold through the last two samples of each
signal: interpolation on the step of a new sample, extrapolation while it is held; the slopes come
from the data, never from the estimates, which would close a loop through the large gains).
``f(x_hat)`` is held over the step, evaluated with ``(v_L, a_L)`` clipped to the design box, so it is
globally Lipschitz with the certified ``k_f``. A zero-order hold (``first_order_hold: false``) leaves
an intra-sample ripple: on the thesis's model at 100 Hz it biases ``a_L`` by ~0.5 d' [m/s^2 per m/s].

Samples and dropouts (NaN = no new sample): a range sample older than ``hold_s`` is not used (the L
term is dropped: the thesis's "position lost"); the same for the range rate and the M term. The
first range sample initialises ``d = range``, ``d' = range rate`` (0 if absent), ``a_L = a_E``.
Before it the observer knows nothing of the lead and reports its placeholder initial state
``(0, 0, 0)`` (it invents nothing; every track has one row per measurement row, and these rows are
scored like any other: with a 50 ms radar latency they are the first five rows at 100 Hz).
``reset(t0, x0)`` with ``x0`` (``range_m``, ``range_rate_mps``, ``lead_accel_mps2``) starts from
``x0`` at ``t0`` instead.

States scored: ``range_m``, ``range_rate_mps`` and ``lead_accel_mps2`` (the lead's acceleration
``a_L``, the state these observers exist for; truth: the kinematic lead's dv/dt).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from roadtruth.harness.errors import InputError
from roadtruth.observers.base import EstimateTrack, ScalarLoopObserver
from roadtruth.observers.lmi import DesignFailed, DesignResult, DesignStatus
from roadtruth.observers.registry import register

#: Lead model of sec. 5.2.2 (MATLAB case): m = 1850 kg, tau = 0.5 s, K_d = 0.3 N s^2/m^2, d_m = 100 N.
SEED_LEAD = {"mass_kg": 1850.0, "tau_s": 0.5, "kd_Ns2pm2": 0.3, "dm_N": 100.0}

_COMMON: dict[str, Any] = {
    "lead_mass_kg": SEED_LEAD["mass_kg"],   # None = the passed vehicle's mass
    "lead_tau_s": SEED_LEAD["tau_s"],
    "lead_kd_Ns2pm2": SEED_LEAD["kd_Ns2pm2"],
    "lead_dm_N": SEED_LEAD["dm_N"],
    "lead_speed_range_mps": (0.0, 45.0),     # design box of f (k_f) and saturation of its arguments
    "lead_accel_range_mps2": (-10.0, 6.0),
    "lambda_": 1.0,                          # lambda of (4.20)/(4.57), fixed (homogeneous LMIs)
    "sigma": 1.0,                            # sigma of (4.55)-(4.58); the author's public code uses 1
    "z_min": 1.0,                            # Remark 4.3.1: lower bound on Z_2 (multi only)
    "theta_factor": 2.0,                     # theta = theta_factor * theta_0: kappa = 2 k_f (theta_factor - 1)
    "first_order_hold": True,                # inputs as ramps through the last two samples (else held)
    "hold_s": 0.12,                          # a radar sample is used for at most this long [s]
    "use_cache": True,
}



@register
class HighGainRadarStandard(ScalarLoopObserver):
    """Standard high-gain observer (Thm 4.3.1) on radar range: range, range rate, lead acceleration."""

    name = "hgo_radar_standard"
    citation = ("H. Bessafa, PhD thesis, Univ. Lorraine 2024, Thm 4.3.1, eqs. (4.15)-(4.21); "
                "application sec. 5.2 (5.1)-(5.3)")
    inputs = ("range_m", "range_rate_mps", "vx_mps", "ax_mps2")
    states = ("range_m", "range_rate_mps", "lead_accel_mps2")
    variant = "standard"
    uses_rate = False
    default_options = dict(_COMMON)

    def _setup(self) -> None:
        o = self.options
        try:
            lo_v, hi_v = (float(x) for x in o["lead_speed_range_mps"])
            lo_a, hi_a = (float(x) for x in o["lead_accel_range_mps2"])
            vals = [float(o[k]) for k in ("lead_tau_s", "lead_kd_Ns2pm2", "lead_dm_N", "lambda_", "sigma",
                                          "theta_factor", "hold_s", "z_min")]
        except (TypeError, ValueError) as exc:
            raise InputError(f"bad option value ({exc})", field=f"observer {self.name}") from exc
        mass = self.vehicle.mass_kg if o["lead_mass_kg"] is None else float(o["lead_mass_kg"])
        if not (lo_v < hi_v and lo_a < hi_a and mass > 0 and vals[0] > 0 and vals[1] >= 0 and vals[3] > 0
                and vals[4] >= 1.0 and vals[5] > 1.0 and vals[6] > 0):
            raise InputError("bad option: need ranges lo < hi, lead mass/tau/lambda/hold_s > 0, sigma >= 1, "
                             "theta_factor > 1", field=f"observer {self.name}")
        self._lead = {"mass_kg": mass, "tau_s": vals[0], "kd_Ns2pm2": vals[1], "dm_N": vals[2]}
        self._box = (lo_v, hi_v, lo_a, hi_a)
        self._hold = vals[6]
        self._fohs = bool(o["first_order_hold"])
        self._gains: tuple[np.ndarray, np.ndarray] | None = None
        self._lm: tuple[float, ...] | None = None
        km = self._lead["kd_Ns2pm2"] / mass
        self._fpar = (km, self._lead["dm_N"] / mass, 1.0 / self._lead["tau_s"])
        self._disc: dict[tuple[float, bool, bool], tuple[tuple[float, ...], ...]] = {}

    def lead_model(self) -> dict[str, float]:
        """Lead parameters of (1.35): ``mass_kg``, ``tau_s``, ``kd_Ns2pm2``, ``dm_N``."""
        return dict(self._lead)

    def _compute_design(self) -> DesignResult:
        from roadtruth.observers.high_gain_radar_design import design_for
        return design_for(self.design_request(self.lead_model()))

    def gains(self) -> tuple[np.ndarray, np.ndarray]:
        """``(L, M)``: (3,) output-injection gains of range [1/s, 1/s^2, 1/s^3] and range rate."""
        if self._gains is None:
            d = self.design()
            if d.status not in (DesignStatus.CERTIFIED, DesignStatus.REJECTED) or "K" not in d.gains:
                raise DesignFailed(f"{self.name}: design {d.status.value}: {d.reason}")
            th = float(d.gain("theta")[0])
            T = np.array([th, th ** 2, th ** 3])
            L = T * d.gain("K")
            if not self.uses_rate:
                M = np.zeros(3)
            elif "M" in d.gains:   # Methods 1 and 2 give M in state coordinates
                M = d.gain("M").reshape(3)
            else:                  # Thm 4.3.4: M = T(theta) N / theta^n
                M = T * d.gain("N") / th ** 3
            self._gains = (L, M)
        return self._gains

    def _discrete(self, h: float, use_y: bool, use_z: bool) -> tuple[tuple[float, ...], ...]:
        """Exact discretisation of the linear part for step ``h`` [s] with inputs ``u0 + u1 s``.

        Returns ``(Phi, Gamma0, Gamma1)`` flattened row-major (9 floats each): ``x(h) = Phi x(0) +
        Gamma0 u0 + Gamma1 u1``, ``Gamma0 = int_0^h e^(A s) ds``, ``Gamma1 = int_0^h e^(A (h - s)) s ds``.
        """
        key = (h, use_y, use_z)
        hit = self._disc.get(key)
        if hit is not None:
            return hit
        from scipy.linalg import expm

        L, M = self.gains()
        Acl = np.diag([1.0, 1.0], k=1)
        if use_y:
            Acl[:, 0] -= L
        if use_z:
            Acl[:, 1] -= M
        aug = np.zeros((9, 9))
        aug[:3, :3], aug[:3, 3:6], aug[3:6, 6:] = Acl * h, np.eye(3) * h, np.eye(3) * h
        E = expm(aug)
        out = (tuple(E[:3, :3].reshape(-1).tolist()), tuple(E[:3, 3:6].reshape(-1).tolist()),
               tuple(E[:3, 6:].reshape(-1).tolist()))
        if len(self._disc) > 64:  # irregular steps: keep the cache small
            self._disc.clear()
        self._disc[key] = out
        return out

    def lead_f(self, v_lead: float, a_lead: float) -> float:
        """``f`` of (1.35) [m/s^3] at the lead speed [m/s] and acceleration [m/s^2], saturated to the box."""
        lo_v, hi_v, lo_a, hi_a = self._box
        v = lo_v if v_lead < lo_v else (hi_v if v_lead > hi_v else v_lead)
        a = lo_a if a_lead < lo_a else (hi_a if a_lead > hi_a else a_lead)
        km, dm, itau = self._fpar
        return -2.0 * km * v * a - (a + km * v * v + dm) * itau

    def _initial_state(self) -> list[float]:
        return [0.0, 0.0, 0.0]

    def _reset_extra(self) -> None:
        self._started = False
        self._slope_y = 0.0  # slopes of the range and range-rate samples [m/s, m/s^2]
        self._slope_z = 0.0
        self._slope_e = 0.0  # slope of the ego acceleration samples [m/s^3]

    def reset(self, t0_s: float, x0: Mapping[str, float] | None = None) -> None:
        """Start at ``t0_s`` [s]; with ``x0`` the observer starts from it instead of the first sample."""
        super().reset(t0_s, x0)
        if x0:
            self._started = True

    def run(self, t: np.ndarray, Y: np.ndarray, x0: Mapping[str, float] | None = None) -> EstimateTrack:
        """Compiled loop (:mod:`roadtruth.observers.high_gain_radar_loop`), equal to stepping :meth:`step`."""
        from roadtruth.observers.high_gain_radar_loop import run_compiled
        return run_compiled(self, t, Y, x0)

    def _advance(self, t_s: float, y: list[float]) -> None:
        prev_y, prev_z, prev_e = self._u[0], self._u[1], self._u[3]
        t_y, t_z, t_e = self._t_last[0], self._t_last[1], self._t_last[3]
        h = self._tick(t_s, y)
        if self._fresh[0]:
            dt = t_s - t_y
            self._slope_y = (self._u[0] - prev_y) / dt if 0.0 < dt <= self._hold else 0.0
        if self._fresh[1]:
            dt = t_s - t_z
            self._slope_z = (self._u[1] - prev_z) / dt if 0.0 < dt <= self._hold else 0.0
        if self._fresh[3]:
            dt = t_s - t_e
            self._slope_e = (self._u[3] - prev_e) / dt if 0.0 < dt <= self._hold else 0.0
        rng, rate, ve, ae = self._u
        if not self._started:
            if rng != rng:
                return  # no lead seen yet: hold the initial state
            self._z = [rng, rate if rate == rate else 0.0, ae if ae == ae else 0.0]
            self._started = True
            return
        if h <= 0.0:
            return
        tl = self._t_last
        age_y = t_s - tl[0]
        age_z = t_s - tl[1]
        use_z = self.uses_rate and age_z <= self._hold
        use_y = age_y <= self._hold
        x1, x2, x3 = self._z
        ae = ae if ae == ae else 0.0
        # First-order hold: over the step [t - h, t] each signal is the line through its last two
        # samples (interpolation on the step of a new sample, extrapolation while held). The slope
        # comes from the data only: a slope from the observer's own estimates would feed back
        # through the large gains. With a zero-order hold a fast observer picks up an intra-sample
        # ripple (a bias ~ L3 h^2 d'/2 on a_L).
        sy = self._slope_y if self._fohs else 0.0
        sz = self._slope_z if self._fohs else 0.0
        y0 = rng - sy * (age_y + h)
        z0 = rate - sz * (age_z + h)
        se = 0.0
        if self._fohs and t_s - tl[3] <= self._hold:
            se = self._slope_e
            ae = ae - se * (t_s - tl[3] + h)
        key = (h, use_y, use_z)
        disc = self._disc.get(key)
        Phi, Gam, Gam1 = disc if disc is not None else self._discrete(h, use_y, use_z)
        l1, l2, l3, m1, m2, m3 = self._lm if self._lm is not None else self._float_gains()
        # f of (1.35) at (v_L, a_L) clipped to the design box (globally Lipschitz with k_f)
        lo_v, hi_v, lo_a, hi_a = self._box
        v = x2 + (ve if ve == ve else 0.0)
        v = lo_v if v < lo_v else (hi_v if v > hi_v else v)
        a = lo_a if x3 < lo_a else (hi_a if x3 > hi_a else x3)
        km, dm, itau = self._fpar
        g1, g2, g3 = 0.0, -ae, -2.0 * km * v * a - (a + km * v * v + dm) * itau
        r1, r2, r3 = 0.0, -se, 0.0  # slopes of the inputs [per s]
        if use_y:
            g1 += l1 * y0
            g2 += l2 * y0
            g3 += l3 * y0
            r1 += l1 * sy
            r2 += l2 * sy
            r3 += l3 * sy
        if use_z:
            g1 += m1 * z0
            g2 += m2 * z0
            g3 += m3 * z0
            r1 += m1 * sz
            r2 += m2 * sz
            r3 += m3 * sz
        n1 = (Phi[0] * x1 + Phi[1] * x2 + Phi[2] * x3 + Gam[0] * g1 + Gam[1] * g2 + Gam[2] * g3
              + Gam1[0] * r1 + Gam1[1] * r2 + Gam1[2] * r3)
        n2 = (Phi[3] * x1 + Phi[4] * x2 + Phi[5] * x3 + Gam[3] * g1 + Gam[4] * g2 + Gam[5] * g3
              + Gam1[3] * r1 + Gam1[4] * r2 + Gam1[5] * r3)
        n3 = (Phi[6] * x1 + Phi[7] * x2 + Phi[8] * x3 + Gam[6] * g1 + Gam[7] * g2 + Gam[8] * g3
              + Gam1[6] * r1 + Gam1[7] * r2 + Gam1[8] * r3)
        if n1 - n1 == 0.0 and n2 - n2 == 0.0 and n3 - n3 == 0.0:
            self._z = [n1, n2, n3]
        else:  # cannot happen with a certified design and finite inputs; stay finite
            self._z = [rng if rng - rng == 0.0 else 0.0, 0.0, 0.0]

    def _float_gains(self) -> tuple[float, ...]:
        L, M = self.gains()
        self._lm = tuple(float(x) for x in (*L, *M))
        return self._lm

    def _values(self) -> list[float]:
        return [self._z[0], self._z[1], self._z[2]]

    def lead_accel_mps2(self) -> float:
        """Current estimate of the lead vehicle's acceleration ``a_L`` [m/s^2] (the third state)."""
        return self._z[2]

    def internal_state(self) -> tuple[float, float, float]:
        """``(range [m], range rate [m/s], lead acceleration [m/s^2])`` estimates."""
        return (self._z[0], self._z[1], self._z[2])


@register
class HighGainRadarMulti(HighGainRadarStandard):
    """Generalized multi-output HGO (Thm 4.3.4): range (y) and range rate (z = h(x)) injections."""

    name = "hgo_radar_multi"
    citation = ("H. Bessafa, PhD thesis, Univ. Lorraine 2024, Thm 4.3.4, eqs. (4.44)-(4.60); "
                "application sec. 5.2.3-5.2.4")
    variant = "multi"
    uses_rate = True
    default_options = dict(_COMMON)


@register
class HighGainRadarStandardPrinted(HighGainRadarStandard):
    """Standard HGO with the gains printed in sec. 5.2.2(a) (K, P, theta = 39.3974), same certification."""

    name = "hgo_radar_standard_printed"
    citation = "H. Bessafa, PhD thesis, Univ. Lorraine 2024, sec. 5.2.2(a) (printed SHGO design)"
    variant = "standard_printed"
    default_options = dict(_COMMON)


def _check_extra(obs: HighGainRadarStandard, rules: dict[str, Any]) -> None:
    """Validate the variant's own options: ``rules`` maps an option to a predicate on its value."""
    for key, ok in rules.items():
        try:
            good = bool(ok(obs.options[key]))
        except (TypeError, ValueError):
            good = False
        if not good:
            raise InputError(f"bad option {key} = {obs.options[key]!r}", field=f"observer {obs.name}")


def _is_direction(v: Any) -> bool:
    u = np.asarray(v, dtype=float).reshape(-1)
    return u.shape == (3,) and bool(np.all(np.isfinite(u))) and float(np.linalg.norm(u)) > 0


@register
class HighGainRadarMethod1(HighGainRadarStandard):
    """Method 1 (Thm 4.3.2): SHGO gain plus a range-rate gain M bounded in norm by (4.33)."""

    name = "hgo_radar_method1"
    citation = ("H. Bessafa, PhD thesis, Univ. Lorraine 2024, Thm 4.3.2, eqs. (4.24)-(4.33); "
                "application sec. 5.2.2, Table 5.1")
    variant = "method1"
    uses_rate = True
    # alpha of (4.27): share of lambda spent on f; (1 - alpha) bounds ||M||. The thesis gives no value.
    # M = m1_norm_fraction * (4.33)'s bound along m1_direction (the theorem allows any direction; the
    # lead acceleration is the state the observer exists for).
    default_options = dict(_COMMON, m1_alpha=0.5, m1_norm_fraction=0.9, m1_direction=(0.0, 0.0, 1.0))

    def _setup(self) -> None:
        super()._setup()
        _check_extra(self, {"m1_alpha": lambda v: 0.0 < float(v) < 1.0,
                            "m1_norm_fraction": lambda v: 0.0 <= float(v) < 1.0, "m1_direction": _is_direction})


@register
class HighGainRadarMethod2(HighGainRadarStandard):
    """Method 2 (Thm 4.3.3): range-rate gain from LMI (4.39) on the mean-value (DMVT) vertices of h."""

    name = "hgo_radar_method2"
    citation = ("H. Bessafa, PhD thesis, Univ. Lorraine 2024, Thm 4.3.3, eqs. (4.34)-(4.41), Lemma 4.3.1; "
                "application sec. 5.2.2, Table 5.1")
    variant = "method2"
    uses_rate = True
    # sigma of (4.39)-(4.40) (theta <= sigma); m2_lambda = None uses lambda_
    default_options = dict(_COMMON, m2_sigma=40.0, m2_lambda=None)

    def _setup(self) -> None:
        super()._setup()
        _check_extra(self, {"m2_sigma": lambda v: float(v) >= 1.0,
                            "m2_lambda": lambda v: v is None or float(v) > 0.0})


@register
class HighGainRadarMethod2Printed(HighGainRadarMethod2):
    """Method 2 with the design printed in sec. 5.2.2(b) (P, Y, Z, theta = 30.3704), same certification."""

    name = "hgo_radar_method2_printed"
    citation = "H. Bessafa, PhD thesis, Univ. Lorraine 2024, sec. 5.2.2(b) (printed Method 2 design)"
    variant = "method2_printed"
    # lambda is not printed for this design: None = the largest lambda for which (4.39) holds
    default_options = dict(_COMMON, m2_sigma=40.0, m2_lambda=None)
