r"""Linear single-track (bicycle) model: the matrices the LMI designs and the observers build on.

Model (Y. Wang, PhD dissertation, Auburn 2014, eqs. (3.13)–(3.18); also Rajamani, *Vehicle Dynamics and Control*,
2nd ed., sec. 2.3). With the CONTRACT slip definitions linearised for small angles,

.. math::

    \alpha_f = \delta - \frac{v_y + l_f r}{v_x}, \qquad
    \alpha_r = -\frac{v_y - l_r r}{v_x}, \qquad
    F_{yf} = C_f \alpha_f,\ F_{yr} = C_r \alpha_r,

    m(\dot v_y + v_x r) = F_{yf} + F_{yr}, \qquad I_z \dot r = l_f F_{yf} - l_r F_{yr}.

``C_f``, ``C_r`` are the axle cornering stiffnesses of the vehicle set (``By*Cy*Fz_static``, mu = 1).
Three equivalent state-space forms are provided: ``(v_y, r)`` (3.17), ``(beta, r)`` (3.16) and
``(alpha_f, alpha_r)`` (3.18). The ZOH discretisation of a 2x2 system is in closed form
(:func:`expm2_zoh`), because these models are stiff at low speed and a per-step ``scipy`` call would
dominate the run time. The model-only baselines built on it (``open_loop_bicycle``,
``kinematic_vy``) are in :mod:`roadtruth.observers.open_loop`.
"""

from __future__ import annotations

import cmath
import math

import numpy as np

from roadtruth.harness.truth.vehicle import VehicleParams

Matrix2 = tuple[float, float, float, float]  # row-major (a11, a12, a21, a22)


# ---- closed-form 2x2 exponential -----------------------------------------------------------------

def expm2_zoh(a11: float, a12: float, a21: float, a22: float, h: float) -> tuple[Matrix2, Matrix2]:
    """Exact ZOH of a 2x2 system: ``E = expm(A h)`` and ``G = int_0^h expm(A s) ds``.

    Then ``x(t+h) = E x(t) + G g`` for ``x' = A x + g`` with constant ``g``. Uses the identity
    ``M^2 = q I`` for ``M = A - s I`` (``s = tr A / 2``, ``q = s^2 - det A``), so every analytic
    function of ``A`` is ``f0 I + f1 M`` with ``f0, f1`` from the eigenvalues ``s +- sqrt(q)``;
    near-repeated eigenvalues use a series, near-singular ``A`` a Taylor expansion of ``G``.

    Parameters
    ----------
    a11, a12, a21, a22 : float
        Entries of A [1/s].
    h : float
        Step [s], >= 0.

    Returns
    -------
    E, G : tuple of 4 floats each (row-major); G in [s].
    """
    s = 0.5 * (a11 + a22)
    m11 = a11 - s  # M = [[m11, a12], [a21, -m11]]
    q = m11 * m11 + a12 * a21
    qh2 = q * h * h
    sh = s * h
    if abs(qh2) < 1e-4:
        # Near-repeated eigenvalues: series in q h^2 (error ~ (q h^2)^3 / 5040).
        es = math.exp(sh)
        e0 = es * (1.0 + qh2 / 2.0 + qh2 * qh2 / 24.0)
        e1 = es * h * (1.0 + qh2 / 6.0 + qh2 * qh2 / 120.0)
        E = (e0 + e1 * m11, e1 * a12, e1 * a21, e0 - e1 * m11)
        if abs(sh) > 1e-3:
            # A is far from singular (det ~ s^2): G = A^-1 (E - I).
            det = a11 * a22 - a12 * a21
            b11, b12, b21, b22 = E[0] - 1.0, E[1], E[2], E[3] - 1.0
            G = ((a22 * b11 - a12 * b21) / det, (a22 * b12 - a12 * b22) / det,
                 (-a21 * b11 + a11 * b21) / det, (-a21 * b12 + a11 * b22) / det)
        else:
            # ||A h|| is tiny: G = h sum_k (A h)^k / (k+1)!
            t11, t12, t21, t22 = h, 0.0, 0.0, h  # current term
            g11, g12, g21, g22 = h, 0.0, 0.0, h
            for k in range(1, 8):
                c = h / (k + 1)
                t11, t12, t21, t22 = ((a11 * t11 + a12 * t21) * c, (a11 * t12 + a12 * t22) * c,
                                      (a21 * t11 + a22 * t21) * c, (a21 * t12 + a22 * t22) * c)
                g11 += t11
                g12 += t12
                g21 += t21
                g22 += t22
            G = (g11, g12, g21, g22)
        return E, G
    if q > 0.0:
        w = math.sqrt(q)
        l1, l2 = s + w, s - w
        x1, x2 = math.exp(l1 * h), math.exp(l2 * h)
        e0, e1 = 0.5 * (x1 + x2), (x1 - x2) / (2.0 * w)
        g_1 = math.expm1(l1 * h) / l1 if l1 != 0.0 else h
        g_2 = math.expm1(l2 * h) / l2 if l2 != 0.0 else h
        g0, g1 = 0.5 * (g_1 + g_2), (g_1 - g_2) / (2.0 * w)
    else:
        om = math.sqrt(-q)
        lam = complex(s, om)
        ex = cmath.exp(lam * h)
        gl = (ex - 1.0) / lam  # |lam h| >= om h >= 1e-2 here: no cancellation issue
        e0, e1 = ex.real, ex.imag / om
        g0, g1 = gl.real, gl.imag / om
    E = (e0 + e1 * m11, e1 * a12, e1 * a21, e0 - e1 * m11)
    G = (g0 + g1 * m11, g1 * a12, g1 * a21, g0 - g1 * m11)
    return E, G


