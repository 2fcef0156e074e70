"""Replay vehicles: the fields the observers use, and the rest of a full vehicle set derived from them.

A replay vehicle (``kind: replay``, docs/VEHICLES.md) gives mass, yaw inertia, l_f, l_r, the axle
cornering stiffnesses, grip, steering ratio and wheel radius. The single-track observers use only
those (and the tire shape, for which the shipped sets' shape is taken unless ``tire_shape`` is given).
``replay_vehicle_mapping`` completes it to a full mapping that ``roadtruth.harness.truth.vehicle.parse_vehicle``
validates like any other file, and says in one line which fields were derived and by which rule:

- roll / pitch inertia: 0.2 / 0.9 × yaw inertia (the shipped sedan's ratios, rounded; Ix + Iy ≥ Iz);
- track: ``track_m`` or 0.6 × wheelbase; CG height: ``h_cg_m`` or 0.21 × wheelbase;
- unsprung mass per corner: 2 % of the mass; wheel spin inertia: 0.42 × unsprung mass × r²;
- suspension: 1.5 Hz ride frequency of each corner's sprung mass, damping ratio 0.3, anti-roll bars
  0.6 / 0.25 × the front / rear corner stiffness;
- tires: Magic Formula shape C_y 1.9, E_y 0.97, B_x 12, C_x 1.65, E_x 0.5; radial stiffness 250 kN/m;
- drivetrain: rwd, drive torque for 0.5 g, brake torque per wheel for 1.2 g, 60 % front bias;
- steering: ``max_road_wheel_angle_rad`` or 0.6 rad, full Ackermann.
"""

from __future__ import annotations

import math
from typing import Any

from roadtruth.harness.errors import VehicleError
from roadtruth.harness.files.strict_yaml import short_repr

G = 9.81  # m/s^2

#: Fields a replay vehicle must give (what the observers use).
REPLAY_REQUIRED = ("name", "mass_kg", "yaw_inertia_kgm2", "lf_m", "lr_m", "cornering_stiffness_f_Npr",
                   "cornering_stiffness_r_Npr", "grip", "steering_ratio", "wheel_radius_m")
#: Fields it may give; everything else of a full set is derived.
REPLAY_OPTIONAL = ("kind", "description", "source", "track_m", "h_cg_m", "max_road_wheel_angle_rad", "tire_shape")
#: Full-set field -> the replay vehicle's own name, so that a range error names the field of the file.
FIELD_NAMES = {
    "tires.front.cornering_stiffness_Npr": "cornering_stiffness_f_Npr",
    "tires.rear.cornering_stiffness_Npr": "cornering_stiffness_r_Npr", "tires.grip": "grip",
    "steering.ratio": "steering_ratio", "steering.max_road_wheel_angle_rad": "max_road_wheel_angle_rad",
    "track_f_m": "track_m", "tires.front.Cy": "tire_shape.Cy", "tires.front.Ey": "tire_shape.Ey",
}
TIRE_SHAPE = {"Cy": 1.9, "Ey": 0.97, "Bx": 12.0, "Cx": 1.65, "Ex": 0.5}


def _num(data: dict[str, Any], key: str, errors: list[str]) -> float:
    v = data.get(key)
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v <= 0:
        errors.append(f"{key}: {'required field is missing' if v is None else f'must be a positive number (got {short_repr(v)})'}")
        return math.nan
    return float(v)


