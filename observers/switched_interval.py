r"""Switched unknown-input interval observer of Ifqir et al. (ACC 2018), in a sound derivative-free form.

S. Ifqir, N. Aït Oufroukh, D. Ichalal, S. Mammar, "Vehicle Lateral Dynamics Estimation using Switched
Unknown Inputs Interval Observers: Experimental Validation", ACC 2018, pp. 1138-1143,
doi:10.23919/ACC.2018.8431486.

Guaranteed bounds ``x^- <= x <= x^+`` for ``x = [v_y, r, psi_L, y_L]`` of the linear bicycle + lane model
(12)-(16) (corrected (10)-(11), see :mod:`roadtruth.observers.switched_interval_design`), with road curvature
``rho`` an unknown input removed by decoupling (``P_i E_i = 0``, (24)-(25)), cornering stiffness
``c = c_0 (1 ± unc)`` and ``N = 3`` speed modes (35) with gains from the Theorem 2 SDP.

Runtime form (derivative-free and sound; it replaces the printed eq. (19), which is not an inclusion:
its ``|x^±|`` corrections are sign-inconsistent): in ``z = P_i x = x + H_i y``,

.. math::

    \dot z^\pm = N_{0,i} z^\pm + (K_i - N_{0,i}H_i)\,y + G_i u + P_i (A_{kin}(v_x) - A_{kin}(v_i)) x
    \pm P_i\big(D_i \bar X + b(|u| + \zeta)\big),\qquad x^\pm = z^\pm - H_i y,

``N_0 = P A_0 - K C`` Metzler, ``G = P B_0``, ``D = (A^+ - A^-)/2``, ``\bar X = \max(|x^+|, |x^-|)``,
``b = unc [c_{f0}/m, c_{f0} l_f / I_z, 0, 0]``. Every product of a known matrix with an interval (``y``
within its noise bound, the kinematic term ``(v_i - v_x) r``) uses Lemma 3(1). Steps are the exact ZOH of
the Metzler ``N_0`` block (``e^{N_0 h} >= 0``), forcing held over the step.

Structure (design constraints, see the design module): ``P = [e_1, e_2 + h, 0, 0]`` with ``h_3 = h_4 = 0``
and the camera columns of ``K`` zero in rows 1-2. So the ``(v_y, r)`` bounds run on ``r``, ``delta``, ``v_x``
only (the camera cannot tighten ``v_y`` when ``P >= 0``), ``z_3 = z_4 = 0`` exactly and the
lane bounds are the camera sample ± its noise bound (``x_3 = z_3 - (H y)_3 = psi_L``). Between camera
samples (NaN, 20 Hz cameras, marking gaps) the lane bounds are propagated open loop (they widen) with
``psi_L' = r - v_x rho``, ``y_L' = v_y + l_s r + v_x psi_L - l_s v_x rho``, ``|rho| <= curvature_bound_1pm``
(the unknown input needs a bound only there). A missing gyro sample is replaced by the interval
``[r^-, r^+]``.

Modes: ``sigma = i`` while ``v_x`` stays in ``[v_i - dV, v_i + dV]`` (overlapping bands = hysteresis);
on leaving, the mode whose band holds ``v_x`` with the nearest centre. ``x^±`` is kept and ``z^±``
re-initialised. With a common ``Q`` (default) the dwell time is 0 (arbitrary switching, Remark 1);
otherwise a switch sooner than ``tau_a = ln(mu)/epsilon`` after the previous one is counted in
``dwell_violations`` (the band must be left, so it cannot be postponed soundly), a speed outside
every band in ``out_of_band_steps`` (no guarantee there), and a model bound on ``r`` disjoint from the
gyro's in ``inconsistent_steps`` (the measurement interval is kept: the plant has left the model).

Sampled data (runner at 100 Hz): over a step, ``r``, ``delta`` and ``v_x`` are taken in the hull of their
two end samples (exact for signals monotone over the step). Sensor latency is not modelled for the gyro;
camera samples are aged by ``camera_latency_s`` (their bounds widened by the drift over that age).

``beta_rad`` bounds: ``atan(v_y^± / v_x)`` with ``v_x`` in ``[v_x - V_v, v_x + V_v]`` (monotone in both).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from roadtruth.harness.errors import InputError
from roadtruth.observers.base import ScalarLoopObserver
from roadtruth.observers.bicycle import expm2_zoh
from roadtruth.observers.lmi import DesignFailed, DesignResult, DesignStatus
from roadtruth.observers.registry import register


def _mul(a: float, lo: float, hi: float) -> tuple[float, float]:
    """Bounds of ``a x`` for ``x`` in ``[lo, hi]`` (Lemma 3(1), scalar)."""
    return (a * lo, a * hi) if a >= 0.0 else (a * hi, a * lo)


def _mul_ii(al: float, ah: float, bl: float, bh: float) -> tuple[float, float]:
    """Bounds of ``a b`` for ``a`` in ``[al, ah]`` and ``b`` in ``[bl, bh]``."""
    p = (al * bl, al * bh, ah * bl, ah * bh)
    return min(p), max(p)


@register
class SwitchedIntervalIfqir(ScalarLoopObserver):
    """Switched unknown-input interval observer of Ifqir et al. (ACC 2018), sound derivative-free form."""

    name = "switched_interval_ifqir"
    citation = ("S. Ifqir, N. Ait Oufroukh, D. Ichalal, S. Mammar, ACC 2018, pp. 1138-1143, "
                "eqs. (12)-(29), Theorem 2; derivative-free sound form (the printed eq. (19) is not an inclusion)")
    inputs = ("yaw_rate_radps", "delta_rad", "vx_mps", "psi_lane_rad", "y_lane_m")
    states = ("vy_mps", "yaw_rate_radps", "psi_lane_rad", "y_lane_m", "beta_rad")
    has_bounds = True
    variant = "sound"
    default_options: dict[str, Any] = {
        "mode_speeds_mps": (13.5, 20.0, 26.5),   # v_x^i (not given by the paper)
        "mode_halfwidth_mps": 4.0,               # dV: bands 9.5-17.5, 16-24, 22.5-30.5 m/s (overlap = hysteresis)
        "stiffness_uncertainty": 0.1,            # |dc_i| <= 10 % c_i0 (the paper's value)
        "lookahead_m": 0.5,                      # camera look-ahead l_s
        "epsilon": 0.5,                          # ISS decay rate in (27) [1/s]
        "eta": 100.0,                            # Metzler shift in (28) [1/s]
        "common_Q": True,                        # one Q for all modes: mu = 1, no dwell time needed
        "input_bound_rad": 0.002,                # zeta: |delta_meas - delta| (A2)
        "noise_bound_r_radps": 0.012,            # gyro noise + bias bound
        "noise_bound_psi_rad": 0.006,            # camera heading noise bound
        "noise_bound_y_m": 0.15,                 # camera offset noise bound
        "noise_bound_vx_mps": 0.1,               # speed error bound
        "camera_latency_s": 0.05,                # age of a camera sample (Mobileye class): widen by the drift
        "curvature_bound_1pm": 0.02,             # |rho| bound, used only between camera samples
        "initial_vy_halfwidth_mps": 1.0,
        "initial_r_halfwidth_radps": 0.5,
        "initial_psi_halfwidth_rad": 0.2,
        "initial_y_halfwidth_m": 2.0,
        "vx_min_mps": 1.0,                       # floor of v_x in beta
        "use_cache": True,
    }

    def _setup(self) -> None:
        o = self.options
        speeds = tuple(float(v) for v in o["mode_speeds_mps"])
        dv, unc = float(o["mode_halfwidth_mps"]), float(o["stiffness_uncertainty"])
        if not speeds or min(speeds) - dv <= 0.0 or dv <= 0.0:
            raise InputError(f"bad modes {o['mode_speeds_mps']} ± {dv}: every band must be > 0 m/s",
                             field=f"observer {self.name} mode_speeds_mps")
        if not 0.0 <= unc < 1.0:
            raise InputError(f"stiffness_uncertainty {unc} not in [0, 1)", field=f"observer {self.name}")
        for key in ("input_bound_rad", "noise_bound_r_radps", "noise_bound_psi_rad", "noise_bound_y_m",
                    "noise_bound_vx_mps", "camera_latency_s", "curvature_bound_1pm", "lookahead_m"):
            if not float(o[key]) >= 0.0:
                raise InputError(f"{key} = {o[key]} must be >= 0", field=f"observer {self.name} {key}")
        self._zeta, self._vr = float(o["input_bound_rad"]), float(o["noise_bound_r_radps"])
        self._vpsi, self._vyl = float(o["noise_bound_psi_rad"]), float(o["noise_bound_y_m"])
        self._vv, self._lat = float(o["noise_bound_vx_mps"]), float(o["camera_latency_s"])
        self._rho, self._ls = float(o["curvature_bound_1pm"]), float(o["lookahead_m"])
        self._vmin = float(o["vx_min_mps"])
        self._modes: list[tuple[float, ...]] | None = None
        self.dwell_time_s = 0.0

    def _compute_design(self) -> DesignResult:
        from roadtruth.observers.switched_interval_design import design_for
        return design_for(self.design_request())

    def mode_constants(self) -> list[tuple[float, ...]]:
        """Per mode the runtime scalars (see :meth:`_load`); raises :class:`DesignFailed` if uncertified."""
        if self._modes is None:
            self._load()
        assert self._modes is not None
        return self._modes

    def _load(self) -> None:
        d = self.design()
        if d.status is not DesignStatus.CERTIFIED:
            raise DesignFailed(f"{self.name}: design {d.status.value}: {d.reason}")
        C = d.gain("C")
        B0, b = d.gain("B0"), d.gain("b")
        modes = []
        i = 0
        while f"K{i}" in d.gains:
            K, H, P = d.gain(f"K{i}"), d.gain(f"H{i}"), d.gain(f"P{i}")
            A0, D = d.gain(f"A0{i}"), d.gain(f"D{i}")
            v_c, v_lo, v_hi = (float(x) for x in d.gains[f"mode{i}"])
            N0 = P @ A0 - K @ C
            M = K - N0 @ H
            G, PD, Pb = P @ B0, P @ D, P @ b
            if np.abs(N0[:2, 2:]).max() > 1e-9 or np.abs(M[:2, 1:]).max() > 1e-9 or np.abs(H[:2, 1:]).max() > 0:
                raise DesignFailed(f"{self.name}: mode {i} rows 1-2 are not camera-free")
            modes.append((v_c, v_lo, v_hi, N0[0, 0], N0[0, 1], N0[1, 0], N0[1, 1], M[0, 0], M[1, 0], G[0], G[1],
                          H[0, 0], H[1, 0], PD[0, 0], PD[0, 1], PD[1, 0], PD[1, 1], Pb[0], Pb[1], P[0, 0], P[1, 0]))
            i += 1
        self.dwell_time_s = float(d.margins["dwell_time_s"])
        self._modes = [tuple(float(x) for x in m) for m in modes]

    # ---- state -------------------------------------------------------------------------------------
    def _initial_state(self) -> list[float]:
        return [0.0, 0.0, 0.0, 0.0]

    def _reset_extra(self) -> None:
        o = self.options
        c = self._z
        hw = (float(o["initial_vy_halfwidth_mps"]), float(o["initial_r_halfwidth_radps"]),
              float(o["initial_psi_halfwidth_rad"]), float(o["initial_y_halfwidth_m"]))
        self._lo = [c[k] - hw[k] for k in range(4)]
        self._hi = [c[k] + hw[k] for k in range(4)]
        self._zl = [0.0, 0.0]
        self._zh = [0.0, 0.0]
        self._mode = -1
        self._dprev = self._vprev = 0.0
        self._fw = (0.0, 0.0)
        self._t_switch = -math.inf
        self.dwell_violations = 0
        self.out_of_band_steps = 0
        self.inconsistent_steps = 0
        self.switches = 0

    def z_bounds(self) -> tuple[list[float], list[float]]:
        """Bounds of ``z_1, z_2`` (the ``(v_y, r)`` rows of ``z = P x``) of the current mode."""
        return list(self._zl), list(self._zh)

    def forcing_width(self) -> tuple[float, float]:
        """Width ``Delta`` of the forcing of ``z_1, z_2`` over the last step (the ISS input of (29))."""
        return self._fw

    def mode(self) -> int:
        """Active mode index (-1 before the first step with ``delta``, ``r``, ``v_x``)."""
        return self._mode

    def _select_mode(self, v: float, t_s: float, rl: float, rh: float) -> None:
        modes = self._modes if self._modes is not None else self.mode_constants()
        cur = self._mode
        if cur >= 0 and modes[cur][1] <= v <= modes[cur][2]:
            return
        inside = [i for i, m in enumerate(modes) if m[1] <= v <= m[2]]
        pool = inside or list(range(len(modes)))
        new = min(pool, key=lambda i: (abs(modes[i][0] - v), i))
        if not inside:
            self.out_of_band_steps += 1
        if new == cur:
            return
        if cur >= 0:
            self.switches += 1
            if t_s - self._t_switch < self.dwell_time_s:
                self.dwell_violations += 1
        self._t_switch = t_s
        self._mode = new
        m = modes[new]
        h1, h2 = m[11], m[12]
        # z = x + H y with y = r in [rl, rh] (Lemma 3(1)); x^± is kept across the switch
        a, bb = _mul(h1, rl, rh)
        self._zl[0], self._zh[0] = self._lo[0] + a, self._hi[0] + bb
        a, bb = _mul(h2, rl, rh)
        self._zl[1], self._zh[1] = self._lo[1] + a, self._hi[1] + bb

    def _advance(self, t_s: float, y: list[float]) -> None:
        h = self._tick(t_s, y)
        r_m, delta, v, psi_m, yl_m = self._u
        lo, hi = self._lo, self._hi
        if delta != delta or v != v or (r_m != r_m and self._mode < 0):
            return  # not started: the initial box is reported
        fresh = self._fresh
        if self._mode < 0:
            self._dprev, self._vprev = delta, v
            lo[1], hi[1] = r_m - self._vr, r_m + self._vr  # the latest gyro sample
        # Sampled data: over the step a signal is taken within the hull of its two end samples
        # (exact for a signal monotone over 10 ms; the stiffness slack covers the O(h^2) rest).
        # lo[1], hi[1] still hold the bounds of r at the previous step.
        if fresh[0]:
            r0l, r0h = r_m - self._vr, r_m + self._vr        # r now
            rl, rh = min(lo[1], r0l), max(hi[1], r0h)        # r over the step
        else:
            r0l, r0h = rl, rh = lo[1], hi[1]
        self._select_mode(v, t_s, lo[1], hi[1])
        dprev, vprev = self._dprev, self._vprev
        self._dprev, self._vprev = delta, v
        if h <= 0.0:
            return
        m = self._modes  # type: ignore[index]
        (v_c, _, _, n11, n12, n21, n22, m1, m2, g1, g2, h1, h2, d11, d12, d21, d22, pb1, pb2, p1,
         p2) = m[self._mode]  # type: ignore[index]
        vl, vh = min(v, vprev) - self._vv, max(v, vprev) + self._vv
        zeta = self._zeta
        ul, uh = min(delta, dprev) - zeta, max(delta, dprev) + zeta
        xb1 = max(abs(lo[0]), abs(hi[0]))
        xb2 = max(abs(rl), abs(rh))
        au = max(abs(ul), abs(uh))
        w1 = d11 * xb1 + d12 * xb2 + pb1 * au
        w2 = d21 * xb1 + d22 * xb2 + pb2 * au
        kl, kh = _mul_ii(v_c - vh, v_c - vl, rl, rh)      # (v_i - v_x) r, kinematic term of A
        a1l, a1h = _mul(m1, rl, rh)
        a2l, a2h = _mul(m2, rl, rh)
        k1l, k1h = _mul(p1, kl, kh)
        k2l, k2h = _mul(p2, kl, kh)
        f1l = a1l + g1 * ul + k1l - w1      # g >= 0: P >= 0 and B0 >= 0
        f1h = a1h + g1 * uh + k1h + w1
        f2l = a2l + g2 * ul + k2l - w2
        f2h = a2h + g2 * uh + k2h + w2
        self._fw = (f1h - f1l, f2h - f2l)
        E, Gm = expm2_zoh(n11, n12, n21, n22, h)
        zl, zh = self._zl, self._zh
        zl0 = E[0] * zl[0] + E[1] * zl[1] + Gm[0] * f1l + Gm[1] * f2l
        zl1 = E[2] * zl[0] + E[3] * zl[1] + Gm[2] * f1l + Gm[3] * f2l
        zh0 = E[0] * zh[0] + E[1] * zh[1] + Gm[0] * f1h + Gm[1] * f2h
        zh1 = E[2] * zh[0] + E[3] * zh[1] + Gm[2] * f1h + Gm[3] * f2h
        zl[0], zl[1], zh[0], zh[1] = zl0, zl1, zh0, zh1
        old_vyh, old_vyl = hi[0], lo[0]
        a, bb = _mul(h1, r0l, r0h)
        lo[0], hi[0] = zl0 - bb, zh0 - a
        a, bb = _mul(h2, r0l, r0h)
        x2l, x2h = zl1 - bb, zh1 - a
        if fresh[0]:
            x2l, x2h = max(x2l, r0l), min(x2h, r0h)   # both are valid enclosures of r
            if x2l > x2h:
                # Empty: the plant left the model (e.g. tire saturation). Keep the measurement, count it.
                self.inconsistent_steps += 1
                x2l, x2h = r0l, r0h
        lo[1], hi[1] = x2l, x2h
        self._lane(h, vl, vh, psi_m, yl_m, fresh[3], fresh[4], min(rl, x2l), max(rh, x2h),
                   min(old_vyl, lo[0]), max(old_vyh, hi[0]))

    def _lane(self, h: float, vl: float, vh: float, psi_m: float, yl_m: float, new_psi: bool,
              new_y: bool, rl: float, rh: float, vyl: float, vyh: float) -> None:
        """Lane bounds: camera sample ± noise (± drift over its age), else open-loop propagation."""
        lo, hi = self._lo, self._hi
        ls, rho = self._ls, self._rho
        vpos = max(vh, 0.0)
        # psi_L' = r - v rho ; worst case over the step
        dpl, dph = rl - vpos * rho, rh + vpos * rho
        pl, ph = lo[2] + h * dpl, hi[2] + h * dph
        psi_max, psi_min = max(hi[2], ph), min(lo[2], pl)
        # y_L' = v_y + l_s r + v psi_L - l_s v rho, v in [vl, vh]
        vpl, vph = _mul_ii(vl, vh, psi_min, psi_max)
        dyl = vyl + ls * rl + vpl - ls * vpos * rho
        dyh = vyh + ls * rh + vph + ls * vpos * rho
        yl, yh = lo[3] + h * dyl, hi[3] + h * dyh
        lat = self._lat
        # a sample taken `lat` ago: the state has since moved by the integral of its rate bounds
        if new_psi:
            pl, ph = psi_m - self._vpsi + lat * dpl, psi_m + self._vpsi + lat * dph
        if new_y:
            yl, yh = yl_m - self._vyl + lat * dyl, yl_m + self._vyl + lat * dyh
        lo[2], hi[2], lo[3], hi[3] = pl, ph, yl, yh

    def _bounds(self) -> tuple[list[float], list[float]]:
        lo, hi = self._lo, self._hi
        v = self._u[2]
        if v != v:
            return [lo[0], lo[1], lo[2], lo[3], -0.5 * math.pi], [hi[0], hi[1], hi[2], hi[3], 0.5 * math.pi]
        vl, vh = max(v - self._vv, self._vmin), max(v + self._vv, self._vmin)
        bh = math.atan(hi[0] / (vl if hi[0] >= 0.0 else vh))
        bl = math.atan(lo[0] / (vh if lo[0] >= 0.0 else vl))
        return [lo[0], lo[1], lo[2], lo[3], bl], [hi[0], hi[1], hi[2], hi[3], bh]

    def _values(self) -> list[float]:
        lo, hi = self._bounds()
        return [0.5 * (a + b) for a, b in zip(lo, hi, strict=True)]
