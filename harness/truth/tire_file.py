"""Reader of TYDEX / MF-Tyre tire property files (``.tir``) for the Magic Formula 6.1 / 6.2 truth model.

File format (MF-Tyre / TYDEX property file): ``[SECTION]`` headers, one ``NAME = value`` per line,
values numbers (Fortran ``D`` exponents accepted) or quoted strings, comments after ``$`` or ``!``
(whole lines or trailing), keys case-insensitive, and table blocks such as ``[SHAPE]`` whose rows are
not assignments (skipped: the truth does not use the tire contour).

Validation: ``[MODEL] FITTYP`` must name MF 6.1 (``61``) or MF 6.2 (``62``); ``6.1`` / ``6.2`` are
read as the same versions. The ``[UNITS]`` block must use SI (meter, newton, radian, kg, second,
pascal): the coefficients of a .tir file are dimensionless except a few, so other units are refused
rather than half-converted. Every problem is one ``VehicleError`` line ``<file>:<line>: <KEY>: ...``.

Defaults of missing keys (MF-Tyre 6.1): every Magic Formula coefficient 0 except PKY4 = 2, every
scaling factor (``L...``) 1; LONGVL = 16.7 m/s, VXLOW = 1 m/s; NOMPRES = INFLPRES (no pressure
effect, dp = 0) when one of them is missing. Without FNOMIN, UNLOADED_RADIUS or the pure-slip core
(PCX1, PDX1, PKX1, PCY1, PDY1, PKY1, PKY2) the model is singular, so those are required.
Missing validity ranges are unbounded (FZMIN 0).

The kernel's coefficient vector ``TireFile.coef`` has the layout ``MF61_NAMES`` (``MF61_INDEX``
maps a name to its index); its last entry ``DPI`` is the normalised pressure change
(INFLPRES − NOMPRES)/NOMPRES.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

import numpy as np

from roadtruth.harness.errors import VehicleError

#: Scaling factors (MF-Tyre 6.1 ``[SCALING_COEFFICIENTS]``), default 1.
SCALING_NAMES: tuple[str, ...] = (
    "LFZO", "LCX", "LMUX", "LEX", "LKX", "LHX", "LVX", "LCY", "LMUY", "LEY", "LKY", "LKYC", "LKZC",
    "LHY", "LVY", "LTR", "LRES", "LXAL", "LYKA", "LVYKA", "LS",
)

#: Layout of the kernel's coefficient vector. Order is fixed: roadtruth.harness.truth.tire_mf61 unpacks it by index.
MF61_NAMES: tuple[str, ...] = (
    "FNOMIN", "UNLOADED_RADIUS", *SCALING_NAMES,
    # longitudinal (pure and combined)
    "PCX1", "PDX1", "PDX2", "PDX3", "PEX1", "PEX2", "PEX3", "PEX4", "PKX1", "PKX2", "PKX3", "PHX1", "PHX2",
    "PVX1", "PVX2", "PPX1", "PPX2", "PPX3", "PPX4", "RBX1", "RBX2", "RBX3", "RCX1", "REX1", "REX2", "RHX1",
    # lateral (pure and combined)
    "PCY1", "PDY1", "PDY2", "PDY3", "PEY1", "PEY2", "PEY3", "PEY4", "PEY5", "PKY1", "PKY2", "PKY3", "PKY4",
    "PKY5", "PKY6", "PKY7", "PHY1", "PHY2", "PVY1", "PVY2", "PVY3", "PVY4", "PPY1", "PPY2", "PPY3", "PPY4",
    "PPY5", "RBY1", "RBY2", "RBY3", "RBY4", "RCY1", "REY1", "REY2", "RHY1", "RHY2", "RVY1", "RVY2", "RVY3",
    "RVY4", "RVY5", "RVY6",
    # aligning moment
    "QBZ1", "QBZ2", "QBZ3", "QBZ4", "QBZ5", "QBZ9", "QBZ10", "QCZ1", "QDZ1", "QDZ2", "QDZ3", "QDZ4", "QDZ6",
    "QDZ7", "QDZ8", "QDZ9", "QDZ10", "QDZ11", "QEZ1", "QEZ2", "QEZ3", "QEZ4", "QEZ5", "QHZ1", "QHZ2", "QHZ3",
    "QHZ4", "SSZ1", "SSZ2", "SSZ3", "SSZ4", "PPZ1", "PPZ2",
    # derived: normalised inflation pressure change
    "DPI",
)
MF61_INDEX: Mapping[str, int] = MappingProxyType({n: i for i, n in enumerate(MF61_NAMES)})
N_MF61_COEF = len(MF61_NAMES)

#: Keys without which the Magic Formula is singular or meaningless.
REQUIRED_NAMES: tuple[str, ...] = ("FNOMIN", "UNLOADED_RADIUS", "PCX1", "PDX1", "PKX1", "PCY1", "PDY1", "PKY1", "PKY2")
#: Non-zero defaults of MF-Tyre 6.1 (all other coefficients default to 0, scaling factors to 1).
NONZERO_DEFAULTS: Mapping[str, float] = MappingProxyType({"PKY4": 2.0, **{n: 1.0 for n in SCALING_NAMES}})

#: Accepted FITTYP values and the Magic Formula version each names.
FITTYP_VERSIONS: Mapping[str, int] = MappingProxyType({"61": 61, "62": 62, "6.1": 61, "6.2": 62})

#: [UNITS] entries: the SI spellings accepted for each quantity.
SI_UNITS: Mapping[str, frozenset[str]] = MappingProxyType({
    "LENGTH": frozenset({"meter", "meters", "metre", "metres", "m"}),
    "FORCE": frozenset({"newton", "newtons", "n"}),
    "ANGLE": frozenset({"radian", "radians", "rad"}),
    "MASS": frozenset({"kg", "kilogram", "kilograms"}),
    "TIME": frozenset({"second", "seconds", "sec", "s"}),
    "PRESSURE": frozenset({"pascal", "pascals", "pa", "n/m2", "n/m**2"}),
})

#: Keys whose value is text (quoted or not) wherever they appear.
TEXT_KEYS = frozenset({"FILE_TYPE", "FILE_FORMAT", "TYRESIDE", "PROPERTY_FILE_FORMAT", "FUNCTION_NAME", "TYPE",
                       "CONTACT_MODEL", "TIRE_VERSION"})
#: Sections that hold text only or tables, not coefficients.
TEXT_SECTIONS = frozenset({"MDI_HEADER", "UNITS"})
TABLE_SECTIONS = frozenset({"SHAPE"})

_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eEdD][+-]?\d+)?$")


@dataclass(frozen=True)
class TireFile:
    """A validated MF 6.1 / 6.2 tire property file.

    Ranges are the file's own values in its ISO convention (slip angle and inclination have the
    opposite sign of roadtruth's, see ``alpha_range_rad`` / ``camber_range_rad``).
    """

    name: str  # file stem
    path: str
    fittyp: int  # 61 or 62
    coef: np.ndarray  # (N_MF61_COEF,) read-only, layout MF61_NAMES
    fnomin_N: float
    unloaded_radius_m: float
    vertical_stiffness_Npm: float | None
    vertical_damping_Nspm: float | None
    longvl_mps: float
    vxlow_mps: float
    nompres_Pa: float | None
    inflpres_Pa: float | None
    fzmin_N: float
    fzmax_N: float
    kpumin: float
    kpumax: float
    alpmin_rad: float  # ISO slip angle
    alpmax_rad: float
    cammin_rad: float  # ISO inclination angle
    cammax_rad: float
    scaling: Mapping[str, float]
    parameters: Mapping[str, float]  # every numeric key of the file (upper case) as read

    @property
    def alpha_range_rad(self) -> tuple[float, float]:
        """Valid slip angle range in roadtruth's convention (α = −α_ISO) [rad]."""
        return -self.alpmax_rad, -self.alpmin_rad

    @property
    def camber_range_rad(self) -> tuple[float, float]:
        """Valid inclination range in roadtruth's convention (γ = −γ_ISO, top toward +y) [rad]."""
        return -self.cammax_rad, -self.cammin_rad

    def coefficient(self, name: str) -> float:
        """One entry of the kernel vector by name (``MF61_NAMES``)."""
        return float(self.coef[MF61_INDEX[name.upper()]])


