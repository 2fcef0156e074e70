"""Vehicle parameter sets: YAML data files, validated on load, exposed as frozen dataclasses.

A set describes the whole car: rigid-body data at the CG, geometry, suspension, tires (Magic Formula
shape per axle), drivetrain and steering. Observers read the bicycle-model view of the same set
(``mass_kg``, ``yaw_inertia_kgm2``, ``lf_m``, ``lr_m``, ``cornering_stiffness_f_Npr`` …), so
the truth model and the observers are built from one source.

Tire slope. With ``D = mu * Fz`` the Magic Formula's initial slope is ``B * C * D``; summed over an
axle at static load and mu = 1 it is the axle cornering stiffness
``C_alpha = B * C * Fz_axle``. A file may give ``By`` directly or ``cornering_stiffness_Npr``, from
which ``By = C_alpha / (Cy * Fz_axle_static)`` is derived (the file says which).

Replay vehicles. A file with ``kind: replay`` gives only what the observers use (mass, yaw inertia,
l_f, l_r, axle cornering stiffnesses, grip, steering ratio, wheel radius); ``replay_vehicle_mapping``
derives the rest by the rules of docs/VEHICLES.md and ``VehicleParams.derived_note`` says which.
It is accepted by ``replay`` only (``load_vehicle(..., replay=True)``): simulating a car needs the
full set, whose suspension, inertias and drivetrain shape the truth.

Every field error of a file is reported at once, joined by ``"; "`` in one line.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from importlib.resources import files
from pathlib import Path
from typing import Any, TypeVar

from roadtruth.harness.errors import VehicleError
from roadtruth.harness.files.strict_yaml import Fields, load_mapping, short_repr

G = 9.81  # m/s^2
DRIVE_LAYOUTS = ("rwd", "fwd", "awd")
TIRE_MODELS = ("magic_formula", "mf61", "fiala")
VEHICLE_KINDS = ("full", "replay")
_T = TypeVar("_T")


@dataclass(frozen=True)
class AxleTire:
    """Magic Formula shape of one axle's tires (pure slip). B [1/rad or 1], C, E [1].

    ``camber_stiffness`` is the camber thrust per unit load and radian of inclination at zero slip
    (F_y,gamma = c_gamma F_z gamma) [1/rad]; ``trail_m`` the pneumatic trail at zero slip [m]
    (the aligning moment is M_z = -t F_y, t falling to 0 at full sliding; docs/PHYSICS.md).
    """

    By: float
    Cy: float
    Ey: float
    Bx: float
    Cx: float
    Ex: float
    stiffness_source: str  # "B given" or "B derived from cornering_stiffness_Npr"
    camber_stiffness: float = 0.0
    trail_m: float = 0.0


@dataclass(frozen=True)
class Tires:
    front: AxleTire
    rear: AxleTire
    radial_stiffness_Npm: float  # vertical tire spring per wheel
    radial_damping_Nspm: float
    relaxation_length_m: float  # first-order lag of slip, time constant sigma/|vx|
    load_sensitivity: float  # peak mu falls by this fraction per 100 % load above static
    grip: float = 1.0  # peak force / (road mu * Fz): 1.0 road tires; racing tires reach ~1.3 on dry asphalt
    rolling_resistance: float = 0.0  # rolling-resistance coefficient f_r (torque f_r Fz R_e against the spin)
    model: str = "magic_formula"  # truth tire model: magic_formula | mf61 | fiala (docs/PHYSICS.md)
    file: str = ""  # mf61: path of the MF 6.1/6.2 tire property file (.tir)
    fiala_front: tuple[float, ...] = ()  # fiala: per-wheel (C_alpha [N/rad], C_kappa [N], a [m], C_gamma [N/rad])
    fiala_rear: tuple[float, ...] = ()


@dataclass(frozen=True)
class Suspension:
    stiffness_f_Npm: float  # per corner, at the wheel
    stiffness_r_Npm: float
    damping_f_Nspm: float
    damping_r_Nspm: float
    arb_f_Npm: float  # anti-roll bar, on the left-right travel difference
    arb_r_Npm: float
    travel_m: float  # bump stop at +-travel
    roll_centre_f_m: float = 0.0  # roll-centre height above the ground at rest [m]
    roll_centre_r_m: float = 0.0
    camber_gain_f_radpm: float = 0.0  # camber change per metre of bump travel (negative: more negative camber)
    camber_gain_r_radpm: float = 0.0
    static_camber_f_rad: float = 0.0  # negative: top of the wheel toward the car's centre
    static_camber_r_rad: float = 0.0


@dataclass(frozen=True)
class Aero:
    """Aerodynamic drag and lift (docs/PHYSICS.md). Areas are coefficient x frontal area [m^2]."""

    drag_area_m2: float = 0.0  # C_d A
    lift_area_f_m2: float = 0.0  # C_l,f A; > 0 lift, < 0 downforce, at the front axle
    lift_area_r_m2: float = 0.0
    air_density_kgpm3: float = 1.2


@dataclass(frozen=True)
class Drivetrain:
    layout: str  # rwd | fwd | awd
    max_drive_torque_Nm: float  # total at the wheels
    max_brake_torque_Nm: float  # per wheel
    brake_bias_front: float  # fraction of brake torque on the front axle


@dataclass(frozen=True)
class Steering:
    ratio: float  # handwheel angle / road-wheel angle
    max_road_wheel_angle_rad: float
    ackermann: float  # 0 = parallel steer, 1 = full Ackermann


@dataclass(frozen=True)
class VehicleParams:
    """One vehicle parameter set (SI units). Masses/inertias are for the whole car at its CG."""

    name: str
    description: str
    source: str
    mass_kg: float
    yaw_inertia_kgm2: float
    roll_inertia_kgm2: float
    pitch_inertia_kgm2: float
    lf_m: float
    lr_m: float
    track_f_m: float
    track_r_m: float
    h_cg_m: float
    wheel_radius_m: float
    unsprung_mass_kg: float  # per corner (upright + wheel)
    wheel_spin_inertia_kgm2: float
    suspension: Suspension
    tires: Tires
    drivetrain: Drivetrain
    steering: Steering
    aero: Aero = Aero()
    path: str = ""
    kind: str = "full"  # "replay": only the observers' fields were given, the rest derived
    derived_note: str = ""  # replay vehicles: which fields were derived and how (one line)

    # ---- bicycle-model view --------------------------------------------------------------
    @property
    def wheelbase_m(self) -> float:
        return self.lf_m + self.lr_m

    @property
    def fz_front_static_N(self) -> float:
        """Static front axle load [N]."""
        return self.mass_kg * G * self.lr_m / self.wheelbase_m

    @property
    def fz_rear_static_N(self) -> float:
        return self.mass_kg * G * self.lf_m / self.wheelbase_m

    @property
    def cornering_stiffness_f_Npr(self) -> float:
        """Front axle cornering stiffness at static load and mu = 1 [N/rad] (= By*Cy*Fz_f)."""
        return self.tires.front.By * self.tires.front.Cy * self.fz_front_static_N

    @property
    def cornering_stiffness_r_Npr(self) -> float:
        return self.tires.rear.By * self.tires.rear.Cy * self.fz_rear_static_N

    @property
    def understeer_gradient_radpmps2(self) -> float:
        """K = m/L (lr/Cf - lf/Cr) [rad/(m/s^2)]; > 0 understeer."""
        m, L = self.mass_kg, self.wheelbase_m
        return m / L * (self.lr_m / self.cornering_stiffness_f_Npr - self.lf_m / self.cornering_stiffness_r_Npr)

    def steady_yaw_rate(self, vx_mps: float, delta_rad: float) -> float:
        """Linear bicycle steady-state yaw rate r = v*delta / (L + K v^2) [rad/s]."""
        return vx_mps * delta_rad / (self.wheelbase_m + self.understeer_gradient_radpmps2 * vx_mps**2)

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d.pop("path", None)
        if self.kind == "full":  # keep a full set's dictionary as it always was
            d.pop("kind", None)
            d.pop("derived_note", None)
        d["derived"] = {
            "wheelbase_m": self.wheelbase_m,
            "fz_front_static_N": self.fz_front_static_N,
            "fz_rear_static_N": self.fz_rear_static_N,
            "cornering_stiffness_f_Npr": self.cornering_stiffness_f_Npr,
            "cornering_stiffness_r_Npr": self.cornering_stiffness_r_Npr,
            "understeer_gradient_radpmps2": self.understeer_gradient_radpmps2,
        }
        return d

    def with_overrides(self, **changes: Any) -> VehicleParams:
        return dataclasses.replace(self, **changes)


# ---- loading ---------------------------------------------------------------------------------

class _AllFields(Fields):
    """``Fields`` that records every failing field of a file in ``errors`` and goes on.

    A failing number reads as NaN, a failing string as "" (or its first choice), so that the rest of
    the file is still checked; the caller raises one ``VehicleError`` listing them all.
    """

    def __init__(self, data: Any, *, source: str, errors: list[str], prefix: str = "", quiet: bool = False) -> None:
        self.errors = errors
        self.quiet = quiet  # a sub-mapping that is not a mapping: its fields are not reported one by one
        if not isinstance(data, Mapping):
            self._record(f"{prefix}: must be a mapping, got {type(data).__name__}")
            data, self.quiet = {}, True
        super().__init__(data, source=source, error=VehicleError, prefix=prefix)

    def _record(self, message: str) -> None:
        if not self.quiet:
            self.errors.append(message)

    def _try(self, read: Callable[[], _T], fallback: _T) -> _T:
        try:
            return read()
        except VehicleError as exc:
            self._record(str(exc).removeprefix(f"{self.source}: "))
            return fallback

    def number(self, key: str, default: Any = ..., **kw: Any) -> float:
        return self._try(lambda: Fields.number(self, key, default, **kw), math.nan)

    def string(self, key: str, default: Any = ..., *, choices: tuple[str, ...] | None = None) -> str:
        return self._try(lambda: Fields.string(self, key, default, choices=choices), choices[0] if choices else "")

    def sub(self, key: str, default: Any = ...) -> _AllFields:
        v = self._try(lambda: Fields.raw(self, key, default), {})
        return _AllFields(v if v is not None else {}, source=self.source, errors=self.errors,
                          prefix=self._name(key), quiet=self.quiet)

    def done(self) -> None:
        for key in sorted(set(self.data) - self._seen):
            self._record(f"{self._name(key)}: unknown field (known: {', '.join(sorted(self._seen))})")


def _raise_all(errors: list[str], source: str, rename: Mapping[str, str] | None = None) -> None:
    """One ``VehicleError`` listing every error; ``rename`` maps full-set field names to the file's own."""
    if errors:
        if rename:
            errors = [next((new + e[len(old):] for old, new in rename.items() if e.startswith(old + ":")), e)
                      for e in errors]
        raise VehicleError("; ".join(errors), source=source)

