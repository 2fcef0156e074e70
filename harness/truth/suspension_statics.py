"""Analytic steady-state roll, lateral load transfer, wheel lift and rollover thresholds of a vehicle set.

These are the closed-form statics the physics tests hold the multibody truth to. They describe the car
exactly as ``roadtruth.harness.truth.car_model`` builds it:

* sprung mass m_s = m − 4 m_u (the chassis), four unsprung corners of mass m_u whose centres sit at
  the wheel centres, at height h_u,i = R − F_z0,i / k_t at rest (R wheel radius, k_t the radial tire
  spring, F_z0,i the static wheel load of axle i);
* each corner on a slide joint inclined in the y–z plane by θ_i, tan θ_i = 2 h_rc,i / t_i, so that a
  wheel rising by dz moves outward by (2 h_rc,i / t_i) dz: the instantaneous centre of the linearised
  (swing-axle) suspension is the roll centre on the centre line at h_rc,i above the ground;
* the spring along the joint axis with k_i cos²θ_i (the vertical wheel rate is k_i); the anti-roll
  bar a fixed tendon on the left–right travel difference with potential ½ k_arb (q_l − q_r)², i.e. a
  force of k_arb per metre of travel DIFFERENCE on each wheel (scaled by cos²θ along the axis like
  the spring, so its vertical rate is unchanged too);
* the tire a radial spring k_t in series, the contact point at the foot of the perpendicular from the
  wheel centre to the road (so the contact travels under the wheel centre when the wheel tilts with
  the body: the wheel body tilts with the chassis because a slide joint does not rotate it).

Sign conventions (ISO 8855): a_y > 0 in a left turn; roll φ > 0 right side down (the body rolls outward
in a left turn); ΔF_z,i is the load gained by the outer wheel of axle i (and lost by the inner one),
ΔF_z,i = M_i / t_i for the axle's overturning moment M_i.

Two forms are given for the roll gradient and the load transfer:

``textbook``
    Milliken & Milliken, *Race Car Vehicle Dynamics*, 1995, ch. 18 (roll axis, eqs. of the "roll
    moment" and "lateral load transfer" sections) and Gillespie, *Fundamentals of Vehicle Dynamics*,
    1992, ch. 8: the sprung mass rolls about the roll axis; geometric transfer m_s,i h_rc,i / t_i,
    elastic K_φ,i / ΣK_φ · m_s h' / t_i amplified by the sprung weight's lateral shift, unsprung
    m_u,i h_u,i / t_i.
``model``
    The exact first-order (small-angle) steady state of the multibody layout above, derived by virtual
    work (see :func:`roll_statics`). It differs from the textbook form by the terms this layout adds:
    the contact travelling under the tilting wheel (a stabilising m_s g h_u), the tilt of the inclined
    axes with the body (a lateral migration of the roll centre, stabilising W_s,i h_rc,i), the
    unsprung corners' inertia reacted through the slide joints (the body), and the tire's series
    compliance acting on the whole overturning moment, not only on the elastic part. For the shipped
    sedan the two differ by less than 4 % in the roll gradient.

All quantities in SI units; angles in radians; "per m/s²" is per unit lateral acceleration a_y.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from roadtruth.harness.truth.vehicle import G, VehicleParams


@dataclass(frozen=True)
class AxleRoll:
    """One axle's roll properties (both corners together)."""

    track_m: float
    roll_centre_m: float  # roll-centre height above ground at rest, h_rc [m]
    slide_inclination_rad: float  # θ = atan(2 h_rc / t) of each corner's slide joint [rad]
    sprung_mass_kg: float  # the sprung mass carried by the axle at rest, m_s,i [kg]
    unsprung_mass_kg: float  # both corners, m_u,i = 2 m_u [kg]
    wheel_centre_height_m: float  # h_u,i = R − F_z0,i / k_t [m]
    static_wheel_load_N: float  # F_z0,i per wheel [N]
    suspension_roll_stiffness_Nmprad: float  # K_s,i = t²/2 (k + 2 k_arb) [N m/rad]
    tire_roll_stiffness_Nmprad: float  # K_t,i = t²/2 k_t [N m/rad]
    roll_stiffness_Nmprad: float  # K_φ,i = K_s K_t / (K_s + K_t), suspension and tires in series [N m/rad]


