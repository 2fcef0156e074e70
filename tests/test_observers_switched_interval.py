"""Seed 004 switched UIO interval observer: certification, inclusion, width bound, literal (19) failure."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from roadtruth.harness.errors import InputError
from roadtruth.harness.truth.vehicle import load_vehicle
from roadtruth.observers.registry import create
from roadtruth.observers.switched_interval import SwitchedIntervalIfqir
from roadtruth.observers.switched_interval_design import C, LateralModel, lateral_model, lmi27, mode_boxes

SEDAN = load_vehicle("sedan")
NOISE_FREE = {"input_bound_rad": 0.0, "noise_bound_r_radps": 0.0, "noise_bound_psi_rad": 0.0,
              "noise_bound_y_m": 0.0, "noise_bound_vx_mps": 0.0, "camera_latency_s": 0.0}
H_OBS = 0.01  # the runner's step [s]


pytestmark = pytest.mark.usefixtures("isolated_design_cache")


def _mode_mats(obs: SwitchedIntervalIfqir, i: int) -> dict[str, np.ndarray]:
    d = obs.design()
    return {k: d.gain(f"{k}{i}") for k in ("K", "H", "P", "q", "Am", "Ap", "A0", "D")}


# ---- certification ---------------------------------------------------------------------------------

@pytest.mark.parametrize("vehicle", ["sedan", "yacine2016", "wang2014"])
def test_every_mode_is_certified(vehicle: str) -> None:
    obs = create("switched_interval_ifqir", load_vehicle(vehicle))
    d = obs.design()
    assert d.certified, d.reason
    model = lateral_model(obs.design_request())
    gamma, eps = d.margins["gamma"], d.margins["epsilon"]
    for i in range(3):
        g = _mode_mats(obs, i)
        Q, P, K = np.diag(g["q"]), g["P"], g["K"]
        v_c, v_lo, v_hi = d.gains[f"mode{i}"]
        assert np.all(g["q"] >= 1.0 - 1e-9)                     # alpha I <= Q, Q diagonal by construction
        assert P.min() >= 0.0 and np.abs(P @ model.E(v_c)).max() < 1e-9   # P >= 0, P E = 0 (24)
        assert np.allclose(P, np.eye(4) + g["H"] @ C)
        assert np.all(P[:, 2:] == 0.0)                           # digest §2.8: forced zero columns
        n_minus, n_plus = P @ g["Am"] - K @ C, P @ g["Ap"] - K @ C
        off = ~np.eye(4, dtype=bool)
        assert n_minus[off].min() >= 0.0                         # Metzler N^-
        assert np.linalg.eigvals(n_plus).real.max() < 0.0        # Hurwitz N^+
        assert np.linalg.eigvalsh(lmi27(Q, n_plus, gamma, eps)).max() < 0.0
        unc = 0.1
        for cf in (0.9 * model.cf0, 1.1 * model.cf0):
            for cr in (0.9 * model.cr0, 1.1 * model.cr0):
                for v in (v_lo, v_hi):
                    A = model.A(cf, cr, v, v_kin=v_c)
                    assert np.all(g["Am"] <= A + 1e-12) and np.all(A <= g["Ap"] + 1e-12)
                    N = P @ A - K @ C
                    assert N[off].min() >= 0.0
                    assert np.linalg.eigvalsh(lmi27(Q, N, gamma, eps)).max() < 0.0
        am, ap, _, _ = mode_boxes(model, unc, v_c, v_lo, v_hi)
        np.testing.assert_allclose(am, g["Am"])
    assert d.margins["dwell_time_s"] == 0.0 and d.margins["mu"] == pytest.approx(1.0)


def test_separate_Q_reports_a_dwell_time() -> None:
    d = create("switched_interval_ifqir", SEDAN, common_Q=False).design()
    assert d.certified, d.reason
    mu, eps = d.margins["mu"], d.margins["epsilon"]
    assert d.margins["dwell_time_s"] == pytest.approx(math.log(mu) / eps)
    assert 0.0 <= d.margins["dwell_time_s"] <= d.margins["dwell_time_paper_s"] + 1e-12
    qs = np.array([d.gain(f"q{i}") for i in range(3)])
    assert mu == pytest.approx(max((qs[i] / qs[j]).max() for i in range(3) for j in range(3)))


def test_too_wide_speed_band_is_rejected_not_used() -> None:
    obs = create("switched_interval_ifqir", SEDAN, mode_speeds_mps=(12.5, 20.0, 27.5), mode_halfwidth_mps=5.0)
    d = obs.design()
    assert not d.certified and "not Hurwitz" in d.reason
    with pytest.raises(RuntimeError, match="rejected"):
        obs.run(np.arange(3) * H_OBS, np.zeros((3, 5)))


def test_bad_options_are_input_errors() -> None:
    with pytest.raises(InputError):
        create("switched_interval_ifqir", SEDAN, mode_speeds_mps=(3.0,), mode_halfwidth_mps=4.0)
    with pytest.raises(InputError):
        create("switched_interval_ifqir", SEDAN, stiffness_uncertainty=1.5)
    with pytest.raises(InputError):
        create("switched_interval_ifqir", SEDAN, noise_bound_y_m=-1.0)


# ---- the observer's own model ------------------------------------------------------------------------

def _truth(model: LateralModel, cf: float, cr: float, T: float = 24.0, sub: int = 10,
           camera_every: int = 1, gap: tuple[float, float] | None = None) -> tuple[np.ndarray, ...]:
    """Uncertain linear model, inputs ZOH at the observer rate, RK4 at H_OBS/sub.

    v_x ramps 12 -> 28 -> 14 m/s (modes 0 -> 1 -> 2 -> 1 -> 0), rho(t) varies, delta is a sum of sines.
    Returns t, Y (observer inputs) and X (n, 5) truth [v_y, r, psi_L, y_L, beta].
    """
    n = int(round(T / H_OBS))
    t = np.arange(n) * H_OBS
    vx = np.interp(t, [0, 2, 10, 14, 22, T], [12, 12, 28, 28, 14, 14])
    delta = 0.02 * np.sin(2 * np.pi * 0.4 * t) + 0.012 * np.sin(2 * np.pi * 1.3 * t + 1.0)
    rho = 0.006 * np.sin(2 * np.pi * t / 9.0) + 0.004 * (t > 7.0)
    x = np.array([0.3, 0.0, 0.02, -0.4])
    X = np.zeros((n, 4))
    B = model.B(cf)
    for k in range(n):
        X[k] = x
        A, e = model.A(cf, cr, vx[k]), model.E(vx[k])
        g = B * delta[k] + e * rho[k]
        hh = H_OBS / sub
        for _ in range(sub):
            k1 = A @ x + g
            k2 = A @ (x + 0.5 * hh * k1) + g
            k3 = A @ (x + 0.5 * hh * k2) + g
            k4 = A @ (x + hh * k3) + g
            x = x + hh / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    cam = np.full(n, np.nan)
    cam[::camera_every] = 1.0
    if gap is not None:
        cam[(t >= gap[0]) & (t < gap[1])] = np.nan
    Y = np.column_stack([X[:, 1], delta, vx, X[:, 2] * cam, X[:, 3] * cam])
    Xb = np.column_stack([X, np.arctan2(X[:, 0], vx)])
    return t, Y, Xb


STIFFNESS_CASES = [(1.0, 1.0), (0.9, 0.9), (1.1, 0.9), (0.9, 1.1), (1.1, 1.1), (0.95, 1.07)]


@pytest.mark.parametrize(("kf", "kr"), STIFFNESS_CASES)
def test_inclusion_on_own_model(kf: float, kr: float) -> None:
    obs = create("switched_interval_ifqir", SEDAN, **NOISE_FREE)
    model = lateral_model(obs.design_request())
    t, Y, X = _truth(model, kf * model.cf0, kr * model.cr0)
    tr = obs.run(t, Y, x0={"vy_mps": 0.1, "psi_lane_rad": 0.0, "y_lane_m": 0.0})
    assert tr.lo is not None and tr.hi is not None
    assert np.all(tr.lo <= X) and np.all(X <= tr.hi), "inclusion lost"
    assert obs.switches >= 4 and obs.dwell_violations == 0 and obs.out_of_band_steps == 0
    assert obs.inconsistent_steps == 0
    w = tr.hi - tr.lo
    assert w[-1, 0] < 0.6 and np.all(w[-200:, 2:4] < 1e-12)  # v_y tightens; lane = camera exactly


def test_inclusion_with_camera_at_20hz_and_a_gap() -> None:
    obs = create("switched_interval_ifqir", SEDAN, **NOISE_FREE)
    model = lateral_model(obs.design_request())
    t, Y, X = _truth(model, 1.1 * model.cf0, 0.9 * model.cr0, T=12.0, camera_every=5, gap=(5.0, 6.5))
    tr = obs.run(t, Y)
    assert np.all(tr.lo <= X) and np.all(X <= tr.hi)
    w = tr.hi - tr.lo
    in_gap = (t > 6.0) & (t < 6.5)
    assert w[in_gap, 3].max() > 10 * w[(t > 8) & (t < 9), 3].max()  # open loop widens, camera recovers
    # the (v_y, r) bounds do not use the camera: identical with and without it
    tr2 = create("switched_interval_ifqir", SEDAN, **NOISE_FREE).run(t, np.column_stack([Y[:, :3], Y[:, 3:] * np.nan]))
    np.testing.assert_array_equal(tr2.lo[:, :2], tr.lo[:, :2])


def test_width_obeys_the_iss_bound() -> None:
    """V = w^T Q w of the (v_y, r) rows of z satisfies V+ <= e^{-eps h} V + gamma/eps (1 - e^{-eps h}) |Delta|^2,
    hence the asymptotic bound sqrt(gamma/(alpha eps)) Delta_max (29)."""
    obs = create("switched_interval_ifqir", SEDAN, **NOISE_FREE)
    model = lateral_model(obs.design_request())
    d = obs.design()
    gamma, eps, alpha = d.margins["gamma"], d.margins["epsilon"], d.margins["alpha"]
    t, Y, X = _truth(model, 0.9 * model.cf0, 1.1 * model.cr0, T=16.0)
    obs.reset(0.0)
    q = d.gain("q0")[:2]
    decay = math.exp(-eps * H_OBS)
    v_prev, dmax, checked = None, 0.0, 0
    for k in range(len(t)):
        lo_prev, hi_prev = obs._bounds()
        mode_prev = obs.mode()
        obs.step(float(t[k]), Y[k])
        zl, zh = obs.z_bounds()
        w = np.array(zh) - np.array(zl)
        assert np.all(w >= -1e-12)
        v_now = float(w @ (q * w))
        if v_prev is not None and obs.mode() == mode_prev:
            g = _mode_mats(obs, obs.mode())
            PD, Pb = (g["P"] @ g["D"])[:2, :2], (g["P"] @ d.gain("b"))[:2]
            xb = np.array([max(abs(lo_prev[0]), abs(hi_prev[0])), max(abs(lo_prev[1]), abs(hi_prev[1]))])
            fw = np.array(obs.forcing_width())
            assert np.all(fw >= 2 * (PD @ xb + Pb * abs(Y[k, 1])) - 1e-12)  # contains the uncertainty term
            delta_norm = float(np.linalg.norm(fw))
            dmax = max(dmax, delta_norm)
            assert v_now <= decay * v_prev + gamma / eps * (1 - decay) * delta_norm**2 + 1e-12
            checked += 1
        v_prev = v_now
    assert checked > len(t) - 10
    assert math.sqrt(v_prev / alpha) <= math.sqrt(gamma / (alpha * eps)) * dmax


# ---- literal eq. (19) ----------------------------------------------------------------------------------

def _literal_run(obs: SwitchedIntervalIfqir, vx: float, T: float = 6.0, dt: float = 1e-3) -> tuple[np.ndarray, ...]:
    """Eq. (19) as printed, mode 1, frozen v_x, nominal stiffness, exact y and y', zeta = 0 (Euler, dt)."""
    model = lateral_model(obs.design_request())
    g = _mode_mats(obs, 1)
    P, K, H = g["P"], g["K"], g["H"]
    n_plus, n_minus, n0 = P @ g["Ap"] - K @ C, P @ g["Am"] - K @ C, P @ g["A0"] - K @ C
    A, B, E = model.A(model.cf0, model.cr0, vx), model.B(model.cf0), model.E(vx)
    b = 0.1 * B
    Pp, Pm = np.maximum(P, 0), np.maximum(P, 0) - P
    n = int(T / dt)
    x = np.array([0.2, 0.0, 0.01, 0.1])
    xl, xh = x - 0.3, x + 0.3
    ts, Xs, Lo, Hi = [], [], [], []
    for k in range(n):
        tk = k * dt
        u = 0.03 * np.sin(2 * np.pi * 0.5 * tk)
        rho = 0.005 * np.sin(2 * np.pi * tk / 5.0)
        xdot = A @ x + B * u + E * rho
        y, ydot = C @ x, C @ xdot
        dp, dm = b * abs(u), -b * abs(u)            # (18) with zeta = 0
        common = K @ y + P @ B * u - H @ ydot
        fh = n_plus @ xh + common + (n_plus - n0) @ (np.abs(xh) - xh) + Pp @ dp - Pm @ dm
        fl = n_minus @ xl + common - (n_minus - n0) @ (np.abs(xl) + xl) + Pp @ dm - Pm @ dp
        ts.append(tk)
        Xs.append(x.copy())
        Lo.append(xl.copy())
        Hi.append(xh.copy())
        x, xl, xh = x + dt * xdot, xl + dt * fl, xh + dt * fh
    return np.array(ts), np.array(Xs), np.array(Lo), np.array(Hi)


