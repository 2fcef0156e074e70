"""Certified LMI design toolkit shared by the LMI observers.

* Polytopes of the scheduling parameters: the 4-vertex trapezoid of ``(1/v_x, a_x/v_x)`` (Wang 2014,
  Lemma 9, with the printed typo in the 4th vertex corrected) and the 16-vertex set of Lemma 10.
* :func:`solve_lmi`: one cvxpy problem, Clarabel first, SCS as fallback; strict inequalities are
  imposed as ``<< -strictness * I`` with ``strictness`` tied to the solver tolerance.
* :func:`certify_design`: after every solve the result is re-checked in NumPy, independently of the
  solver: every LMI at every vertex and on a dense grid of the physical scheduling domain
  (eigenvalues with a margin), optional Metzler conditions, and frozen closed-loop stability. A design
  that fails is ``certified=False`` with the reason; it is never silently used as good.
* A disk cache of :class:`DesignResult` (JSON) keyed by a hash of everything the design depends on,
  in the user cache folder (``$ROADTRUTH_CACHE`` overrides it); each entry carries a SHA-256 of its
  content, so an edited entry is ignored and the design recomputed (why a checksum and not a re-check:
  see the cache section).

cvxpy is imported lazily (only a cold design needs it).
"""

from __future__ import annotations

import enum
import hashlib
import inspect
import itertools
import json
import math
import os
import time
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from roadtruth.harness.files.disk_cache import CACHE_ENV, cache_folder, read_entry, write_entry  # noqa: F401 (CACHE_ENV re-exported)


class DesignStatus(enum.Enum):
    """Outcome of a design. Only CERTIFIED designs carry a valid certificate."""

    CERTIFIED = "certified"            # solved (or given) and re-checked at vertices and on the grid
    REJECTED = "rejected"              # gains exist but the NumPy re-check failed
    INFEASIBLE = "infeasible"          # the solver proved the LMIs infeasible
    SOLVER_FAILED = "solver_failed"    # no solver returned a usable answer
    NOT_APPLICABLE = "not_applicable"  # no LMI design (model-only baselines, filters)


@dataclass(frozen=True)
class DesignResult:
    """Serialisable design: gains (name -> nested lists), Lyapunov matrix P and the certificate.

    ``margins`` holds the checked quantities (e.g. ``lmi_max_eig_vertices`` <= -margin to certify);
    ``gamma`` the certified performance bound where the design has one.
    """

    status: DesignStatus
    certified: bool
    reason: str
    gains: dict[str, list[Any]] = field(default_factory=dict)
    P: list[list[float]] | None = None
    margins: dict[str, float] = field(default_factory=dict)
    gamma: float | None = None
    solver_stats: dict[str, Any] = field(default_factory=dict)
    variant: str = ""
    key: str = ""
    from_cache: bool = field(default=False, compare=False)
    design_time_s: float = field(default=0.0, compare=False)

    @classmethod
    def not_applicable(cls, variant: str, reason: str) -> DesignResult:
        return cls(DesignStatus.NOT_APPLICABLE, False, reason, variant=variant)

    def gain(self, name: str) -> np.ndarray:
        """Gain ``name`` as a float array."""
        return np.asarray(self.gains[name], dtype=float)

    def to_json_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["status"] = self.status.value
        d.pop("from_cache")
        d.pop("design_time_s")
        return d

    @classmethod
    def from_json_dict(cls, d: Mapping[str, Any]) -> DesignResult:
        d = dict(d)
        d["status"] = DesignStatus(d["status"])
        return cls(**d)


class DesignFailed(RuntimeError):
    """An observer has no usable gains (infeasible or failed design); the runner reports it as an error."""


def usable_gains(name: str, design: DesignResult, keys: Sequence[str]) -> tuple[float, ...]:
    """The gains ``keys`` of a design, flattened in order, for running an observer.

    Certified designs and rejected ones that still carry gains (the "as printed" variants, which run
    with ``certified = False``) are usable; anything else raises :class:`DesignFailed`.
    """
    if design.status not in (DesignStatus.CERTIFIED, DesignStatus.REJECTED) or any(k not in design.gains for k in keys):
        raise DesignFailed(f"{name}: design {design.status.value}: {design.reason}")
    return tuple(float(x) for k in keys for x in design.gain(k).reshape(-1))