@dataclass(frozen=True)
class RollStatics:
    """Sprung-mass geometry and the steady-state roll gradient of a set."""

    sprung_mass_kg: float  # m_s [kg]
    sprung_cg_height_m: float  # h_s [m]
    sprung_cg_behind_front_axle_m: float  # a_s [m]
    roll_axis_height_m: float  # h_ra = h_rc,f + (h_rc,r − h_rc,f) a_s / L, under the sprung CG [m]
    roll_arm_m: float  # h' = h_s − h_ra [m]
    front: AxleRoll
    rear: AxleRoll
    roll_gradient_radpmps2: float  # dφ/da_y of the model (see ``roll_statics``) [rad/(m/s²)]
    textbook_roll_gradient_radpmps2: float  # m_s h' / (ΣK_φ − m_s g h') [rad/(m/s²)]

    @property
    def roll_stiffness_Nmprad(self) -> float:
        """ΣK_φ = K_φ,f + K_φ,r [N m/rad]."""
        return self.front.roll_stiffness_Nmprad + self.rear.roll_stiffness_Nmprad


@dataclass(frozen=True)
class AxleTransfer:
    """Lateral load transfer of one axle per unit lateral acceleration [N per m/s²] (outer gains, inner loses).

    ``geometric + elastic + unsprung = textbook``; ``model`` is the multibody model's exact value.
    """

    geometric: float  # m_s,i h_rc,i / t_i
    elastic: float  # K_φ,i (dφ/da_y)_textbook / t_i
    unsprung: float  # m_u,i h_u,i / t_i
    model: float  # exact first-order transfer of the modelled car

    @property
    def textbook(self) -> float:
        return self.geometric + self.elastic + self.unsprung


@dataclass(frozen=True)
class LoadTransfer:
    front: AxleTransfer
    rear: AxleTransfer


@dataclass(frozen=True)
class WheelLift:
    """Lateral acceleration at which each axle's inner wheel unloads (F_z = 0), linear transfer assumed."""

    front_mps2: float  # F_z0,f / ΔF_z,f' [m/s²]
    rear_mps2: float
    first: str  # "front" or "rear": the axle that lifts first

    @property
    def lift_mps2(self) -> float:
        """a_y of the first lift (the lower of the two) [m/s²]."""
        return min(self.front_mps2, self.rear_mps2)


def slide_inclination(roll_centre_m: float, track_m: float) -> float:
    """θ = atan(2 h_rc / t) [rad]: the slide-joint inclination that puts the roll centre at h_rc [m]."""
    return math.atan2(2.0 * roll_centre_m, track_m)


def _axles(v: VehicleParams) -> tuple[AxleRoll, AxleRoll, float, float, float]:
    """(front, rear, m_s, h_s, a_s) of the set as car_model builds it."""
    m, mu, L = v.mass_kg, v.unsprung_mass_kg, v.wheelbase_m
    ms = m - 4.0 * mu
    kt = v.tires.radial_stiffness_Npm
    s = v.suspension
    out = []
    for track, k, k_arb, lever, h_rc in (
            (v.track_f_m, s.stiffness_f_Npm, s.arb_f_Npm, v.lr_m, getattr(s, "roll_centre_f_m", 0.0)),
            (v.track_r_m, s.stiffness_r_Npm, s.arb_r_Npm, v.lf_m, getattr(s, "roll_centre_r_m", 0.0))):
        fz0 = m * G * lever / L / 2.0
        ks = 0.5 * track**2 * (k + 2.0 * k_arb)
        ktr = 0.5 * track**2 * kt
        out.append(AxleRoll(track_m=track, roll_centre_m=float(h_rc),
                            slide_inclination_rad=slide_inclination(float(h_rc), track),
                            sprung_mass_kg=2.0 * fz0 / G - 2.0 * mu, unsprung_mass_kg=2.0 * mu,
                            wheel_centre_height_m=v.wheel_radius_m - fz0 / kt, static_wheel_load_N=fz0,
                            suspension_roll_stiffness_Nmprad=ks, tire_roll_stiffness_Nmprad=ktr,
                            roll_stiffness_Nmprad=ks * ktr / (ks + ktr)))
    f, r = out
    hs = (m * v.h_cg_m - f.unsprung_mass_kg * f.wheel_centre_height_m
          - r.unsprung_mass_kg * r.wheel_centre_height_m) / ms
    # Sprung CG behind the front axle: the sprung shares balance about it (m_s,r L = m_s a_s).
    a_s = r.sprung_mass_kg * L / ms
    return f, r, ms, hs, a_s


