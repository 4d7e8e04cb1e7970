"""GNSS/INS data integrity (issue 16) on a short simulated flight, against the simulator's truth.

IMU: a 5 s time gap is bridged and the events' sigmas grow to cover their errors; a gyro spike is found and
interpolated (heading as good as without it); duplicated and swapped samples are dropped and sorted; a gap too
long to bridge is a ResultError. GNSS: one LC epoch 1000 km off is rejected before the graph is built, a small
offset after the first pass, a pseudorange outlier in TC too, each named by its epoch time. RINEX 3 and 2: an
epoch header claiming 99 satellites is skipped with a warning naming the file and line, duplicated and swapped
epochs are dropped and sorted with a warning. Clean data raise no warning at all.
"""
from __future__ import annotations

import copy
import json

import numpy as np
import pytest


from dgcal.fields.crs import geodetic_to_ecef  # noqa: E402
from dgcal.fields.errors import ResultError  # noqa: E402
from dgcal.fields.frames import R_ecef_to_ned  # noqa: E402
from dgcal.pos.ins.imu_data import ImuData  # noqa: E402
from dgcal.pos.ins.integrity import check_imu  # noqa: E402
from dgcal.pos.smoother.initial import GnssFixes  # noqa: E402

SIGMA_LC = np.array([0.02, 0.02, 0.04])      # PPK-class antenna positions (N, E, D m)


@pytest.fixture(scope="module")
def flight():
    """A 3-minute multirotor flight at 100 Hz (events on the strips from ~70 s), its LC fixes from the true
    antenna track with PPK-class noise, and the clean LC solution."""
    from dgcal.pos.gnss_ins import process
    from dgcal.sim.pos import simulate_pos
    sim = simulate_pos(seed=0, duration_s=180.0, rate_hz=100.0, carrier=False)
    t = np.array([e.t_gps for e in sim.obs.epochs])
    st = sim.traj.at(t)
    p_ant = st.p_ecef + np.einsum("kij,j->ki", st.R_body_to_ecef, sim.lever_arm_b)
    rng = np.random.default_rng(5)
    noise_ned = rng.normal(size=(len(t), 3)) * SIGMA_LC
    p = p_ant + np.einsum("kji,kj->ki", R_ecef_to_ned(st.lat, st.lon), noise_ned)
    lc = GnssFixes(t, p, np.tile(SIGMA_LC, (len(t), 1)))
    clean = process("lc", sim.imu, sim.grade, sim.lever_arm_b, lc_fixes=lc, events=sim.events, forward=False)
    return {"sim": sim, "lc": lc, "clean": clean}


def _run(flight, imu=None, lc=None):
    from dgcal.pos.gnss_ins import process
    sim = flight["sim"]
    return process("lc", imu if imu is not None else sim.imu, sim.grade, sim.lever_arm_b,
                   lc_fixes=lc if lc is not None else flight["lc"], events=sim.events, forward=False)


def _event_errors(res, traj):
    """Errors of the events (N, E, D m; roll, pitch, heading deg) against the truth and their sigmas."""
    ev = res.events
    te = traj.at(ev.t)
    dp = geodetic_to_ecef(ev.lat, ev.lon, ev.h) - te.p_ecef
    d_ned = np.einsum("kij,kj->ki", R_ecef_to_ned(te.lat, te.lon), dp)
    d_att = ev.rph - te.rph
    d_att[:, 2] = (d_att[:, 2] + 180.0) % 360.0 - 180.0
    return np.column_stack([d_ned, d_att]), ev.sigma


def _without(imu, keep) -> ImuData:
    return ImuData(imu.t[keep], imu.dtheta[keep], imu.dvel[keep], imu.rate_hz)


