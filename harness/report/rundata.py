"""Reading a run folder back: what the report (and ``compare``) may rely on, and nothing else.

The report never re-simulates and never recomputes metrics: it reads ``run.json``, ``metrics.csv``
and, per scenario, ``truth.csv``, ``estimates.csv``, ``events.json`` and ``scenario.json``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from harness.errors import InputError


class RunFolderError(InputError):
    """A run folder is missing or lacks the files a run writes."""


def read_metrics(run_dir: Path) -> pd.DataFrame:
    """``metrics.csv`` of a run folder, validated (raises RunFolderError naming the file)."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise RunFolderError("not a run folder (does not exist)", source=str(run_dir))
    path = run_dir / "metrics.csv"
    if not path.is_file():
        raise RunFolderError("missing metrics.csv (not a roadtruth run folder?)", source=str(run_dir))
    try:
        m = pd.read_csv(path, keep_default_na=True)
    except (ValueError, pd.errors.ParserError) as e:
        raise RunFolderError(f"unreadable CSV ({e})", source=str(path)) from None
    missing = [c for c in ("scenario", "observer", "state", "rmse", "status") if c not in m.columns]
    if missing:
        raise RunFolderError(f"missing columns {missing}", source=str(path))
    m["state"] = m["state"].fillna("")
    m["status"] = m["status"].fillna("ok").astype(str)
    return m


def read_run_json(run_dir: Path) -> dict[str, Any]:
    path = Path(run_dir) / "run.json"
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise RunFolderError(f"invalid JSON ({e.msg} at line {e.lineno})", source=str(path)) from None
    if not isinstance(data, dict):
        raise RunFolderError("expected a JSON object", source=str(path))
    return data


@dataclass(frozen=True)
class ScenarioFiles:
    """The saved outputs of one scenario of a run (each read lazily, once)."""

    name: str
    folder: Path

    def _csv(self, filename: str) -> pd.DataFrame:
        path = self.folder / filename
        if not path.is_file():
            return pd.DataFrame()
        return pd.read_csv(path)

    def _json(self, filename: str, default: Any) -> Any:
        path = self.folder / filename
        if not path.is_file():
            return default
        try:
            return json.loads(path.read_text())
        except json.JSONDecodeError as e:
            raise RunFolderError(f"invalid JSON ({e.msg})", source=str(path)) from None

    @cached_property
    def truth(self) -> pd.DataFrame:
        return self._csv("truth.csv")

    @cached_property
    def estimates(self) -> pd.DataFrame:
        return self._csv("estimates.csv")

    @cached_property
    def events(self) -> list[dict[str, Any]]:
        raw = self._json("events.json", [])
        return [e for e in raw if isinstance(e, dict) and _finite(e.get("t_s"))]

    @cached_property
    def info(self) -> dict[str, Any]:
        return self._json("scenario.json", {})


def _finite(x: Any) -> bool:
    return isinstance(x, int | float) and math.isfinite(x)


@dataclass(frozen=True)
class RunData:
    """A whole run folder: metrics, run description and per-scenario files."""

    folder: Path
    metrics: pd.DataFrame
    run: dict[str, Any]

    @classmethod
    def load(cls, run_dir: Path) -> RunData:
        run_dir = Path(run_dir)
        return cls(folder=run_dir, metrics=read_metrics(run_dir), run=read_run_json(run_dir))

    @cached_property
    def scenario_names(self) -> list[str]:
        listed = [s["name"] for s in self.run.get("scenarios", []) if isinstance(s, dict) and "name" in s]
        return list(dict.fromkeys([*listed, *self.metrics["scenario"].astype(str).unique().tolist()]))

    @cached_property
    def observer_names(self) -> list[str]:
        return list(dict.fromkeys(self.metrics["observer"].astype(str).tolist()))

    @cached_property
    def states(self) -> list[str]:
        from harness.signals import ESTIMABLE

        present = [s for s in self.metrics["state"].astype(str).unique() if s]
        order = {s: i for i, s in enumerate(ESTIMABLE)}
        return sorted(present, key=lambda s: (order.get(s, len(order)), s))

    @cached_property
    def scored_states(self) -> list[str]:
        """States with at least one scored row (others had no truth/reference to compare with)."""
        m = self.metrics
        ok = m["status"].astype(str).str.startswith("ok") & m["rmse"].notna()
        scored = set(m.loc[ok, "state"])
        return [s for s in self.states if s in scored]

    def run_status(self, scenario: str, observer: str) -> str:
        """The status of one observer run: ``ok`` if any of its states was scored, else the first
        reason (a state without truth is a state-level skip, not a failed run)."""
        m = self.metrics
        rows = m[(m["scenario"] == scenario) & (m["observer"] == observer)]["status"].astype(str).tolist()
        runs = self.run.get("observer_runs", {})
        r = runs.get(scenario, {}).get(observer) if isinstance(runs, dict) else None
        if isinstance(r, dict) and r.get("status"):
            return str(r["status"])
        if not rows:
            return "absent"
        return "ok" if any(s.startswith("ok") for s in rows) else rows[0]

    def scenario(self, name: str) -> ScenarioFiles:
        return ScenarioFiles(name=name, folder=self.folder / name)

    def scenario_entry(self, name: str) -> dict[str, Any]:
        """The scenario's entry in run.json (status, seeds, render results), or {}."""
        for s in self.run.get("scenarios", []):
            if isinstance(s, dict) and s.get("name") == name:
                return s
        return {}


