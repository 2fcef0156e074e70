"""Derived channels of a column map: safe expressions over log columns, mapped signals and the vehicle.

A column-map entry may compute its signal instead of reading one column::

    vx_mps: {expr: "mean(omega_rl_radps, omega_rr_radps) * wheel_radius_m"}
    beta_rad: {derive: sideslip}                       # atan2(vy_mps, vx_mps)
    delta_rad: {derive: road_wheel_angle}              # handwheel_rad / steering_ratio
    ax_mps2: {derive: derivative, of: [vx_mps], cutoff_hz: 2.0}
    omega_rl_radps: {expr: "col('Wheel Speed RL')", unit: rpm}

An expression is parsed with :mod:`ast` and only numbers, names, ``+ - * / **``, unary minus and the
functions of ``FUNCTIONS`` are accepted; nothing is passed to ``eval``. A name is, in this order,

1. another key of the same map (its value in SI, after that entry's own unit/scale/offset);
2. a vehicle parameter (``VEHICLE_NAMES``: ``steering_ratio``, ``wheel_radius_m`` …, SI);
3. a log column (raw, as logged; ``col('any name')`` for a column name that is not an identifier).

The result is then converted like a column: ``si = result * unit * scale + offset``. A division by zero
(±inf) in the result is a missing sample (NaN), not an error.

``ddt(x, f_c)`` and ``lowpass(x, f_c)`` are causal (they use only past samples, like an ECU would):
two cascaded first-order low-pass stages with time constant ``tau = 1 / (2 pi f_c)`` each, stepped on
the log's own time stamps; ``ddt`` filters the backward difference ``(x_k - x_{k-1}) / (t_k - t_{k-1})``.
Their low-frequency delay is ``2 tau`` (80 ms at 4 Hz). A NaN input sample gives a NaN output and
leaves the filter state as it was.
"""

from __future__ import annotations

import ast
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

MAX_EXPR_CHARS = 400
MAX_EXPR_NODES = 200

#: Named derivations: name -> (expression template, default inputs, what it is).
#: ``{of}`` is the comma-joined input list, ``{of0}`` its first item, ``{cutoff_hz}`` the cut-off.
DERIVATIONS: dict[str, tuple[str, tuple[str, ...], str]] = {
    "road_wheel_angle": ("{of0} / steering_ratio", ("handwheel_rad",),
                         "delta = handwheel angle / the vehicle's steering ratio"),
    "sideslip": ("atan2(vy_mps, vx_mps)", ("vy_mps", "vx_mps"), "beta = atan2(v_y, v_x)"),
    "lateral_velocity": ("vx_mps * tan(beta_rad)", ("vx_mps", "beta_rad"), "v_y = v_x tan(beta)"),
    "wheel_speed": ("mean({of}) * wheel_radius_m", ("omega_rl_radps", "omega_rr_radps"),
                    "v_x = mean of the wheel speeds x the vehicle's wheel radius (non-driven wheels)"),
    "derivative": ("ddt({of0}, {cutoff_hz})", ("vx_mps",),
                   "causal time derivative, low-passed at cutoff_hz (a_x from dv_x/dt)"),
}
DEFAULT_CUTOFF_HZ = 2.0

#: Vehicle parameters an expression may name (SI), read from the replay's vehicle.
VEHICLE_NAMES: dict[str, str] = {
    "steering_ratio": "steering.ratio", "wheel_radius_m": "wheel_radius_m", "mass_kg": "mass_kg",
    "yaw_inertia_kgm2": "yaw_inertia_kgm2", "lf_m": "lf_m", "lr_m": "lr_m", "wheelbase_m": "wheelbase_m",
    "track_f_m": "track_f_m", "track_r_m": "track_r_m",
}


def _mean(*xs: np.ndarray) -> np.ndarray:
    # plain mean: a NaN in one input is a NaN result (a missing wheel speed is not silently dropped)
    return np.sum(np.broadcast_arrays(*xs), axis=0) / len(xs)


#: name -> (numpy function, min args, max args). ddt/lowpass/col are handled by the evaluator.
FUNCTIONS: dict[str, tuple[Callable[..., np.ndarray] | None, int, int]] = {
    "mean": (_mean, 1, 8), "min": (np.fmin, 2, 2), "max": (np.fmax, 2, 2), "abs": (np.abs, 1, 1),
    "sqrt": (np.sqrt, 1, 1), "atan2": (np.arctan2, 2, 2), "atan": (np.arctan, 1, 1), "tan": (np.tan, 1, 1),
    "sin": (np.sin, 1, 1), "cos": (np.cos, 1, 1), "hypot": (np.hypot, 2, 2),
    "deg2rad": (np.deg2rad, 1, 1), "rad2deg": (np.rad2deg, 1, 1),
    "ddt": (None, 2, 2), "lowpass": (None, 2, 2), "col": (None, 1, 1),
}

