"""PPK on a simulated kinematic baseline: honest fixed-epoch sigmas, slips; LAMBDA against cssrlib's."""
import numpy as np
import pytest

from dgcal.fields.crs import ecef_to_geodetic, geodetic_to_ecef
from dgcal.fields.frames import R_ecef_to_enu
from dgcal.pos.gnss.ambiguity import bootstrap_success_rate, decorrelate, lambda_ils, resolve
from dgcal.pos.gnss.ppk import PpkOptions, ppk
from dgcal.sim.gnss import DEFAULT_T0_GPS, circle_trajectory, simulate_carrier_pair

BASE = np.asarray(geodetic_to_ecef(35.31, 139.50, 40.0), float).reshape(3)


def _flight(seed, duration=120.0, slips=()):
    t = DEFAULT_T0_GPS + np.arange(0.0, duration)
    p, _v = circle_trajectory(t, 35.33, 139.52, 80.0, 100.0, 10.0)       # 3 km baseline, 10 m/s circle
    rover, base, nav = simulate_carrier_pair(t, p, BASE, seed=seed, systems=("G", "E"), n_freq=2, slips=slips)
    return t, p, rover, base, nav


@pytest.mark.parametrize("seed", [2, 5])
def test_simulated_kinematic_baseline_sigmas_are_honest(seed):
    t, p, rover, base, nav = _flight(seed)
    # simulate_carrier_pair has no differential atmosphere (the same Klobuchar at both ends): no budget for it
    res = ppk(rover, base, nav, BASE, PpkOptions(n_freq=2, iono_ppm=0.0, tropo_zenith_m=0.0), p_init=p[0] + 3.0)
    f = res.status == 3
    assert f.mean() >= 0.95
    lat, lon, _ = ecef_to_geodetic(p[0])
    R = R_ecef_to_enu(lat, lon)
    e = (res.p[f] - p[f]) @ R.T
    s = np.sqrt(np.einsum("ij,njk,ik->ni", R, res.P[f], R))
    z = np.sqrt(np.mean((e / s) ** 2, axis=0))
    print(f"\nseed {seed}: {100 * f.mean():.0f} % fixed, 3D RMS {1e3 * np.sqrt(np.mean(np.sum(e ** 2, 1))):.1f} mm, "
          f"error/sigma RMS E/N/U {np.round(z, 2).tolist()}")
    assert np.all((z > 0.7) & (z < 1.4))
    assert np.max(np.linalg.norm(e, axis=1)) < 0.05          # no wrong fix slipped through


def test_fixed_positions_carry_the_differential_atmosphere_budget():
    """With the default budget (0.5 ppm slant ionosphere, 1.5 mm zenith troposphere) a fixed position's covariance
    grows by the least-squares map of the atmosphere errors: on this 3 km baseline by millimetres, mostly in height
    (the troposphere of the rover moves the height)."""
    t, p, rover, base, nav = _flight(5, duration=40.0)
    bare = ppk(rover, base, nav, BASE, PpkOptions(n_freq=2, iono_ppm=0.0, tropo_zenith_m=0.0), p_init=p[0] + 3.0)
    full = ppk(rover, base, nav, BASE, PpkOptions(n_freq=2), p_init=p[0] + 3.0)
    f = (bare.status == 3) & (full.status == 3)
    assert f.mean() > 0.9
    assert np.allclose(bare.p[f], full.p[f], atol=1e-9)        # the budget changes the sigmas only
    lat, lon, _ = ecef_to_geodetic(p[0])
    R = R_ecef_to_enu(lat, lon)
    extra = np.einsum("ij,njk,lk->nil", R, full.P[f] - bare.P[f], R)
    var = np.einsum("nii->ni", extra)
    assert np.all(var > 0)
    assert np.all(np.sqrt(np.median(var[:, 2])) > np.sqrt(np.median(var[:, :2], axis=0)))
    assert 1e-3 < np.sqrt(np.median(var[:, 2])) < 2e-2


def test_slips_flagged_and_unflagged_are_handled():
    """A flagged slip (LLI) and an unflagged 7-cycle slip: both reset their ambiguity, no fixed epoch is off."""
    t0 = DEFAULT_T0_GPS
    t, p, rover, base, nav = _flight(3, 90.0, slips=[(t0 + 30.0, "G03", 0, 3, True), (t0 + 50.0, "G17", 1, 7, False)])
    i5, i17 = rover.sats.index("G03"), rover.sats.index("G17")
    if not (np.isfinite(rover.L[30, i5, 0]) and np.isfinite(rover.L[50, i17, 1])):
        pytest.skip("slipped satellites not visible")
    res = ppk(rover, base, nav, BASE, PpkOptions(n_freq=2), p_init=p[0] + 3.0)
    f = res.status == 3
    assert f.mean() >= 0.9 and f[30] and f[50] and f[51]
    assert np.max(np.linalg.norm(res.p[f] - p[f], axis=1)) < 0.05
    assert res.slips_rover >= 2


