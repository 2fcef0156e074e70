"""The ground-truth record handed out by ``roadtruth.harness.truth.simulate``: one row per simulation step.

``Truth.frame`` holds every canonical signal of CONTRACT.md (``roadtruth.harness.signals.CANONICAL``) plus the
extras listed in docs/ARCHITECTURE.md ("Truth") and the IMU-site specific force. ``RAW_COLUMNS`` is
the order in which the compiled stepping loop writes its log; ``build_frame`` adds the columns that
are cheap functions of logged ones (sideslip, axle slip angles and forces, mean steer angle).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
import pandas as pd

from roadtruth.harness.errors import InputError
from roadtruth.harness.signals import CANONICAL, WHEELS
from roadtruth.harness.truth.truth_events import TruthEvent, scoring_end_s, truth_status

#: Below this speed [m/s] sideslip and axle slip angles are not defined (NaN in the frame).
ROLLING_SPEED_MPS = 0.5

#: Per-wheel quantities; each is logged as four consecutive columns fl, fr, rl, rr.
WHEEL_QUANTITIES: tuple[str, ...] = ("fz_{}_N", "fy_{}_N", "fx_{}_N", "alpha_{}_rad", "kappa_{}", "mu_{}",
                                     "omega_{}_radps", "gamma_{}_rad", "mz_{}_Nm")

#: Columns written by the stepping loop, in this order.
RAW_COLUMNS: tuple[str, ...] = (
    "t_s", "x_m", "y_m", "z_m", "psi_rad", "roll_rad", "pitch_rad",
    "vx_mps", "vy_mps", "vz_mps", "yaw_rate_radps", "roll_rate_radps",
    "wx_body_radps", "wy_body_radps", "wz_body_radps",
    "ax_body_mps2", "ay_body_mps2", "az_body_mps2",
    "fspec_x_body_mps2", "fspec_y_body_mps2", "fspec_z_body_mps2",
    "dwx_body_radps2", "dwy_body_radps2", "dwz_body_radps2", "yaw_acc_radps2",
    "ax_mps2", "ay_mps2",
    "delta_fl_rad", "delta_fr_rad", "steer_cmd_rad", "drive_torque_Nm", "brake_torque_Nm",
    "s_m", "rho_1pm", "y_lane_m", "psi_lane_rad",
    "lead_x_m", "lead_y_m", "lead_v_mps", "lead_accel_mps2", "range_m", "range_rate_mps",
    *(q.format(w) for q in WHEEL_QUANTITIES for w in WHEELS),
)
RAW_INDEX: dict[str, int] = {name: i for i, name in enumerate(RAW_COLUMNS)}

#: Extra (non-canonical) columns of the frame, for sensors and renders.
EXTRA_COLUMNS: tuple[str, ...] = (
    "z_m", "vz_mps", "wx_body_radps", "wy_body_radps", "wz_body_radps",
    "dwx_body_radps2", "dwy_body_radps2", "dwz_body_radps2",
    "ax_body_mps2", "ay_body_mps2", "az_body_mps2",
    "fspec_x_body_mps2", "fspec_y_body_mps2", "fspec_z_body_mps2",
    "s_m", "lead_x_m", "lead_y_m", "lead_v_mps", "steer_cmd_rad", "drive_torque_Nm", "brake_torque_Nm",
    *(q.format(w) for q in ("gamma_{}_rad", "mz_{}_Nm") for w in WHEELS),
)
FRAME_COLUMNS: tuple[str, ...] = (*CANONICAL.keys(), *EXTRA_COLUMNS)


def build_frame(raw: np.ndarray, lf_m: float, lr_m: float) -> pd.DataFrame:
    """Truth frame from the loop's raw log.

    Parameters
    ----------
    raw : (n, len(RAW_COLUMNS)) array in ``RAW_COLUMNS`` order.
    lf_m, lr_m : CG to front / rear axle [m], for the axle slip angles.

    Returns
    -------
    DataFrame with ``FRAME_COLUMNS``. Derived columns: β = atan2(v_y, v_x) (NaN, like the axle slip
    angles, where |v_x| < ROLLING_SPEED_MPS: a car at rest has no sideslip); δ = (δ_fl + δ_fr)/2;
    α_f = δ − atan((v_y + l_f r)/v_x), α_r = −atan((v_y − l_r r)/v_x) (CONTRACT.md); F_y,f/r = sums of
    the wheels' tire-frame lateral forces.
    """
    # One column-major block filled in place: the DataFrame wraps it without copying or consolidating.
    out = np.empty((raw.shape[0], len(FRAME_COLUMNS)), order="F")
    cols = {name: out[:, i] for i, name in enumerate(FRAME_COLUMNS)}
    for name in FRAME_COLUMNS:
        if name in RAW_INDEX:
            cols[name][:] = raw[:, RAW_INDEX[name]]
    raw_cols = {name: raw[:, i] for i, name in enumerate(RAW_COLUMNS)}
    vx, vy, r = raw_cols["vx_mps"], raw_cols["vy_mps"], raw_cols["yaw_rate_radps"]
    delta = 0.5 * (raw_cols["delta_fl_rad"] + raw_cols["delta_fr_rad"])
    # Sideslip and axle slip angles are undefined at standstill: NaN below ROLLING_SPEED_MPS.
    rolling = np.abs(vx) >= ROLLING_SPEED_MPS
    with np.errstate(divide="ignore", invalid="ignore"):
        cols["beta_rad"][:] = np.where(rolling, np.arctan2(vy, vx), np.nan)
        cols["alpha_f_rad"][:] = np.where(rolling, delta - np.arctan((vy + lf_m * r) / vx), np.nan)
        cols["alpha_r_rad"][:] = np.where(rolling, -np.arctan((vy - lr_m * r) / vx), np.nan)
    cols["delta_rad"][:] = delta
    cols["fy_f_N"][:] = raw_cols["fy_fl_N"] + raw_cols["fy_fr_N"]
    cols["fy_r_N"][:] = raw_cols["fy_rl_N"] + raw_cols["fy_rr_N"]
    return pd.DataFrame(out, columns=list(FRAME_COLUMNS), copy=False)


@dataclass(frozen=True, eq=False)
class Truth:
    """Ground truth of one simulated scenario.

    Attributes
    ----------
    scenario : the ``Scenario`` simulated.
    vehicle : the ``VehicleParams`` used.
    seed : the run's seed (recorded; the truth itself is deterministic).
    dt_s : simulation step [s].
    frame : DataFrame, one row per step, ``FRAME_COLUMNS`` (canonical signals + extras).
    qpos : (n, nq) MuJoCo generalized positions per step (for renders).
    model_xml : MJCF of the model that was stepped (``mujoco.MjModel.from_xml_string``): the car and
        the floor, without the scenario's visual-only geoms (``render_xml`` has them).
    status : ``"ok"`` or ``"diverged: <cause> at t=<t> s"`` (frame truncated there).
    events : ((t_s, label), ...) sorted by time: the scenario's own, the simulator's and the truth
        events' labels.
    truth_events : what the car did (``roadtruth.harness.truth.truth_events.TruthEvent``: spun out, left the road,
        wheel lift, rolled over, stopped), sorted by time.
    """

    scenario: Any
    vehicle: Any
    seed: int
    dt_s: float
    frame: pd.DataFrame
    qpos: np.ndarray
    model_xml: str
    status: str
    events: tuple[tuple[float, str], ...]
    truth_events: tuple[TruthEvent, ...] = ()

    @cached_property
    def render_xml(self) -> str:
        """MJCF of the stepped model plus the scenario's lane markings, road surface, friction patches
        and lead car (built on first use). Same bodies, joints and ``qpos`` layout as ``model_xml``,
        so the logged ``qpos`` poses it."""
        from roadtruth.harness.truth.car_model import build_mjcf

        return build_mjcf(self.vehicle, self.scenario, timestep_s=self.dt_s, visuals=True)

    @property
    def ok(self) -> bool:
        """The simulation ran to the end (it may still have spun out: see ``truth_status``)."""
        return self.status == "ok"

    @property
    def truth_status(self) -> str:
        """``ok`` or what the car did, e.g. ``spun out at t=3.41 s`` (``roadtruth.harness.truth.truth_events``)."""
        return truth_status(self.truth_events, self.status)

    @property
    def scored_until_s(self) -> float | None:
        """Where scoring stops [s] (the first spin-out or roll-over), None if it runs to the end."""
        return scoring_end_s(self.truth_events)

    def at_rate(self, hz: float) -> pd.DataFrame:
        """The frame decimated to ``hz`` (every k-th step; ``1/hz`` must be a multiple of ``dt_s``)."""
        if not hz > 0.0:
            raise InputError(f"log rate must be > 0 Hz (got {hz!r})", field="--log-rate")
        k = 1.0 / (hz * self.dt_s)
        step = int(round(k))
        if step < 1 or abs(k - step) > 1e-6 * k:
            raise InputError(f"log rate {hz:g} Hz does not divide the simulation rate {1.0 / self.dt_s:g} Hz",
                             field="--log-rate")
        return self.frame.iloc[::step].reset_index(drop=True)