def roll_statics(v: VehicleParams) -> RollStatics:
    """Roll stiffness per axle, roll axis, roll arm and the steady-state roll gradient of a set.

    Roll stiffness (body rolled by φ about the roll centre, wheels on the ground): the travels are
    q_l = −q_r = −(t/2) φ / cos θ along the axes, so the springs store ½ k cos²θ · 2 q² = ½ (k t²/2) φ²
    and the bar ½ k_arb cos²θ (q_l − q_r)² = ½ (k_arb t²) φ²: K_s = t²/2 (k + 2 k_arb), independent of
    θ. The tires add K_t = t²/2 k_t in series: K_φ = K_s K_t / (K_s + K_t) (Milliken 1995, ch. 18).

    Textbook gradient (Milliken 1995, ch. 18; Gillespie 1992, ch. 8): the sprung mass rolls about the
    roll axis; the roll moment is the lateral inertia force on the roll arm plus the moment of the
    sprung weight, whose CG has moved sideways by h' sin φ:
    ΣK_φ φ = m_s a_y h' + m_s g h' φ  ⇒  dφ/da_y = m_s h' / (ΣK_φ − m_s g h').
    The m_s g h' term is why a soft car rolls more than the lateral force alone explains (and would
    roll over at ΣK_φ = m_s g h' on its own springs).

    Model gradient: virtual work on the multibody car (small angles, steady state) gives, with the
    tire roll x_i = (δ_out − δ_in)/t_i and φ the body roll, per axle (a virtual travel along the axes)
    K_t,i x_i = K_s,i (φ − x_i) + W_s,i h_rc,i φ + m_s,i h_rc,i a_y
    (W_s,i = m_s,i g; the second term is the sprung load along the axes tilted with the body), and for
    the whole car (a virtual rigid roll; contacts under the wheel centres)
    Σ K_t,i x_i = m h a_y + [m_s g h_s − Σ W_s,i h_u,i] φ − Σ W_s,i h_rc,i (φ − x_i).
    Eliminating x_i, with e_i = (K_t,i − W_s,i h_rc,i) / (K_t,i + K_s,i):
    dφ/da_y = (m h − Σ e_i m_s,i h_rc,i) / (Σ e_i (K_s,i + W_s,i h_rc,i) + Σ W_s,i (h_u,i + h_rc,i) − m_s g h_s).
    With rigid tires and h_u, h_rc → 0 in the stabilising terms it is the textbook form.
    """
    f, r, ms, hs, a_s = _axles(v)
    L = v.wheelbase_m
    h_ra = f.roll_centre_m + (r.roll_centre_m - f.roll_centre_m) * a_s / L
    arm = hs - h_ra
    k_sum = f.roll_stiffness_Nmprad + r.roll_stiffness_Nmprad
    textbook = ms * arm / (k_sum - ms * G * arm)
    num = v.mass_kg * v.h_cg_m
    den = -ms * G * hs
    for a in (f, r):
        ws = a.sprung_mass_kg * G
        e = (a.tire_roll_stiffness_Nmprad - ws * a.roll_centre_m) / (
            a.tire_roll_stiffness_Nmprad + a.suspension_roll_stiffness_Nmprad)
        num -= e * a.sprung_mass_kg * a.roll_centre_m
        den += e * (a.suspension_roll_stiffness_Nmprad + ws * a.roll_centre_m)
        den += ws * (a.wheel_centre_height_m + a.roll_centre_m)
    return RollStatics(sprung_mass_kg=ms, sprung_cg_height_m=hs, sprung_cg_behind_front_axle_m=a_s,
                       roll_axis_height_m=h_ra, roll_arm_m=arm, front=f, rear=r,
                       roll_gradient_radpmps2=num / den, textbook_roll_gradient_radpmps2=textbook)