def test_lambda_matches_cssrlib_and_decorrelates():
    from cssrlib.mlambda import mlambda  # a required dependency
    rng = np.random.default_rng(7)
    for _ in range(60):
        n = int(rng.integers(2, 20))
        A = rng.normal(size=(n + 4, n))
        Q = np.linalg.inv(A.T @ A) * rng.uniform(0.01, 1.0)
        a = rng.normal(size=n) * 4
        F, s = lambda_ils(a, Q)
        F2, s2, _, _ = mlambda(a, Q)
        np.testing.assert_allclose(s, s2, rtol=1e-8)
        r = a - F[:, 0]
        assert r @ np.linalg.solve(Q, r) == pytest.approx(s[0])
        L, D, Z = decorrelate(Q)
        np.testing.assert_allclose(Z.T @ Q @ Z, L.T @ np.diag(D) @ L, atol=1e-9)
        assert abs(np.linalg.det(Z)) == pytest.approx(1.0)
    # precise ambiguities near integers: full fix with a high ratio and success rate
    n = 8
    Q = np.diag(np.full(n, 0.01)) + 0.005
    a = np.arange(n) + rng.normal(0, 0.02, n)
    fx = resolve(a, Q)
    assert fx.fixed and fx.mode == "full" and fx.ratio > 10
    np.testing.assert_allclose(np.linalg.solve(fx.C, fx.c), np.arange(n))
    L, D, Z = decorrelate(Q)
    assert bootstrap_success_rate(D) > 0.999


def test_gesv_and_fixed_solution_are_the_numpy_algebra():
    """`gesv` solves as np.linalg.solve does, without its overhead (LinAlgError when singular);
    `fixed_solution` conditions the float state on the fix, its chi-square optionally with extra state variances."""
    from dgcal.pos.gnss.ambiguity import AmbiguityFix, fixed_solution, gesv
    rng = np.random.default_rng(1)
    for n, k in ((3, 1), (30, 39), (60, 1)):
        A = rng.normal(size=(n, n))
        B = rng.normal(size=(n, k)) if k > 1 else rng.normal(size=n)
        S = A @ A.T + np.eye(n)
        X = gesv(S, B)
        assert X.shape == np.shape(B)
        # results, not bits: numpy's and scipy's LAPACK builds may differ by a release
        np.testing.assert_allclose(S @ X, B, rtol=0, atol=1e-9 * np.abs(B).max() * np.linalg.cond(S))
    with pytest.raises(np.linalg.LinAlgError):
        gesv(np.zeros((3, 3)), np.ones(3))
    n = 6
    M = rng.normal(size=(n, n))
    P = M @ M.T + np.eye(n)
    x = rng.normal(size=n)
    Da = np.eye(n)[2:]                                   # the last four states are ambiguities
    fix = AmbiguityFix(True, np.eye(4), np.round(x[2:]) + 1.0, 5.0, 1.0, 1.0, 4, "full")
    var = np.r_[0.0, 0.0, np.full(4, 0.3)]
    xf, Pf, chi2 = fixed_solution(x, P, Da, fix, var)
    np.testing.assert_allclose(xf[2:], fix.c, atol=1e-12)          # the fixed ambiguities hold exactly
    np.testing.assert_allclose(Pf[2:, 2:], 0.0, atol=1e-12)
    r = fix.c - x[2:]
    assert chi2 == pytest.approx(r @ np.linalg.solve(P[2:, 2:] + np.diag(var[2:]), r), rel=1e-12)
    assert fixed_solution(x, P, Da, fix)[2] == pytest.approx(r @ np.linalg.solve(P[2:, 2:], r), rel=1e-12)


def test_multifrequency_recombination_is_unimodular_per_satellite():
    """Rows satellite by satellite in order of first appearance: slot differences, then the lowest slot."""
    from dgcal.pos.gnss.ppk import _multifrequency_combinations
    sat = np.array([4, 2, 7, 2, 4, 4])                   # keys (satellite, slot) as groups list them
    slot = np.array([0, 0, 0, 1, 1, 2])
    T = _multifrequency_combinations(sat, slot)
    expect = np.zeros((6, 6))
    expect[0, [0, 4]] = 1, -1                            # satellite 4: N0 - N1, N1 - N2, N0
    expect[1, [4, 5]] = 1, -1
    expect[2, 0] = 1
    expect[3, [1, 3]] = 1, -1                            # satellite 2: N0 - N1, N0
    expect[4, 1] = 1
    expect[5, 2] = 1                                     # satellite 7: N0
    np.testing.assert_array_equal(T, expect)
    assert abs(np.linalg.det(T)) == pytest.approx(1.0)
