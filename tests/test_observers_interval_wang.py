"""LPV interval observer of seed 001 (Wang 2014, ch. 4): inclusion on its own uncertain model,
the L2 width bound of Theorem 5, the seed's gamma*, the printed gain's failed certification."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from roadtruth.harness.errors import InputError
from roadtruth.harness.truth.vehicle import load_vehicle
from roadtruth.observers.bicycle import expm2_zoh, slip_model_terms
from roadtruth.observers.interval_wang_design import closed_loop, vertex_pairs
from roadtruth.observers.lmi import DesignStatus, metzler_margin
from roadtruth.observers.registry import create

SEED_BOX = {"cf_range_Npr": (60_000.0, 90_000.0), "cr_range_Npr": (35_000.0, 65_000.0)}  # (4.45)
H = 0.01  # the runner's step [s]


pytestmark = pytest.mark.usefixtures("isolated_design_cache")


def _own_model(vehicle, cf_fn, cr_fn, T: float = 6.0, sub: int = 20):
    """Linear bicycle (3.13)-(3.15) with time-varying stiffness, RK4 at h/sub, several cases at once.

    ``cf_fn, cr_fn(t) -> (ncases,)`` [N/rad]. Steering and a_x are piecewise constant and equal on
    ``(t_{k-1}, t_k]`` to their sample at ``t_k`` (what the observer holds); v_x follows a_x from
    8 m/s (inside the design range). Returns t (n,), inputs Y (ncases, n, 4), alpha (ncases, n, 2),
    v_y (ncases, n) and the largest intersample changes of r and of (l_f + l_r) r / v_x.
    """
    m, iz, lf, lr = vehicle.mass_kg, vehicle.yaw_inertia_kgm2, vehicle.lf_m, vehicle.lr_m
    t = np.arange(0.0, T, H)
    ax = 4.0 * np.exp(-t) + 3.0 * np.sin(1.3 * t)
    steer = 0.03 * np.sin(2 * np.pi * 0.6 * t) + 0.01 * np.sin(2 * np.pi * 1.7 * t)
    nc = len(cf_fn(0.0))
    s = np.tile([0.3, 0.05, 8.0], (nc, 1))
    states, nu_r, nu_y = [s], 0.0, 0.0
    hs = H / sub

    def f(tt: float, x: np.ndarray, d: float, a: float) -> np.ndarray:
        vy, r, vx = x.T
        af, ar = d - (vy + lf * r) / vx, -(vy - lr * r) / vx
        cf, cr = cf_fn(tt), cr_fn(tt)
        return np.column_stack([(cf * af + cr * ar) / m - vx * r, (lf * cf * af - lr * cr * ar) / iz,
                                np.full(nc, a)])

    for k in range(1, len(t)):
        d, a, inner = steer[k], ax[k], []
        for j in range(sub):
            tt = t[k - 1] + j * hs
            k1 = f(tt, s, d, a)
            k2 = f(tt + hs / 2, s + hs / 2 * k1, d, a)
            k3 = f(tt + hs / 2, s + hs / 2 * k2, d, a)
            k4 = f(tt + hs, s + hs * k3, d, a)
            s = s + hs / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            inner.append(s)
        inner_arr = np.array(inner)
        nu_r = max(nu_r, float(np.abs(inner_arr[:, :, 1] - s[:, 1]).max()))
        nu_y = max(nu_y, float((lf + lr) * np.abs(inner_arr[:, :, 1] / inner_arr[:, :, 2] - s[:, 1] / s[:, 2]).max()))
        states.append(s)
    S = np.array(states).transpose(1, 0, 2)  # (nc, n, 3)
    vy, r, vx = S[..., 0], S[..., 1], S[..., 2]
    alpha = np.stack([steer - (vy + lf * r) / vx, -(vy - lr * r) / vx], axis=-1)
    Y = np.stack([np.broadcast_to(steer, vy.shape), r, vx, np.broadcast_to(ax, vy.shape)], axis=-1)
    return t, Y, alpha, vy, nu_r, nu_y


def _stiffness_cases(box):
    """Four vertices, a lane switch as in the seed's Fig. 4.3, and a smooth variation inside the box."""
    (flo, fhi), (rlo, rhi) = box
    corners = [(fc, rc) for fc in (flo, fhi) for rc in (rlo, rhi)]

    def cf(t: float) -> np.ndarray:
        lane = fhi if (t < 1.5 or t > 4.5) else flo
        smooth = 0.5 * (flo + fhi) + 0.5 * (fhi - flo) * np.sin(3.1 * t)
        return np.array([c[0] for c in corners] + [lane, smooth])

    def cr(t: float) -> np.ndarray:
        lane = rhi if (t < 1.5 or t > 4.5) else rlo
        smooth = 0.5 * (rlo + rhi) + 0.5 * (rhi - rlo) * np.cos(2.3 * t)
        return np.array([c[1] for c in corners] + [lane, smooth])

    return cf, cr