def replay_vehicle_mapping(data: dict[str, Any], source: str) -> tuple[dict[str, Any], str]:
    """A full vehicle mapping from a replay vehicle mapping, and the one-line note of what was derived.

    Raises one ``VehicleError`` listing every missing, unknown or non-positive field; the ranges of the
    given values are then checked by ``parse_vehicle`` on the full mapping (field names are the same
    except ``cornering_stiffness_*_Npr`` -> ``tires.*.cornering_stiffness_Npr``, ``grip`` ->
    ``tires.grip``, ``steering_ratio`` -> ``steering.ratio``).
    """
    errors: list[str] = []
    for key in sorted(set(data) - set(REPLAY_REQUIRED) - set(REPLAY_OPTIONAL)):
        errors.append(f"{key}: unknown field of a replay vehicle (known: "
                      f"{', '.join(REPLAY_REQUIRED + REPLAY_OPTIONAL)}; docs/VEHICLES.md)")
    if not isinstance(data.get("name"), str) or not data.get("name"):
        errors.append("name: required field is missing" if "name" not in data else "name: must be a string")
    m, iz, lf, lr, cf, cr, grip, ratio, r = (_num(data, k, errors) for k in REPLAY_REQUIRED[1:])
    shape = dict(TIRE_SHAPE)
    given_shape = data.get("tire_shape", {})
    if not isinstance(given_shape, dict) or set(given_shape) - {"Cy", "Ey"}:
        errors.append("tire_shape: must be a mapping of Cy and Ey (the lateral Magic Formula shape)")
    else:
        shape.update(given_shape)
    if errors:
        raise VehicleError("; ".join(errors), source=source)
    L = lf + lr
    track = data.get("track_m", round(0.6 * L, 3))
    h_cg = data.get("h_cg_m", round(0.21 * L, 3))
    unsprung = max(1.0, round(0.02 * m, 1))
    sprung = m - 4.0 * unsprung
    corner_f, corner_r = sprung * lr / L / 2.0, sprung * lf / L / 2.0
    omega = 2.0 * math.pi * 1.5  # ride frequency [rad/s]
    k_f, k_r = omega**2 * corner_f, omega**2 * corner_r
    full: dict[str, Any] = {
        "name": data["name"], "description": data.get("description", ""), "source": data.get("source", ""),
        "mass_kg": m, "yaw_inertia_kgm2": iz, "roll_inertia_kgm2": round(0.2 * iz, 1),
        "pitch_inertia_kgm2": round(0.9 * iz, 1), "lf_m": lf, "lr_m": lr, "track_f_m": track, "track_r_m": track,
        "h_cg_m": h_cg, "wheel_radius_m": r, "unsprung_mass_kg": unsprung,
        "wheel_spin_inertia_kgm2": max(0.01, round(0.42 * unsprung * r * r, 3)),
        "suspension": {"stiffness_f_Npm": round(k_f), "stiffness_r_Npm": round(k_r),
                       "damping_f_Nspm": round(2 * 0.3 * math.sqrt(k_f * corner_f)),
                       "damping_r_Nspm": round(2 * 0.3 * math.sqrt(k_r * corner_r)),
                       "arb_f_Npm": round(0.6 * k_f), "arb_r_Npm": round(0.25 * k_r), "travel_m": 0.12},
        "tires": {"front": {"cornering_stiffness_Npr": cf, **shape}, "rear": {"cornering_stiffness_Npr": cr, **shape},
                  "radial_stiffness_Npm": 250000.0, "grip": grip},
        "drivetrain": {"layout": "rwd", "max_drive_torque_Nm": round(0.5 * m * G * r, 1),
                       "max_brake_torque_Nm": round(1.2 * m * G * r / 4.0, 1), "brake_bias_front": 0.6},
        "steering": {"ratio": ratio, "max_road_wheel_angle_rad": data.get("max_road_wheel_angle_rad", 0.6)},
    }
    derived = ["roll/pitch inertia (0.2/0.9 x yaw inertia)"]
    if "track_m" not in data:
        derived.append(f"track {track:g} m (0.6 x wheelbase)")
    if "h_cg_m" not in data:
        derived.append(f"CG height {h_cg:g} m (0.21 x wheelbase)")
    derived += ["unsprung mass and wheel inertia", "suspension (1.5 Hz ride, damping ratio 0.3)"]
    if "tire_shape" not in data:
        derived.append("tire shape (Cy 1.9, Ey 0.97)")
    derived.append("drivetrain")
    if "max_road_wheel_angle_rad" not in data:
        derived.append("max road-wheel angle 0.6 rad")
    note = (f"replay vehicle {data['name']}: derived {', '.join(derived)}; the replayed observers use "
            "only the given fields and the tire shape")
    return full, note