def _axle_tire(f: _AllFields, fz_axle: float) -> AxleTire:
    cy = f.number("Cy", lo=0.5, hi=3.0)
    if f.has("By") and f.has("cornering_stiffness_Npr"):
        f.raw("By")
        f.raw("cornering_stiffness_Npr")
        f._record(f"{f._name('By')}: give either By or cornering_stiffness_Npr, not both")
        by, src = math.nan, "B given"
    elif f.has("cornering_stiffness_Npr"):
        c_alpha = f.number("cornering_stiffness_Npr", lo=1e3, hi=1e6)
        by, src = c_alpha / (cy * fz_axle), "B derived from cornering_stiffness_Npr"
    else:
        by, src = f.number("By", lo=1.0, hi=40.0), "B given"
    t = AxleTire(By=by, Cy=cy, Ey=f.number("Ey", lo=-10.0, hi=1.0), Bx=f.number("Bx", lo=1.0, hi=60.0),
                 Cx=f.number("Cx", lo=0.5, hi=3.0), Ex=f.number("Ex", lo=-10.0, hi=1.0), stiffness_source=src,
                 camber_stiffness=f.number("camber_stiffness", 0.0, lo=0.0, hi=5.0),
                 trail_m=f.number("trail_m", 0.0, lo=0.0, hi=0.2))
    f.done()
    return t