@pytest.mark.parametrize(("vehicle_name", "options"), [("sedan", {}), ("wang2014", SEED_BOX)])
def test_inclusion_on_own_uncertain_model(vehicle_name: str, options: dict) -> None:
    """Theorem 4: for any stiffness in the box (vertices, switching, varying) and time-varying
    (v_x, a_x), a correct initial bracket gives lo <= alpha <= hi at every step. The sampled-data
    error of held r, v_x is covered by the observer's input-error margins, set here to the measured
    intersample variation; without them the inclusion is lost by O(h) at the vertices."""
    vehicle = load_vehicle(vehicle_name)
    probe = create("interval_wang", vehicle, **options)
    t, Y, alpha, vy, nu_r, nu_y = _own_model(vehicle, *_stiffness_cases((probe.cf_range, probe.cr_range)))
    margins = {"yaw_rate_error_bound_radps": nu_r * 1.001, "y_error_bound_rad": nu_y * 1.001}
    obs = create("interval_wang", vehicle, **options, **margins)
    assert obs.design().certified, obs.design().reason
    bare = create("interval_wang", vehicle, **options)
    worst_bare = 0.0
    for c in range(len(Y)):
        tr = obs.run(t, Y[c])
        lo, hi = tr.lo[:, :2], tr.hi[:, :2]
        assert np.all(lo <= alpha[c]) and np.all(alpha[c] <= hi), f"case {c}"
        # v_y bounds by interval arithmetic through the CONTRACT (atan) slip definitions; the test
        # model uses the linearised ones (3.14), which differ by v_x x^3/3 ~ 1e-3 m/s here.
        assert np.all(tr.lo[:, 3] - 2e-3 <= vy[c]) and np.all(vy[c] <= tr.hi[:, 3] + 2e-3), f"case {c}"
        width = hi - lo
        assert np.all(width[0] == pytest.approx(2 * 0.2))
        assert np.all(width[-200:].max(axis=0) < 0.05 * width[0])  # converged from the 0.4 rad bracket
        b = bare.run(t, Y[c])
        worst_bare = max(worst_bare, float(np.max(np.maximum(b.lo[:, :2] - alpha[c], alpha[c] - b.hi[:, :2]))))
    if vehicle_name == "sedan":
        assert worst_bare > 1e-5  # the margins are needed: the bounds are tight at the vertices