@dataclass(frozen=True)
class SolverSettings:
    """Solver order and tolerances. ``strictness`` (default 100x ``tol``) makes ``< 0`` strict;
    the certificate accepts an LMI only if its largest eigenvalue is <= -``certify_margin``."""

    solvers: tuple[str, ...] = ("CLARABEL", "SCS")
    tol: float = 1e-8
    strictness: float = 1e-6
    certify_margin: float = 1e-7
    scs_eps: float = 1e-7
    scs_max_iters: int = 20_000

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


# ---- polytopes -----------------------------------------------------------------------------------

def box_corners(bounds: Sequence[tuple[float, float]]) -> np.ndarray:
    """All ``2**p`` corners of a box: (2**p, p) array, the last coordinate varying fastest."""
    return np.array(list(itertools.product(*[(lo, hi) for lo, hi in bounds])), dtype=float)


def trapezoid_vertices(v_range: tuple[float, float], a_range: tuple[float, float]) -> np.ndarray:
    """Wang 2014, Lemma 9: ``(1/v, a/v)`` for v, a in boxes lies in the polytope of 4 vertices.

    Returns (4, 2) array ``[theta1, theta2]`` [s/m, 1/s].
    """
    c = box_corners([v_range, a_range])
    return np.column_stack([1.0 / c[:, 0], c[:, 1] / c[:, 0]])


def scheduling_error_range(eps_range: tuple[float, float], eps2_range: tuple[float, float]
                           ) -> tuple[tuple[float, float], tuple[float, float]]:
    """Wang 2014, eq. (3.71): ranges of ``eps1/(1+eps1)`` and ``(eps1-eps2)/(1+eps1)`` (bars restored)."""
    (e1lo, e1hi), (e2lo, e2hi) = eps_range, eps2_range
    x3 = (e1lo / (1 + e1lo), e1hi / (1 + e1hi))
    x4 = (1 - (1 + e2hi) / (1 + e1lo), 1 - (1 + e2lo) / (1 + e1hi))
    return x3, x4


def robust_vertices(v_range: tuple[float, float], a_range: tuple[float, float],
                    eps1_range: tuple[float, float], eps2_range: tuple[float, float]) -> np.ndarray:
    """Wang 2014, Lemma 10 / eq. (3.72): 16 vertices of ``(theta1, theta2, dtheta1, dtheta2)``.

    ``x1 = 1/v``, ``x2 = a``, ``x3 = eps1/(1+eps1)``, ``x4 = (eps1-eps2)/(1+eps1)``; the vector is
    ``(x1, x1 x2, x1 x3, x1 x2 x4)``, multi-affine in the box corners. Returns (16, 4) array.
    """
    x3, x4 = scheduling_error_range(eps1_range, eps2_range)
    c = box_corners([(1.0 / v_range[0], 1.0 / v_range[1]), a_range, x3, x4])
    return np.column_stack([c[:, 0], c[:, 0] * c[:, 1], c[:, 0] * c[:, 2], c[:, 0] * c[:, 1] * c[:, 3]])


def physical_grid(bounds: Sequence[tuple[float, float]], n: int | Sequence[int]) -> np.ndarray:
    """Dense grid of a physical parameter box (ends included): (prod(n), p) array."""
    ns = [n] * len(bounds) if isinstance(n, int) else list(n)
    axes = [np.linspace(lo, hi, k) for (lo, hi), k in zip(bounds, ns, strict=True)]
    return np.array(list(itertools.product(*axes)), dtype=float)


# ---- solving -------------------------------------------------------------------------------------

@dataclass(frozen=True)
class SolveOutcome:
    """``status``: 'optimal' | 'infeasible' | 'failed'; values of the named expressions; stats."""

    status: str
    values: dict[str, np.ndarray]
    stats: dict[str, Any]


def sym(X: Any) -> Any:
    """Symmetric part, needed because cvxpy's ``<<`` requires a symmetric expression."""
    return (X + X.T) / 2