def test_literal_eq19_loses_inclusion_where_the_sound_form_keeps_it() -> None:
    obs = create("switched_interval_ifqir", SEDAN, **NOISE_FREE)
    t, X, lo, hi = _literal_run(obs, 20.0)
    viol = np.maximum(lo - X, X - hi).max(axis=1)
    assert viol.max() > 5e-3, "the printed correction terms should push a bound across the truth"
    assert (lo[:, 0] - X[:, 0]).max() > 5e-3   # the v_y lower bound rises above the truth (digest §5.8)
    # the sound form on the same signals (constant v_x, nominal stiffness, rho(t)) keeps inclusion
    sound = create("switched_interval_ifqir", SEDAN, **NOISE_FREE)
    idx = np.arange(0, len(t), 10)
    Y = np.column_stack([X[idx, 1], 0.03 * np.sin(2 * np.pi * 0.5 * t[idx]), np.full(len(idx), 20.0),
                         X[idx, 2], X[idx, 3]])
    tr = sound.run(t[idx], Y, x0={"vy_mps": 0.2})
    assert np.all(tr.lo[:, :4] <= X[idx]) and np.all(X[idx] <= tr.hi[:, :4])


# ---- robustness, determinism, MuJoCo ------------------------------------------------------------------

def test_nan_inputs_and_determinism() -> None:
    rng = np.random.default_rng(3)
    obs = create("switched_interval_ifqir", SEDAN)
    model = lateral_model(obs.design_request())
    t, Y, _ = _truth(model, model.cf0, model.cr0, T=6.0)
    Y = Y.copy()
    Y[:20] = np.nan
    Y[rng.random(Y.shape) < 0.3] = np.nan
    Y[300:400] = np.nan
    a, b = obs.run(t, Y), create("switched_interval_ifqir", SEDAN).run(t, Y)
    assert a.x.tobytes() == b.x.tobytes() and a.lo.tobytes() == b.lo.tobytes()
    assert np.all(np.isfinite(a.x)) and np.all(np.isfinite(a.lo)) and np.all(np.isfinite(a.hi))
    assert np.all(a.lo <= a.x) and np.all(a.x <= a.hi)
    allnan = obs.run(t[:30], np.full((30, 5), np.nan))
    assert np.all(np.isfinite(allnan.x))