def test_width_obeys_the_l2_bound_of_theorem_5() -> None:
    """The width obeys width' = A_L(eta, xi0) width + d with d = (w+ + margins) - (w- - margins) >= 0;
    the bounded-real LMI with V = width' P width gives, over every step,
    V(t+h) - V(t) <= int (gamma |d|^2 - |width|^2 / gamma) dt, and the integrated L2 bound."""
    vehicle = load_vehicle("sedan")
    probe = create("interval_wang", vehicle)
    t, Y, alpha, _, _, _ = _own_model(vehicle, *_stiffness_cases((probe.cf_range, probe.cr_range)), T=4.0)
    obs = create("interval_wang", vehicle, alpha_bound_rad=0.02)
    d = obs.design()
    gamma, P = float(d.gamma), np.array(d.P)
    assert np.allclose(P, np.diag(np.diag(P)))  # Theorem 2: diagonal Lyapunov matrix
    L, A1 = obs.gains(), slip_model_terms(vehicle)[0].reshape(-1)
    for c in (0, 3, 4):
        tr = obs.run(t, Y[c], x0={"alpha_f_rad": float(alpha[c, 0, 0]), "alpha_r_rad": float(alpha[c, 0, 1])})
        W = tr.hi[:, :2] - tr.lo[:, :2]
        lhs = rhs = 0.0
        for k in range(len(t) - 1):
            e1 = 1.0 / Y[c, k + 1, 2]
            e2 = Y[c, k + 1, 3] * e1
            la, lb = L[0] + e1 * L[2] + e2 * L[4], L[1] + e1 * L[3] + e2 * L[5]
            AL = (e1 * A1[0] - e2 - la, e1 * A1[1] + la, e1 * A1[2] - lb, e1 * A1[3] - e2 + lb)
            E, G = (np.array(m).reshape(2, 2) for m in expm2_zoh(*AL, H))
            dk = np.linalg.solve(G, W[k + 1] - E @ W[k])
            assert np.all(dk >= -1e-9)
            Em, Gm = (np.array(m).reshape(2, 2) for m in expm2_zoh(*AL, H / 2))
            wm = Em @ W[k] + Gm @ dk
            w2 = H / 6 * (W[k] @ W[k] + 4 * wm @ wm + W[k + 1] @ W[k + 1])  # Simpson, exact up to O(h^5)
            dV = W[k + 1] @ P @ W[k + 1] - W[k] @ P @ W[k]
            assert dV <= gamma * H * dk @ dk - w2 / gamma + 1e-10
            lhs += w2
            rhs += gamma**2 * H * dk @ dk
        assert lhs <= rhs + gamma * W[0] @ P @ W[0]
        assert W[-100:].max() < W[0].max()


def test_fresh_design_reproduces_the_seed_gamma() -> None:
    """Digest O5 / 8.5: on the seed car and box, Theorem 5 gives gamma* = 0.3804; the gains make
    A(eta, xi) - L(eta) C Metzler at all 16 vertex pairs (so l1 >= 0 >= l2 at every vertex)."""
    v = load_vehicle("wang2014")
    d = create("interval_wang", v, **SEED_BOX).design()
    assert d.status is DesignStatus.CERTIFIED and d.certified, d.reason
    assert d.margins["gamma_optimal"] == pytest.approx(0.3804, abs=2e-3)
    assert d.gamma <= 1.02 * d.margins["gamma_optimal"]
    _, bf0 = slip_model_terms(v)
    L = [d.gain(k) for k in ("L0", "L1", "L2")]
    verts = vertex_pairs((15 / 3.6, 150 / 3.6), (-8.0, 8.0), *SEED_BOX.values())
    assert len(verts) == 16
    for pt in verts:
        AL = closed_loop(bf0, L, pt)
        assert metzler_margin(AL) >= 0.0 and np.linalg.eigvals(AL).real.max() < -2.6
        l = L[0] + pt[0] * L[1] + pt[1] * L[2]
        assert l[0, 0] > 0.0 > l[1, 0]


def test_printed_gain_is_not_metzler_and_runs_uncertified() -> None:
    """Digest O5: the gain printed in (4.47) violates the Metzler condition at all 16 vertex pairs
    (same-sign entries cannot, with C = [1, -1]); it still runs, flagged certified = False."""
    v = load_vehicle("wang2014")
    obs = create("interval_wang_printed", v, **SEED_BOX)
    d = obs.design()
    assert d.status is DesignStatus.REJECTED and not d.certified
    assert d.margins["metzler_vertices"] == 0.0 and "Metzler at 0 of 16" in d.reason
    _, bf0 = slip_model_terms(v)
    L = [d.gain(k) for k in ("L0", "L1", "L2")]
    for pt in vertex_pairs((15 / 3.6, 150 / 3.6), (-8.0, 8.0), *SEED_BOX.values()):
        assert metzler_margin(closed_loop(bf0, L, pt)) < 0.0
    assert d.margins["closed_loop_max_real_eig"] == pytest.approx(-2.01, abs=0.02)  # Hurwitz nonetheless
    t, Y, _, _, _, _ = _own_model(v, lambda t: np.array([76_500.0]), lambda t: np.array([51_000.0]), T=2.0)
    tr = obs.run(t, Y[0])
    assert np.all(np.isfinite(tr.lo)) and np.all(tr.lo <= tr.x) and np.all(tr.x <= tr.hi)