def solve_lmi(build: Callable[[], tuple[Any, Mapping[str, Any]]], settings: SolverSettings) -> SolveOutcome:
    """Build and solve one cvxpy problem; try the solvers of ``settings`` in order.

    ``build()`` returns ``(problem, {name: expression})``; a fresh problem is built per solver.
    Clarabel's 'infeasible' is final; a solver error or an unsolved status falls through to the next
    solver. An 'optimal_inaccurate' answer is returned (flagged in the stats): every answer is
    re-checked by :func:`certify_design`, which is what decides.
    """
    import cvxpy as cp

    tried: list[str] = []
    last: SolveOutcome | None = None
    for solver in settings.solvers:
        problem, exprs = build()
        kwargs: dict[str, Any] = {}
        if solver == "CLARABEL":
            kwargs = {"tol_gap_abs": settings.tol, "tol_gap_rel": settings.tol, "tol_feas": settings.tol}
        elif solver == "SCS":
            kwargs = {"eps": settings.scs_eps, "max_iters": settings.scs_max_iters}
        t0 = time.perf_counter()
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # an inaccurate status is reported in the stats instead
                problem.solve(solver=getattr(cp, solver), **kwargs)
        except (cp.error.SolverError, ArithmeticError, ValueError) as exc:
            tried.append(f"{solver}: error {exc}".splitlines()[0][:200])
            continue
        stats = {"solver": solver, "status": str(problem.status), "solve_time_s": time.perf_counter() - t0,
                 "objective": float(problem.value) if problem.value is not None and np.isfinite(problem.value)
                 else None, "tried": list(tried)}
        if problem.status in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE):
            values = {k: np.atleast_1d(np.asarray(v.value, dtype=float)) for k, v in exprs.items()}
            # An inaccurate answer is still returned: certify_design() decides whether it holds.
            return SolveOutcome("optimal", values, stats)
        if problem.status in (cp.INFEASIBLE, cp.INFEASIBLE_INACCURATE) and solver == "CLARABEL":
            return SolveOutcome("infeasible", {}, stats)
        tried.append(f"{solver}: {problem.status}")
        last = last or SolveOutcome("infeasible" if "infeasible" in str(problem.status) else "failed", {}, stats)
    return last or SolveOutcome("failed", {}, {"tried": tried})


# ---- certification -------------------------------------------------------------------------------

@dataclass(frozen=True)
class Certificate:
    certified: bool
    reason: str
    margins: dict[str, float]


def metzler_margin(M: np.ndarray) -> float:
    """Smallest off-diagonal entry of a square matrix (>= 0 iff M is Metzler)."""
    M = np.asarray(M, dtype=float)
    off = M[~np.eye(M.shape[0], dtype=bool)]
    return float(off.min()) if off.size else math.inf


def is_metzler(M: np.ndarray, tol: float = 0.0) -> bool:
    """True when every off-diagonal entry is >= -tol."""
    return metzler_margin(M) >= -tol


def _max_eig(mats: Iterable[np.ndarray]) -> float:
    arr = np.array([0.5 * (m + m.T) for m in mats])
    return float(np.linalg.eigvalsh(arr)[:, -1].max()) if len(arr) else -math.inf