def test_mujoco_curvy_road_runs_with_finite_metrics() -> None:
    from roadtruth.harness.evaluation.estimate import run_observers
    from roadtruth.harness.sensors import load_sensor_config
    from roadtruth.harness.sensors.suite import emulate
    from roadtruth.harness.truth.scenario import load_scenario
    from roadtruth.harness.truth.simulate import simulate

    sc = load_scenario("curvy_road")
    sc = replace(sc, duration_s=3.0)
    truth = simulate(sc)
    meas = emulate(truth.frame, SEDAN, load_sensor_config(sc.sensors, sc.sensor_overrides, None), 1,
                   outages=sc.outages, lane_gaps=sc.lane_gaps)
    est, runs = run_observers(meas.frame, SEDAN, ["switched_interval_ifqir"])
    assert runs["switched_interval_ifqir"].status == "ok", runs["switched_interval_ifqir"]
    sub = est[est["state"] == "vy_mps"]
    assert len(sub) > 200 and np.all(np.isfinite(sub[["value", "lo", "hi"]].to_numpy()))
    tt = truth.frame["t_s"].to_numpy()
    vy = np.interp(sub["t_s"].to_numpy(), tt, truth.frame["vy_mps"].to_numpy())
    late = sub["t_s"].to_numpy() > 1.0
    inside = (sub["lo"].to_numpy() <= vy) & (vy <= sub["hi"].to_numpy())
    assert inside[late].mean() > 0.5     # linear-tire regime (ay < 3.3 m/s^2): mostly covered