def roll_gradient(v: VehicleParams) -> float:
    """Steady-state roll gradient dφ/da_y of the modelled car [rad per m/s²] (``roll_statics``)."""
    return roll_statics(v).roll_gradient_radpmps2


def load_transfer(v: VehicleParams) -> LoadTransfer:
    """Lateral load transfer per axle per unit a_y [N per m/s²], textbook parts and the model's value.

    Textbook (Milliken 1995, ch. 18): geometric m_s,i h_rc,i / t_i (the sprung lateral force reacted
    through the links at the roll centre), elastic K_φ,i φ' / t_i with φ' the textbook roll gradient
    (the sprung mass' roll moment about the roll axis, its weight shift included, shared by roll
    stiffness), unsprung m_u,i h_u,i / t_i. Their sum over axles weighted by t_i is m h + m_s g h' φ'.

    Model: from the per-axle virtual-work equation of ``roll_statics``,
    ΔF_z,i t_i = K_t,i x_i = K_t,i [(K_s,i + W_s,i h_rc,i) φ' + m_s,i h_rc,i] / (K_t,i + K_s,i)
    with φ' the model's roll gradient (the unsprung corners' inertia reaches the tires through the
    slide joints and the body, so it is inside φ').
    """
    rs = roll_statics(v)
    out = []
    for a in (rs.front, rs.rear):
        t = a.track_m
        ks, kt = a.suspension_roll_stiffness_Nmprad, a.tire_roll_stiffness_Nmprad
        model = kt * ((ks + a.sprung_mass_kg * G * a.roll_centre_m) * rs.roll_gradient_radpmps2
                      + a.sprung_mass_kg * a.roll_centre_m) / (kt + ks) / t
        out.append(AxleTransfer(geometric=a.sprung_mass_kg * a.roll_centre_m / t,
                                elastic=a.roll_stiffness_Nmprad * rs.textbook_roll_gradient_radpmps2 / t,
                                unsprung=a.unsprung_mass_kg * a.wheel_centre_height_m / t, model=model))
    return LoadTransfer(front=out[0], rear=out[1])


def wheel_lift(v: VehicleParams, *, textbook: bool = False) -> WheelLift:
    """a_y at which the inner front and the inner rear wheel unload, F_z0,i / ΔF_z,i' [m/s²].

    Linear transfer assumed up to the lift (the roll gradient does not change with a_y, the axle
    lateral forces stay m a_y l_r / L and m a_y l_f / L); ``textbook=True`` uses Milliken's parts.
    The first of the two is the lift of the car; the other axle still carries both wheels there.
    """
    lt = load_transfer(v)
    rs = roll_statics(v)
    af = rs.front.static_wheel_load_N / (lt.front.textbook if textbook else lt.front.model)
    ar = rs.rear.static_wheel_load_N / (lt.rear.textbook if textbook else lt.rear.model)
    return WheelLift(front_mps2=af, rear_mps2=ar, first="front" if af <= ar else "rear")


def static_stability_factor(v: VehicleParams) -> float:
    """NHTSA's static stability factor SSF = T / (2 h) [1 = g] with T the mean track, h the CG height.

    The lateral acceleration (in g) at which a rigid car tips about its outer wheels (Gillespie 1992,
    ch. 9, quasi-static rollover of a rigid vehicle).
    """
    return 0.5 * (v.track_f_m + v.track_r_m) / (2.0 * v.h_cg_m)


