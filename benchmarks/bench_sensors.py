"""Cost of emulating the sensor suite: a 60 s scenario at 1 kHz with every sensor on.

Run: ``.venv/bin/python benchmarks/bench_sensors.py``. Prints the median wall time of
``emulate`` per preset (with and without a stack of faults) and per sensor. Target: well under 1 s.
"""

from __future__ import annotations

import statistics
import time

from roadtruth.harness.sensors import SENSORS, emulate, load_sensor_config
from roadtruth.harness.sensors.synthetic import steady_motion_truth
from roadtruth.harness.truth.vehicle import load_vehicle

FAULTS = ("gnss:burst(p_enter=0.01,mean_len=10),imu:spike(p=0.001,magnitude=2),"
          "imu.ay_mps2:bias_step(size=0.3,t_start_s=20),camera:dropout=0.05,radar:delay(extra_s=0.02,jitter_s=0.03),"
          "steering:freeze(t_start_s=30,t_end_s=31),wheel_speed:dropout=0.01,ogs:outage(t_start_s=10,t_end_s=12)")


def timed(fn, repeats: int = 7) -> float:
    fn()  # warm-up (imports, caches)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    vehicle = load_vehicle("sedan")
    truth = steady_motion_truth(60.0, dt_s=0.001, vx_mps=25.0, yaw_rate_radps=0.1, roll_rad=0.02,
                                range_m=50.0, range_rate_mps=-0.2)
    print(f"truth: {len(truth)} rows x {truth.shape[1]} columns (60 s at 1 kHz)")
    everything_on = {name: {"enabled": True} for name in SENSORS}
    for preset in ("ideal", "automotive", "consumer"):
        for label, faults in (("no faults", None), ("8 faults", FAULTS)):
            cfg = load_sensor_config(preset, overrides=everything_on, faults=faults)
            t = timed(lambda cfg=cfg: emulate(truth, vehicle, cfg, seed=1))
            print(f"{preset:>10} {label:>9}: {t * 1e3:7.1f} ms  ({len(cfg.enabled())} sensors)")
    cfg = load_sensor_config("automotive", overrides=everything_on)
    for name in SENSORS:
        only = load_sensor_config("automotive", overrides={n: {"enabled": n == name} for n in SENSORS})
        t = timed(lambda only=only: emulate(truth, vehicle, only, seed=1))
        print(f"   {name:>12} alone (automotive): {t * 1e3:6.1f} ms")


if __name__ == "__main__":
    main()