def test_dwell_time_is_checked_by_the_mode_logic() -> None:
    obs = create("switched_interval_ifqir", SEDAN, common_Q=False, **NOISE_FREE)
    tau = obs.design().margins["dwell_time_s"]
    assert tau > 0.0
    model = lateral_model(obs.design_request())
    t, Y, _ = _truth(model, model.cf0, model.cr0, T=24.0)
    Y = Y.copy()
    Y[1200:1300, 2] = np.where(np.arange(100) % 60 < 30, 23.0, 16.5)   # speed chatter across two bands
    obs.reset(0.0)
    modes = []
    for k in range(len(t)):
        obs.step(float(t[k]), Y[k])
        modes.append(obs.mode())
    modes_a = np.array(modes)
    switch_t = t[1:][np.diff(modes_a) != 0]
    assert obs.switches == len(switch_t) >= 5
    assert obs.dwell_violations == int(np.sum(np.diff(switch_t) < tau)) >= 1


# ---- one compiled kernel shared by step() and run() -----------------------------------------------------

def _switching_inputs(n: int = 4000, h: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """(t, Y) of ``(r, delta, v_x, psi_L, y_L)``: a speed sweep through every band and out of them, speed
    chatter across two bands, a yaw-rate jump the model cannot follow, random dropouts, a 20 Hz camera
    with a marking gap, a total outage, a repeated and an irregular time stamp."""
    t = np.arange(n) * h
    vx = 20.0 + 13.0 * np.sin(2 * np.pi * t / 15.0)
    vx[1200:1300] = np.where(np.arange(100) % 60 < 30, 23.0, 16.5)
    delta = 0.03 * np.sin(2 * np.pi * 0.5 * t)
    r = vx * delta / 2.8
    r[3300:3320] += 0.4
    Y = np.column_stack([r, delta, vx, np.cumsum(r) * h * 0.1, 0.3 * np.sin(t)])
    gen = np.random.default_rng(3)
    Y = Y + gen.normal(0.0, 1e-3, Y.shape)
    Y[gen.random(Y.shape) < 0.1] = np.nan
    Y[:3] = np.nan
    Y[:, 3:][np.arange(n) % 5 != 0] = np.nan
    Y[2000:2100, 3:] = np.nan
    Y[2500:2520] = np.nan
    t = t.copy()
    t[1500] = t[1499]
    t[3000:] += 0.0041
    return t, Y


def _stepped(obs: SwitchedIntervalIfqir, t: np.ndarray, Y: np.ndarray,
             x0: dict[str, float] | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    obs.reset(float(t[0]), x0)
    outs = [obs.step(float(t[i]), Y[i]) for i in range(len(t))]
    return tuple(np.array([getattr(o, f) for o in outs]) for f in ("x", "lo", "hi"))  # type: ignore[return-value]


@pytest.mark.parametrize("opts", [{}, {"common_Q": False, "noise_bound_r_radps": 0.001}], ids=["common_Q", "per_mode_Q"])
def test_run_is_one_compiled_call_equal_to_stepping_bit_for_bit(opts: dict, monkeypatch: pytest.MonkeyPatch) -> None:
    import roadtruth.observers.switched_interval as module

    t, Y = _switching_inputs()
    calls: list[int] = []
    kernel = module.switched_run

    def counted(tt: np.ndarray, *args: object) -> None:
        calls.append(len(tt))
        kernel(tt, *args)

    monkeypatch.setattr(module, "switched_run", counted)
    obs = create("switched_interval_ifqir", SEDAN, **opts)
    got = obs.run(t, Y)
    assert calls == [len(t)]   # the whole log in one compiled call
    monkeypatch.undo()
    ref = create("switched_interval_ifqir", SEDAN, **opts)
    x, lo, hi = _stepped(ref, t, Y)
    for a, b in ((got.x, x), (got.lo, lo), (got.hi, hi)):
        assert a.tobytes() == b.tobytes(), np.abs(a - b).max(axis=0)
    assert np.all(np.isfinite(x)) and np.all(lo <= hi)
    # every branch ran: switches, out-of-band speeds, an inconsistent gyro step (per-mode Q: dwell violations)
    assert ref.switches >= 10 and ref.out_of_band_steps > 0
    assert (ref.inconsistent_steps > 0 and ref.dwell_violations > 0) if opts else ref.dwell_violations == 0
    # run() leaves the observer where stepping leaves it: counters, mode, z bounds and the next step agree
    assert (obs.switches, obs.dwell_violations, obs.out_of_band_steps, obs.inconsistent_steps, obs.mode()) == \
        (ref.switches, ref.dwell_violations, ref.out_of_band_steps, ref.inconsistent_steps, ref.mode())
    assert obs.z_bounds() == ref.z_bounds() and obs.forcing_width() == ref.forcing_width()
    a, b = obs.step(float(t[-1]) + 0.01, Y[-5]), ref.step(float(t[-1]) + 0.01, Y[-5])
    assert a.x.tobytes() == b.x.tobytes() and a.lo.tobytes() == b.lo.tobytes()
    # a run split in two (a host resuming) gives the same bits as one call
    split = create("switched_interval_ifqir", SEDAN, **opts)
    first = split.run(t[:1700], Y[:1700]).hi
    rest = np.array([split.step(float(t[i]), Y[i]).hi for i in range(1700, len(t))])
    assert np.vstack([first, rest]).tobytes() == got.hi.tobytes()


def test_run_from_initial_state_equals_stepping() -> None:
    t, Y = _switching_inputs(2000)
    x0 = {"vy_mps": 0.4, "yaw_rate_radps": -0.1}
    got = create("switched_interval_ifqir", SEDAN).run(t, Y, x0)
    x, lo, hi = _stepped(create("switched_interval_ifqir", SEDAN), t, Y, x0)
    assert lo[1, 0] == 0.4 - 1.0 and hi[1, 1] == -0.1 + 0.5   # before the first sample: the initial box around x0
    assert got.x.tobytes() == x.tobytes() and got.lo.tobytes() == lo.tobytes() and got.hi.tobytes() == hi.tobytes()