def _fail(source: str, line: int | None, key: str | None, message: str) -> VehicleError:
    where = f"{source}:{line}" if line else source
    return VehicleError(message, source=where, field=key)


def _strip_comment(text: str) -> str:
    """Remove a trailing ``$`` / ``!`` comment outside quotes."""
    quote = ""
    for i, ch in enumerate(text):
        if quote:
            if ch == quote:
                quote = ""
        elif ch in "'\"":
            quote = ch
        elif ch in "$!":
            return text[:i]
    return text


def _parse_value(raw: str, key: str, section: str, source: str, line: int) -> str | float:
    raw = raw.strip()
    if len(raw) >= 2 and raw[0] in "'\"" and raw[-1] == raw[0]:
        return raw[1:-1].strip()
    if raw and raw[0] in "'\"":
        raise _fail(source, line, key, f"unterminated quoted value {raw!r}")
    if _NUMBER.match(raw):
        value = float(raw.replace("D", "E").replace("d", "e"))
        if not math.isfinite(value):
            raise _fail(source, line, key, f"value {raw!r} is not finite")
        return value
    if section in TEXT_SECTIONS or key in TEXT_KEYS:
        return raw
    raise _fail(source, line, key, f"value {raw!r} is not a number")


def parse_tir_text(text: str, source: str) -> dict[str, dict[str, tuple[str | float, int]]]:
    """Sections of a .tir text: {SECTION: {KEY: (value, line number)}}, keys and sections upper case."""
    sections: dict[str, dict[str, tuple[str | float, int]]] = {}
    current: str | None = None
    for number, raw_line in enumerate(text.splitlines(), start=1):
        line = raw_line.strip()
        if not line or line[0] in "$!":
            continue
        if line.startswith("["):
            end = line.find("]")
            if end < 2:
                raise _fail(source, number, None, f"malformed section header {line!r}")
            current = line[1:end].strip().upper()
            sections.setdefault(current, {})
            continue
        body = _strip_comment(line).strip()
        if not body:
            continue
        if "=" not in body:
            if current in TABLE_SECTIONS or body.startswith("{") or current is None and body.startswith("{"):
                continue  # table rows ([SHAPE] contour): not used by the truth
            if current is not None and all(_NUMBER.match(tok) for tok in body.split()):
                continue  # numeric table row of a table section without a '{...}' header
            raise _fail(source, number, None, f"expected 'NAME = value', got {body!r}")
        key, _, value = body.partition("=")
        key = key.strip().upper()
        if not key or not re.match(r"^[A-Z_][A-Z0-9_]*$", key):
            raise _fail(source, number, key or None, f"malformed parameter name in {body!r}")
        if current is None:
            raise _fail(source, number, key, "parameter outside any [SECTION]")
        block = sections[current]
        if key in block:
            raise _fail(source, number, key, f"defined twice in [{current}] (first on line {block[key][1]})")
        block[key] = (_parse_value(value, key, current, source, number), number)
    return sections