def rollover_threshold_with_roll(v: VehicleParams) -> float:
    """Quasi-static rollover threshold of the suspended car [1 = g] (Gillespie 1992, ch. 9).

    Body roll moves the CG toward the outer wheels by (h − h_ra) φ with φ = R_φ a_y/g (R_φ the roll
    gradient in rad per g): the car tips when T/2 − (h − h_ra) R_φ a_y/g = h a_y/g, i.e.
    a_y/g = T/(2h) / (1 + R_φ (1 − h_ra/h)) — the SSF with h raised to h + (h − h_ra) R_φ (the "roll
    allowance"). Uses the model's roll gradient and the roll-axis height under the sprung CG.
    """
    rs = roll_statics(v)
    r_phi = rs.roll_gradient_radpmps2 * G
    return static_stability_factor(v) / (1.0 + r_phi * (1.0 - rs.roll_axis_height_m / v.h_cg_m))


def banked_neutral_speed(radius_m: float, bank_rad: float) -> float:
    """Speed at which a curve of radius R banked by φ_b needs no lateral tire force [m/s].

    In the road plane the weight's component m g sin φ_b balances the centripetal component
    m (v²/R) cos φ_b: v = sqrt(g R tan φ_b) (Gillespie 1992, ch. 6). Raises ``ValueError`` for a
    non-positive radius or a bank of 90° or more.
    """
    if not (radius_m > 0.0 and abs(bank_rad) < 0.5 * math.pi):
        raise ValueError(f"need radius > 0 and |bank| < 90 deg (got R={radius_m!r} m, bank={bank_rad!r} rad)")
    return math.sqrt(G * radius_m * math.tan(abs(bank_rad)))


def linear_understeer_gradient(v: VehicleParams, roll_gradient_radpmps2: float | None = None) -> float:
    """Understeer gradient K [rad/(m/s^2)] of the linear car with aligning torque and roll camber.

    The bicycle part K_0 = m/L (l_r/C_f − l_f/C_r) (``VehicleParams.understeer_gradient_radpmps2``);
    the aligning moments −t F_y of all four tires (pneumatic trail t) need F_y,f = m a_y (l_r + t)/L and
    F_y,r = m a_y (l_f − t)/L, which adds m t/L (1/C_f + 1/C_r); body roll φ = (dφ/da_y) a_y leans both
    wheels of an axle outward by (1 + g_c T/2) φ (camber gain g_c per metre of bump, track T), a camber
    thrust c_γ F_z,axle (1 + g_c T/2) φ against the turn that the axle makes up with slip. These are
    the "aligning torque" and "camber thrust" terms of Gillespie (1992, ch. 6). Steady yaw rate:
    r = v δ / (L + K v^2), δ the road-wheel angle.

    ``roll_gradient_radpmps2`` defaults to :func:`roll_gradient` of the car.
    """
    phi = roll_gradient(v) if roll_gradient_radpmps2 is None else roll_gradient_radpmps2
    s, L = v.suspension, v.wheelbase_m
    cf, cr = v.cornering_stiffness_f_Npr, v.cornering_stiffness_r_Npr
    t_f, t_r = v.tires.front.trail_m, v.tires.rear.trail_m
    # Yaw moment balance with each axle's trail: (l_f − t_f) F_f = (l_r + t_r) F_r, F_f + F_r = m a_y.
    span = L + t_r - t_f
    k_bicycle_aligning = v.mass_kg / span * ((v.lr_m + t_r) / cf - (v.lf_m - t_f) / cr)
    lean_f = 1.0 + s.camber_gain_f_radpm * v.track_f_m / 2.0
    lean_r = 1.0 + s.camber_gain_r_radpm * v.track_r_m / 2.0
    k_camber = phi * (v.tires.front.camber_stiffness * v.fz_front_static_N * lean_f / cf
                      - v.tires.rear.camber_stiffness * v.fz_rear_static_N * lean_r / cr)
    return k_bicycle_aligning + k_camber
