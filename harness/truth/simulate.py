"""Ground truth: the compiled MuJoCo stepping loop with Magic Formula tires, driver and logging.

Each step (shared/notes/mujoco-car-and-tires.md, sections 4.2 and 7)::

    mj_step1                      positions/velocities -> kinematics (xpos, xmat, cvel)
    guard                         non-finite state, roll/pitch past 80 deg, chassis height -> stop
    driver                        steering command (profile or path follower), rate limit, Ackermann;
                                  longitudinal demand (PI / brake / time gap) -> wheel torques
    tires (per wheel)             road surface under the wheel (height, normal), contact point =
                                  foot of the perpendicular from the wheel centre, radial-spring F_z,
                                  slip velocities of the contact point on the wheel carrier,
                                  transient slip (deflection states, damped at low speed), camber,
                                  mu(x, y, t), tire model (F_x, F_y, M_z) -> xfrc_applied at the
                                  contact point; brakes as spin-joint friction, rolling resistance
    aero                          drag and axle lift on the chassis
    log                           state at t_k into the preallocated row k
    mj_step2                      forces -> accelerations (accelerometer) -> integrate to t_k+1

The loop is one ``numba`` function (``_run``) that calls ``mj_step1``/``mj_step2`` of the MuJoCo
shared library through ctypes on the raw ``MjModel``/``MjData`` pointers (``_address``) and reads
the NumPy views of ``MjData`` that alias its memory, so it never returns to Python. The very same
function run by the interpreter (``_run.py_func`` with the official bindings) is the reference path
(``simulate(..., compiled=False)``); both give the same bits.
"""

from __future__ import annotations

import ctypes
import functools
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from roadtruth.harness.errors import ScenarioError
from roadtruth.harness.files.parsed_files import ParsedFiles
from roadtruth.harness.signals import WHEELS
from roadtruth.harness.truth.car_model import CORNERS, FRONT_OVERHANG_M, build_mjcf, corner_geometry
from roadtruth.harness.truth.driver import (
    LEAD_LENGTH_M,
    MAX_HANDWHEEL_RATE_RADPS,
    ackermann_angles,
    follow_lead_target,
    path_follower,
    rate_limit,
    speed_controller,
)
from roadtruth.harness.truth.friction_map import SURFACES, mu_at
from roadtruth.harness.truth.road import road_project, road_surface
from roadtruth.harness.truth.tire import combined_with_camber, jit, radial_load_kernel, shape_array
from roadtruth.harness.truth.tire_fiala import fiala_forces
from roadtruth.harness.truth.tire_file import read_tire_file
from roadtruth.harness.truth.tire_mf61 import mf61_forces
from roadtruth.harness.truth.tire_models import TIRE_MODEL_CODES, wheel_coefficients
from roadtruth.harness.truth.truth import RAW_COLUMNS, RAW_INDEX, Truth, build_frame
from roadtruth.harness.truth.truth_events import detect_events, detect_tire_range
from roadtruth.harness.truth.vehicle import G, VehicleParams, load_vehicle, vehicles_dir

#: Without a relaxation length (no transient slip) the slips are kinematic and need speed [m/s].
MIN_START_SPEED_NO_RELAXATION_MPS = 3.0
#: Slip denominators without transient slip use max(|v_x|, V_MIN_SLIP_MPS) [m/s].
V_MIN_SLIP_MPS = 1.0
#: Below this contact-point speed the tire's deflection states get damping (fades out to it) [m/s].
V_LOW_MPS = 1.5
#: Target damping ratio of the tire-spring/quarter-car mode at standstill (limited for the wheel's spin).
STANDSTILL_DAMPING_RATIO = 1.0
#: Deflection states are bounded to |kappa'| <= KAPPA_MAX and |tan alpha'| <= TAN_ALPHA_MAX.
KAPPA_MAX, TAN_ALPHA_MAX = 5.0, 5.0
#: Rolling resistance reverses smoothly over this spin rate [rad/s].
ROLLING_OMEGA_EPS = 0.5
#: Divergence guard limits.
MAX_TILT_RAD = math.radians(80.0)
MAX_CG_HEIGHT_ABOVE_REST_M = 3.0
MAX_STEP_JUMP_M = 1.0
#: Drive torque split (fl, fr, rl, rr) per layout.
DRIVE_SPLIT = {"rwd": (0.0, 0.0, 0.5, 0.5), "fwd": (0.5, 0.5, 0.0, 0.0), "awd": (0.2, 0.2, 0.3, 0.3)}
MAX_STEP_DV_MPS = 2.0  # 2000 m/s^2 for one step: only a MuJoCo reset or a blow-up does that
DIVERGENCE_CAUSES = {1: "non-finite state", 2: "rolled over", 3: "pitched over", 4: "chassis height out of range",
                     5: "state jumped", 6: "non-finite tire force"}

# Raw log column indices (compile-time constants inside the loop).
C_T, C_X, C_Y, C_Z = RAW_INDEX["t_s"], RAW_INDEX["x_m"], RAW_INDEX["y_m"], RAW_INDEX["z_m"]
C_PSI, C_ROLL, C_PITCH = RAW_INDEX["psi_rad"], RAW_INDEX["roll_rad"], RAW_INDEX["pitch_rad"]
C_VX, C_VY, C_VZ = RAW_INDEX["vx_mps"], RAW_INDEX["vy_mps"], RAW_INDEX["vz_mps"]
C_R, C_P = RAW_INDEX["yaw_rate_radps"], RAW_INDEX["roll_rate_radps"]
C_WB, C_AB, C_FS, C_DWB = (RAW_INDEX["wx_body_radps"], RAW_INDEX["ax_body_mps2"], RAW_INDEX["fspec_x_body_mps2"],
                           RAW_INDEX["dwx_body_radps2"])