# ---- writing (the pipeline's side of the same format) --------------------------------------------

#: Every float in a run's CSV files is written with this format, so the same seed gives the same bytes.
FLOAT_FORMAT = "%.10g"


def write_csv(frame: pd.DataFrame, path: Path) -> None:
    """A frame as CSV with the fixed float format; NaN is an empty cell."""
    frame.to_csv(path, index=False, float_format=FLOAT_FORMAT, na_rep="", lineterminator="\n")


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, np.generic):
        return _jsonable(x.item())
    if isinstance(x, float) and not math.isfinite(x):
        return None  # JSON has no inf/NaN; None reads as "unbounded"/"unknown"
    if isinstance(x, Path):
        return str(x)
    return x


def write_json(data: Any, path: Path) -> None:
    path.write_text(json.dumps(_jsonable(data), indent=1, default=str) + "\n")


def events_list(events: Any) -> list[dict[str, Any]]:
    """Truth/scenario events ((t_s, label) pairs or dicts) as ``[{"t_s", "label"}]`` sorted by time."""
    out = []
    for e in events or ():
        if isinstance(e, dict):
            t, label = e.get("t_s"), e.get("label", "")
        else:
            t, label = e[0], e[1] if len(e) > 1 else ""
        if _finite(t) or isinstance(t, np.floating):
            out.append({"t_s": float(t), "label": str(label)})
    return sorted(out, key=lambda e: e["t_s"])


def scenario_info(sc: Any, veh: Any, *, max_road_points: int = 1500) -> dict[str, Any]:
    """What the report shows about a scenario: description, friction patches, road centre line."""
    patches = [{"name": p.name, "surface": p.surface, "mu": p.mu, "vertices": np.asarray(p.vertices),
                "t_start_s": p.t_start_s, "t_end_s": p.t_end_s} for p in sc.friction.patches]
    road = None
    if getattr(sc, "road", None) is not None:
        samples = np.asarray(sc.road.samples)
        step = max(1, len(samples) // max_road_points)
        road = {"x_m": np.round(samples[::step, 1], 3), "y_m": np.round(samples[::step, 2], 3),
                "lane_width_m": sc.road.lane_width_m}
    return {
        "name": sc.name, "description": sc.description, "tags": list(sc.tags),
        "standard": getattr(sc, "standard", ""), "vehicle": veh.name, "duration_s": sc.duration_s,
        "initial_speed_mps": sc.initial_speed_mps, "sensors": sc.sensors,
        "friction": {"mu_default": sc.friction.mu_default, "patches": patches},
        "road": road, "lead": sc.lead is not None,
        "outages": [{"sensor": o.sensor, "t_start_s": o.t_start_s, "t_end_s": o.t_end_s} for o in sc.outages],
        "lane_gaps": [list(g) for g in sc.lane_gaps],
    }


def versions() -> dict[str, str | None]:
    """Versions of roadtruth and the packages that change results."""
    import platform
    from importlib.metadata import PackageNotFoundError, version

    out: dict[str, str | None] = {"python": platform.python_version()}
    for pkg in ("roadtruth", "mujoco", "numpy", "scipy", "pandas", "numba", "cvxpy"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = None
    return out


def git_revision() -> str | None:
    """The source tree's git revision (``+dirty`` with local changes), or None outside a checkout."""
    import subprocess

    root = Path(__file__).resolve().parents[2]
    try:
        rev = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True,
                             timeout=5, check=False)
        if rev.returncode != 0:
            return None
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                               capture_output=True, text=True, timeout=5, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    return rev.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