def certify_design(*, P: np.ndarray | None, lmis: Mapping[str, Callable[[np.ndarray], np.ndarray]],
                   vertices: np.ndarray, grid: np.ndarray | None = None,
                   closed_loop: Callable[[np.ndarray], np.ndarray] | None = None,
                   stability_rate: float = 0.0,
                   metzler: Callable[[np.ndarray], np.ndarray] | None = None,
                   margin: float = 1e-7) -> Certificate:
    """Re-check a design in NumPy, independently of the solver.

    Parameters
    ----------
    P : (n, n) array or None
        Lyapunov matrix; must be symmetric positive definite (min eigenvalue >= margin).
    lmis : name -> function(point) -> symmetric matrix that must be negative definite
        Each is checked at every vertex (max eigenvalue <= -margin) and on ``grid``.
    vertices : (v, p) array
        Vertices of the scheduling polytope in the coordinates the LMIs are affine in.
    grid : (g, p) array or None
        Dense points of the physical scheduling domain mapped to the same coordinates; catches a
        wrong polytope (a point outside it) as well as a wrong vertex LMI.
    closed_loop : function(point) -> (n, n) array, optional
        Frozen error dynamics; every eigenvalue must have real part <= -stability_rate (+ tolerance).
    metzler : function(point) -> (n, n) array, optional
        Matrix that must be Metzler at every vertex and grid point (interval observers).
    margin : float
        Strictness accepted by the check (below the solver's strictness).

    Returns
    -------
    Certificate with ``margins``: ``p_min_eig``, ``<lmi>_max_eig_vertices`` / ``_grid``,
    ``closed_loop_max_real_eig``, ``metzler_min_offdiag``.
    """
    margins: dict[str, float] = {}
    failures: list[str] = []
    points = vertices if grid is None else np.vstack([vertices, grid])
    if P is not None:
        P = np.asarray(P, dtype=float)
        asym = float(np.abs(P - P.T).max())
        pmin = float(np.linalg.eigvalsh(0.5 * (P + P.T)).min())
        margins["p_min_eig"] = pmin
        margins["p_cond"] = float(np.linalg.cond(P)) if pmin > 0 else math.inf
        if not np.all(np.isfinite(P)) or pmin < margin or asym > 1e-9 * max(1.0, float(np.abs(P).max())):
            failures.append(f"P not positive definite (min eig {pmin:.3g})")
    for name, fn in lmis.items():
        try:
            mv = _max_eig(fn(p) for p in vertices)
            mg = _max_eig(fn(p) for p in grid) if grid is not None else -math.inf
        except (np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
            failures.append(f"{name}: evaluation failed ({exc})")
            continue
        margins[f"{name}_max_eig_vertices"] = mv
        if grid is not None:
            margins[f"{name}_max_eig_grid"] = mg
        if not (mv <= -margin):
            failures.append(f"{name} not negative definite at a vertex (max eig {mv:.3g})")
        elif not (mg <= -margin):
            failures.append(f"{name} not negative definite on the grid (max eig {mg:.3g})")
    if closed_loop is not None:
        re = max(float(np.linalg.eigvals(closed_loop(p)).real.max()) for p in points)
        margins["closed_loop_max_real_eig"] = re
        if not (re <= -stability_rate + 1e-9 * max(1.0, stability_rate)):
            failures.append(f"closed loop not stable at rate {stability_rate:.4g} (max Re eig {re:.4g})")
    if metzler is not None:
        mm = min(metzler_margin(metzler(p)) for p in points)
        margins["metzler_min_offdiag"] = mm
        if mm < 0.0:
            failures.append(f"not Metzler (min off-diagonal {mm:.4g})")
    if failures:
        return Certificate(False, "; ".join(failures), margins)
    return Certificate(True, "all checks passed at every vertex and grid point", margins)


# ---- cache ---------------------------------------------------------------------------------------
#
# Why a digest and not re-certification on load: the certificate's checks are closures that each
# family builds inside its own design function (its vertex LMIs, grid, decay rate, Metzler
# structure), and several stored designs cannot be re-checked from what they hold (the "as printed"
# variants carry no P, the UIO's (1.26) needs the solver's lambda, the switched design's LMIs need its
# per-mode Q and gamma). So an entry carries a SHA-256 of its content and key (``roadtruth.harness.files.disk_cache``);
# any edit makes it unreadable and the design is recomputed and re-certified from scratch.

_MEMO: dict[str, DesignResult] = {}
#: Sub-folder of the cache root (``roadtruth.harness.files.disk_cache.cache_root``) holding the designs.
CACHE_KIND = "designs"


def design_cache_dir() -> Path:
    """``designs/`` under ``$ROADTRUTH_CACHE``, else under the user cache folder (never the working directory)."""
    return cache_folder(CACHE_KIND)


@dataclass(frozen=True)
class DesignRequest:
    """What an observer's LMI design depends on, handed to its design module.

    The design modules take this instead of the observer object, so they never import the
    observer classes (no observer <-> design import cycle).

    Attributes
    ----------
    vehicle : the ``VehicleParams`` the observer was built for.
    variant : the observer's variant (``""`` for the family's main form).
    options : the observer's options (defaults merged).
    model : a family's own model data the design needs (stiffness ranges, a lead-vehicle or
        Takagi-Sugeno model, the generalized UIO model); None if the family has none.
    """

    vehicle: Any
    variant: str
    options: Mapping[str, Any]
    model: Any = None


def source_fingerprint(*objects: Any) -> str:
    """Hash of the source files defining ``objects`` (a code change invalidates cached designs)."""
    h = hashlib.sha256()
    for obj in objects:
        try:
            path = inspect.getsourcefile(obj)
            h.update(Path(path).read_bytes() if path else repr(obj).encode())
        except (TypeError, OSError):
            h.update(repr(obj).encode())
    return h.hexdigest()[:16]


def design_key(payload: Mapping[str, Any]) -> str:
    """SHA-256 of the canonical JSON of everything the design depends on."""
    text = json.dumps(payload, sort_keys=True, separators=(",", ":"), default=repr)
    return hashlib.sha256(text.encode()).hexdigest()


#: Designs shipped with the package (``scripts/ship_designs.py`` writes them for the shipped vehicles
#: with default options): same entry format and digest check as the user cache, read after it, so a
#: fresh install runs the default suite without solving an SDP. A key is a hash of everything the
#: design depends on, source code included, so an edited design module simply misses them.
SHIPPED_DESIGNS_DIR = Path(__file__).resolve().parent / "designs"
#: Set to ``0`` to ignore the shipped designs (tests of the design code itself do).
SHIPPED_DESIGNS_ENV = "ROADTRUTH_SHIPPED_DESIGNS"


def _design_folders(folder: Path | None) -> list[Path]:
    if folder is not None:
        return [folder]
    folders = [design_cache_dir()]
    if os.environ.get(SHIPPED_DESIGNS_ENV, "1").strip() != "0":
        folders.append(SHIPPED_DESIGNS_DIR)
    return folders


def load_design(key: str, folder: Path | None = None) -> DesignResult | None:
    """The cached design of ``key`` (the user cache, then the shipped designs; or only ``folder``),
    or None when absent, unreadable, edited (digest mismatch) or inconsistent (a ``certified`` flag
    that disagrees with the status)."""
    for where in _design_folders(folder):
        result = _load_design_from(where, key)
        if result is not None:
            return result
    return None


def _load_design_from(folder: Path, key: str) -> DesignResult | None:
    data = read_entry(folder, key)
    try:
        result = DesignResult.from_json_dict(data["design"])  # type: ignore[index]
    except (ValueError, KeyError, TypeError):
        return None
    if result.key != key or result.certified != (result.status is DesignStatus.CERTIFIED):
        return None
    return result


def store_design(result: DesignResult, payload: Mapping[str, Any], folder: Path | None = None) -> None:
    """Write the design and its digest atomically; cache failures never break a run."""
    write_entry(folder or design_cache_dir(), result.key, {"payload": payload, "design": result.to_json_dict()})


def cached_design(payload: Mapping[str, Any], compute: Callable[[], DesignResult], *,
                  use_cache: bool = True) -> DesignResult:
    """Return the design for ``payload`` from memory, then disk, else ``compute()`` and store it.

    A disk entry is used only if its digest matches (see the note above this section); a tampered or
    corrupt entry is recomputed and overwritten.
    """
    key = design_key(payload)
    if use_cache:
        if key in _MEMO:
            return _MEMO[key]
        hit = load_design(key)
        if hit is not None:
            hit = _replace(hit, from_cache=True)
            _MEMO[key] = hit
            return hit
    t0 = time.perf_counter()
    result = compute()
    result = _replace(result, key=key, design_time_s=time.perf_counter() - t0)
    if use_cache:
        store_design(result, payload)
        _MEMO[key] = result
    return result


def clear_memory_cache() -> None:
    """Forget in-process designs (the disk cache is untouched)."""
    _MEMO.clear()


def _replace(result: DesignResult, **changes: Any) -> DesignResult:
    from dataclasses import replace
    return replace(result, **changes)