C_RDOT, C_AX, C_AY = RAW_INDEX["yaw_acc_radps2"], RAW_INDEX["ax_mps2"], RAW_INDEX["ay_mps2"]
C_DFL, C_DFR, C_CMD = RAW_INDEX["delta_fl_rad"], RAW_INDEX["delta_fr_rad"], RAW_INDEX["steer_cmd_rad"]
C_TD, C_TB = RAW_INDEX["drive_torque_Nm"], RAW_INDEX["brake_torque_Nm"]
C_S, C_RHO, C_YL, C_PL = RAW_INDEX["s_m"], RAW_INDEX["rho_1pm"], RAW_INDEX["y_lane_m"], RAW_INDEX["psi_lane_rad"]
C_LX, C_LY, C_LV = RAW_INDEX["lead_x_m"], RAW_INDEX["lead_y_m"], RAW_INDEX["lead_v_mps"]
C_LA = RAW_INDEX["lead_accel_mps2"]
C_RANGE, C_RR = RAW_INDEX["range_m"], RAW_INDEX["range_rate_mps"]
C_FZ, C_FY, C_FX = RAW_INDEX["fz_fl_N"], RAW_INDEX["fy_fl_N"], RAW_INDEX["fx_fl_N"]
C_ALPHA, C_KAPPA, C_MU, C_OMEGA = (RAW_INDEX["alpha_fl_rad"], RAW_INDEX["kappa_fl"], RAW_INDEX["mu_fl"],
                                   RAW_INDEX["omega_fl_radps"])
C_GAMMA, C_MZ = RAW_INDEX["gamma_fl_rad"], RAW_INDEX["mz_fl_Nm"]
N_RAW = len(RAW_COLUMNS)

# Float parameters (par) and integer parameters (ip) of the loop.
(P_DT, P_L, P_TRACK, P_ACK, P_DMAX, P_DRATE, P_R, P_KT, P_CT, P_SIGMA, P_LS, P_MASS, P_TDRIVE, P_TBRAKE,
 P_MU0, P_DS, P_LOOK, P_PREVIEW, P_GAIN, P_OFFSET, P_KUS, P_BRAKE_T0, P_BRAKE_DEC, P_GAP, P_STANDSTILL,
 P_BUMPER, P_LEAD_HALF, P_HCG, P_GRIP, P_RR, P_DRAG, P_LIFT_F, P_LIFT_R, P_LF, P_LR, P_GATE, N_PAR) = range(37)
(I_STEER_MODE, I_SPEED_MODE, I_CHASSIS, I_HAS_LEAD, I_ACC, I_WHEEL, I_HEAD, I_SPIN, I_STEERQ, I_STEERA,
 I_TORQUE, I_SUSPQ, I_TIRE_MODEL, I_FLAT, I_GATE, I_BODY_GEOM, I_FLOOR_GEOM, I_CONTACT_BIT) = (
    0, 1, 2, 3, 4, 5, 9, 13, 17, 19, 21, 25, 29, 30, 31, 32, 33, 34)
N_IP = 35
#: The chassis box is checked against the floor only while it is within this distance of it (plus
#: what it can move in one step) [m]: everywhere else the check finds nothing, so skipping it changes
#: no bit of the result and saves MuJoCo's collision pass, ~7 % of a step (benchmarks/bench_simulate.py).
CONTACT_GATE_M = 0.05
# Loop state (st): tire deflection states v (4, lateral) and u (4, longitudinal) [m], speed integrator,
# previous steer, unwrapped yaw, road hint, last x, y, vx, vy (world) for the jump check, road hints
# of the four wheels.
S_ALPHA, S_KAPPA, S_INT, S_DELTA, S_PSI, S_HINT, S_LASTX, S_LASTY, S_LASTVX, S_LASTVY, S_WHINT, N_ST = (
    0, 4, 8, 9, 10, 11, 12, 13, 14, 15, 16, 20)