def test_outage_and_speed_outside_the_domain_fall_back_to_the_bracket() -> None:
    v = load_vehicle("sedan")
    probe = create("interval_wang", v)
    t, Y, alpha, _, _, _ = _own_model(v, *_stiffness_cases((probe.cf_range, probe.cr_range)), T=5.0)
    Yc = Y[4].copy()
    Yc[200:260, 1:3] = np.nan  # 0.6 s without r and v_x
    tr = create("interval_wang", v).run(t, Yc)
    gap = slice(212, 260)  # older than hold_s = 0.1 s
    np.testing.assert_allclose(tr.lo[gap, 0], -0.2, atol=1e-12)
    np.testing.assert_allclose(tr.hi[gap, 1], 0.2, atol=1e-12)
    assert np.all(tr.hi[-100:, :2] - tr.lo[-100:, :2] < 0.02)  # re-converged after the outage
    slow = Y[4].copy()
    slow[:, 2] = 3.0  # below 15 km/h: no certified model
    s = create("interval_wang", v).run(t, slow)
    np.testing.assert_allclose(s.hi[:, :2], 0.2, atol=1e-12)


@pytest.mark.parametrize("name", ["interval_wang", "interval_wang_printed"])
def test_run_is_one_compiled_call_and_equals_stepping_bit_for_bit(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """run() advances the whole log in one call of the compiled kernel that step() calls per sample, so
    estimates and bounds are the same bits: through dropouts, an outage past hold_s (fallback to the
    bracket and restart), a speed below the design range, a repeated and an irregular time stamp and
    an initial state."""
    import roadtruth.observers.interval_wang as module

    v = load_vehicle("sedan")
    probe = create(name, v)
    t, Y, _, _, _, _ = _own_model(v, *_stiffness_cases((probe.cf_range, probe.cr_range)), T=5.0)
    Yc = Y[4].copy()
    gen = np.random.default_rng(3)
    Yc[:3] = np.nan
    Yc[gen.random(Yc.shape) < 0.2] = np.nan
    Yc[200:260, 1:3] = np.nan        # 0.6 s without r and v_x
    Yc[300:320, 2] = 3.0             # below the design speed range
    t = t.copy()
    t[150] = t[149]                  # repeated time stamp
    t[350:] += 0.0041                # irregular step
    calls: list[int] = []
    kernel = module.interval_run

    def counted(tt: np.ndarray, *args: object) -> None:
        calls.append(len(tt))
        kernel(tt, *args)

    for x0 in (None, {"alpha_f_rad": 0.01}):
        monkeypatch.setattr(module, "interval_run", counted)
        calls.clear()
        obs = create(name, v)
        tr = obs.run(t, Yc, x0)
        assert calls == [len(t)]   # one compiled call for the whole run
        monkeypatch.undo()
        ref = create(name, v)
        ref.reset(float(t[0]), x0)
        outs = [ref.step(float(t[i]), Yc[i]) for i in range(len(t))]
        for got, key in ((tr.x, "x"), (tr.lo, "lo"), (tr.hi, "hi")):
            want = np.array([getattr(o, key) for o in outs])
            assert got is not None and got.tobytes() == want.tobytes(), key
        assert np.all(np.isfinite(tr.x)) and np.ptp(tr.hi[:, 0] - tr.lo[:, 0]) > 0.1  # fell back and narrowed
        nxt, nref = obs.step(float(t[-1]) + 0.01, Yc[-1]), ref.step(float(t[-1]) + 0.01, Yc[-1])
        assert nxt.x.tobytes() == nref.x.tobytes() and nxt.lo.tobytes() == nref.lo.tobytes()


def test_bad_options_are_input_errors() -> None:
    v = load_vehicle("sedan")
    with pytest.raises(InputError, match="contain"):
        create("interval_wang", v, cf_range_Npr=(1.0, 2.0))
    with pytest.raises(InputError, match="stiffness_uncertainty"):
        create("interval_wang", v, stiffness_uncertainty=-0.1)
    with pytest.raises(InputError, match="pair"):
        create("interval_wang", v, cr_range_Npr=5.0)
    with pytest.raises(InputError, match="cannot initialise"):
        create("interval_wang", v).reset(0.0, {"vy_mps": 0.0})


def test_mujoco_double_lane_change_runs_with_finite_coverage() -> None:
    from roadtruth.harness.evaluation.estimate import run_observers
    from roadtruth.harness.evaluation.scoring import score
    from roadtruth.harness.sensors import load_sensor_config
    from roadtruth.harness.sensors.suite import emulate
    from roadtruth.harness.truth.scenario import load_scenario
    from roadtruth.harness.truth.simulate import simulate

    sedan = load_vehicle("sedan")
    sc = replace(load_scenario("double_lane_change"), duration_s=3.0)
    truth = simulate(sc)
    meas = emulate(truth.frame, sedan, load_sensor_config(sc.sensors, sc.sensor_overrides, None), 1,
                   outages=sc.outages, lane_gaps=sc.lane_gaps)
    names = ["interval_wang", "interval_wang_printed"]
    est, runs = run_observers(meas.frame, sedan, names)
    assert runs["interval_wang"].status == "ok" and runs["interval_wang"].certified
    assert runs["interval_wang_printed"].status == "ok" and not runs["interval_wang_printed"].certified
    sub = est[est["observer"] == "interval_wang"]
    assert np.all(np.isfinite(sub[["value", "lo", "hi"]].to_numpy()))
    m = score(truth.frame, est, scenario=sc, runs=runs)
    rows = m[(m["observer"] == "interval_wang") & m["state"].isin(["alpha_f_rad", "alpha_r_rad"])]
    assert len(rows) == 2 and np.all((rows["coverage"] >= 0) & (rows["coverage"] <= 1))
    assert np.all(np.isfinite(rows[["rmse", "mean_width"]].to_numpy()))


def _independent_copy(vehicle, L, t, Y, s0, box=None, upper=True):
    """One copy of Theorem 4's observer in alpha coordinates, written independently of the
    observer: held inputs, alpha_f jumping with the held steering (the integral of delta'), SciPy
    ``solve_ivp`` between samples, ``w`` from Lemma 12 as ``max``/``min`` over the box corners."""
    from scipy.integrate import solve_ivp
    A1, bf0 = slip_model_terms(vehicle)
    ell = vehicle.lf_m + vehicle.lr_m
    C = np.array([1.0, -1.0])
    out = np.zeros((len(t), 2))
    s = np.array(s0, dtype=float)
    out[0] = s
    for k in range(1, len(t)):
        d, r, v, a = Y[k]
        s = s + np.array([d - Y[k - 1, 0], 0.0])
        e1 = 1.0 / v
        e2 = np.clip(a, -8.0, 8.0) * e1
        Lk = L[0] + e1 * L[1] + e2 * L[2]
        yv = d - ell * r / v

        def f(_, x, e1=e1, e2=e2, Lk=Lk, yv=yv, r=r, d=d):
            dx = (e1 * A1 - e2 * np.eye(2)) @ x + np.array([e2 * d + r, r]) + Lk * (yv - C @ x)
            if box is not None:
                T = e1 * bf0 * x[None, :]  # T(x) = eta1 Bf0 diag(x)
                cand = np.stack([T * box[0][None, :], T * box[1][None, :]])
                dx = dx + (cand.max(axis=0) if upper else cand.min(axis=0)).sum(axis=1)
            return dx

        s = solve_ivp(f, (t[k - 1], t[k]), s, rtol=1e-12, atol=1e-14, method="DOP853").y[:, -1]
        out[k] = s
    return out


def test_printed_gain_with_a_zero_width_box_is_exactly_its_closed_loop() -> None:
    """With the stiffness box collapsed to the nominal (w = 0, no drift inflation) each copy of
    ``interval_wang_printed`` is the Luenberger loop x' = A x + B u + L(eta)(y - C x) with the
    printed L(eta) = (1.71, 1.34) + eta1 (-58.6, -43.0) + eta2 (-0.56, -0.44); it must equal an
    independent simulation of that loop to 1e-9 rad (a wrong sign of the scheduled L1 term moves
    it by ~1e-2 rad, which the certified designs, with L1 ~ 1e-9, cannot reveal)."""
    v = load_vehicle("wang2014")
    t, Y, _, _, _, _ = _own_model(v, lambda t: np.array([76_500.0]), lambda t: np.array([51_000.0]), T=3.0)
    obs = create("interval_wang_printed", v, stiffness_uncertainty=0.0, alpha_bound_rad=0.05)
    L = [obs.design().gain(k).reshape(2) for k in ("L0", "L1", "L2")]
    assert L[1][0] == pytest.approx(-58.5902) and L[1][1] == pytest.approx(-42.9510)
    tr = obs.run(t, Y[0], x0={"alpha_f_rad": 0.01, "alpha_r_rad": -0.02})
    for hi, s0 in ((True, (0.06, 0.03)), (False, (-0.04, -0.07))):
        ref = _independent_copy(v, L, t, Y[0], s0)
        got = tr.hi[:, :2] if hi else tr.lo[:, :2]
        np.testing.assert_allclose(got, ref, atol=1e-9, rtol=0)


def test_one_step_bounds_contain_the_continuous_time_bounds() -> None:
    """Theorem 4 in continuous time: the copies obey x+' = A_L x+ + B u + L y + w+(x+) with w+
    evaluated along the path. The discrete observer evaluates w at the start of each step and adds
    the rigorous drift bound Lambda D; so over every step its upper bound is >= the continuous one
    and its lower bound <= (Metzler A_L, nonnegative E and G). A wide box, low speed and a 50 ms
    step from a tight bracket that the inputs push away make w grow within the step: without the
    drift term the discrete bounds fall inside the continuous ones."""
    v = load_vehicle("sedan")
    obs = create("interval_wang", v, stiffness_uncertainty=0.5, alpha_bound_rad=0.002)
    assert obs.design().certified, obs.design().reason
    L = [obs.design().gain(k).reshape(2) for k in ("L0", "L1", "L2")]
    cf0, cr0 = v.cornering_stiffness_f_Npr, v.cornering_stiffness_r_Npr
    box = (np.array([obs.cf_range[0] - cf0, obs.cr_range[0] - cr0]), np.array([obs.cf_range[1] - cf0, obs.cr_range[1] - cr0]))
    h = 0.05
    worst_gap = np.inf
    rng = np.random.default_rng(5)
    for _ in range(6):
        d, r, vx, ax = rng.uniform(-0.05, 0.05), rng.uniform(-0.3, 0.3), rng.uniform(4.5, 8.0), rng.uniform(-8, 8)
        Y = np.array([[d, r, vx, ax]] * 2)
        t = np.array([0.0, h])
        x0 = {"alpha_f_rad": 0.0, "alpha_r_rad": 0.0}  # a tight bracket that the inputs push away
        tr = obs.run(t, Y, x0=x0)
        up = _independent_copy(v, L, t, Y, tr.hi[0, :2], box, upper=True)
        lo = _independent_copy(v, L, t, Y, tr.lo[0, :2], box, upper=False)
        assert np.all(tr.hi[1, :2] >= up[1] - 1e-12) and np.all(tr.lo[1, :2] <= lo[1] + 1e-12)
        worst_gap = min(worst_gap, float(np.min(tr.hi[1, :2] - up[1])), float(np.min(lo[1] - tr.lo[1, :2])))
    assert worst_gap >= -1e-12
