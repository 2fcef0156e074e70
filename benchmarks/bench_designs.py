"""Certification results of every LMI observer, per vehicle, including the printed gains.

Run: ``python benchmarks/bench_designs.py``. For each vehicle (the default ``sedan``; ``wang2014``,
the 800 kg car of Y. Wang's 2014 dissertation, for which its printed gains were designed; ``yacine2016``,
the car of Yacine et al. 2015; ``carla_bessafa``, the CARLA car of Bessafa 2024) and each registered observer with an LMI design it calls
``observer.design()`` (the same call ``roadtruth run`` makes, served from the design cache when
warm) and prints the status, the certified figure of merit and the margins the docs quote.
Extra rows: Wang's interval observer with the dissertation's own stiffness box (C_f 60-90 kN/rad,
C_r 35-65 kN/rad), the Takagi–Sugeno observer on the paper's speed range (0.2-17 m/s), the unknown-input observer at δ2 = 1 and on the textbook car of Nguyen's chapter
(m 1573 kg, I_z 2873 kg m², l_f 1.10 m, l_r 1.58 m, C_f = C_r = 160 kN/rad). Deterministic: no
random numbers are drawn. Figures quoted in docs/OBSERVERS.md and README.md come from this script.
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any

os.environ.setdefault("MUJOCO_GL", "egl")

VEHICLES = ("sedan", "wang2014", "yacine2016", "carla_bessafa")

#: The margins worth printing per observer family (name prefix -> margin keys), in order.
SHOWN = {
    "lpv_wang_hinf": ("gamma", "gamma_optimal", "gamma_open_loop", "bounded_real_max_eig_vertices",
                      "closed_loop_max_real_eig"),
    "lpv_wang": ("decay_rate_radps", "max_decay_rate_radps", "open_loop_decay_rate_radps"),
    "interval_wang": ("gamma", "gamma_optimal", "gamma_without_metzler", "metzler_vertices",
                      "metzler_min_offdiag", "closed_loop_max_real_eig"),
    "uio_nguyen": ("lambda", "lambda_delta", "slowest_pole_real", "fastest_pole_abs", "unmovable_mode_max_real"),
    "ts_yacine": ("slowest_vertex_real_eig", "fastest_vertex_abs_eig", "p_cond"),
    "switched_interval": ("gamma", "iss_gain", "dwell_time_s", "width_matrix_max_real_eig"),
    "hgo_radar": ("theta", "theta0", "kappa_per_s", "kappa_vertex_per_s", "k_f"),
}


def textbook_car() -> Any:
    """The car assumed for Nguyen's vehicle example: the sedan with the textbook mass, inertia, geometry
    and 160 kN/rad on both axles (the Magic Formula ``By`` rescaled so that ``By Cy F_z`` equals it)."""
    from roadtruth.harness.truth.vehicle import load_vehicle

    sedan = load_vehicle("sedan")
    m, lf, lr, g = 1573.0, 1.10, 1.58, 9.81
    fzf, fzr = m * g * lr / (lf + lr), m * g * lf / (lf + lr)
    t = sedan.tires
    tires = dataclasses.replace(t, front=dataclasses.replace(t.front, By=160e3 / (t.front.Cy * fzf)),
                                rear=dataclasses.replace(t.rear, By=160e3 / (t.rear.Cy * fzr)))
    return sedan.with_overrides(name="textbook", mass_kg=m, yaw_inertia_kgm2=2873.0, lf_m=lf, lr_m=lr,
                                tires=tires)


def shown_margins(observer: str, margins: dict[str, float]) -> str:
    widths = [v for k, v in margins.items() if k.endswith("width_matrix_max_real_eig")]
    if widths:  # switched interval observer: the width condition, worst mode
        margins = {**margins, "width_matrix_max_real_eig": max(widths)}
    for prefix, keys in SHOWN.items():
        if observer.startswith(prefix):
            return ", ".join(f"{k} {margins[k]:.4g}" for k in keys if k in margins)
    return ""


def scheduled_gains(design: Any) -> str:
    """``L0`` and the largest entry of ``L1``, ``L2`` of a gain-scheduled design ``L0 + θ1 L1 + θ2 L2``."""
    if not {"L0", "L1", "L2"} <= set(design.gains):
        return ""
    l0 = ", ".join(f"{x:.4g}" for x in design.gain("L0").ravel())
    return (f"; L0 = ({l0}), max|L1| {abs(design.gain('L1')).max():.2g}, "
            f"max|L2| {abs(design.gain('L2')).max():.2g}")


def line(vehicle: str, observer: str, design: Any, note: str = "") -> str:
    gamma = "" if design.gamma is None else f"{design.gamma:.4g}"
    head = f"{vehicle:11s} {observer + note:44s} {design.status.value:10s} {gamma:>9s}  "
    return (head + shown_margins(observer, design.margins) + scheduled_gains(design)
            + ("" if design.certified else f"  [{design.reason[:110]}]"))


def main() -> None:
    import argparse

    from roadtruth.harness.truth.vehicle import load_vehicle
    from roadtruth.observers.registry import available_observers, create

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--vehicles", default=",".join(VEHICLES), help="comma-separated vehicles of the main table")
    p.add_argument("--no-extra", action="store_true", help="only the main table (no option variants)")
    a = p.parse_args()
    print(f"{'vehicle':11s} {'observer':44s} {'status':10s} {'gamma':>9s}  margins")
    for vname in a.vehicles.split(","):
        veh = load_vehicle(vname)
        for name in available_observers():
            design = create(name, veh).design()
            if design.status.value == "not_applicable":
                continue
            print(line(vname, name, design))
    if a.no_extra:
        return
    wang = load_vehicle("wang2014")
    box = {"cf_range_Npr": (60e3, 90e3), "cr_range_Npr": (35e3, 65e3)}
    print(line("wang2014", "interval_wang", create("interval_wang", wang, **box).design(), " (dissertation box)"))
    print(line("wang2014", "interval_wang_printed", create("interval_wang_printed", wang, **box).design(),
               " (dissertation box)"))
    for vname in VEHICLES:
        print(line(vname, "uio_nguyen", create("uio_nguyen", load_vehicle(vname), delta2=1.0).design(),
                   " (delta2 = 1)"))
    print(line("textbook", "uio_nguyen", create("uio_nguyen", textbook_car()).design()))
    sedan = load_vehicle("sedan")
    for unc in (0.15, 0.2, 0.3):
        print(line("sedan", "switched_interval_ifqir",
                   create("switched_interval_ifqir", sedan, stiffness_uncertainty=unc).design(), f" (±{unc:.0%} box)"))
    for modes in ((12.5, 20.0, 27.5),):
        print(line("sedan", "switched_interval_ifqir",
                   create("switched_interval_ifqir", sedan, mode_speeds_mps=modes, mode_halfwidth_mps=5.0).design(),
                   " (modes 12.5/20/27.5, half-width 5)"))
    yacine = load_vehicle("yacine2016")
    print(line("yacine2016", "ts_yacine", create("ts_yacine", yacine, vx_range_mps=(0.2, 17.0)).design(),
               " (paper speed range 0.2-17 m/s)"))


if __name__ == "__main__":
    main()