@jit
def _run(step1: Any, step2: Any, m_ptr: int, d_ptr: int, k0: int, k1: int, par: np.ndarray, ip: np.ndarray,
         st: np.ndarray, shape: np.ndarray, fz0: np.ndarray, wheel: np.ndarray, tcoef: np.ndarray,
         drive_split: np.ndarray,
         brake_split: np.ndarray,
         steer_open: np.ndarray, v_target: np.ndarray, dv_target: np.ndarray, lead: np.ndarray,
         samples: np.ndarray, verts: np.ndarray, meta: np.ndarray,
         qpos: np.ndarray, qvel: np.ndarray, qacc: np.ndarray, xpos: np.ndarray, xmat: np.ndarray,
         xipos: np.ndarray, cvel: np.ndarray, subtree_com: np.ndarray, xfrc: np.ndarray, ctrl: np.ndarray,
         sensordata: np.ndarray, frictionloss: np.ndarray, log: np.ndarray, qlog: np.ndarray,
         geom_xpos: np.ndarray, geom_xmat: np.ndarray, geom_size: np.ndarray, flags: np.ndarray) -> tuple[int, int]:
    """Steps k0 .. k1-1; returns (first step not logged, divergence code or 0).

    ``wheel`` (4, 6) per wheel: [camber at rest (roadtruth sign), camber per metre of axis travel,
    low-speed damping time of the longitudinal and lateral deflection states [s], camber stiffness
    c_γ [1/rad], pneumatic trail t_0 [m]] (see ``_wheel_table``).

    ``math.hypot`` is avoided on purpose: numba's version differs from CPython's in the last bit,
    which would break the bit-equality of the compiled and interpreted paths.

    ``flags`` (1,) int32 aliases the model's ``opt.disableflags`` (see ``_disableflags_view``): with
    ``ip[I_GATE] == 1`` the contact bit is set for a step whose chassis box is farther from the floor
    plane than ``par[P_GATE]`` plus twice what the box can move in a step (``_floor_clearance``),
    from the kinematics of the step before, so MuJoCo skips a collision check that would find nothing.
    """
    dt = par[P_DT]
    cb = ip[I_CHASSIS]
    samples_ds = par[P_DS]
    gate = ip[I_GATE] == 1
    flags0 = flags[0]
    for k in range(k0, k1):
        if gate:
            far = False
            if k > k0:
                clear, reach = _floor_clearance(geom_xpos, geom_xmat, geom_size, ip[I_BODY_GEOM], ip[I_FLOOR_GEOM],
                                                xpos[cb], qvel)
                far = clear > par[P_GATE] + 2.0 * dt * reach
            flags[0] = flags0 | ip[I_CONTACT_BIT] if far else flags0
        step1(m_ptr, d_ptr)
        t = k * dt
        # ---- guard (state k) -------------------------------------------------------------------
        for j in range(qpos.shape[0]):
            if not math.isfinite(qpos[j]):
                return k, 1
        for j in range(qvel.shape[0]):
            if not math.isfinite(qvel[j]):
                return k, 1
        r00, r01, r02 = xmat[cb, 0], xmat[cb, 1], xmat[cb, 2]
        r10, r11, r12 = xmat[cb, 3], xmat[cb, 4], xmat[cb, 5]
        r20, r21, r22 = xmat[cb, 6], xmat[cb, 7], xmat[cb, 8]
        roll = math.atan2(r21, r22)
        pitch = -math.asin(min(max(r20, -1.0), 1.0))
        if abs(roll) > MAX_TILT_RAD:
            return k, 2
        if abs(pitch) > MAX_TILT_RAD:
            return k, 3
        x, y, z = xpos[cb, 0], xpos[cb, 1], xpos[cb, 2]
        z_above = z
        if ip[I_FLAT] == 0:
            z_above = z - road_surface(samples, samples_ds, x, y, int(st[S_HINT]))[1]
        if z_above < 0.0 or z_above > par[P_HCG] + MAX_CG_HEIGHT_ABOVE_REST_M:
            return k, 4
        if k > k0 and (math.sqrt((x - st[S_LASTX]) ** 2 + (y - st[S_LASTY]) ** 2) > MAX_STEP_JUMP_M
                       or math.sqrt((qvel[0] - st[S_LASTVX]) ** 2 + (qvel[1] - st[S_LASTVY]) ** 2) > MAX_STEP_DV_MPS):
            return k, 5
        st[S_LASTX], st[S_LASTY], st[S_LASTVX], st[S_LASTVY] = x, y, qvel[0], qvel[1]
        # ---- chassis state -------------------------------------------------------------------------
        yaw = math.atan2(r10, r00)
        dpsi = yaw - st[S_PSI]
        psi = st[S_PSI] + math.atan2(math.sin(dpsi), math.cos(dpsi))
        st[S_PSI] = psi
        cpsi, spsi = math.cos(psi), math.sin(psi)
        vwx, vwy, vwz = qvel[0], qvel[1], qvel[2]
        wbx, wby, wbz = qvel[3], qvel[4], qvel[5]
        vx = cpsi * vwx + spsi * vwy
        vy = -spsi * vwx + cpsi * vwy
        r = r20 * wbx + r21 * wby + r22 * wbz
        roll_rate = wbx + (wby * math.sin(roll) + wbz * math.cos(roll)) * math.tan(pitch)
        row = log[k]
        row[C_T], row[C_X], row[C_Y], row[C_Z] = t, x, y, z
        row[C_PSI], row[C_ROLL], row[C_PITCH] = psi, roll, pitch
        row[C_VX], row[C_VY], row[C_VZ], row[C_R], row[C_P] = vx, vy, vwz, r, roll_rate
        row[C_WB], row[C_WB + 1], row[C_WB + 2] = wbx, wby, wbz
        # ---- road and lead ------------------------------------------------------------------------
        i_road, s, _, _, rho = road_project(samples, samples_ds, x, y, int(st[S_HINT]))
        st[S_HINT] = i_road
        look = par[P_LOOK]
        _, _, e_l, psi_l, _ = road_project(samples, samples_ds, x + look * cpsi, y + look * spsi, i_road)
        dl = psi - psi_l
        row[C_S], row[C_RHO], row[C_YL], row[C_PL] = s, rho, e_l, math.atan2(math.sin(dl), math.cos(dl))
        rng = math.nan
        if ip[I_HAS_LEAD] == 1:
            lx, ly, lpsi, lv = lead[k, 0], lead[k, 1], lead[k, 2], lead[k, 3]
            bx = x + par[P_BUMPER] * cpsi
            by = y + par[P_BUMPER] * spsi
            ex = lx - par[P_LEAD_HALF] * math.cos(lpsi) - bx
            ey = ly - par[P_LEAD_HALF] * math.sin(lpsi) - by
            rng = math.sqrt(ex * ex + ey * ey)
            ux, uy = ex / max(rng, 1e-9), ey / max(rng, 1e-9)
            vbx = vwx - r * par[P_BUMPER] * spsi
            vby = vwy + r * par[P_BUMPER] * cpsi
            row[C_RR] = (lv * math.cos(lpsi) - vbx) * ux + (lv * math.sin(lpsi) - vby) * uy
            row[C_LX], row[C_LY], row[C_LV], row[C_LA] = lx, ly, lv, lead[k, 4]
        else:
            row[C_RR] = math.nan
            row[C_LX], row[C_LY], row[C_LV], row[C_LA] = math.nan, math.nan, math.nan, math.nan
        row[C_RANGE] = rng
        # ---- driver: steering ------------------------------------------------------------------------
        if ip[I_STEER_MODE] == 0:
            cmd = steer_open[k]
        else:
            cmd = path_follower(samples, samples_ds, s, x, y, psi, vx, par[P_PREVIEW], par[P_GAIN],
                                par[P_OFFSET], par[P_L], par[P_KUS])
        delta = rate_limit(st[S_DELTA], cmd, par[P_DRATE], par[P_DMAX], dt)
        st[S_DELTA] = delta
        d_fl, d_fr = ackermann_angles(delta, par[P_L], par[P_TRACK], par[P_ACK])
        ctrl[ip[I_STEERA]] = d_fl
        ctrl[ip[I_STEERA + 1]] = d_fr
        row[C_CMD] = delta
        row[C_DFL] = qpos[ip[I_STEERQ]]
        row[C_DFR] = qpos[ip[I_STEERQ + 1]]
        # ---- driver: speed ---------------------------------------------------------------------------
        mode = ip[I_SPEED_MODE]
        if mode == 2:
            vt = follow_lead_target(lead[k, 3], rng, vx, par[P_GAP], par[P_STANDSTILL])
            a_dem, st[S_INT] = speed_controller(0, t, vx, vt, 0.0, st[S_INT], 0.0, 0.0, dt)
        else:
            a_dem, st[S_INT] = speed_controller(mode, t, vx, v_target[k], dv_target[k], st[S_INT],
                                                par[P_BRAKE_T0], par[P_BRAKE_DEC], dt)
        torque = par[P_MASS] * a_dem * par[P_R]
        t_drive = min(max(torque, 0.0), par[P_TDRIVE])
        t_brake = max(-torque, 0.0)
        row[C_TD], row[C_TB] = t_drive, t_brake
        for i in range(4):
            # Brakes are dry friction on the spin joint: the constraint solver holds a braked wheel at
            # rest exactly (a torque law would need a stiff explicit damper around zero spin).
            frictionloss[ip[I_SPIN + i]] = min(brake_split[i] * t_brake, par[P_TBRAKE])
            ctrl[ip[I_TORQUE + i]] = drive_split[i] * t_drive
            row[C_OMEGA + i] = qvel[ip[I_SPIN + i]]
        # ---- tires (docs/PHYSICS.md, "Contact" and "Slip") -------------------------------------
        R = par[P_R]
        sig = par[P_SIGMA]
        for i in range(4):
            wb = ip[I_WHEEL + i]
            hb = ip[I_HEAD + i]
            cx, cy, cz = xpos[wb, 0], xpos[wb, 1], xpos[wb, 2]
            if ip[I_FLAT] == 1:
                zr, nx, ny, nz = 0.0, 0.0, 0.0, 1.0
            else:
                iw, zr, nx, ny, nz = road_surface(samples, samples_ds, cx, cy, int(st[S_WHINT + i]))
                st[S_WHINT + i] = iw
            # Contact point: foot of the perpendicular from the wheel centre to the road plane.
            h = (cz - zr) * nz
            px, py, pz = cx - h * nx, cy - h * ny, cz - h * nz
            defl = R - h
            # Tire frame: heading of the wheel carrier projected on the road plane, y = n x x.
            hx, hy, hz = xmat[hb, 0], xmat[hb, 3], xmat[hb, 6]
            hd = hx * nx + hy * ny + hz * nz
            exx, exy, exz = hx - hd * nx, hy - hd * ny, hz - hd * nz
            en = math.sqrt(exx * exx + exy * exy + exz * exz)
            exx, exy, exz = exx / en, exy / en, exz / en
            eyx, eyy, eyz = ny * exz - nz * exy, nz * exx - nx * exz, nx * exy - ny * exx
            # Inclination of the wheel plane to the road normal (> 0: top toward +y) plus kinematic camber.
            an = xmat[hb, 1] * nx + xmat[hb, 4] * ny + xmat[hb, 7] * nz
            gamma = -math.asin(min(max(an, -1.0), 1.0)) + wheel[i, 0] + wheel[i, 1] * qpos[ip[I_SUSPQ + i]]
            # Velocity of the wheel centre (cvel is [w; v] at the subtree COM of the root body), then of
            # the contact point as a point of the wheel carrier (the spin does not move it).
            ox, oy, oz = cx - subtree_com[cb, 0], cy - subtree_com[cb, 1], cz - subtree_com[cb, 2]
            vcx = cvel[wb, 3] + cvel[wb, 1] * oz - cvel[wb, 2] * oy
            vcy = cvel[wb, 4] + cvel[wb, 2] * ox - cvel[wb, 0] * oz
            vcz = cvel[wb, 5] + cvel[wb, 0] * oy - cvel[wb, 1] * ox
            wcx, wcy, wcz = cvel[hb, 0], cvel[hb, 1], cvel[hb, 2]
            rx, ry, rz = px - cx, py - cy, pz - cz
            vpx = vcx + wcy * rz - wcz * ry
            vpy = vcy + wcz * rx - wcx * rz
            vpz = vcz + wcx * ry - wcy * rx
            vxt = vpx * exx + vpy * exy + vpz * exz
            vyt = vpx * eyx + vpy * eyy + vpz * eyz
            fz = radial_load_kernel(defl, -(vcx * nx + vcy * ny + vcz * nz), par[P_KT], par[P_CT])
            re = R - max(defl, 0.0) / 3.0
            omega = qvel[ip[I_SPIN + i]]
            vsx = vxt - omega * re
            w_low = 0.0
            if sig > 0.0:
                # Transient slip: tire deflections u, v driven by the slip velocities, relaxing at
                # |v_x|/sigma (exact over the step), with damping below V_LOW (a damped spring at rest).
                rate = abs(vxt) / sig
                u, vv = st[S_KAPPA + i], st[S_ALPHA + i]
                if rate * dt > 1e-12:
                    ek = math.exp(-rate * dt)
                    u = -vsx / rate + (u + vsx / rate) * ek
                    vv = -vyt / rate + (vv + vyt / rate) * ek
                else:
                    u -= vsx * dt
                    vv -= vyt * dt
                u = min(max(u, -KAPPA_MAX * sig), KAPPA_MAX * sig)
                vv = min(max(vv, -TAN_ALPHA_MAX * sig), TAN_ALPHA_MAX * sig)
                st[S_KAPPA + i], st[S_ALPHA + i] = u, vv
                w_low = 0.5 + 0.5 * math.cos(math.pi * min(abs(vxt) / V_LOW_MPS, 1.0))
                kappa = (u - w_low * wheel[i, 2] * vsx) / sig
                alpha = math.atan((vv - w_low * wheel[i, 3] * vyt) / sig)
            else:
                vxa = max(abs(vxt), V_MIN_SLIP_MPS)
                kappa = -vsx / vxa
                alpha = -math.atan(vyt / vxa)
            mu = mu_at(par[P_MU0], verts, meta, px, py, t)
            # The tire's grip multiplies the road's mu in the peak only (logged mu stays the road's).
            mu_t = mu * par[P_GRIP]  # 1 for a tire file: the file's friction is the tire's
            if ip[I_TIRE_MODEL] == 1:
                # The slips already carry the direction (α > 0 gives F_y > 0 rolling either way), so
                # the file is evaluated as rolling forward.
                fx, fy, mz = mf61_forces(tcoef[i], fz, kappa, alpha, gamma, abs(vxt), mu_t, mu_t)
                if sig > 0.0 and w_low > 0.0:
                    # The file's zero-slip forces (ply steer, conicity, rolling offsets) are rolling
                    # effects: they fade out toward standstill, where they would push a parked car.
                    f0x, f0y, m0z = mf61_forces(tcoef[i], fz, 0.0, 0.0, gamma, abs(vxt), mu_t, mu_t)
                    fx -= w_low * f0x
                    fy -= w_low * f0y
                    mz -= w_low * m0z
            elif ip[I_TIRE_MODEL] == 2:
                fx, fy, mz = fiala_forces(tcoef[i], fz, kappa, alpha, gamma, mu_t)
            else:
                fx, fy, mz = combined_with_camber(alpha, kappa, gamma, fz, mu_t, shape[i], fz0[i], par[P_LS],
                                                  wheel[i, 4], wheel[i, 5])
            if not (math.isfinite(fx) and math.isfinite(fy) and math.isfinite(fz) and math.isfinite(mz)):
                return k, 6  # MuJoCo would silently reset the state on a NaN force
            Fx = fx * exx + fy * eyx + fz * nx
            Fy = fx * exy + fy * eyy + fz * ny
            Fz = fx * exz + fy * eyz + fz * nz
            xfrc[wb, 0], xfrc[wb, 1], xfrc[wb, 2] = Fx, Fy, Fz
            lx_, ly_, lz_ = px - xipos[wb, 0], py - xipos[wb, 1], pz - xipos[wb, 2]
            xfrc[wb, 3] = ly_ * Fz - lz_ * Fy + mz * nx
            xfrc[wb, 4] = lz_ * Fx - lx_ * Fz + mz * ny
            xfrc[wb, 5] = lx_ * Fy - ly_ * Fx + mz * nz
            # Rolling resistance: the load's forward shift in the patch, a torque against the spin.
            ctrl[ip[I_TORQUE + i]] -= par[P_RR] * fz * re * math.tanh(omega / ROLLING_OMEGA_EPS)
            row[C_FZ + i], row[C_FY + i], row[C_FX + i] = fz, fy, fx
            row[C_ALPHA + i], row[C_KAPPA + i], row[C_MU + i] = alpha, kappa, mu
            row[C_GAMMA + i], row[C_MZ + i] = gamma, mz
        # ---- aero: drag against the chassis velocity at its COM, lift at the axles along body z ----
        vv2 = vwx * vwx + vwy * vwy + vwz * vwz
        if par[P_DRAG] > 0.0 or par[P_LIFT_F] != 0.0 or par[P_LIFT_R] != 0.0:
            vmag = math.sqrt(vv2)
            dfx, dfy, dfz = -par[P_DRAG] * vmag * vwx, -par[P_DRAG] * vmag * vwy, -par[P_DRAG] * vmag * vwz
            lf_ = par[P_LIFT_F] * vx * vx
            lr_ = par[P_LIFT_R] * vx * vx
            tx = ty = tz = 0.0
            for side in range(2):
                arm = par[P_LF] if side == 0 else -par[P_LR]
                lift = lf_ if side == 0 else lr_
                # axle point in the world, relative to the chassis COM; force along body z
                ax_w = x + r00 * arm - xipos[cb, 0]
                ay_w = y + r10 * arm - xipos[cb, 1]
                az_w = z + r20 * arm - xipos[cb, 2]
                fxl, fyl, fzl = lift * r02, lift * r12, lift * r22
                tx += ay_w * fzl - az_w * fyl
                ty += az_w * fxl - ax_w * fzl
                tz += ax_w * fyl - ay_w * fxl
                dfx += fxl
                dfy += fyl
                dfz += fzl
            xfrc[cb, 0], xfrc[cb, 1], xfrc[cb, 2] = dfx, dfy, dfz
            xfrc[cb, 3], xfrc[cb, 4], xfrc[cb, 5] = tx, ty, tz
        for j in range(qpos.shape[0]):
            qlog[k, j] = qpos[j]
        step2(m_ptr, d_ptr)
        # ---- accelerations of state k (computed by step2) ---------------------------------------
        a0 = ip[I_ACC]
        fsx, fsy, fsz = sensordata[a0], sensordata[a0 + 1], sensordata[a0 + 2]
        # Specific force minus gravity seen in the body frame: a = f + R^T g, g = (0, 0, -G).
        abx, aby, abz = fsx - G * r20, fsy - G * r21, fsz - G * r22
        row[C_FS], row[C_FS + 1], row[C_FS + 2] = fsx, fsy, fsz
        row[C_AB], row[C_AB + 1], row[C_AB + 2] = abx, aby, abz
        awx = r00 * abx + r01 * aby + r02 * abz
        awy = r10 * abx + r11 * aby + r12 * abz
        row[C_AX] = cpsi * awx + spsi * awy
        row[C_AY] = -spsi * awx + cpsi * awy
        dwx, dwy, dwz = qacc[3], qacc[4], qacc[5]
        row[C_DWB], row[C_DWB + 1], row[C_DWB + 2] = dwx, dwy, dwz
        row[C_RDOT] = r20 * dwx + r21 * dwy + r22 * dwz
    return k1, 0