def test_clean_data_raise_no_warning(flight, tmp_path):
    s = flight["clean"].summary
    assert s["warnings"] == []
    assert s["integrity"]["imu"]["counts"] == {"out_of_order": 0, "duplicate": 0, "gap": 0, "spike": 0}
    assert s["integrity"]["gnss_rejected"] == []
    e, sig = _event_errors(flight["clean"], flight["sim"].traj)
    assert np.sqrt(np.mean((e / sig) ** 2)) < 1.5
    # TC on the simulated code and Doppler, and its RINEX file read back: nothing either
    from dgcal.pos.gnss.rinex import write_rinex_obs
    from dgcal.pos.gnss.rinex_obs import read_obs_file
    from dgcal.pos.gnss.spp import SppOptions
    from dgcal.pos.gnss_ins import process
    sim = flight["sim"]
    opts = SppOptions(code_sigma_zenith_m=sim.sigma_pr, doppler_sigma_zenith_mps=sim.sigma_doppler,
                      model_errors=False, systems=("G", "E"))
    tc = process("tc", sim.imu, sim.grade, sim.lever_arm_b, raw_obs=sim.obs, nav=sim.nav, spp_opts=opts,
                 forward=False)
    assert tc.summary["warnings"] == [] and tc.summary["integrity"]["gnss_rejected"] == []
    write_rinex_obs(tmp_path / "obs.rnx", sim.obs)
    assert read_obs_file(tmp_path / "obs.rnx").warnings == []


def test_imu_gap_is_bridged_and_the_sigmas_grow(flight):
    imu = flight["sim"].imu
    i0 = int(np.searchsorted(imu.t, imu.t[0] + 90.0))
    i1 = i0 + int(round(5.0 * imu.rate_hz))                  # samples i0 .. i1-1 lost: 5 s
    res = _run(flight, _without(imu, np.r_[0:i0, i1:len(imu)]))
    it = res.summary["integrity"]["imu"]
    assert it["counts"]["gap"] == 1 and it["samples_out"] == len(imu)
    gap = it["issues"][0]
    assert gap["t0_gps"] == pytest.approx(imu.t[i0 - 1], abs=1e-6)
    assert gap["t1_gps"] == pytest.approx(imu.t[i1 - 1], abs=1e-6) and gap["n"] == i1 - i0
    assert any("gap" in w and f"{imu.t[i0 - 1]:.3f}" in w for w in res.summary["warnings"])
    e, sig = _event_errors(res, flight["sim"].traj)
    _, sig_clean = _event_errors(flight["clean"], flight["sim"].traj)
    ev_t = res.events.t
    near = (ev_t > imu.t[i0] - 1.0) & (ev_t < imu.t[i1] + 1.0)
    assert near.sum() >= 2
    # the events in and around the gap: their sigmas grow (attitude) and cover their errors
    assert np.all(sig[near, 3:] > 5 * sig_clean[near, 3:])
    assert np.all(np.abs(e[near] / sig[near]) <= 3.0)
    assert np.all(np.abs(e / sig) <= 3.5) and np.sqrt(np.mean((e / sig) ** 2)) < 1.5
    assert np.max(np.abs(e[:, :3])) < 0.1                   # the GNSS keeps the positions (it was 256 m)


def test_gyro_spike_is_replaced(flight):
    imu = flight["sim"].imu
    j = int(np.searchsorted(imu.t, imu.t[0] + 100.0))
    spiky = ImuData(imu.t.copy(), imu.dtheta.copy(), imu.dvel.copy(), imu.rate_hz)
    spiky.dtheta[j, 2] += 0.5                               # 50 rad/s for 10 ms: a 29 deg heading jump
    spiky.dvel[j + 300, 0] += 0.5                           # and an accelerometer spike 3 s later (50 m/s^2)
    res = _run(flight, spiky)
    it = res.summary["integrity"]["imu"]
    assert it["counts"]["spike"] == 2 and it["counts"]["gap"] == 0
    times = sorted(i["t0_gps"] for i in it["issues"])
    assert times == pytest.approx([imu.t[j], imu.t[j + 300]], abs=1e-6)
    assert any("spike" in w and f"{imu.t[j]:.3f}" in w for w in res.summary["warnings"])
    e, sig = _event_errors(res, flight["sim"].traj)
    e0, _ = _event_errors(flight["clean"], flight["sim"].traj)
    assert np.max(np.abs(e[:, 5])) < np.max(np.abs(e0[:, 5])) + 0.02    # heading (it was 21 deg off)
    assert np.all(np.abs(e / sig) <= 3.5)


