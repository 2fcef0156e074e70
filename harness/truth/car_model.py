"""The car's MuJoCo model: the base model ``mjcf/car.xml`` with a ``VehicleParams``' values written in.

``mjcf/car.xml`` (package ``roadtruth.mjcf``) is real MJCF that MuJoCo opens on its own; it holds the
layout (shared/notes/mujoco-car-and-tires.md, section 4.1), the joint types, actuators, sensors,
materials and every constant that does not depend on the vehicle::

    chassis  <freejoint>, inertial at the CG, collision box with the floor only
      upright_XX  slide joint susp_XX (q > 0 = bump), spring/damper, bump stops = range; the axis is
                  inclined in the y-z plane (top inward) by atan(2 h_rc / track), so the axle's roll
                  centre sits at h_rc on the centre line (docs/PHYSICS.md, "Suspension")
        [front] knuckle_XX  hinge steer_XX (z), position servo
          wheel_XX  hinge spin_XX (y), motor (drive + brake torque)

``build_mjcf`` writes the set's values into the named elements of that file (masses, inertias, corner
positions, suspension axes, rates and travel, anti-roll bars, wheel and body sizes, GNSS site, chase
camera), the scenario's floor and time step, and for renders the scenario's visuals (road surface
mesh, lane dashes, friction patches, the lead car of ``mjcf/lead_car.xml``), and returns the MJCF text.
Each value is named by its element and attribute (``("joint", "susp_fl", "stiffness")``); once per
process the base file is cut at those attributes into a template, so a model costs a string join.
Why not ``mujoco.MjSpec``: a spec compiles to the same model, but the text is what a truth keeps for
its renders and what ``roadtruth mjcf`` writes, and ``MjSpec.to_xml`` prints 6 significant digits,
so its text would reload as a different model (a spring rate off by 0.04 N/m, an inertia by
0.004 kg m^2). Numbers are written with 9 significant digits, as the models have always carried them.

Wheels have NO MuJoCo contact: the tire forces (normal load from a radial tire spring, Magic Formula
Fx/Fy/Mz) are computed by ``roadtruth.harness.truth.simulate`` each step and applied at the contact point through
``xfrc_applied``. Anti-roll bars are fixed tendons on the left-right travel difference. Springs,
dampers and bars act along the inclined axes with their vertical rates preserved (k_axis = k cos^2 θ).

Mass bookkeeping: the set's ``mass_kg`` and ``*_inertia_kgm2`` are for the WHOLE car about its CG.
The unsprung corners (upright, knuckle, wheel) are subtracted, so the chassis gets the remainder and
its inertial frame is placed so that the whole car's CG sits at the chassis body origin at rest.
The chassis body origin is therefore the car's (static) CG; its height at rest is ``h_cg_m``.
The static equilibrium is built in: each suspension spring's ``springref`` carries its sprung load
at q = 0, and the corners hang so that each tire spring is compressed by its static load.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np

from roadtruth.harness.errors import VehicleError
from roadtruth.harness.truth.road_mesh import road_surface_mesh
from roadtruth.harness.truth.vehicle import G, VehicleParams
from roadtruth.mjcf import template_path

CORNERS: tuple[str, ...] = ("fl", "fr", "rl", "rr")
#: Fractions of the unsprung corner mass in the upright, the steering knuckle and the wheel.
UPRIGHT_SHARE, KNUCKLE_SHARE = 0.3, 0.1
#: The base model of the car and the lead car's model (files of ``roadtruth.mjcf``).
BASE_MODEL, LEAD_CAR_MODEL = "car.xml", "lead_car.xml"
#: Chassis collision box: ground clearance under the CG plane and body size margins [m].
GROUND_CLEARANCE_M = 0.12
FRONT_OVERHANG_M = 0.9
REAR_OVERHANG_M = 0.9
BODY_HEIGHT_M = 1.35
TIRE_HALF_WIDTH_M = 0.11
#: Lane marking dashes: length and period [m]; width [m].
DASH_LENGTH_M, DASH_PERIOD_M, MARKING_WIDTH_M = 3.0, 12.0, 0.15
MAX_DASHES = 4000
#: Half thickness of a dash [m], and its clearance over a 3D road surface [m] (its lowest bottom point
#: above the surface: enough to win the depth test against the road mesh, too little to see).
MARKING_HALF_THICKNESS_M, MARKING_CLEARANCE_M = 0.002, 0.003
PATCH_RGBA = {"ice": "0.70 0.85 1.0 0.85", "snow": "0.96 0.96 0.98 0.9", "wet": "0.25 0.30 0.40 0.8",
              "dry": "0.45 0.45 0.42 0.6", "": "0.85 0.55 0.25 0.6"}


@dataclass(frozen=True)
class CornerGeometry:
    """Where each corner sits (chassis frame, origin at the CG, at rest) and its static loads."""

    position: np.ndarray  # (4, 3) wheel centres [m]
    fz_static: np.ndarray  # (4,) static wheel loads [N]
    tire_deflection: np.ndarray  # (4,) static tire compression [m]
    spring_ref: np.ndarray  # (4,) suspension springref along the inclined axis [m]
    incline: np.ndarray  # (4,) inclination θ of each slide axis from the vertical [rad] (top inward)



def _attribute_text(text: str) -> str:
    """``text`` escaped for a double-quoted XML attribute (what ``xml.sax.saxutils.escape`` with
    ``&quot;`` does; that module imports urllib, http and ssl, tens of ms of every command's start)."""
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;").replace('"', "&quot;")

def suspension_incline(v: VehicleParams) -> np.ndarray:
    """Inclination θ (4,) [rad] of each corner's slide axis: tan θ = 2 h_rc / track (roll centre at h_rc)."""
    s = v.suspension
    th_f = math.atan(2.0 * s.roll_centre_f_m / v.track_f_m)
    th_r = math.atan(2.0 * s.roll_centre_r_m / v.track_r_m)
    return np.array([th_f, th_f, th_r, th_r])


def corner_geometry(v: VehicleParams) -> CornerGeometry:
    """Wheel-centre positions, static loads, tire deflections and spring references of a set."""
    L = v.wheelbase_m
    fz_f = v.mass_kg * G * v.lr_m / L / 2.0
    fz_r = v.mass_kg * G * v.lf_m / L / 2.0
    fz = np.array([fz_f, fz_f, fz_r, fz_r])
    defl = fz / v.tires.radial_stiffness_Npm
    k = np.array([v.suspension.stiffness_f_Npm] * 2 + [v.suspension.stiffness_r_Npm] * 2)
    x = np.array([v.lf_m, v.lf_m, -v.lr_m, -v.lr_m])
    y = np.array([v.track_f_m, -v.track_f_m, v.track_r_m, -v.track_r_m]) / 2.0
    z = v.wheel_radius_m - defl - v.h_cg_m
    th = suspension_incline(v)
    # Static equilibrium at q = 0: the axis spring (k cos^2 θ) carries the sprung load's axial component.
    spring_ref = -(fz - v.unsprung_mass_kg * G) / (k * np.cos(th))
    return CornerGeometry(np.column_stack([x, y, z]), fz, defl, spring_ref, th)


def _wheel_inertia(v: VehicleParams) -> tuple[float, float]:
    """(spin, transverse) inertia of a wheel [kg m^2]; transverse ~ 0.6 spin, as for a disc+tyre."""
    return v.wheel_spin_inertia_kgm2, 0.6 * v.wheel_spin_inertia_kgm2


def chassis_inertial(v: VehicleParams) -> tuple[float, np.ndarray, np.ndarray]:
    """Sprung mass [kg], its CG offset from the car CG (3,) [m] and its diagonal inertia (3,) [kg m^2].

    Whole-car targets minus the corners (point masses plus their own inertia, parallel-axis terms
    about the car CG) minus the chassis' own parallel-axis term. Raises ``VehicleError`` if the corners
    leave too little. If the remainder breaks the triangle inequality I_x + I_y >= I_z (a set whose
    whole-car roll + pitch inertia is below its yaw inertia), the chassis pitch inertia is raised to
    1.01 I_z − I_x: yaw and roll stay exact, the whole car's pitch inertia is then larger than the set's.
    """
    g = corner_geometry(v)
    mu = v.unsprung_mass_kg
    ms = v.mass_kg - 4.0 * mu
    offset = -mu * g.position.sum(axis=0) / ms
    spin, trans = _wheel_inertia(v)
    # Own inertia of a corner (upright + knuckle small boxes, wheel disc) about its centre.
    own = np.array([trans, spin, trans]) + 0.02 * mu * np.ones(3)
    p = g.position
    corners = mu * np.array([np.sum(p[:, 1] ** 2 + p[:, 2] ** 2), np.sum(p[:, 0] ** 2 + p[:, 2] ** 2),
                             np.sum(p[:, 0] ** 2 + p[:, 1] ** 2)]) + 4.0 * own
    self_term = ms * np.array([offset[1] ** 2 + offset[2] ** 2, offset[0] ** 2 + offset[2] ** 2,
                               offset[0] ** 2 + offset[1] ** 2])
    target = np.array([v.roll_inertia_kgm2, v.pitch_inertia_kgm2, v.yaw_inertia_kgm2])
    inertia = target - corners - self_term
    if np.any(inertia <= 0.05 * target):
        raise VehicleError(f"the unsprung corners leave no inertia for the chassis (roll/pitch/yaw "
                           f"remainder {inertia.round(1).tolist()} kg m^2)", source=v.path or v.name,
                           field="unsprung_mass_kg")
    if inertia[0] + inertia[1] < 1.001 * inertia[2]:
        # A rigid body needs I_x + I_y >= I_z. Some published sets give a yaw inertia that breaks it;
        # yaw and roll are what the observers and the lateral dynamics use, so pitch gives way.
        inertia[1] = 1.01 * inertia[2] - inertia[0]
    return ms, offset, inertia


def _f(x: float) -> str:
    return f"{x:.9g}"


def _vec(a: Any) -> str:
    return " ".join(_f(float(x)) for x in a)


#: A value written into the base model: (element tag, element name, attribute). Unnamed elements are
#: addressed by tag (``mujoco``, ``option``) and a body's ``inertial`` by the body's name.
Key = tuple[str, str | None, str]
#: Where the scenario's visuals go: the asset list's end, and the world between floor and chassis.
_ASSETS, _WORLD = "roadtruth_assets", "roadtruth_world"


@cache
def _model_text(name: str) -> str:
    """Text of a shipped model file of ``roadtruth.mjcf`` (read once per process)."""
    with open(template_path(name), encoding="utf-8") as fh:
        return fh.read()


def _element(root: ET.Element, named: dict[tuple[str, str], ET.Element], key: Key) -> ET.Element:
    tag, name, _ = key
    if tag == root.tag and name is None:
        return root
    found = root.find(tag) if name is None else named.get(("body", name)) if tag == "inertial" else named.get((tag, name))
    if found is not None and tag == "inertial":
        found = found.find("inertial")
    if found is None:
        raise LookupError(f"the base car model {BASE_MODEL} has no <{tag}{'' if name is None else f' of {name}'}>")
    return found


@cache
def _base_template(keys: tuple[Key, ...]) -> tuple[tuple[str, ...], tuple[Key | str, ...]]:
    """The base model cut at the values ``keys`` name: (literal pieces, what goes between them).

    Built once per process (per set of keys): the base file is parsed, each named attribute and the
    two visual insertion points get a marker, the tree is written out and cut at the markers. A model
    is then the pieces joined with its values, as fast as formatting a string, and its elements,
    order and every other attribute are the base file's.
    """
    root = ET.fromstring(_model_text(BASE_MODEL))
    named = {(el.tag, el.get("name")): el for el in root.iter() if el.get("name") is not None}
    slots: list[Key | str] = [*keys, _ASSETS, _WORLD]
    for j, key in enumerate(keys):
        _element(root, named, key).set(key[2], f"@@{j}@@")
    asset, worldbody = root.find("asset"), root.find("worldbody")
    floor = named.get(("geom", "floor"))
    if asset is None or worldbody is None or floor is None:
        raise LookupError(f"the base car model {BASE_MODEL} needs an <asset>, a <worldbody> and a floor geom")
    asset.append(ET.Element(_ASSETS))
    worldbody.insert(list(worldbody).index(floor) + 1, ET.Element(_WORLD))
    # The base file's comments are left out (the lines they leave are dropped): the text is the model.
    text = re.sub(r"\n\s*\n", "\n", ET.tostring(root, encoding="unicode")) + "\n"
    text = text.replace(f"<{_ASSETS} />", f"@@{len(keys)}@@").replace(f"<{_WORLD} />", f"@@{len(keys) + 1}@@")
    cut = re.split(r"@@(\d+)@@", text)
    if len(cut) != 2 * len(slots) + 1:
        raise LookupError(f"the base car model {BASE_MODEL} already contains a '@@' marker")
    return tuple(cut[0::2]), tuple(slots[int(j)] for j in cut[1::2])


def _corner_values(out: dict[Key, str], v: VehicleParams, i: int, g: CornerGeometry) -> None:
    """Corner ``i``'s position, suspension joint, masses, inertias and wheel sizes, into ``out``."""
    name = CORNERS[i]
    front = i < 2
    mu = v.unsprung_mass_kg
    s = v.suspension
    k = s.stiffness_f_Npm if front else s.stiffness_r_Npm
    c = s.damping_f_Nspm if front else s.damping_r_Nspm
    spin, trans = _wheel_inertia(v)
    R = v.wheel_radius_m
    own = 0.02 * mu
    m_up = mu * (UPRIGHT_SHARE + (0.0 if front else KNUCKLE_SHARE))
    th = float(g.incline[i])
    side = 1.0 if g.position[i, 1] > 0.0 else -1.0
    c2 = math.cos(th) ** 2
    out["body", f"upright_{name}", "pos"] = _vec(g.position[i])
    susp = ("joint", f"susp_{name}")
    out[(*susp, "axis")] = f"0 {_f(side * math.sin(th))} {_f(math.cos(th))}"
    out[(*susp, "range")] = f"{_f(-s.travel_m / math.cos(th))} {_f(s.travel_m / math.cos(th))}"
    out[(*susp, "stiffness")], out[(*susp, "springref")] = _f(k * c2), _f(g.spring_ref[i])
    out[(*susp, "damping")] = _f(c * c2)
    i_up = _f(own * (0.75 if front else 1.0))
    out["inertial", f"upright_{name}", "mass"] = _f(m_up)
    out["inertial", f"upright_{name}", "diaginertia"] = f"{i_up} {i_up} {i_up}"
    if front:
        i_kn = _f(own * 0.25)
        out["inertial", f"knuckle_{name}", "mass"] = _f(mu * KNUCKLE_SHARE)
        out["inertial", f"knuckle_{name}", "diaginertia"] = f"{i_kn} {i_kn} {i_kn}"
    out["inertial", f"wheel_{name}", "mass"] = _f(mu * (1 - UPRIGHT_SHARE - KNUCKLE_SHARE))
    out["inertial", f"wheel_{name}", "diaginertia"] = f"{_f(trans)} {_f(spin)} {_f(trans)}"
    out["geom", f"tire_{name}", "size"] = f"{_f(R)} {_f(TIRE_HALF_WIDTH_M)}"
    out["geom", f"rim_{name}", "size"] = f"{_f(0.6 * R)} {_f(TIRE_HALF_WIDTH_M + 0.005)}"
    out["geom", f"spoke_{name}", "size"] = f"{_f(0.55 * R)} {_f(TIRE_HALF_WIDTH_M + 0.01)} 0.03"


@cache
def _lead_car_text() -> str:
    """The ``lead`` body of ``mjcf/lead_car.xml`` as MJCF text."""
    lead = ET.fromstring(_model_text(LEAD_CAR_MODEL)).find("worldbody/body[@name='lead']")
    if lead is None:
        raise LookupError(f"the lead car model {LEAD_CAR_MODEL} has no <body name=\"lead\">")
    lead.tail = None
    return ET.tostring(lead, encoding="unicode")


def _patch_mesh(vertices: np.ndarray, extent: tuple[float, float, float, float]) -> tuple[str, str] | None:
    """Vertex and face strings of a thin prism over a polygon clipped to ``extent`` (x0, x1, y0, y1)."""
    poly = [tuple(p) for p in np.asarray(vertices, dtype=np.float64)]
    x0, x1, y0, y1 = extent
    for axis, bound, keep_above in ((0, x0, True), (0, x1, False), (1, y0, True), (1, y1, False)):
        out: list[tuple[float, float]] = []
        for j in range(len(poly)):
            a, b = poly[j - 1], poly[j]
            ina = (a[axis] >= bound) if keep_above else (a[axis] <= bound)
            inb = (b[axis] >= bound) if keep_above else (b[axis] <= bound)
            if ina != inb:
                t = (bound - a[axis]) / (b[axis] - a[axis])
                out.append((a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])))
            if inb:
                out.append(b)
        poly = out
        if len(poly) < 3:
            return None
    area2 = sum(poly[j - 1][0] * poly[j][1] - poly[j][0] * poly[j - 1][1] for j in range(len(poly)))
    if abs(area2) < 1e-6:
        return None
    if area2 < 0:
        poly = poly[::-1]
    tris = _ear_clip(poly)
    n = len(poly)
    verts = [(x, y, 0.004) for x, y in poly] + [(x, y, 0.001) for x, y in poly]
    faces = [t for t in tris] + [(c + n, b + n, a + n) for a, b, c in tris]
    for j in range(n):
        k = (j + 1) % n
        faces += [(j, j + n, k + n), (j, k + n, k)]
    return (" ".join(f"{_f(x)} {_f(y)} {_f(z)}" for x, y, z in verts),
            " ".join(f"{a} {b} {c}" for a, b, c in faces))