@jit
def _floor_clearance(geom_xpos: np.ndarray, geom_xmat: np.ndarray, geom_size: np.ndarray, box: int, plane: int,
                     body_pos: np.ndarray, qvel: np.ndarray) -> tuple[float, float]:
    """Distance [m] of the box geom ``box``'s lowest corner above the plane geom ``plane`` (negative:
    through it), and a bound [m/s] on the speed of any point of the box (free joint: ``qvel[0:3]``
    the body origin's world velocity, ``qvel[3:6]`` its angular velocity)."""
    nx, ny, nz = geom_xmat[plane, 2], geom_xmat[plane, 5], geom_xmat[plane, 8]
    cx, cy, cz = geom_xpos[box, 0], geom_xpos[box, 1], geom_xpos[box, 2]
    d = nx * (cx - geom_xpos[plane, 0]) + ny * (cy - geom_xpos[plane, 1]) + nz * (cz - geom_xpos[plane, 2])
    for a in range(3):
        d -= abs(nx * geom_xmat[box, a] + ny * geom_xmat[box, 3 + a] + nz * geom_xmat[box, 6 + a]) * geom_size[box, a]
    ox, oy, oz = cx - body_pos[0], cy - body_pos[1], cz - body_pos[2]
    sx, sy, sz = geom_size[box, 0], geom_size[box, 1], geom_size[box, 2]
    arm = math.sqrt(ox * ox + oy * oy + oz * oz) + math.sqrt(sx * sx + sy * sy + sz * sz)
    v = math.sqrt(qvel[0] * qvel[0] + qvel[1] * qvel[1] + qvel[2] * qvel[2])
    w = math.sqrt(qvel[3] * qvel[3] + qvel[4] * qvel[4] + qvel[5] * qvel[5])
    return d, v + w * arm