def _check_units(sections: dict[str, dict[str, tuple[str | float, int]]], source: str) -> None:
    for key, (value, line) in sections.get("UNITS", {}).items():
        accepted = SI_UNITS.get(key)
        if accepted is None:
            continue  # unknown quantity: nothing of ours is expressed in it
        if str(value).strip().lower() not in accepted:
            raise _fail(source, line, key, f"unit {value!r} is not supported; use SI units "
                        f"({', '.join(sorted(SI_UNITS[key])[:2])}) in the [UNITS] block")


def _fittyp(sections: dict[str, dict[str, tuple[str | float, int]]], source: str) -> int:
    if "MODEL" not in sections:
        raise _fail(source, None, "MODEL", "section [MODEL] missing (it names the Magic Formula version, FITTYP)")
    if "FITTYP" not in sections["MODEL"]:
        raise _fail(source, None, "FITTYP", "missing in [MODEL]; only MF 6.1 (FITTYP = 61) and MF 6.2 (62) files are read")
    value, line = sections["MODEL"]["FITTYP"]
    text = f"{value:g}" if isinstance(value, float) else str(value).strip()
    if text not in FITTYP_VERSIONS:
        raise _fail(source, line, "FITTYP", f"{text} is not supported; only MF 6.1 (FITTYP = 61) and MF 6.2 (62) files are read")
    return FITTYP_VERSIONS[text]