def _grip(t: _AllFields, model: str, tire_file: str, fz_front_axle_N: float) -> float:
    """The tire's peak force per unit of road mu F_z. A tire file carries its own friction (PDY1, LMUY):
    then grip is the file's peak at the front static load, for the observers' model only."""
    if model != "mf61":
        return t.number("grip", 1.0, lo=0.3, hi=2.0)
    if t.has("grip"):
        t.raw("grip")
        t._record(f"{t._name('grip')}: a tire file sets its own friction (PDY1, LMUY); grip is read from it")
    if not tire_file:
        return math.nan
    from roadtruth.harness.truth.tire_models import file_grip

    return file_grip(tire_file, fz_front_axle_N / 2.0)


def parse_vehicle(data: dict[str, Any], source: str) -> VehicleParams:
    """Validate a vehicle mapping (as read from YAML) and build ``VehicleParams``.

    ``kind: replay`` files (only the observers' fields) are completed by ``replay_vehicle_mapping``.
    Raises one ``VehicleError`` listing every field error of the file.
    """
    errors: list[str] = []
    kind = data.get("kind", "full") if isinstance(data, Mapping) else "full"
    if kind not in VEHICLE_KINDS:
        raise VehicleError(f"must be one of {', '.join(VEHICLE_KINDS)} (got {short_repr(kind)})", source=source,
                           field="kind")
    note = ""
    if kind == "replay":
        from roadtruth.harness.truth.vehicle_replay import replay_vehicle_mapping

        data, note = replay_vehicle_mapping(data, source)
    f = _AllFields({k: v for k, v in data.items() if k != "kind"}, source=source, errors=errors)
    name = f.string("name")
    mass = f.number("mass_kg", lo=50.0, hi=40000.0)
    lf = f.number("lf_m", lo=0.1, hi=5.0)
    lr = f.number("lr_m", lo=0.1, hi=5.0)
    L = lf + lr
    s = f.sub("suspension")
    susp = Suspension(
        stiffness_f_Npm=s.number("stiffness_f_Npm", lo=1e3, hi=1e6),
        stiffness_r_Npm=s.number("stiffness_r_Npm", lo=1e3, hi=1e6),
        damping_f_Nspm=s.number("damping_f_Nspm", lo=0.0, hi=1e5),
        damping_r_Nspm=s.number("damping_r_Nspm", lo=0.0, hi=1e5),
        arb_f_Npm=s.number("arb_f_Npm", 0.0, lo=0.0, hi=1e6),
        arb_r_Npm=s.number("arb_r_Npm", 0.0, lo=0.0, hi=1e6),
        travel_m=s.number("travel_m", 0.12, lo=0.01, hi=0.5),
        roll_centre_f_m=s.number("roll_centre_f_m", 0.0, lo=-0.2, hi=1.0),
        roll_centre_r_m=s.number("roll_centre_r_m", 0.0, lo=-0.2, hi=1.0),
        camber_gain_f_radpm=s.number("camber_gain_f_radpm", 0.0, lo=-5.0, hi=5.0),
        camber_gain_r_radpm=s.number("camber_gain_r_radpm", 0.0, lo=-5.0, hi=5.0),
        static_camber_f_rad=s.number("static_camber_f_rad", 0.0, lo=-0.1, hi=0.1),
        static_camber_r_rad=s.number("static_camber_r_rad", 0.0, lo=-0.1, hi=0.1),
    )
    s.done()
    t = f.sub("tires")
    model = t.string("model", "magic_formula", choices=TIRE_MODELS)
    fz_f, fz_r = mass * G * lr / L, mass * G * lf / L
    if model == "magic_formula":
        front, rear = _axle_tire(t.sub("front"), fz_f), _axle_tire(t.sub("rear"), fz_r)
        tire_file, fiala = "", ((), ())
    else:
        from roadtruth.harness.truth.tire_models import fitted_axle_tires

        tire_file, fiala, (front, rear) = fitted_axle_tires(model, t, source, fz_f, fz_r)
    tires = Tires(
        front=front,
        rear=rear,
        radial_stiffness_Npm=t.number("radial_stiffness_Npm", lo=1e4, hi=5e6),
        radial_damping_Nspm=t.number("radial_damping_Nspm", 300.0, lo=0.0, hi=1e5),
        relaxation_length_m=t.number("relaxation_length_m", 0.3, lo=0.0, hi=3.0),
        load_sensitivity=t.number("load_sensitivity", 0.0, lo=0.0, hi=0.5),
        grip=_grip(t, model, tire_file, fz_f),
        rolling_resistance=t.number("rolling_resistance", 0.0, lo=0.0, hi=0.1),
        model=model,
        file=tire_file,
        fiala_front=fiala[0],
        fiala_rear=fiala[1],
    )
    t.done()
    a = f.sub("aero", {})
    aero = Aero(
        drag_area_m2=a.number("drag_area_m2", 0.0, lo=0.0, hi=20.0),
        lift_area_f_m2=a.number("lift_area_f_m2", 0.0, lo=-10.0, hi=10.0),
        lift_area_r_m2=a.number("lift_area_r_m2", 0.0, lo=-10.0, hi=10.0),
        air_density_kgpm3=a.number("air_density_kgpm3", 1.2, lo=0.5, hi=1.5),
    )
    a.done()
    d = f.sub("drivetrain")
    drive = Drivetrain(
        layout=d.string("layout", choices=DRIVE_LAYOUTS),
        max_drive_torque_Nm=d.number("max_drive_torque_Nm", lo=1.0, hi=1e5),
        max_brake_torque_Nm=d.number("max_brake_torque_Nm", lo=1.0, hi=1e5),
        brake_bias_front=d.number("brake_bias_front", 0.6, lo=0.0, hi=1.0),
    )
    d.done()
    st = f.sub("steering")
    steer = Steering(
        ratio=st.number("ratio", lo=1.0, hi=40.0),
        max_road_wheel_angle_rad=st.number("max_road_wheel_angle_rad", 0.6, lo=0.05, hi=1.2),
        ackermann=st.number("ackermann", 1.0, lo=0.0, hi=1.0),
    )
    st.done()
    v = VehicleParams(
        name=name,
        description=f.string("description", ""),
        source=f.string("source", ""),
        mass_kg=mass,
        yaw_inertia_kgm2=f.number("yaw_inertia_kgm2", lo=10.0, hi=1e6),
        roll_inertia_kgm2=f.number("roll_inertia_kgm2", lo=1.0, hi=1e6),
        pitch_inertia_kgm2=f.number("pitch_inertia_kgm2", lo=1.0, hi=1e6),
        lf_m=lf,
        lr_m=lr,
        track_f_m=f.number("track_f_m", lo=0.3, hi=4.0),
        track_r_m=f.number("track_r_m", lo=0.3, hi=4.0),
        h_cg_m=f.number("h_cg_m", lo=0.1, hi=3.0),
        wheel_radius_m=f.number("wheel_radius_m", lo=0.1, hi=1.5),
        unsprung_mass_kg=f.number("unsprung_mass_kg", lo=1.0, hi=1000.0),
        wheel_spin_inertia_kgm2=f.number("wheel_spin_inertia_kgm2", lo=0.01, hi=100.0),
        suspension=susp,
        tires=tires,
        drivetrain=drive,
        steering=steer,
        aero=aero,
        path=source,
        kind=kind,
        derived_note=note,
    )
    f.done()
    # physical consistency of values that are each in range (a NaN is a field error reported above)
    if 4 * v.unsprung_mass_kg >= 0.5 * v.mass_kg:
        errors.append(f"unsprung_mass_kg: unsprung mass 4x{v.unsprung_mass_kg:g} kg is not below half the "
                      "total mass")
    if v.roll_inertia_kgm2 + v.pitch_inertia_kgm2 < v.yaw_inertia_kgm2:
        errors.append(f"pitch_inertia_kgm2: roll + pitch inertia {v.roll_inertia_kgm2 + v.pitch_inertia_kgm2:g} "
                      f"kg m^2 is below the yaw inertia {v.yaw_inertia_kgm2:g}: no rigid body has that "
                      "(Ix + Iy >= Iz)")
    if v.h_cg_m <= v.wheel_radius_m * 0.5:
        errors.append(f"h_cg_m: CG height {v.h_cg_m:g} m is below half the wheel radius")
    if kind == "replay":
        from roadtruth.harness.truth.vehicle_replay import FIELD_NAMES

        _raise_all(errors, source, FIELD_NAMES)
    _raise_all(errors, source)
    return v