def test_duplicated_and_swapped_imu_samples():
    from dgcal.sim.pos import simulate_pos
    imu = simulate_pos(seed=1, duration_s=60.0, rate_hz=100.0, carrier=False).imu
    order = np.r_[0:1000, 1000, 1000, 1001:2000, 2001, 2000, 2002:len(imu)]   # one repeated, one pair swapped
    bad = ImuData(imu.t[order], imu.dtheta[order], imu.dvel[order], imu.rate_hz)
    fixed, rep = check_imu(bad)
    assert rep.count("duplicate") == 1 and rep.count("out_of_order") == 1
    assert rep.issues[0].t0 == pytest.approx(imu.t[1000]) and rep.issues[1].t0 == pytest.approx(imu.t[2000])
    np.testing.assert_array_equal(fixed.t, imu.t)
    np.testing.assert_array_equal(fixed.dtheta, imu.dtheta)
    w = rep.warnings()
    assert w[0].startswith("IMU: 1 sample out of time order") and w[1].startswith("IMU: 1 duplicated time stamp")
    # a gap longer than can be bridged
    keep = np.r_[0:1000, 1000 + 1500:len(imu)]
    with pytest.raises(ResultError, match=r"IMU gap of 15.000 s .* longer than the 10 s"):
        check_imu(_without(imu, keep))


def test_gnss_epoch_1000_km_off_is_rejected(flight):
    lc = flight["lc"]
    k = len(lc.t) // 2 + 5
    bad = GnssFixes(lc.t, lc.p_ecef.copy(), lc.sigma_ned)
    bad.p_ecef[k] += np.array([1.0e6, 0.0, 0.0])
    bad.p_ecef[k + 20] += np.array([0.0, 0.3, 0.0])         # 0.3 m: within the IMU's bound, caught after pass one
    res = _run(flight, lc=bad)
    rej = res.summary["integrity"]["gnss_rejected"]
    assert [r["t_gps"] for r in rej] == pytest.approx([lc.t[k], lc.t[k + 20]])
    assert rej[0]["kind"] == "position" and "normalised" not in rej[0] and rej[1]["normalised"] > 5
    assert any(f"{lc.t[k]:.3f}" in w for w in res.summary["warnings"])
    assert any(f"{lc.t[k + 20]:.3f}" in w for w in res.summary["warnings"])
    e, sig = _event_errors(res, flight["sim"].traj)
    assert np.all(np.abs(e / sig) <= 3.5)
    near = np.abs(res.events.t - lc.t[k]) < 5.0
    assert near.any() and np.all(np.abs(e[near] / sig[near]) <= 3.0)


def test_tc_pseudorange_outlier_is_rejected(flight):
    from dgcal.pos.gnss.spp import SppOptions
    from dgcal.pos.gnss_ins import process
    sim = flight["sim"]
    obs = copy.deepcopy(sim.obs)
    k = 100
    obs.epochs[k].pr_m[2] += 50.0
    opts = SppOptions(code_sigma_zenith_m=sim.sigma_pr, doppler_sigma_zenith_mps=sim.sigma_doppler,
                      model_errors=False, systems=("G", "E"), raim=False)
    res = process("tc", sim.imu, sim.grade, sim.lever_arm_b, raw_obs=obs, nav=sim.nav, spp_opts=opts, forward=False)
    rej = [r for r in res.summary["integrity"]["gnss_rejected"] if r["kind"] == "pseudorange"]
    assert [r["t_gps"] for r in rej] == pytest.approx([obs.epochs[k].t_gps])


# ------------------------------------------------------------------------------------------------- RINEX
def _rinex3_records(text: str) -> tuple[list[str], list[list[str]]]:
    lines = text.splitlines(keepends=True)
    end = next(i for i, s in enumerate(lines) if "END OF HEADER" in s) + 1
    recs, cur = [], None
    for s in lines[end:]:
        if s.startswith(">"):
            cur = [s]
            recs.append(cur)
        else:
            cur.append(s)
    return lines[:end], recs