def _disableflags_view(m: mujoco.MjModel) -> np.ndarray | None:
    """A (1,) int32 array aliasing ``m.opt.disableflags`` in the model's memory, or None if its place
    cannot be told for certain. The bindings give no address for it, so it is found: the one aligned
    word of the struct's head that follows three different values written through the bindings."""
    n_words = 512  # 2 KB: the size fields and the options, well inside the struct
    head = np.ctypeslib.as_array((ctypes.c_int32 * n_words).from_address(m._address))
    original = int(m.opt.disableflags)
    found = None
    try:
        candidates = np.ones(n_words, dtype=bool)
        for probe in (0x5A5A5, 0x2A2A2, original ^ 0x7FFF):
            m.opt.disableflags = probe
            candidates &= head == probe
        hits = np.flatnonzero(candidates)
        if hits.size == 1:
            found = hits
    finally:
        m.opt.disableflags = original
    if found is None:
        return None
    view = head[found[0]:found[0] + 1]
    return view if int(view[0]) == original else None


# ---- setup -----------------------------------------------------------------------------------------

def _mujoco_library() -> ctypes.CDLL:
    """The MuJoCo shared library shipped with the Python bindings (the ABI is pinned by the version)."""
    here = Path(os.path.dirname(mujoco.__file__))
    candidates = sorted(here.glob(f"libmujoco.so.{mujoco.__version__}")) or sorted(here.glob("libmujoco*.so*")) \
        or sorted(here.glob("libmujoco*.dylib")) or sorted(here.glob("mujoco*.dll"))
    if not candidates:
        raise RuntimeError(f"no MuJoCo shared library next to {here}")
    return ctypes.CDLL(str(candidates[0]))


