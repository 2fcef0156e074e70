"""``roadtruth mjcf``: the MuJoCo model of a vehicle (and a scenario's road) as a file for MuJoCo's viewer.

The file is the render model of :func:`roadtruth.harness.truth.car_model.build_mjcf` (the car, and with a scenario
its road surface, lane markings, friction patches and lead car), checked by compiling it with
MuJoCo before it is written, with a keyframe ``start`` at the scenario's initial pose and speed.
In roadtruth the tire forces come from its own loop (``harness/truth/simulate.py``), not from MuJoCo
contacts, so in the viewer the car settles on its body box: the file shows the geometry, joints,
masses and road, not the drive.
"""

from __future__ import annotations

from pathlib import Path

from roadtruth.harness.files.outdir import OutputPathError, check_writable, write_atomic

#: The root element every model roadtruth writes starts with (how ``--out`` recognises its own file).
MODEL_PREFIX = '<mujoco model="roadtruth_'


def model_text(vehicle: str, scenario: str | None = None) -> str:
    """MJCF text of ``vehicle`` (a set name or YAML path) on ``scenario`` (a name, path or None)."""
    import mujoco

    from roadtruth.harness.truth.car_model import build_mjcf
    from roadtruth.harness.truth.scenario import load_scenario
    from roadtruth.harness.truth.vehicle import load_vehicle

    sc = load_scenario(scenario) if scenario else None
    v = load_vehicle(vehicle)
    xml = build_mjcf(v, sc, visuals=True)
    model = mujoco.MjModel.from_xml_string(xml)  # raises on a model MuJoCo would not open
    if sc is not None and sc.road is not None:
        from roadtruth.harness.truth.simulate import _initial_state

        d = mujoco.MjData(model)
        _initial_state(model, d, v, sc)  # the pose and speed a simulation of the scenario starts from
        key = (f'  <keyframe>\n    <key name="start" qpos="{" ".join(repr(float(q)) for q in d.qpos)}" '
               f'qvel="{" ".join(repr(float(q)) for q in d.qvel)}"/>\n  </keyframe>\n')
        xml = xml.replace("</mujoco>", key + "</mujoco>", 1)
        mujoco.MjModel.from_xml_string(xml)
    header = (f"<!-- Written by roadtruth mjcf: vehicle {v.name}"
              f"{', scenario ' + sc.name if sc is not None else ''}. Tire forces are applied by roadtruth's "
              "simulation loop, not by MuJoCo contacts: in MuJoCo's viewer the car rests on its body box. -->\n")
    return xml.replace("<mujoco ", header + "<mujoco ", 1) if xml.startswith("<mujoco ") else header + xml


def write_model(vehicle: str, scenario: str | None, out: Path) -> None:
    """Write :func:`model_text` to ``out``: a new file, or a model this command wrote before."""
    check_writable(out, what="--out", folder=False)
    if out.exists():
        try:
            ours = MODEL_PREFIX in out.read_text(encoding="utf-8", errors="strict")[:2000]
        except (OSError, UnicodeDecodeError):
            ours = False
        if not ours or out.is_dir():
            raise OutputPathError(f"--out {out} exists and is not a model roadtruth wrote; choose a new file")
    write_atomic(out, model_text(vehicle, scenario))
