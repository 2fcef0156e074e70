"""Write the certified LMI designs of the shipped vehicles into ``observers/designs/`` (package data).

    python scripts/ship_designs.py [--vehicles sedan,...] [--check]

``--check`` writes nothing: in a fresh process with an empty user cache it designs every registered
observer on each vehicle and exits 1, naming them, when any design was solved instead of read from
``observers/designs/`` (a stale folder: run the script without ``--check``). Each miss is solved, so
a stale folder makes the check slow; a current one takes seconds.

Every registered observer is designed with its default options on each vehicle in a scratch cache;
the entries (``<key>.json`` + ``<key>.sha256``, the format of :mod:`roadtruth.harness.files.disk_cache`) are copied
into ``observers/designs/``, whose previous entries are replaced (the folder holds nothing else).
A design key hashes the design's inputs and source code, so after editing an observer or design
module, run this again; a stale entry is never used, only missed (the design is then solved at run
time and cached in the user cache folder as before).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--vehicles", default="sedan", help="comma-separated vehicle sets (default sedan)")
    p.add_argument("--check", action="store_true",
                   help="write nothing; exit 1 if a design is not served from the shipped folder")
    a = p.parse_args(argv)
    if a.check:
        return check([v.strip() for v in a.vehicles.split(",") if v.strip()])
    scratch = Path(tempfile.mkdtemp(prefix="roadtruth-designs-"))
    os.environ["ROADTRUTH_CACHE"] = str(scratch)
    os.environ["ROADTRUTH_SHIPPED_DESIGNS"] = "0"
    sys.path.insert(0, str(ROOT))
    from roadtruth.harness.truth.vehicle import load_vehicle
    from roadtruth.observers.lmi import SHIPPED_DESIGNS_DIR
    from roadtruth.observers.registry import available_observers, create

    total = 0.0
    for vname in [v.strip() for v in a.vehicles.split(",") if v.strip()]:
        veh = load_vehicle(vname)
        for name in available_observers():
            t = time.perf_counter()
            try:
                status = create(name, veh).design().status.value
            except Exception as exc:  # noqa: BLE001 - report and go on; nothing is shipped for it
                status = f"error: {type(exc).__name__}: {exc}"[:120]
            dt = time.perf_counter() - t
            total += dt
            print(f"{vname:<14} {name:<38} {dt:7.2f} s  {status}", flush=True)
    entries = sorted((scratch / "designs").glob("*.json")) if (scratch / "designs").is_dir() else []
    shutil.rmtree(SHIPPED_DESIGNS_DIR, ignore_errors=True)
    SHIPPED_DESIGNS_DIR.mkdir(parents=True)
    for entry in entries:
        digest = entry.with_suffix(".sha256")
        if digest.is_file():
            shutil.copy2(entry, SHIPPED_DESIGNS_DIR / entry.name)
            shutil.copy2(digest, SHIPPED_DESIGNS_DIR / digest.name)
    shutil.rmtree(scratch, ignore_errors=True)
    print(f"shipped {len(entries)} designs in {SHIPPED_DESIGNS_DIR} ({total:.0f} s of solving)")
    return 0


def check(vehicles: list[str]) -> int:
    """0 when every design of every registered observer on ``vehicles`` is read from the shipped
    folder in a fresh process (empty user cache), else 1 with the missed designs on stderr."""
    scratch = Path(tempfile.mkdtemp(prefix="roadtruth-designs-check-"))
    os.environ["ROADTRUTH_CACHE"] = str(scratch)
    os.environ["ROADTRUTH_SHIPPED_DESIGNS"] = "1"
    sys.path.insert(0, str(ROOT))
    from roadtruth.harness.truth.vehicle import load_vehicle
    from roadtruth.observers.registry import available_observers, create

    missed: list[str] = []
    served = 0
    try:
        for vname in vehicles:
            veh = load_vehicle(vname)
            for name in available_observers():
                try:
                    design = create(name, veh).design()
                except Exception as exc:  # noqa: BLE001 - a design that raises is not shippable either
                    missed.append(f"{vname} {name}: {type(exc).__name__}: {exc}"[:160])
                    continue
                if design.status.value == "not_applicable":
                    continue
                if design.from_cache:
                    served += 1
                else:
                    missed.append(f"{vname} {name}: solved in {design.design_time_s:.1f} s, not shipped")
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    for m in missed:
        print(m, file=sys.stderr)
    print(f"{served} designs served from the shipped folder, {len(missed)} missed")
    return 1 if missed else 0


if __name__ == "__main__":
    sys.exit(main())
