"""The honesty table (issue 27): errors against their sigmas wherever a reference exists, in the same table in every
report and under `honesty` in every JSON summary, and a line where none exists. The helper on synthetic errors (honest,
too small, too large, an outlier), then each report's reference: the DG and triangulation check points, a flow
truth, the campaign's truth (trajectory, EOPs, mounting) and the steps' tables gathered."""
from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from dgcal.fields.crs import R_ecef_to_ned_at, ecef_to_geodetic, geodetic_to_ecef
from dgcal.fields.io.formats import EOP, Points, Trajectory, write_eop, write_trajectory
from dgcal.reports.bundle import triangulation_honesty
from dgcal.reports.campaign import collect
from dgcal.reports.flow import flow_honesty
from dgcal.reports.honesty import (HEADER, add_honesty, honesty_html, honesty_rows, honesty_section, merge_sections,
                                   no_reference, verdict)
from dgcal.reports.html import HtmlReport
from dgcal.reports.mounting import check_honesty

RNG = np.random.default_rng(27)


def _row(rows, quantity, reference=None):
    got = [r for r in rows if r["quantity"] == quantity and (reference is None or r["reference"] == reference)]
    assert len(got) == 1, (quantity, reference, rows)
    return got[0]


def test_rows_of_honest_too_small_and_too_large_sigmas():
    sig = np.array([0.02, 0.05, 3.0])
    err = RNG.normal(size=(400, 3)) * sig
    rows = honesty_rows(err, sig, ("E", "N", "U"), "known position")
    assert [r["quantity"] for r in rows] == ["E", "N", "U"]
    for r, s in zip(rows, sig):
        assert r["n"] == 400 and r["reference"] == "known position" and r["unit"] == "m"
        assert r["median_sigma"] == pytest.approx(s)
        assert r["rms_error"] == pytest.approx(s, rel=0.15)
        assert 0.85 < r["error_over_sigma_rms"] < 1.15 and r["max_abs_error_over_sigma"] < 5
        assert r["verdict"] == "honest"
    assert {r["verdict"] for r in honesty_rows(err, sig / 2, "ENU")} == {"sigmas too small"}
    assert {r["verdict"] for r in honesty_rows(err, sig * 2, "ENU")} == {"sigmas too large"}
    out = err.copy()
    out[7, 0] = 6.0 * sig[0]                                   # one error beyond 5 sigma: too small there
    assert [r["verdict"] for r in honesty_rows(out, sig, "ENU")] == ["sigmas too small", "honest", "honest"]
    assert verdict(1.0, 4.99) == "honest" and verdict(0.69, 1.0) == "sigmas too large"
    assert verdict(1.41, 2.0) == verdict(0.5, 5.0) == "sigmas too small"


def test_rows_leave_out_values_without_a_finite_positive_sigma():
    err = np.array([[0.1, np.nan], [0.2, 0.1], [0.3, 0.2], [np.inf, 0.1]])
    sig = np.array([[0.1, 0.1], [0.0, 0.1], [np.nan, 0.1], [0.1, 0.1]])
    a, b = honesty_rows(err, sig, ("a", "b"))
    assert a["n"] == 1 and a["error_over_sigma_rms"] == pytest.approx(1.0)
    assert b["n"] == 3 and b["max_abs_error_over_sigma"] == pytest.approx(2.0)
    assert honesty_rows(np.full((3, 1), np.nan), np.ones((3, 1)), ["none"]) == []
    one = honesty_rows(np.array([0.1, -0.2]), np.array([0.1, 0.1]), ["pooled"], unit="deg")   # 1-D: one quantity
    assert one[0]["n"] == 2 and one[0]["unit"] == "deg"
    with pytest.raises(ValueError):
        honesty_rows(np.zeros((2, 3)), np.ones(3), ["E", "N"])