def _ear_clip(poly: list[tuple[float, float]]) -> list[tuple[int, int, int]]:
    """Triangles of a simple counter-clockwise polygon (ear clipping)."""
    idx = list(range(len(poly)))
    tris: list[tuple[int, int, int]] = []

    def cross(o: tuple[float, float], a: tuple[float, float], b: tuple[float, float]) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    guard = 0
    while len(idx) > 3 and guard < 10000:
        guard += 1
        for j in range(len(idx)):
            a, b, c = idx[j - 1], idx[j], idx[(j + 1) % len(idx)]
            if cross(poly[a], poly[b], poly[c]) <= 0:
                continue
            if any(cross(poly[a], poly[b], poly[p]) >= 0 and cross(poly[b], poly[c], poly[p]) >= 0
                   and cross(poly[c], poly[a], poly[p]) >= 0 for p in idx if p not in (a, b, c)):
                continue
            tris.append((a, b, c))
            idx.pop(j)
            break
        else:
            break  # degenerate: fall back to a fan of what is left
    for j in range(1, len(idx) - 1):
        tris.append((idx[0], idx[j], idx[j + 1]))
    return tris


def _ground_extent(scenario: Any) -> tuple[float, float, float, float]:
    """(x0, x1, y0, y1) [m] of the floor plane: the road's bounding box with a 60 m margin."""
    smp = scenario.road.samples
    pad = 60.0
    return (float(smp[:, 1].min() - pad), float(smp[:, 1].max() + pad),
            float(smp[:, 2].min() - pad), float(smp[:, 2].max() + pad))