def _rinex2_text(obs, n_epochs: int) -> str:
    """The simulated code, Doppler and C/N0 of the first epochs as RINEX 2.11 (C1 D1 S1, 12 satellites per
    line, continuation lines)."""
    from dgcal.pos.gnss.rinex import calendar_from_gps_seconds

    def hdr(text, label):
        return f"{text:<60}{label:<20}\n"
    p = obs.p_approx_ecef
    y, mo, d, h, mi, s = calendar_from_gps_seconds(obs.epochs[0].t_gps)
    out = [hdr(f"{2.11:9.2f}{'':11}{'OBSERVATION DATA':<20}{'M (MIXED)':<20}", "RINEX VERSION / TYPE"),
           hdr("DGCAL", "MARKER NAME"), hdr(f"{p[0]:14.4f}{p[1]:14.4f}{p[2]:14.4f}", "APPROX POSITION XYZ"),
           hdr(f"{1:6d}{1:6d}", "WAVELENGTH FACT L1/2"),
           hdr(f"{3:6d}{'C1':>6}{'D1':>6}{'S1':>6}", "# / TYPES OF OBSERV"),
           hdr(f"{y:6d}{mo:6d}{d:6d}{h:6d}{mi:6d}{s:13.7f}     GPS", "TIME OF FIRST OBS"), hdr("", "END OF HEADER")]
    for ep in obs.epochs[:n_epochs]:
        y, mo, d, h, mi, s = calendar_from_gps_seconds(ep.t_gps)
        ids = "".join(ep.sat)
        line = f" {y % 100:02d} {mo:2d} {d:2d} {h:2d} {mi:2d}{s:11.7f}  0{ep.n:3d}" + ids[:36]
        out.append(line + "\n")
        for c in range(36, len(ids), 36):
            out.append(" " * 32 + ids[c:c + 36] + "\n")
        for i in range(ep.n):
            vals = np.nan_to_num([ep.pr_m[i], ep.doppler_hz[i], ep.cn0_dbhz[i]])     # 0: blank
            out.append("".join(f"{v:14.3f}  " for v in vals).rstrip() + "\n")
    return "".join(out)


def _rinex2_records(text: str) -> tuple[list[str], list[list[str]]]:
    lines = text.splitlines(keepends=True)
    end = next(i for i, s in enumerate(lines) if "END OF HEADER" in s) + 1
    recs, cur = [], None
    for s in lines[end:]:
        if s[1:3].isdigit():                                # " yy mm dd ...": an epoch header
            cur = [s]
            recs.append(cur)
        else:
            cur.append(s)
    return lines[:end], recs


@pytest.mark.parametrize("version", [3, 2])
def test_rinex_epoch_records_are_checked(flight, tmp_path, version):
    from dgcal.pos.gnss.rinex import read_rinex_obs, write_rinex_obs
    from dgcal.pos.gnss.rinex_obs import read_obs_file
    from dgcal.pos.gnss.spp import SppOptions, spp
    sim = flight["sim"]
    n_ep = 20
    if version == 3:
        short = copy.copy(sim.obs)
        short.epochs = sim.obs.epochs[:n_ep]
        write_rinex_obs(tmp_path / "clean.rnx", short)
        head, recs = _rinex3_records((tmp_path / "clean.rnx").read_text())
        count = slice(32, 35)
    else:
        (tmp_path / "clean.rnx").write_text(_rinex2_text(sim.obs, n_ep))
        head, recs = _rinex2_records((tmp_path / "clean.rnx").read_text())
        count = slice(29, 32)
    assert len(recs) == n_ep
    clean = read_obs_file(tmp_path / "clean.rnx")
    assert clean.warnings == [] and len(clean) == n_ep
    np.testing.assert_allclose(clean.t_gps, [e.t_gps for e in sim.obs.epochs[:n_ep]])

    def write(name, records):
        (tmp_path / name).write_text("".join(head) + "".join("".join(r) for r in records))
        return tmp_path / name

    def line_of(records, k):
        return len(head) + sum(len(r) for r in records[:k]) + 1

    # the first epoch header claims 99 satellites: that record is skipped, named by file and line
    r99 = copy.deepcopy(recs)
    r99[0][0] = r99[0][0][:count.start] + " 99" + r99[0][0][count.stop:]
    rx = read_obs_file(write(f"s99.{version}o", r99))
    assert len(rx.warnings) == 1 and f"s99.{version}o:{line_of(r99, 0)}:" in rx.warnings[0]
    assert "99 satellites" in rx.warnings[0]
    np.testing.assert_allclose(rx.t_gps, clean.t_gps[1:])
    # ... and the first fix is where the antenna was (the reading used to move it by 400 m)
    raw = read_rinex_obs(tmp_path / f"s99.{version}o", systems=("G", "E"), rinex=rx)
    sol = spp(raw, sim.nav, SppOptions(model_errors=False, systems=("G", "E")))
    k_true = np.searchsorted(sim.obs.truth["t_gps"], sol.t_gps[0])
    assert sol.ok[0] and np.linalg.norm(sol.p_ecef[0] - sim.obs.truth["p_ecef"][k_true]) < 10.0
    # a record claiming fewer satellites than it lists
    rlow = copy.deepcopy(recs)
    rlow[5][0] = rlow[5][0][:count.start] + f"{len(rlow[5]) - 3:3d}" + rlow[5][0][count.stop:]
    rx = read_obs_file(write(f"low.{version}o", rlow))
    assert len(rx.warnings) == 1 and f"low.{version}o:{line_of(rlow, 5)}:" in rx.warnings[0]
    assert len(rx) == n_ep - 1
    # a duplicated epoch: the first kept, the second named
    rdup = recs[:8] + [recs[7]] + recs[8:]
    rx = read_obs_file(write(f"dup.{version}o", rdup))
    assert len(rx.warnings) == 1 and f"dup.{version}o:{line_of(rdup, 8)}:" in rx.warnings[0]
    assert "repeats the epoch of line" in rx.warnings[0] and str(line_of(rdup, 7)) in rx.warnings[0]
    np.testing.assert_array_equal(rx.t_gps, clean.t_gps)
    # two epochs swapped: sorted back, named
    rsw = recs[:10] + [recs[11], recs[10]] + recs[12:]
    rx = read_obs_file(write(f"swap.{version}o", rsw))
    assert len(rx.warnings) == 1 and f"swap.{version}o:{line_of(rsw, 11)}:" in rx.warnings[0]
    assert "sorted" in rx.warnings[0]
    np.testing.assert_array_equal(rx.t_gps, clean.t_gps)
    for s, so in clean.systems.items():
        np.testing.assert_array_equal(rx.systems[s].val, so.val)