_BINOPS: dict[type, Callable[[np.ndarray, np.ndarray], np.ndarray]] = {
    ast.Add: np.add, ast.Sub: np.subtract, ast.Mult: np.multiply, ast.Div: np.divide, ast.Pow: np.power,
}


class ExpressionError(ValueError):
    """An expression that is not allowed or cannot be evaluated (the message is one line)."""


@dataclass(frozen=True)
class Expression:
    """A checked expression: its text, parsed tree and the bare names and ``col()`` columns it uses."""

    text: str
    tree: ast.Expression
    names: frozenset[str]
    columns: frozenset[str]


def parse_expression(text: str) -> Expression:
    """Parse and check an expression (module doc). Raises ``ExpressionError`` naming what is not allowed."""
    if not isinstance(text, str) or not text.strip():
        raise ExpressionError("expression must be a non-empty string")
    if len(text) > MAX_EXPR_CHARS:
        raise ExpressionError(f"expression longer than {MAX_EXPR_CHARS} characters")
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise ExpressionError(f"expression {text!r} is not valid: {exc.msg}") from None
    nodes = list(ast.walk(tree))
    if len(nodes) > MAX_EXPR_NODES:
        raise ExpressionError(f"expression has more than {MAX_EXPR_NODES} parts")
    names: set[str] = set()
    columns: set[str] = set()
    called = {id(n.func) for n in nodes if isinstance(n, ast.Call)}
    for node in nodes:
        if isinstance(node, ast.Expression | ast.Load | ast.operator | ast.unaryop):
            if isinstance(node, ast.operator) and type(node) not in _BINOPS:
                raise ExpressionError(f"operator {type(node).__name__} is not allowed (only + - * / **)")
            if isinstance(node, ast.unaryop) and not isinstance(node, ast.USub | ast.UAdd):
                raise ExpressionError(f"operator {type(node).__name__} is not allowed")
            continue
        if isinstance(node, ast.BinOp | ast.UnaryOp):
            continue
        if isinstance(node, ast.Name):
            if id(node) not in called:
                names.add(node.id)
            continue
        if isinstance(node, ast.Constant):
            if isinstance(node.value, bool) or not isinstance(node.value, int | float | str):
                raise ExpressionError(f"constant {node.value!r} is not allowed (numbers only)")
            continue
        if isinstance(node, ast.Call):
            fn = node.func.id if isinstance(node.func, ast.Name) else None
            if fn not in FUNCTIONS:
                raise ExpressionError(f"function {ast.unparse(node.func)!r} is not allowed "
                                      f"(allowed: {', '.join(sorted(FUNCTIONS))})")
            _f, lo, hi = FUNCTIONS[fn]
            if node.keywords or not lo <= len(node.args) <= hi or any(isinstance(a, ast.Starred) for a in node.args):
                want = f"{lo}" if lo == hi else f"{lo} to {hi}"
                raise ExpressionError(f"{fn}() takes {want} positional argument(s)")
            if fn == "col":
                arg = node.args[0]
                if not (isinstance(arg, ast.Constant) and isinstance(arg.value, str)):
                    raise ExpressionError("col() takes a quoted column name: col('Wheel Speed RL')")
                columns.add(arg.value)
            elif fn in ("ddt", "lowpass"):
                fc = node.args[1]
                if not (isinstance(fc, ast.Constant) and isinstance(fc.value, int | float)
                        and not isinstance(fc.value, bool) and 0 < fc.value < 1e4):
                    raise ExpressionError(f"{fn}(x, cutoff_hz): cutoff_hz must be a number in (0, 1e4) Hz")
            continue
        raise ExpressionError(f"{type(node).__name__} is not allowed in an expression "
                              "(numbers, names, + - * / **, and the listed functions only)")
    # a string constant is only allowed as the argument of col()
    for node in nodes:
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value not in columns:
            raise ExpressionError(f"text {node.value!r} is only allowed as col('column name')")
    return Expression(text=text.strip(), tree=tree, names=frozenset(names), columns=frozenset(columns))