def _dash_frames(road: Any, mids_m: np.ndarray, half_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frames of the lane dashes on a 3D road, left and right marking of each dash in turn.

    Parameters
    ----------
    road : the ``roadtruth.harness.truth.road.Road`` (not flat).
    mids_m : (k,) path coordinates of the dash centres [m].
    half_m : lateral offset of the markings from the centre line [m].

    Returns
    -------
    pos : (2k, 3) box centres [m]; xaxis, yaxis : (2k, 3) unit box axes (world frame).

    Each box lies in the road's tangent plane at its centre: z axis = the surface normal n there,
    x axis = the road direction lifted onto that plane, (t, grad z . t) normalised, so that it stays
    over the marking line; y = n x x. On a curved grade the plane leaves the surface by a few mm
    over the dash's length, so the box is then moved along n until its lowest bottom point (of 5
    along each long edge) is ``MARKING_CLEARANCE_M`` above the surface.
    """
    x, y, psi = road.pose_at(mids_m)
    side = np.repeat([[1.0, -1.0]], mids_m.size, axis=0).ravel()
    s = np.repeat(mids_m, 2)
    x, y, psi = np.repeat(x, 2), np.repeat(y, 2), np.repeat(psi, 2)
    c, sn = np.cos(psi), np.sin(psi)
    px, py = x - side * half_m * sn, y + side * half_m * c
    on = road.surface(px, py, s_hint_m=s)
    n = on["normal"]
    grad_t = -(n[:, 0] * c + n[:, 1] * sn) / n[:, 2]  # dz/d(horizontal step along t)
    xaxis = np.column_stack([c, sn, grad_t])
    xaxis /= np.linalg.norm(xaxis, axis=1, keepdims=True)
    yaxis = np.cross(n, xaxis)
    pos = np.column_stack([px, py, on["z_m"]]) + MARKING_HALF_THICKNESS_M * n
    # Bottom points along both long edges: their height over the surface decides the final lift.
    u = np.linspace(-0.5, 0.5, 5) * DASH_LENGTH_M
    v = np.array([-0.5, 0.5]) * MARKING_WIDTH_M
    uu, vv = (a.ravel() for a in np.meshgrid(u, v))
    bottom = (pos[:, None, :] + uu[None, :, None] * xaxis[:, None, :] + vv[None, :, None] * yaxis[:, None, :]
              - MARKING_HALF_THICKNESS_M * n[:, None, :])
    under = road.surface(bottom[..., 0].ravel(), bottom[..., 1].ravel(),
                         s_hint_m=(s[:, None] + uu[None, :]).ravel())["z_m"].reshape(bottom.shape[:2])
    low = (bottom[..., 2] - under).min(axis=1)
    # A move d along n raises a point's height over a plane by d / n_z.
    pos += ((MARKING_CLEARANCE_M - low) * n[:, 2])[:, None] * n
    return pos, xaxis, yaxis


def _scenario_visuals(scenario: Any, extent: tuple[float, float, float, float]) -> tuple[str, str]:
    """(assets, world geoms) of the road markings, 3D road surface, friction patches and lead car."""
    road = scenario.road
    assets, geoms = [], []
    half = road.lane_width_m / 2.0
    gaps = tuple(getattr(scenario, "lane_gaps", ()) or ())
    starts = np.arange(0.0, road.length_m - DASH_LENGTH_M, DASH_PERIOD_M)
    if len(starts) * 2 > MAX_DASHES:
        starts = starts[:: int(math.ceil(len(starts) * 2 / MAX_DASHES))]
    flat = road.is_flat
    if not flat:
        # A visual strip of the 3D road surface (the tires read the surface from the road itself).
        verts, faces = road_surface_mesh(road, road.lane_width_m + 1.0)
        assets.append(f'<mesh name="road_surface" vertex="{" ".join(_f(v) for v in verts.ravel())}" '
                      f'face="{" ".join(str(int(i)) for i in faces.ravel())}" inertia="shell"/>')
        geoms.append('<geom name="road_surface" type="mesh" mesh="road_surface" contype="0" conaffinity="0" '
                     'rgba="0.30 0.31 0.32 1" group="2"/>')
    mids = [s0 + DASH_LENGTH_M / 2.0 for s0 in starts]
    mids = [mid for mid in mids if not any(a <= mid <= b for a, b in gaps)]
    size = f'size="{_f(DASH_LENGTH_M / 2)} {_f(MARKING_WIDTH_M / 2)} {_f(MARKING_HALF_THICKNESS_M)}"'
    if flat:
        for mid in mids:
            x, y, psi = road.pose_at(mid)
            for side in (1.0, -1.0):
                px, py = x - side * half * math.sin(psi), y + side * half * math.cos(psi)
                geoms.append(f'<geom type="box" {size} pos="{_f(px)} {_f(py)} 0.006" euler="0 0 {_f(psi)}" '
                             'contype="0" conaffinity="0" material="marking" group="2"/>')
    elif mids:
        pos, xaxis, yaxis = _dash_frames(road, np.asarray(mids), half)
        for c, ax, ay in zip(pos, xaxis, yaxis, strict=True):
            geoms.append(f'<geom type="box" {size} pos="{_vec(c)}" xyaxes="{_vec(ax)} {_vec(ay)}" '
                         'contype="0" conaffinity="0" material="marking" group="2"/>')
    for j, p in enumerate(scenario.friction.patches):
        mesh = _patch_mesh(p.vertices, extent)
        if mesh is None:
            continue
        assets.append(f'<mesh name="patch_{j}" vertex="{mesh[0]}" face="{mesh[1]}" inertia="shell"/>')
        geoms.append(f'<geom name="patch_{j}" type="mesh" mesh="patch_{j}" contype="0" conaffinity="0" '
                     f'rgba="{PATCH_RGBA.get(p.surface, PATCH_RGBA[""])}" group="2"/>')
    if scenario.lead is not None:
        geoms.append(_lead_car_text())
    return "".join(assets), "".join(geoms)


def build_mjcf(vehicle: VehicleParams, scenario: Any = None, *, timestep_s: float = 0.001,
               visuals: bool = False) -> str:
    """MJCF text of the car (``mjcf/car.xml`` with the set's values) on the scenario's floor.

    Parameters
    ----------
    vehicle : the parameter set; masses and inertias are matched for the whole car.
    scenario : optional ``Scenario``; sizes and places the floor plane under its road.
    timestep_s : simulation step [s] (``implicitfast``).
    visuals : add the scenario's visual-only geoms: lane markings (dashed, ``lane_gaps`` skipped), the
        3D road surface mesh, coloured friction patches and a mocap ``lead`` body when it has a lead
        vehicle. The physics model goes without them: none of them collides or carries mass, yet
        MuJoCo would place every one of them at every step (thousands of dashes on a long road).

    Returns
    -------
    XML string for ``mujoco.MjModel.from_xml_string``: the base model's elements in its order, the
    visuals (if any) in the world between the floor and the chassis.
    """
    g = corner_geometry(vehicle)
    ms, offset, inertia = chassis_inertial(vehicle)
    s = vehicle.suspension
    body_len = vehicle.wheelbase_m + FRONT_OVERHANG_M + REAR_OVERHANG_M
    body_cx = (vehicle.lf_m + FRONT_OVERHANG_M - vehicle.lr_m - REAR_OVERHANG_M) / 2.0
    half_w = max(vehicle.track_f_m, vehicle.track_r_m) / 2.0 + 0.05
    z_bottom = GROUND_CLEARANCE_M - vehicle.h_cg_m
    z_top = BODY_HEIGHT_M - vehicle.h_cg_m
    assets, world_visuals, extent = "", "", (-500.0, 2500.0, -1000.0, 1000.0)
    if scenario is not None:
        extent = _ground_extent(scenario)
        if visuals:
            assets, world_visuals = _scenario_visuals(scenario, extent)
    floor_z = 0.0
    if scenario is not None and not scenario.road.is_flat:
        # The floor (the body's collision plane, and the ground of the renders) under the lowest road
        # point; the 3D road itself is the tires' surface and a visual mesh.
        floor_z = min(0.0, float(scenario.road.samples[:, 5].min()) - 1.5)
    cx, cy = (extent[0] + extent[1]) / 2.0, (extent[2] + extent[3]) / 2.0
    hx, hy = (extent[1] - extent[0]) / 2.0, (extent[3] - extent[2]) / 2.0
    out: dict[Key, str] = {
        ("mujoco", None, "model"): f"roadtruth_{vehicle.name}",
        ("option", None, "timestep"): _f(timestep_s),
        ("option", None, "gravity"): f"0 0 {_f(-G)}",
        ("material", "ground", "texrepeat"): f"{_f(hx / 5)} {_f(hy / 5)}",
        ("geom", "floor", "pos"): f"{_f(cx)} {_f(cy)} {_f(floor_z)}",
        ("geom", "floor", "size"): f"{_f(hx)} {_f(hy)} 0.1",
        ("body", "chassis", "pos"): f"0 0 {_f(vehicle.h_cg_m)}",
        ("inertial", "chassis", "pos"): _vec(offset),
        ("inertial", "chassis", "mass"): _f(ms),
        ("inertial", "chassis", "diaginertia"): _vec(inertia),
        ("geom", "body", "pos"): f"{_f(body_cx)} 0 {_f((z_bottom + z_top * 0.55) / 2 + 0.1)}",
        ("geom", "body", "size"): f"{_f(body_len / 2)} {_f(half_w - 0.12)} {_f((z_top * 0.55 - z_bottom) / 2)}",
        ("geom", "cabin", "pos"): f"{_f(body_cx - 0.3)} 0 {_f(z_top * 0.8)}",
        ("geom", "cabin", "size"): f"{_f(body_len * 0.28)} {_f(half_w - 0.2)} {_f(z_top * 0.2 + 0.05)}",
        ("site", "gnss", "pos"): f"{_f(-0.2)} 0 {_f(z_top + 0.02)}",
        ("camera", "chase", "pos"): f"{_f(-vehicle.lr_m - 7.0)} 0 {_f(2.8 - vehicle.h_cg_m)}",
        ("fixed", "arb_f", "stiffness"): _f(s.arb_f_Npm * math.cos(g.incline[0]) ** 2),
        ("fixed", "arb_r", "stiffness"): _f(s.arb_r_Npm * math.cos(g.incline[2]) ** 2),
    }
    for i in range(4):
        _corner_values(out, vehicle, i, g)
    pieces, slots = _base_template(tuple(out))
    fill = {_ASSETS: assets, _WORLD: world_visuals}
    text = [pieces[0]]
    for slot, piece in zip(slots, pieces[1:], strict=True):
        # XML-escaped: a set's name is the user's text (every number is plain digits).
        text += [fill[slot] if isinstance(slot, str) else _attribute_text(out[slot]), piece]
    return "".join(text)