_STEP_FUNCTIONS: tuple[Any, Any] | None = None


def _step_functions() -> tuple[Any, Any]:
    global _STEP_FUNCTIONS
    if _STEP_FUNCTIONS is None:
        lib = _mujoco_library()
        fns = []
        for name in ("mj_step1", "mj_step2"):
            f = getattr(lib, name)
            # Pointers passed as machine-word integers (the raw addresses of MjModel/MjData).
            f.argtypes = [ctypes.c_size_t, ctypes.c_size_t]
            f.restype = None
            fns.append(f)
        _STEP_FUNCTIONS = (fns[0], fns[1])
    return _STEP_FUNCTIONS


#: Parsed vehicle sets (an edited file is read again): a suite or a sweep simulates the same set many
#: times, and parsing its YAML costs more than building the model.
_VEHICLES = ParsedFiles()


def _resolve_vehicle(scenario: Any, vehicle: VehicleParams | str | None) -> VehicleParams:
    ref = scenario.vehicle if vehicle is None else vehicle
    if isinstance(ref, VehicleParams):
        return ref
    path = Path(ref)
    if path.suffix.lower() not in (".yaml", ".yml"):
        path = vehicles_dir() / f"{ref}.yaml"  # a shipped set's name (roadtruth.harness.truth.vehicle.load_vehicle)
    return _VEHICLES.get(path, lambda: load_vehicle(ref))  # not a file: load_vehicle says why


@functools.lru_cache(maxsize=32)
def _shape_table(front: Any, rear: Any) -> np.ndarray:
    """``shape_array`` of a pair of axle tires, kept: its peak-slip bisections run in the interpreter.
    Shared between runs: ``_run`` only reads it (left writeable, so the compiled signature is the same)."""
    return shape_array(front, rear)


def _lead_track(scenario: Any, v: VehicleParams, t: np.ndarray) -> np.ndarray:
    """(n, 5) lead [x, y, psi, v, a] on the time grid (kinematic, on the road centre line).

    ``a`` [m/s^2] is the exact derivative of the piecewise-linear speed profile: the slope of the
    segment holding ``t`` (right-continuous at a breakpoint), 0 outside the points.
    """
    out = np.full((t.shape[0], 5), np.nan)
    if scenario.lead is None:
        return out
    s = scenario.lead.path_coordinate(t, v.lf_m)
    x, y, psi = scenario.road.pose_at(s)
    out[:, 0], out[:, 1], out[:, 2], out[:, 3] = x, y, psi, scenario.lead.speed(t)
    pts = np.asarray(scenario.lead.speed_points, dtype=np.float64)
    slopes = np.append(np.diff(pts[:, 1]) / np.diff(pts[:, 0]), 0.0)
    seg = np.searchsorted(pts[:, 0], t, side="right") - 1
    out[:, 4] = np.where(seg >= 0, slopes[np.clip(seg, 0, None)], 0.0)
    return out


def _initial_state(m: mujoco.MjModel, d: mujoco.MjData, v: VehicleParams, scenario: Any) -> None:
    """Road start pose at the initial speed, suspension at its static equilibrium, wheels rolling."""
    mujoco.mj_resetData(m, d)
    x0, y0, psi0 = (float(a) for a in scenario.road.samples[0, 1:4])
    v0 = scenario.initial_speed_mps
    d.qpos[0:3] = (x0, y0, v.h_cg_m)
    d.qpos[3:7] = (math.cos(psi0 / 2.0), 0.0, 0.0, math.sin(psi0 / 2.0))
    d.qvel[0:3] = (v0 * math.cos(psi0), v0 * math.sin(psi0), 0.0)
    defl = corner_geometry(v).tire_deflection
    for i, c in enumerate(CORNERS):
        d.qvel[m.jnt_dofadr[m.joint(f"spin_{c}").id]] = v0 / (v.wheel_radius_m - defl[i] / 3.0)


def _wheel_table(v: VehicleParams, dt_s: float) -> np.ndarray:
    """Per-wheel constants of the loop (4, 6); see ``_run``.

    Camber: automotive camber (negative = top toward the car's centre) becomes roadtruth's sign
    (positive = top toward +y) by the side: +1 on the left wheels, −1 on the right ones; the gain is
    per metre of vertical travel, and the axis travel q moves the wheel q cos θ vertically.
    Low-speed damping of the deflection states: for the tire spring C/σ against the quarter car's mass
    the time 2ζ/ω_n gives the damping ratio ζ; longitudinally it is also kept below half the time
    the wheel's spin inertia needs against it over one step, so the explicit coupling stays stable.
    """
    s, tires = v.suspension, v.tires
    g = corner_geometry(v)
    sig = tires.relaxation_length_m
    out = np.zeros((4, 6))
    for i in range(4):
        front = i < 2
        side = 1.0 if i % 2 == 0 else -1.0
        ax = tires.front if front else tires.rear
        out[i, 0] = side * (s.static_camber_f_rad if front else s.static_camber_r_rad)
        out[i, 1] = side * (s.camber_gain_f_radpm if front else s.camber_gain_r_radpm) * math.cos(g.incline[i])
        if sig > 0.0:
            m_q = g.fz_static[i] / G
            k_x = ax.Bx * ax.Cx * g.fz_static[i] / sig
            k_y = ax.By * ax.Cy * g.fz_static[i] / sig
            tau_x = 2.0 * STANDSTILL_DAMPING_RATIO / math.sqrt(k_x / m_q)
            tau_spin = 0.5 * v.wheel_spin_inertia_kgm2 / (k_x * v.wheel_radius_m ** 2 * dt_s)
            out[i, 2] = min(tau_x, tau_spin)
            out[i, 3] = 2.0 * STANDSTILL_DAMPING_RATIO / math.sqrt(k_y / m_q)
        out[i, 4], out[i, 5] = ax.camber_stiffness, ax.trail_m
    return out