def test_section_in_a_page_and_as_a_fragment():
    sec = honesty_section(honesty_rows(RNG.normal(size=(5, 1)), np.ones(1), ["delay"], "truth", "ms"),
                          ["what the sigma includes"])
    page = add_honesty(HtmlReport("t"), sec).render()
    assert "Honesty: errors against their sigmas" in page
    assert all(f"<th>{h}</th>" in page for h in ("reference", "quantity", "error/sigma RMS", "verdict"))
    assert "(only 5 values)" in page and "what the sigma includes" in page and " ms</td>" in page
    frag = honesty_html(sec)
    assert frag.startswith("<h2>") and frag in page           # the same markup in the string-built pages
    none = honesty_html(no_reference("No reference: nothing to compare with."))
    assert "<table>" not in none and "No reference: nothing to compare with." in none
    assert "No reference" in honesty_html(None)
    assert len(HEADER) == 8


def test_merged_sections_name_their_origin():
    a = honesty_section(honesty_rows(np.ones((3, 1)), np.ones(1), ["E"], "check points"), ["note a"])
    b = no_reference("No reference: b has none.")
    m = merge_sections([a, None, b], ["triangulation", "pos", "check"])
    assert [r["reference"] for r in m["rows"]] == ["triangulation: check points"]
    assert m["notes"] == ["triangulation: note a", "check: No reference: b has none."]


def _check_json(sig_pred: np.ndarray, survey: np.ndarray | None, n: int = 40) -> dict:
    total = np.sqrt(sig_pred ** 2 + (0 if survey is None else survey ** 2))
    err = RNG.normal(size=(n, 3)) * total
    asprs = {"n_checkpoints": n}
    if survey is not None:
        asprs.update(checkpoint_RMSE_H=float(np.hypot(survey[0], survey[1])), checkpoint_RMSE_V=float(survey[2]))
    return {"points": [{"id": f"C{i}", "err_enu": e.tolist(), "sigma_pred_enu": sig_pred.tolist()}
                       for i, e in enumerate(err)], "asprs_2023": asprs}


def test_dg_check_points_with_their_survey_sigma():
    """The survey sigma belongs in the denominator: errors drawn with predicted + survey sigma are honest with it,
    and the same errors over the predicted sigma alone are not."""
    pred, survey = np.array([0.01, 0.01, 0.02]), np.array([0.03, 0.03, 0.06])
    js = {"joint": _check_json(pred, survey), "two-step": _check_json(pred, None)}
    h = check_honesty(js)
    assert len(h["rows"]) == 6
    for q in "ENU":
        r = _row(h["rows"], q, "check points, joint")
        assert r["verdict"] == "honest" and r["median_sigma"] == pytest.approx(np.hypot(pred, survey)["ENU".index(q)])
        assert _row(h["rows"], q, "check points, two-step")["verdict"] == "honest"
    assert any("survey sigmas are added" in n for n in h["notes"])
    assert any("(two-step)" in n and "exact" in n for n in h["notes"])
    bare = {k: {**v, "asprs_2023": {}} for k, v in js.items()}
    assert _row(check_honesty(bare)["rows"], "E", "check points, joint")["verdict"] == "sigmas too small"
    assert check_honesty({})["rows"] == []


def test_triangulation_check_points():
    n = 30
    sig = np.tile([0.01, 0.01, 0.02], (n, 1))
    survey = np.tile([0.02, 0.02, 0.04], (n, 1))
    err = RNG.normal(size=(n, 3)) * np.hypot(sig, survey)
    check = [{"id": f"K{i}", "evaluated": True, "dENU_m": e.tolist(), "sigma_ENU_m": s.tolist()}
             for i, (e, s) in enumerate(zip(err, sig))] + [{"id": "K_out", "evaluated": False}]
    res = SimpleNamespace(check=check)
    ids = np.array([c["id"] for c in check])
    pts = Points(ids, np.zeros((n + 1, 3)), np.vstack([survey, [[np.nan] * 3]]), np.array(["check"] * (n + 1)))
    h = triangulation_honesty(res, pts)
    assert [r["verdict"] for r in h["rows"]] == ["honest"] * 3 and h["rows"][0]["n"] == n
    assert any("survey sigmas" in s and "added" in s for s in h["notes"])
    assert {r["verdict"] for r in triangulation_honesty(res)["rows"]} == {"sigmas too small"}   # survey left out
    pts.sigma[:5] = np.nan
    assert any("other 5 are taken as exact" in s for s in triangulation_honesty(res, pts)["notes"])
    none = triangulation_honesty(SimpleNamespace(check=[{"id": "K", "evaluated": False}]))
    assert none["rows"] == [] and none["notes"][0].startswith("No check point evaluated")