def test_cli_reports_integrity(flight, tmp_path, capsys):
    """`dgcal pos --mode lc` on files: the IMU gap and the RINEX duplicate on the console, in pos_summary.json and
    in the report."""
    from dgcal.cli import main
    from dgcal.pos.ins.imu_data import write_imu_csv
    from dgcal.sim.pos import write_pos_dataset
    sim = copy.copy(flight["sim"])
    d = tmp_path / "data"
    write_pos_dataset(d, sim)
    imu = sim.imu
    i0 = int(np.searchsorted(imu.t, imu.t[0] + 100.0))
    write_imu_csv(d / "imu.csv", _without(imu, np.r_[0:i0, i0 + 300:len(imu)]))
    head, recs = _rinex3_records((d / "obs.rnx").read_text())
    (d / "obs.rnx").write_text("".join(head) + "".join("".join(r) for r in recs[:30] + [recs[29]] + recs[30:]))
    t = json.loads((d / "truth.json").read_text())
    out = tmp_path / "out"
    rc = main(["pos", "--mode", "lc", "--rinex-obs", str(d / "obs.rnx"), "--rinex-nav", str(d / "nav.rnx"),
               "--imu", str(d / "imu.csv"), "--events", str(d / "events.csv"), "--imu-grade", t["imu_grade"],
               "--lever-arm", *[str(v) for v in t["lever_arm_gnss_m"]], "--code-sigma", "0.3",
               "--doppler-sigma", "0.1", "--set", "model_errors=false", "--set", "forward=false", "--no-progress",
               "--out", str(out)])
    assert rc == 0
    err = capsys.readouterr().err
    assert "warning: IMU: 1 time gap bridged" in err and "repeats the epoch of line" in err
    s = json.loads((out / "pos_summary.json").read_text())
    assert s["integrity"]["imu"]["counts"]["gap"] == 1 and len(s["integrity"]["rinex"]) == 1
    assert "Data integrity" in (out / "report.html").read_text()


def test_block_medians_are_numpys():
    """The IMU spike test's per-block noise medians equal np.median for odd, even and tiny blocks."""
    from dgcal.pos.ins.integrity import _block_medians
    rng = np.random.default_rng(11)
    for m in (200, 201, 2, 1):
        x = np.abs(rng.standard_normal((40, m, 3)))
        assert np.array_equal(_block_medians(x), np.median(x, axis=1))