def vehicles_dir() -> Path:
    return Path(str(files("roadtruth.harness") / "vehicles"))


def available_vehicles() -> list[str]:
    """Names of the shipped vehicle sets (file stems of ``harness/vehicles/*.yaml``)."""
    return sorted(p.stem for p in vehicles_dir().glob("*.yaml"))


def load_vehicle(name_or_path: str | Path, *, replay: bool = False) -> VehicleParams:
    """Load a shipped set by name (``"sedan"``) or any YAML file by path.

    ``replay=True`` also accepts a replay vehicle (``kind: replay``); without it such a file is refused,
    since simulating a car needs the fields a replay vehicle leaves out.
    """
    p = Path(name_or_path)
    if p.suffix.lower() not in (".yaml", ".yml"):
        p = vehicles_dir() / f"{name_or_path}.yaml"
        if not p.is_file():
            raise VehicleError(f"unknown vehicle {str(name_or_path)!r} (available: {', '.join(available_vehicles())})")
    data = load_mapping(p, VehicleError)
    if data.get("kind") == "replay" and not replay:
        raise VehicleError("a replay vehicle (kind: replay) has only the fields observers use; simulating a car "
                           "needs the full vehicle format (docs/VEHICLES.md)", source=str(p), field="kind")
    return parse_vehicle(data, str(p))