def test_flow_truth_rows():
    n = 60
    rows = []
    for i in range(n):
        r = {"t_gps": float(i)}
        for a, s in (("roll", 0.2), ("pitch", 0.3), ("yaw", 0.5)):
            r[f"sigma_{a}"], r[f"err_{a}"] = s, float(RNG.normal() * s)
        r["sigma_agl_m"], r["err_agl_m"] = 2.0, float(RNG.normal() * 2.0)
        rows.append(r)
    rows.append({"t_gps": 99.0, "sigma_roll": 0.2, "sigma_pitch": 0.2, "sigma_yaw": 0.2, "sigma_agl_m": 1.0})
    run = SimpleNamespace(rows=rows, table2={"n_pairs": n}, summary={})
    h = flow_honesty(run)
    assert [r["quantity"] for r in h["rows"]] == ["roll", "pitch", "yaw", "height above ground"]
    assert all(r["n"] == n and r["verdict"] == "honest" for r in h["rows"])
    assert h["rows"][0]["unit"] == "deg" and h["rows"][3]["unit"] == "m"
    assert flow_honesty(SimpleNamespace(rows=rows, table2=None, summary={}))["notes"][0].startswith("No reference")


T0 = 1300190400.0


def _trajectories(tmp: Path, n: int = 1001) -> tuple[Path, Path]:
    """A true trajectory and an estimate of it with honest sigmas (position N/E/D m, roll/pitch/heading deg)."""
    t = T0 + 0.1 * np.arange(n)
    lat, lon, h = 23.7 + 1e-5 * np.arange(n), 120.6 + 2e-5 * np.arange(n), 340.0 + 0.01 * np.arange(n)
    rph = np.column_stack([np.full(n, 1.0), np.full(n, 2.0), np.full(n, 35.0)])
    sig = np.array([0.02, 0.03, 0.05, 0.01, 0.01, 0.04])
    true = Trajectory(t, lat, lon, h, np.zeros((n, 3)), rph)
    p = geodetic_to_ecef(lat, lon, h)
    d_ned = RNG.normal(size=(n, 3)) * sig[:3]
    p_est = p + np.einsum("nji,nj->ni", R_ecef_to_ned_at(p), d_ned)      # NED error -> ECEF
    g = ecef_to_geodetic(p_est)
    est = Trajectory(t, g[:, 0], g[:, 1], g[:, 2], np.zeros((n, 3)), rph + RNG.normal(size=(n, 3)) * sig[3:],
                     np.tile(sig, (n, 1)))
    write_trajectory(tmp / "true_trajectory.csv", true)
    write_trajectory(tmp / "trajectory.csv", est)
    return tmp / "true_trajectory.csv", tmp / "trajectory.csv"


def _eops(tmp: Path, n: int = 60) -> tuple[Path, Path]:
    img = np.array([f"IMG_{i:04d}.JPG" for i in range(n)])
    xyz = np.column_stack([254000 + 70.0 * np.arange(n), np.full(n, 2622000.0), np.full(n, 340.0)])
    opk = np.tile([1.0, -0.5, 35.0], (n, 1))
    sig = np.array([0.05, 0.05, 0.03, 0.002, 0.002, 0.001])
    write_eop(tmp / "true_eop.csv", EOP(img, xyz, opk))
    write_eop(tmp / "eop.csv", EOP(img[1:], xyz[1:] + RNG.normal(size=(n - 1, 3)) * sig[:3],
                                   opk[1:] + RNG.normal(size=(n - 1, 3)) * sig[3:], np.tile(sig, (n - 1, 1))))
    return tmp / "true_eop.csv", tmp / "eop.csv"