def tire_file_from_text(text: str, source: str = "<text>") -> TireFile:
    """Validate the text of a .tir file and build its ``TireFile`` (``source`` names it in errors)."""
    sections = parse_tir_text(text, source)
    fittyp = _fittyp(sections, source)
    _check_units(sections, source)
    numeric: dict[str, tuple[float, int, str]] = {}
    for section, block in sections.items():
        if section in TEXT_SECTIONS:
            continue
        for key, (value, line) in block.items():
            if not isinstance(value, float):
                continue
            if key in numeric and key in MF61_INDEX:
                first = numeric[key]
                raise _fail(source, line, key, f"defined twice ([{first[2]}] line {first[1]} and [{section}])")
            numeric.setdefault(key, (value, line, section))
    for key in REQUIRED_NAMES:
        if key not in numeric:
            raise _fail(source, None, key, "required coefficient missing")

    def get(key: str, default: float | None) -> float | None:
        return numeric[key][0] if key in numeric else default

    fnomin = float(numeric["FNOMIN"][0])
    r0 = float(numeric["UNLOADED_RADIUS"][0])
    for key, value in (("FNOMIN", fnomin), ("UNLOADED_RADIUS", r0)):
        if value <= 0.0:
            raise _fail(source, numeric[key][1], key, f"must be positive, got {value:g}")
    nompres, inflpres = get("NOMPRES", None), get("INFLPRES", None)
    if nompres is not None and nompres <= 0.0:
        raise _fail(source, numeric["NOMPRES"][1], "NOMPRES", f"must be positive, got {nompres:g}")
    dpi = (inflpres - nompres) / nompres if nompres is not None and inflpres is not None else 0.0

    coef = np.zeros(N_MF61_COEF)
    for i, name in enumerate(MF61_NAMES):
        coef[i] = get(name, NONZERO_DEFAULTS.get(name, 0.0)) if name != "DPI" else dpi
    coef.flags.writeable = False
    inf = math.inf
    return TireFile(
        name=Path(source).stem, path=source, fittyp=fittyp, coef=coef, fnomin_N=fnomin, unloaded_radius_m=r0,
        vertical_stiffness_Npm=get("VERTICAL_STIFFNESS", None), vertical_damping_Nspm=get("VERTICAL_DAMPING", None),
        longvl_mps=float(get("LONGVL", 16.7)), vxlow_mps=float(get("VXLOW", 1.0)),
        nompres_Pa=nompres, inflpres_Pa=inflpres,
        fzmin_N=float(get("FZMIN", 0.0)), fzmax_N=float(get("FZMAX", inf)),
        kpumin=float(get("KPUMIN", -inf)), kpumax=float(get("KPUMAX", inf)),
        alpmin_rad=float(get("ALPMIN", -inf)), alpmax_rad=float(get("ALPMAX", inf)),
        cammin_rad=float(get("CAMMIN", -inf)), cammax_rad=float(get("CAMMAX", inf)),
        scaling=MappingProxyType({n: float(coef[MF61_INDEX[n]]) for n in SCALING_NAMES}),
        parameters=MappingProxyType({k: v[0] for k, v in numeric.items()}),
    )


def read_tire_file(path: str | Path) -> TireFile:
    """Read and validate a .tir file (MF 6.1 / 6.2). Raises ``VehicleError`` (one line) on bad input."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise VehicleError(f"cannot read tire file: {exc.strerror or exc}", source=str(p)) from None
    return tire_file_from_text(text, str(p))


def shipped_tire_path(name: str) -> Path:
    """Path of a tire file shipped with roadtruth (``harness/tires/<name>``, ``.tir`` optional)."""
    base = Path(__file__).resolve().parents[1] / "tires"
    candidate = base / (name if name.endswith(".tir") else f"{name}.tir")
    if not candidate.is_file():
        shipped = ", ".join(sorted(p.stem for p in base.glob("*.tir")))
        raise VehicleError(f"no shipped tire file {name!r} (shipped: {shipped})", field="tires.file")
    return candidate
