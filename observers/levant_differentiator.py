r"""Levant's arbitrary-order robust exact differentiator, discrete time (reusable).

Continuous form (non-recursive, A. Levant, "Higher-order sliding modes, differentiation and
output-feedback control", Int. J. Control 76(9-10):924-941, 2003; "Homogeneity approach to high-order
sliding mode design", Automatica 41(5):823-830, 2005). For a signal ``f`` with
``|f^(k+1)| <= L`` (``L`` the *Lipschitz constant* of ``f^(k)``), with ``e = z_0 - f``:

.. math::

    \dot z_i = -\lambda_{k-i} L^{(i+1)/(k+1)} \lceil e \rfloor^{(k-i)/(k+1)} + z_{i+1},
    \quad i = 0..k-1, \qquad
    \dot z_k = -\lambda_0 L \,\mathrm{sign}(e),

``⌈e⌋^p = |e|^p sign(e)``. In finite time ``z_i = f^(i)`` exactly (no noise, continuous time).
The gains are the tabulated ``lambda`` of Levant (2005) / Livne & Levant (2014) (:data:`LAMBDAS`)
times the power of ``L`` above: :func:`levant_gains`.

Discretisation (M. Livne, A. Levant, "Proper discretization of homogeneous differentiators",
Automatica 50(8):2007-2014, 2014): with the sampling step ``tau`` (may vary),

.. math::

    z_i \leftarrow z_i + \tau\,\dot z_i + \sum_{s=2}^{k-i} z_{i+s}\,\tau^s/s!,

the Taylor terms keeping the homogeneous accuracy of the continuous differentiator. Accuracy after
the finite transient (Levant 2003, Livne & Levant 2014): without noise
``|z_i - f^(i)| <= mu_i L tau^(k+1-i)``; with sampling noise bounded by ``eps`` (and ``tau`` small)
``|z_i - f^(i)| <= nu_i L^(i/(k+1)) eps^((k+1-i)/(k+1))``. For the first derivative of a
second-order differentiator (k = 2) that is ``O(tau^2)`` and ``O(L^(1/3) eps^(2/3))``: noise is
amplified by ``(L/eps)^(1/3)``, the price the lane-camera premises of Yacine et al. (2015) pay.

Yacine et al. (2015) use a "third-order sliding mode differentiator" (Levant's k = 2:
a 3-sliding mode keeps ``z_0, z_1, z_2``) on the camera offset ``y_L`` and heading ``psi_L``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: Tabulated non-recursive gains ``(lambda_0, ..., lambda_k)`` per order k (Levant 2005, Livne &
#: Levant 2014). ``lambda_0`` multiplies the discontinuous last term.
LAMBDAS: dict[int, tuple[float, ...]] = {
    1: (1.1, 1.5),
    2: (1.1, 2.12, 2.0),
    3: (1.1, 3.06, 4.16, 3.0),
    4: (1.1, 4.57, 9.30, 10.03, 5.0),
    5: (1.1, 6.75, 20.26, 32.24, 23.72, 7.0),
}


def levant_gains(order: int, lipschitz: float) -> tuple[float, ...]:
    """Gains ``g_i = lambda_(k-i) L^((i+1)/(k+1))`` of the ``z_i`` equations, ``i = 0..k``.

    Parameters
    ----------
    order : int
        Differentiator order k (1..5): estimates ``f, f', ..., f^(k)``.
    lipschitz : float
        ``L > 0``, a bound on ``|f^(k+1)|`` [unit of f / s^(k+1)].

    Returns
    -------
    (k+1,) tuple of floats; ``g_i`` in [unit of f^(i+1) / |unit of f|^((k-i)/(k+1))].
    """
    if order not in LAMBDAS:
        raise ValueError(f"differentiator order must be one of {sorted(LAMBDAS)} (got {order!r})")
    if not (isinstance(lipschitz, int | float) and math.isfinite(lipschitz) and lipschitz > 0.0):
        raise ValueError(f"Lipschitz constant must be a positive finite number (got {lipschitz!r})")
    lam = LAMBDAS[order]
    k = order
    return tuple(lam[k - i] * float(lipschitz) ** ((i + 1) / (k + 1)) for i in range(k + 1))


@dataclass(frozen=True)
class DifferentiatorSpec:
    """Order k and Lipschitz constant L [unit of f / s^(k+1)] of one differentiator."""

    order: int = 2
    lipschitz: float = 1.0


class LevantDifferentiator:
    """Discrete Levant differentiator of order k on an irregularly sampled signal.

    ``update(f, tau)`` feeds one sample taken ``tau`` [s] after the previous one; afterwards ``z``
    holds the estimates of ``(f, f', ..., f^(k))`` *at the time of that sample*. As in Livne &
    Levant's explicit scheme, ``z(t_j)`` is propagated from ``z(t_(j-1))`` with the output error of
    the previous sample, ``e = z_0(t_(j-1)) - f(t_(j-1))``; the new sample enters the next step. The
    first sample initialises ``z_0 = f`` and the derivatives to zero.

    Parameters
    ----------
    order : int
        k (1..5).
    lipschitz : float
        L > 0, bound on ``|f^(k+1)|``.
    """

    __slots__ = ("order", "lipschitz", "gains", "_exps", "_fact", "z", "initialized", "samples", "_f_prev")

    def __init__(self, order: int = 2, lipschitz: float = 1.0) -> None:
        self.order = int(order)
        self.lipschitz = float(lipschitz)
        self.gains = levant_gains(self.order, self.lipschitz)
        k = self.order
        self._exps = tuple((k - i) / (k + 1) for i in range(k + 1))
        self._fact = tuple(1.0 / math.factorial(s) for s in range(k + 1))
        self.z = [0.0] * (k + 1)
        self.initialized = False
        self.samples = 0
        self._f_prev = 0.0

    def reset(self, f0: float | None = None) -> None:
        """Forget the past; with ``f0`` start at ``z = (f0, 0, ..., 0)``."""
        self.z = [0.0] * (self.order + 1)
        self.initialized = False
        self.samples = 0
        self._f_prev = 0.0
        if f0 is not None:
            self.z[0] = self._f_prev = float(f0)
            self.initialized = True
            self.samples = 1

    def update(self, f: float, tau: float) -> None:
        """Feed sample ``f`` taken ``tau`` [s] (> 0) after the previous one (Livne-Levant step)."""
        if not self.initialized:
            self.reset(f)
            return
        self.samples += 1
        f_prev, self._f_prev = self._f_prev, float(f)
        if tau <= 0.0:
            return
        z, g, ex, fa = self.z, self.gains, self._exps, self._fact
        k = self.order
        e = z[0] - f_prev
        ae = abs(e)
        sg = 1.0 if e > 0.0 else (-1.0 if e < 0.0 else 0.0)
        new = [0.0] * (k + 1)
        for i in range(k + 1):
            dz = -g[i] * (ae ** ex[i]) * sg if i < k else -g[k] * sg
            if i < k:
                dz += z[i + 1]
            zi = z[i] + tau * dz
            ts = tau
            for s in range(2, k - i + 1):
                ts *= tau
                zi += z[i + s] * ts * fa[s]
            new[i] = zi
        self.z = new

    def derivative(self, i: int = 1) -> float:
        """Current estimate of ``f^(i)`` (``i = 0..k``)."""
        return self.z[i]

    def accuracy_bound_noise(self, eps: float, i: int = 1) -> float:
        """Order of the noise-induced error of ``z_i``: ``L^(i/(k+1)) eps^((k+1-i)/(k+1))`` (no constant).

        A scale, not a guaranteed bound: the constant ``nu_i`` of Levant (2003) is not tabulated.
        """
        k = self.order
        return self.lipschitz ** (i / (k + 1)) * abs(eps) ** ((k + 1 - i) / (k + 1))
