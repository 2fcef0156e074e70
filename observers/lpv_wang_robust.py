r"""Robust H2 and unstructured LPV slip-angle observers (Y. Wang 2014, ch. 3, sec. 3.2.3).

Same model, inputs, outputs and derived ``v_y, beta`` as :mod:`roadtruth.observers.lpv_wang`; the observers are
scheduled on the *measured* ``theta_m = (1/v_m, a_m/v_m)``, which may be wrong by the multiplicative
errors ``v_m = (1 + eps1) v_x``, ``a_m = (1 + eps2) a_x`` (3.68)-(3.73), ``eps1`` in +-0.1, ``eps2`` in
+-0.2 (the ``scheduling_error`` option applies such an error on purpose, as in the dissertation's
experiment). Designs on the 16 vertices of Lemma 10 in :mod:`roadtruth.observers.lpv_wang_robust_design`.

* ``lpv_wang_h2``: robust H2 Luenberger observer (3.31), ``L(theta_m) = L0 + theta_m1 L1 + theta_m2 L2``,
  designed by the standard H2 LMIs (the printed (3.41) lacks the output term, see the design module);
  ``gamma`` bounds the H2 norm from ``w = (x_hat, delta, delta', r)`` to ``e``.
* ``lpv_wang_unstructured_hinf`` / ``lpv_wang_unstructured_h2``: unstructured observer (3.47)-(3.48)

  .. math::

      \dot{\hat x} = A_o(\theta_m)\hat x + B_{ou}(\theta_m)(\delta, \dot\delta, r)^T + B_{oy}(\theta_m) y,

  all three matrices affine in ``theta_m``, designed by (3.53) (L2 gain) or (3.52) (H2, corrected).
  The steering-rate column of ``B_ou`` is the plant's ``(1, 0)^T`` (fixed in the design, and so printed
  in sec. 3.3), so with ``z1 = alpha_f_hat - delta`` no differentiated steering is needed:
  ``z1' = [A_o x_hat]_1 + B_ou[0, 0] delta + B_ou[0, 2] r + B_oy[0] y``.
* ``*_printed``: the gains and matrices printed in sec. 3.3, through the same certification.

Without fresh ``delta, r, v_x`` for ``hold_s`` the observers predict with the plant model at
``theta_m`` (``L = 0``, i.e. ``A_o = A``, ``B_ou = B``, ``B_oy = 0``). Discretisation: exact ZOH per
step (closed form), so the stiff unstructured matrices (eigenvalues to -6400 1/s) are safe. The
per-step update is the compiled kernel of the Luenberger variants
(:mod:`roadtruth.observers.lpv_wang_loop`, unstructured form).
"""

from __future__ import annotations

from typing import Any

from roadtruth.observers.lmi import DesignResult, usable_gains
from roadtruth.observers.lpv_wang import _COMMON, LPVWang
from roadtruth.observers.lpv_wang_loop import UNSTRUCTURED
from roadtruth.observers.registry import register

_ROBUST: dict[str, Any] = {**_COMMON, "eps1_range": (-0.1, 0.1), "eps2_range": (-0.2, 0.2)}
_CITE = "Y. Wang, PhD dissertation, Auburn University 2014, ch. 3"


class _RobustDesign(LPVWang):
    """Shared: the design comes from :mod:`roadtruth.observers.lpv_wang_robust_design`."""

    def _compute_design(self) -> DesignResult:
        from roadtruth.observers.lpv_wang_robust_design import design_for
        return design_for(self.design_request())


@register
class LPVWangH2(_RobustDesign):
    """Robust H2 LPV Luenberger slip-angle observer on the 16 vertices of Lemma 10."""

    name = "lpv_wang_h2"
    citation = f"{_CITE}, eqs. (3.31)-(3.41) (H2 LMIs in the standard form), Lemma 10"
    variant = "h2"
    default_options = {**_ROBUST, "gamma_slack": 1.05}


@register
class LPVWangH2Printed(_RobustDesign):
    """H2 LPV Luenberger slip-angle observer with the gains printed in sec. 3.3."""

    name = "lpv_wang_h2_printed"
    citation = f"{_CITE}, sec. 3.3 (printed H2 gains)"
    variant = "h2_printed"
    default_options = dict(_ROBUST)


@register
class LPVWangUnstructuredHinf(_RobustDesign):
    """Unstructured LPV slip-angle observer (3.47), H-infinity design (3.53)."""

    name = "lpv_wang_unstructured_hinf"
    citation = f"{_CITE}, eqs. (3.44)-(3.53), (3.74)-(3.75)"
    variant = "unstructured_hinf"
    structure = UNSTRUCTURED   # the kernel's observer form (lpv_wang_loop)
    default_options = {**_ROBUST, "gamma_slack": 1.01}

    def gains(self) -> tuple[float, ...]:
        """``Ao_i`` (4 each), ``Bou_i`` (6 each), ``Boy_i`` (2 each), i = 0..2, flattened row-major."""
        if self._L is None:
            from roadtruth.observers.lpv_wang_robust_design import UNSTRUCTURED_KEYS
            self._L = usable_gains(self.name, self.design(), UNSTRUCTURED_KEYS)
        return self._L


@register
class LPVWangUnstructuredHinfPrinted(LPVWangUnstructuredHinf):
    """Unstructured H-infinity LPV slip-angle observer with the matrices printed in sec. 3.3."""

    name = "lpv_wang_unstructured_hinf_printed"
    citation = f"{_CITE}, sec. 3.3 (printed unstructured H-infinity matrices)"
    variant = "unstructured_hinf_printed"
    default_options = dict(_ROBUST)


@register
class LPVWangUnstructuredH2(LPVWangUnstructuredHinf):
    """Unstructured LPV slip-angle observer (3.47), H2 design ((3.52) in the standard form)."""

    name = "lpv_wang_unstructured_h2"
    citation = f"{_CITE}, eqs. (3.44)-(3.52) (H2 LMIs in the standard form)"
    variant = "unstructured_h2"
    default_options = {**_ROBUST, "gamma_slack": 1.05}


@register
class LPVWangUnstructuredH2Printed(LPVWangUnstructuredHinf):
    """Unstructured H2 LPV slip-angle observer with the matrices printed in sec. 3.3."""

    name = "lpv_wang_unstructured_h2_printed"
    citation = f"{_CITE}, sec. 3.3 (printed unstructured H2 matrices)"
    variant = "unstructured_h2_printed"
    default_options = dict(_ROBUST)