def _events(scenario: Any, frame_mu: np.ndarray, t: np.ndarray, status_t: float | None,
            status: str) -> tuple[tuple[float, str], ...]:
    """Scenario events + friction changes under each wheel + driver actions (+ divergence)."""
    names = {v: k for k, v in SURFACES.items()}
    for p in scenario.friction.patches:
        names.setdefault(p.mu, p.name)
    ev: list[tuple[float, str]] = [(float(a), str(b)) for a, b in scenario.events]
    if t.size:
        for i, w in enumerate(WHEELS):
            mu = frame_mu[:, i]
            for k in np.flatnonzero(mu[1:] != mu[:-1]) + 1:
                label = names.get(float(mu[k]), "a patch")
                ev.append((float(t[k]), f"{w} enters {label} (μ {mu[k]:g})"))
    own_times = [float(a) for a, _ in scenario.events]
    duration = t[-1] if t.size else -1.0

    def add_driver_event(t_s: float, label: str) -> None:
        # The scenario usually labels its own manoeuvre start; do not say it twice.
        if t_s <= duration and not any(abs(t_s - a) < 1e-6 for a in own_times):
            ev.append((t_s, label))

    st = scenario.driver.steer
    if st.type != "path_follower" and (st.amplitude_rad != 0.0 or st.type == "ramp"):
        add_driver_event(st.t_start_s, f"steer {st.type.replace('_', ' ')} starts")
    sp = scenario.driver.speed
    if sp.type == "brake":
        add_driver_event(sp.t_start_s, f"brake {sp.decel_mps2:g} m/s² starts")
    if status_t is not None:
        ev.append((status_t, status))
    return tuple(sorted(ev, key=lambda e: e[0]))


@dataclass(frozen=True, eq=False)
class _Prepared:
    """Everything ``_run`` needs for one simulation, built by ``_prepare`` (no step taken yet)."""

    vehicle: VehicleParams
    model: mujoco.MjModel
    data: mujoco.MjData
    xml: str
    t: np.ndarray  # (n,) step times [s]
    fz_static: np.ndarray  # (4,) static wheel loads [N]
    log: np.ndarray  # (n, N_RAW) raw log, written by _run
    qlog: np.ndarray  # (n, nq) generalized positions per step, written by _run
    args: tuple[Any, ...]  # _run's arguments after (step1, step2, m_ptr, d_ptr)


def _prepare(scenario: Any, vehicle: VehicleParams | str | None, dt_s: float) -> _Prepared:
    """Validate the inputs, build the physics model at its initial state and the loop's arrays."""
    if not (dt_s > 0.0 and dt_s <= 0.01):
        raise ScenarioError(f"time step must be in (0, 0.01] s (got {dt_s!r})", field="dt_s")
    v = _resolve_vehicle(scenario, vehicle)
    if v.tires.relaxation_length_m <= 0.0 and scenario.initial_speed_mps < MIN_START_SPEED_NO_RELAXATION_MPS:
        raise ScenarioError(f"initial speed {scenario.initial_speed_mps:g} m/s is below "
                            f"{MIN_START_SPEED_NO_RELAXATION_MPS:g} m/s, the limit of kinematic slips (vehicle "
                            f"{v.name} has no relaxation length, so no transient slip at standstill)",
                            source=scenario.path, field="initial_speed_mps")
    xml = build_mjcf(v, scenario, timestep_s=dt_s)
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    _initial_state(m, d, v, scenario)

    n = int(round(scenario.duration_s / dt_s)) + 1
    t = np.arange(n) * dt_s
    drv = scenario.driver
    steer_open = np.ascontiguousarray(drv.steer_profile(t))
    v_target, dv_target = (np.ascontiguousarray(a) for a in drv.speed_target(t, scenario.initial_speed_mps))
    lead = _lead_track(scenario, v, t)
    verts, meta = scenario.friction.arrays()
    g = corner_geometry(v)

    par = np.zeros(N_PAR)
    par[P_DT], par[P_L], par[P_TRACK], par[P_ACK] = dt_s, v.wheelbase_m, v.track_f_m, v.steering.ackermann
    par[P_DMAX] = v.steering.max_road_wheel_angle_rad
    par[P_DRATE] = MAX_HANDWHEEL_RATE_RADPS / v.steering.ratio
    par[P_R], par[P_KT], par[P_CT] = v.wheel_radius_m, v.tires.radial_stiffness_Npm, v.tires.radial_damping_Nspm
    par[P_SIGMA], par[P_LS] = v.tires.relaxation_length_m, v.tires.load_sensitivity
    par[P_GRIP] = 1.0 if v.tires.model == "mf61" else v.tires.grip
    par[P_MASS], par[P_TDRIVE], par[P_TBRAKE] = v.mass_kg, v.drivetrain.max_drive_torque_Nm, v.drivetrain.max_brake_torque_Nm
    par[P_MU0], par[P_DS], par[P_LOOK] = scenario.friction.mu_default, scenario.road.ds_m, scenario.lookahead_m
    par[P_PREVIEW], par[P_GAIN], par[P_OFFSET] = drv.steer.preview_s, drv.steer.gain, drv.steer.lane_offset_m
    par[P_KUS] = v.understeer_gradient_radpmps2
    par[P_BRAKE_T0], par[P_BRAKE_DEC] = drv.speed.t_start_s, drv.speed.decel_mps2
    par[P_GAP], par[P_STANDSTILL] = drv.speed.time_gap_s, drv.speed.standstill_m
    par[P_BUMPER], par[P_LEAD_HALF], par[P_HCG] = v.lf_m + FRONT_OVERHANG_M, LEAD_LENGTH_M / 2.0, v.h_cg_m
    par[P_RR] = v.tires.rolling_resistance
    half_rho = 0.5 * v.aero.air_density_kgpm3
    par[P_DRAG], par[P_LIFT_F], par[P_LIFT_R] = (half_rho * v.aero.drag_area_m2, half_rho * v.aero.lift_area_f_m2,
                                                 half_rho * v.aero.lift_area_r_m2)
    par[P_LF], par[P_LR] = v.lf_m, v.lr_m

    ip = np.zeros(N_IP, dtype=np.int64)
    ip[I_STEER_MODE] = 1 if drv.closed_loop_steer else 0
    ip[I_SPEED_MODE] = {"hold": 0, "profile": 0, "brake": 1, "follow_lead": 2}[drv.speed.type]
    ip[I_CHASSIS] = m.body("chassis").id
    ip[I_HAS_LEAD] = 1 if scenario.lead is not None else 0
    ip[I_ACC] = m.sensor_adr[m.sensor("imu_acc").id]
    for i, c in enumerate(CORNERS):
        ip[I_WHEEL + i] = m.body(f"wheel_{c}").id
        ip[I_HEAD + i] = m.body(f"knuckle_{c}" if i < 2 else f"upright_{c}").id
        ip[I_SPIN + i] = m.jnt_dofadr[m.joint(f"spin_{c}").id]
        ip[I_TORQUE + i] = m.actuator(f"torque_{c}").id
        ip[I_SUSPQ + i] = m.jnt_qposadr[m.joint(f"susp_{c}").id]
    ip[I_TIRE_MODEL] = TIRE_MODEL_CODES[v.tires.model]
    ip[I_FLAT] = 1 if scenario.road.is_flat else 0
    flags = _disableflags_view(m)
    ip[I_GATE] = 1 if flags is not None and math.isfinite(CONTACT_GATE_M) else 0
    if flags is None:
        flags = np.zeros(1, dtype=np.int32)
    ip[I_BODY_GEOM], ip[I_FLOOR_GEOM] = m.geom("body").id, m.geom("floor").id
    ip[I_CONTACT_BIT] = int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    par[P_GATE] = CONTACT_GATE_M + float(m.geom_margin[ip[I_BODY_GEOM]] + m.geom_margin[ip[I_FLOOR_GEOM]])
    for i, c in enumerate(CORNERS[:2]):
        ip[I_STEERQ + i] = m.jnt_qposadr[m.joint(f"steer_{c}").id]
        ip[I_STEERA + i] = m.actuator(f"steer_{c}").id

    st = np.zeros(N_ST)
    st[S_PSI] = float(scenario.road.samples[0, 3])
    bias = v.drivetrain.brake_bias_front
    brake_split = np.array([bias / 2, bias / 2, (1 - bias) / 2, (1 - bias) / 2])
    drive_split = np.array(DRIVE_SPLIT[v.drivetrain.layout], dtype=np.float64)
    log = np.full((n, N_RAW), np.nan)
    qlog = np.zeros((n, m.nq))
    args = (0, n, par, ip, st, _shape_table(v.tires.front, v.tires.rear), np.ascontiguousarray(g.fz_static),
            _wheel_table(v, dt_s), wheel_coefficients(v.tires), drive_split, brake_split, steer_open, v_target, dv_target, lead,
            np.ascontiguousarray(scenario.road.samples), verts, meta,
            d.qpos, d.qvel, d.qacc, d.xpos, d.xmat, d.xipos, d.cvel, d.subtree_com, d.xfrc_applied, d.ctrl,
            d.sensordata, m.dof_frictionloss, log, qlog, d.geom_xpos, d.geom_xmat, m.geom_size, flags)
    return _Prepared(v, m, d, xml, t, g.fz_static, log, qlog, args)