def derivation_expression(name: str, of: list[str] | None, cutoff_hz: float | None) -> str:
    """The expression of a named derivation (``DERIVATIONS``) with its inputs filled in."""
    template, default_of, _what = DERIVATIONS[name]
    inputs = list(of) if of else list(default_of)
    return template.format(of=", ".join(inputs), of0=inputs[0],
                           cutoff_hz=repr(float(cutoff_hz if cutoff_hz is not None else DEFAULT_CUTOFF_HZ)))


def causal_lowpass(t: np.ndarray, x: np.ndarray, cutoff_hz: float) -> np.ndarray:
    """Two cascaded first-order low-pass stages (tau = 1/(2 pi f_c) each) stepped on time stamps ``t`` [s].

    Causal: output k uses samples 0..k only. A NaN input gives a NaN output and keeps the state.
    """
    tau = 1.0 / (2.0 * math.pi * cutoff_hz)
    out = np.full(x.shape, np.nan)
    s1 = s2 = math.nan
    t_prev = math.nan
    for k, (tk, xk) in enumerate(zip(t.tolist(), x.tolist(), strict=True)):
        if not math.isfinite(xk):
            continue
        if not math.isfinite(s1):
            s1 = s2 = xk
        else:
            a = (tk - t_prev) / (tau + tk - t_prev)  # backward-Euler step of ds/dt = (x - s)/tau
            s1 += a * (xk - s1)
            s2 += a * (s1 - s2)
        t_prev = tk
        out[k] = s2
    return out


def causal_derivative(t: np.ndarray, x: np.ndarray, cutoff_hz: float) -> np.ndarray:
    """Backward difference dx/dt [unit of x per s], low-passed causally (``causal_lowpass``)."""
    d = np.full(x.shape, np.nan)
    with np.errstate(invalid="ignore"):
        d[1:] = np.diff(x) / np.diff(t)
    return causal_lowpass(t, d, cutoff_hz)


def evaluate(expr: Expression, lookup: Callable[[str], np.ndarray], column: Callable[[str], np.ndarray],
             t: np.ndarray) -> np.ndarray:
    """Evaluate a checked expression to an (n,) float array.

    ``lookup(name)`` resolves a bare name (map key, vehicle parameter or log column); ``column(name)``
    resolves ``col('name')``; ``t`` [s] is the log's time for ``ddt``/``lowpass``.
    """

    def ev(node: ast.AST) -> np.ndarray:
        if isinstance(node, ast.Expression):
            return ev(node.body)
        if isinstance(node, ast.Constant):
            return np.asarray(float(node.value))
        if isinstance(node, ast.Name):
            return np.asarray(lookup(node.id), dtype=float)
        if isinstance(node, ast.UnaryOp):
            v = ev(node.operand)
            return -v if isinstance(node.op, ast.USub) else v
        if isinstance(node, ast.BinOp):
            return _BINOPS[type(node.op)](ev(node.left), ev(node.right))
        if isinstance(node, ast.Call):
            fn = node.func.id  # type: ignore[attr-defined]  # checked by parse_expression
            if fn == "col":
                return np.asarray(column(node.args[0].value), dtype=float)  # type: ignore[attr-defined]
            args = [ev(a) for a in node.args]
            if fn in ("ddt", "lowpass"):
                x = np.broadcast_to(args[0], t.shape).astype(float)
                f = causal_derivative if fn == "ddt" else causal_lowpass
                return f(t, x, float(args[1]))
            numpy_fn = FUNCTIONS[fn][0]
            assert numpy_fn is not None
            return numpy_fn(*args)
        raise ExpressionError(f"{type(node).__name__} is not allowed")  # unreachable after parse_expression

    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        out = np.broadcast_to(ev(expr.tree), t.shape).astype(float)
    out[~np.isfinite(out)] = np.nan
    return out


def evaluation_order(deps: Mapping[str, frozenset[str]]) -> list[str]:
    """Keys of derived channels so that each comes after the derived channels it names.

    Raises ``ExpressionError`` naming a cycle (``a -> b -> a``).
    """
    order: list[str] = []
    state: dict[str, int] = {}  # 1 visiting, 2 done

    def visit(k: str, path: list[str]) -> None:
        if state.get(k) == 2:
            return
        if state.get(k) == 1:
            cycle = path[path.index(k):] + [k]
            raise ExpressionError(f"derived channels refer to each other in a cycle: {' -> '.join(cycle)}")
        state[k] = 1
        for d in sorted(deps[k]):
            if d in deps:
                visit(d, [*path, k])
        state[k] = 2
        order.append(k)

    for k in deps:
        visit(k, [])
    return order