def test_campaign_gathers_the_steps_tables_and_the_truth(tmp_path):
    """report.json's `honesty`: the triangulation's and the check's rows (their step named), the POS step's line
    that it has no reference, and the truth's rows: mounting, trajectory and EOPs (image by image, the truth's
    files relative to truth.json)."""
    (tmp_path / "truth").mkdir()
    traj_true, traj = _trajectories(tmp_path)
    eop_true, eop = _eops(tmp_path)
    traj_true.rename(tmp_path / "truth" / "trajectory.csv")
    eop_true.rename(tmp_path / "truth" / "eop.csv")
    tri = {"warnings": [], "honesty": honesty_section(honesty_rows(np.full((4, 1), 0.01), [0.01], ["E"],
                                                                   "check points"), ["tri note"])}
    chk = {"checks": {}, "honesty": check_honesty({"joint": _check_json(np.array([0.01, 0.01, 0.02]), None)})}
    pos = {"mode": "tc", "honesty": no_reference("No reference: none in TC.")}
    for name, d in (("tri.json", tri), ("check.json", chk), ("pos.json", pos)):
        (tmp_path / name).write_text(json.dumps(d))
    mount = {"method": "joint", "lever_arm_m": [0.13, -0.06, 0.17], "lever_arm_sigma_m": [0.01, 0.01, 0.01],
             "boresight_R_cam_to_body": np.eye(3).tolist(), "boresight_sigma_deg": [0.01, 0.01, 0.01],
             "delay_s": -0.1395, "delay_sigma_s": 0.0005,
             "covariance": (np.diag([0.0005] + [0.01] * 3 + [np.radians(0.01)] * 3) ** 2).tolist()}
    (tmp_path / "mounting.json").write_text(json.dumps(mount))
    truth = {"lever_arm_m": [0.12, -0.06, 0.18], "delay_s": -0.14, "boresight_R_cam_to_body": np.eye(3).tolist(),
             "files": {"trajectory": "truth/trajectory.csv (true IMU trajectory)", "eop": "truth/eop.csv (true)"}}
    (tmp_path / "truth.json").write_text(json.dumps(truth))
    files = {"camera": {}, "triangulation": {"summary": tmp_path / "tri.json", "eop": eop},
             "pos": {"summary": tmp_path / "pos.json", "trajectory": traj}, "check": {"check": tmp_path / "check.json"},
             "mounts": {"joint": {"mounting": tmp_path / "mounting.json"}}}
    d = collect({"truth": "truth.json", "_base": tmp_path}, tmp_path, files)
    h = d["honesty"]
    assert _row(h["rows"], "E", "triangulation: check points")["n"] == 4
    assert _row(h["rows"], "U", "check: check points, joint")["verdict"] == "honest"
    assert "pos: No reference: none in TC." in h["notes"] and "triangulation: tri note" in h["notes"]
    assert _row(h["rows"], "delay", "truth: mounting joint")["error_over_sigma_rms"] == pytest.approx(1.0, rel=1e-6)
    assert _row(h["rows"], "lever arm x/y/z", "truth: mounting joint")["n"] == 3
    for q in ("N", "E", "D", "roll", "pitch", "heading"):
        r = _row(h["rows"], q, "truth: POS trajectory")
        assert r["n"] == 1001 and r["verdict"] == "honest", r
    for q in ("X", "Y", "Z", "omega", "phi", "kappa"):
        r = _row(h["rows"], q, "truth: triangulation EOPs")
        assert r["n"] == 59 and r["verdict"] == "honest", r
    bare = collect({}, tmp_path, {"camera": {}, "triangulation": {}, "pos": {}, "check": {}, "mounts": {}})
    assert bare["honesty"]["rows"] == [] and bare["honesty"]["notes"][0].startswith("No reference")