def simulate(scenario: Any, vehicle: VehicleParams | str | None = None, seed: int | None = None,
             dt_s: float = 0.001, *, compiled: bool = True) -> Truth:
    """Simulate a scenario and return its ground truth.

    Parameters
    ----------
    scenario : ``roadtruth.harness.truth.scenario.Scenario``.
    vehicle : a ``VehicleParams``, a set name/path, or None for the scenario's own vehicle.
    seed : recorded in the result (default: the scenario's); the truth itself has no randomness.
    dt_s : simulation step [s] (1 kHz default).
    compiled : run the numba-compiled loop (default) or the same loop interpreted with the
        official MuJoCo bindings (the reference path; identical results, ~100x slower).

    Returns
    -------
    Truth; ``status`` is ``"ok"`` or ``"diverged: <cause> at t=<t> s"`` with the frame truncated.

    Raises
    ------
    ScenarioError : initial speed below 3 m/s, or a step that is not positive.
    """
    p = _prepare(scenario, vehicle, dt_s)
    v, m, d, xml, t, log, qlog, args = p.vehicle, p.model, p.data, p.xml, p.t, p.log, p.qlog, p.args
    drv = scenario.driver
    flags = args[-1]
    flags0 = int(flags[0])
    if compiled:
        step1, step2 = _step_functions()
        k_end, code = _run(step1, step2, m._address, d._address, *args)
    else:
        def step1(_m: int, _d: int) -> None:
            mujoco.mj_step1(m, d)

        def step2(_m: int, _d: int) -> None:
            mujoco.mj_step2(m, d)

        k_end, code = _run.py_func(step1, step2, 0, 0, *args)
    flags[0] = flags0  # the loop leaves the contact bit as its last step set it (or a divergence left it)

    status, status_t = "ok", None
    if code != 0:
        status_t = float(k_end * dt_s)
        status = f"diverged: {DIVERGENCE_CAUSES[code]} at t={status_t:.3f} s"
    frame = build_frame(log[:k_end], v.lf_m, v.lr_m)
    # What the car did, found on the finished frame (roadtruth.harness.truth.truth_events); road-relative checks
    # only where the driver follows the road (an open-loop profile leaves the nominal road by design).
    happened = detect_events(frame, fz_static_N=p.fz_static, road=scenario.road if drv.closed_loop_steer else None,
                             half_track_m=0.5 * v.track_f_m,
                             divergence=None if code == 0 else (status_t, DIVERGENCE_CAUSES[code]))
    if v.tires.model == "mf61":
        tf = read_tire_file(v.tires.file)
        # The file's ranges are in its ISO signs: slip angle and inclination flip.
        happened = tuple(sorted([*happened, *detect_tire_range(frame, {
            "alpha_rad": (-tf.alpmax_rad, -tf.alpmin_rad), "kappa": (tf.kpumin, tf.kpumax),
            "gamma_rad": (-tf.cammax_rad, -tf.cammin_rad), "fz_N": (tf.fzmin_N, tf.fzmax_N)})], key=lambda e: e.t_s))
    events = _events(scenario, log[:k_end, C_MU:C_MU + 4], t[:k_end], status_t, status)
    # The roll-over is already there as the simulator's divergence event.
    events = tuple(sorted([*events, *((e.t_s, e.label) for e in happened if e.kind != "rolled over")],
                          key=lambda e: e[0]))
    return Truth(scenario=scenario, vehicle=v, seed=int(scenario.seed if seed is None else seed), dt_s=dt_s,
                 frame=frame, qpos=qlog[:k_end], model_xml=xml, status=status, events=events,
                 truth_events=happened)