# ---- model matrices ------------------------------------------------------------------------------

def axle_stiffness(vehicle: VehicleParams) -> tuple[float, float]:
    """Front and rear axle cornering stiffness ``(C_f, C_r)`` [N/rad] at static load, mu = 1."""
    return vehicle.cornering_stiffness_f_Npr, vehicle.cornering_stiffness_r_Npr


def vy_r_model(vehicle: VehicleParams, vx_mps: float) -> tuple[np.ndarray, np.ndarray]:
    """Linear bicycle in ``(v_y, r)``, Wang 2014 eq. (3.17) (``-v_x r`` moved into A).

    Returns
    -------
    A : (2, 2) array [1/s]; B : (2,) array, input delta [rad] -> ``(m/s^2, rad/s^2)``.
    """
    m, iz, lf, lr = vehicle.mass_kg, vehicle.yaw_inertia_kgm2, vehicle.lf_m, vehicle.lr_m
    cf, cr = axle_stiffness(vehicle)
    v = vx_mps
    A = np.array([[-(cf + cr) / (m * v), -(lf * cf - lr * cr) / (m * v) - v],
                  [-(lf * cf - lr * cr) / (iz * v), -(lf * lf * cf + lr * lr * cr) / (iz * v)]])
    B = np.array([cf / m, lf * cf / iz])
    return A, B


def ay_output(vehicle: VehicleParams, vx_mps: float) -> tuple[np.ndarray, float]:
    """Lateral acceleration of the linear model, ``a_y = (F_yf + F_yr)/m = C x + D delta`` for x = (v_y, r)."""
    m, lf, lr = vehicle.mass_kg, vehicle.lf_m, vehicle.lr_m
    cf, cr = axle_stiffness(vehicle)
    v = vx_mps
    return np.array([-(cf + cr) / (m * v), -(lf * cf - lr * cr) / (m * v)]), cf / m


def beta_r_model(vehicle: VehicleParams, vx_mps: float, ax_mps2: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Linear bicycle in ``(beta, r)``, Wang 2014 eq. (3.16), ``beta = v_y / v_x`` and ``v_x' = a_x``.

    Returns
    -------
    A : (2, 2) array [1/s]; B : (2,) array, input delta.
    """
    m, iz, lf, lr = vehicle.mass_kg, vehicle.yaw_inertia_kgm2, vehicle.lf_m, vehicle.lr_m
    cf, cr = axle_stiffness(vehicle)
    v = vx_mps
    A = np.array([[-(cf + cr + m * ax_mps2) / (m * v), (-lf * cf + lr * cr) / (m * v * v) - 1.0],
                  [(-lf * cf + lr * cr) / iz, -(lf * lf * cf + lr * lr * cr) / (iz * v)]])
    B = np.array([cf / (m * v), lf * cf / iz])
    return A, B


def slip_model_terms(vehicle: VehicleParams) -> tuple[np.ndarray, np.ndarray]:
    """``A1`` and ``Bf0`` of the slip-angle LPV model, Wang 2014 eq. (3.19).

    ``A(theta) = theta1 A1 - theta2 I`` with ``theta1 = 1/v_x``, ``theta2 = a_x/v_x`` and
    ``A1 = Bf0 diag(C_f, C_r)``, ``Bf0 = [[-(1/m + lf^2/Iz), lf lr/Iz - 1/m], [lf lr/Iz - 1/m, -(1/m + lr^2/Iz)]]``.

    Returns
    -------
    A1 : (2, 2) array [1/m]; Bf0 : (2, 2) array [1/kg].
    """
    m, iz, lf, lr = vehicle.mass_kg, vehicle.yaw_inertia_kgm2, vehicle.lf_m, vehicle.lr_m
    cf, cr = axle_stiffness(vehicle)
    bf0 = np.array([[-(1.0 / m + lf * lf / iz), lf * lr / iz - 1.0 / m],
                    [lf * lr / iz - 1.0 / m, -(1.0 / m + lr * lr / iz)]])
    return bf0 @ np.diag([cf, cr]), bf0


def alpha_model(vehicle: VehicleParams, vx_mps: float, ax_mps2: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Linear bicycle in ``(alpha_f, alpha_r)``, Wang 2014 eq. (3.18).

    ``x' = A x + B u`` with ``u = (delta, delta_dot, r)``.

    Returns
    -------
    A : (2, 2) array [1/s]; B : (2, 3) array.
    """
    A1, _ = slip_model_terms(vehicle)
    th1, th2 = 1.0 / vx_mps, ax_mps2 / vx_mps
    A = th1 * A1 - th2 * np.eye(2)
    B = np.array([[th2, 1.0, 1.0], [0.0, 0.0, 1.0]])
    return A, B


def slip_angles(delta: float, vy: float, r: float, vx: float, lf: float, lr: float) -> tuple[float, float]:
    """Axle slip angles by the CONTRACT definitions ``alpha_f = delta - atan((vy + lf r)/vx)``,
    ``alpha_r = -atan((vy - lr r)/vx)`` [rad]."""
    return delta - math.atan((vy + lf * r) / vx), -math.atan((vy - lr * r) / vx)
