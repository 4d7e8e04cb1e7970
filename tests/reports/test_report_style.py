"""One readable report style for every verb (issue 30): numbers by unit (no e± notation), summary keys as words,
lists as numbers with units, units in every numeric column's header, the glossary, one method naming, improvement
as (old − new)/old, one distortion sign, the boresight as angles about the axes of its sigmas.

The fast tests build pages from small made-up records; `test_every_verbs_report_renders_clean` (marker slow, a few
minutes) runs every verb on simulated and real data and reads each report as headless Chromium renders it."""
from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dgcal.reports.boresight import boresight_angles_deg, nominal_mounting
from dgcal.reports.glossary import label, method_name
from dgcal.reports.html import HtmlReport
from dgcal.reports.mounting import check_report_html, improvement_pct, mount_report_html
from dgcal.reports.units import fmt_number, fmt_value, gps_time, pm

sys.path.insert(0, str(Path(__file__).parent))
from report_text import parse, problems  # noqa: E402


# ------------------------------------------------------------------------------------------------ units, labels
@pytest.mark.parametrize("unit", ["m", "°", "deg", "px", "ms", "s", "ppm", "%", "m/s", "°/h", "mg", ""])
def test_no_e_notation_at_any_magnitude(unit):
    for v in np.concatenate([10.0 ** np.arange(-12, 13), -10.0 ** np.arange(-12, 13) * 1.2345]):
        for coordinate in (False, True):
            text = fmt_number(v, unit, coordinate)
            shown = len(text.split(".")[1]) if "." in text else 0      # the resolution the text claims
            assert "e" not in text.lower(), (v, unit, text)
            assert abs(float(text) - v) <= max(1e-3 * abs(v), 0.51 * 10.0 ** -shown), (v, unit, text)


def test_numbers_at_their_units_resolution():
    assert fmt_number(2622600.123456, "m", coordinate=True) == "2622600.123"      # coordinates in full
    assert fmt_number(0.0123456, "m") == "0.012"                                   # metres to the mm
    assert fmt_value([0.00107, 9.09e-4], "m") == "0.00107, 0.00091"                # one column, one resolution
    assert fmt_number(1.23456, "px") == "1.23" and fmt_number(12.3456, "ms") == "12.35"
    assert fmt_number(35.123456789, "deg", coordinate=True) == "35.12345679"
    assert fmt_value([1, 2.5, None], "m") == "1, 2.500, –" and fmt_value(True) == "yes"
    assert pm(0.01234, 0.00041, "m") == "+0.01234 ± 0.00041" and pm(-140.2, 2.13, "ms") == "-140.20 ± 2.13"
    assert gps_time(1300200000.0) == "week 2149, 484800.000 s of week (2021-03-19 14:40:00 GPST)"


def test_summary_keys_read_as_words_with_units():
    assert label("n_images") == "images"
    assert label("gyro_bias_deg_h_mean") == "gyro bias, mean (°/h)"
    assert label("nav_frame_origin_deg_m") == "navigation frame origin (lat, lon °, h m)"
    assert label("ddp") == "double-differenced phase"
    assert label("median_sigma_3d_m") == "median σ 3D (m)"                     # not listed: humanised
    assert label("clock_offset_ms") == "clock offset (ms)" and label("some_new_key") == "some new key"
    assert label("already words (m)") == "already words (m)"
    assert [method_name(n) for n in ("proposed", "traditional", "iso", "joint")] == ["joint", "two-step",
                                                                                    "integrated", "joint"]


def test_a_page_of_a_raw_summary_reads_clean():
    """Keys, lists, GPS times, sigma columns and a key other helpers may add later, through the shared builder."""
    summary = {"n_images": 61, "sigma0": 0.8480398148607204, "t_start_gps": 1300200000.0,
               "gyro_bias_deg_h_mean": [0.123456, -2.5e-4, 3.0], "nav_frame_origin_deg_m": [35.1234567891, 139.5, 45.2],
               "rms_3d_m": 9.09e-4, "base_ecef_m": [-3962108.6731, 3381309.5742, 3668678.6383],
               "datum_statement": "EPSG:32651, heights ellipsoidal", "new_sigma_px": 1.2e-5, "converged": True}
    rep = HtmlReport("test page")
    rep.headline([("lever arm x (m)", pm(0.1, 0.0012, "m"))])
    rep.kv_table(summary.items())
    rep.table(["point", "dE (m)", "σE (m)", "images"], [["A", 0.00107, 9.09e-4, 3], ["B", -0.0123, 0.0021, 4]])
    rep.warnings(["correlation 0.97 between delay and lever_x"])
    page = rep.render()
    assert problems(page) == []
    text = " ".join(parse(page).text)
    for words in ("images", "σ0 (a posteriori, unitless)", "week 2149", "gyro bias, mean (°/h)",
                  "0.12346, -0.00025, 3.00000", "35.12345679", "-3962108.673", "datum statement", "new σ (px)",
                  "lever x", "Glossary", "yes"):
        assert words in text, words
    assert "A 0.001 0.00091 3" in text and "B -0.012 0.00210 4" in text         # a column: one resolution


def test_keys_a_later_version_adds_show_as_words():
    """The triangulation page's further results: a new statement with its flat details, nested records left to the
    JSON file, keys the page shows elsewhere skipped."""
    from dgcal.reports.tables import flat_pairs
    s = {"sigma0": 1.0, "datum": {"text": "3 GCPs and 40 camera centres fix the block", "n_centres": 40,
                                  "centre_sigma_m": [0.02, 0.02, 0.05], "precision": {"weak": False}},
         "new_offset_deg": 0.00012, "runs": [{"a": 1}]}
    pairs = flat_pairs(s, skip={"sigma0"})
    assert pairs == [("datum", "3 GCPs and 40 camera centres fix the block"), ("datum: centres", 40),
                     ("datum: centre σ (m)", [0.02, 0.02, 0.05]), ("new_offset_deg", 0.00012)]
    rep = HtmlReport("t")
    rep.kv_table(pairs)
    page = rep.render()
    assert problems(page) == [] and "new offset (°)" in page and "0.020, 0.020, 0.050" in page


# ------------------------------------------------------------------------------------------------ mounting, check
def _mounting(method: str, R_cam_to_body: np.ndarray, delay_sigma: float = 0.002) -> dict:
    return {"method": method, "lever_arm_m": [-0.3012, 0.1198, 0.2003], "lever_arm_sigma_m": [0.0021, 0.0019, 0.0032],
            "boresight_R_cam_to_body": R_cam_to_body.tolist(), "boresight_sigma_deg": [0.0031, 0.0029, 0.0102],
            "delay_s": -0.1402 if delay_sigma else 0.0, "delay_sigma_s": delay_sigma, "n_epochs": 61,
            "parameters": ["delay", "lever_x", "lever_y", "lever_z", "bore_x", "bore_y", "bore_z"],
            "correlation": np.eye(7).tolist(), "sigma0": 1.02, "redundancy": 359, "rejected_epochs": [],
            "warnings": ["high correlation -0.97 between delay and lever_x"], "per_epoch": {}}


def test_boresight_angles_are_about_the_body_axes_of_the_sigmas():
    """R_cam_to_body = Exp(θ) R_nominal: the angles come back, about body axes (as mounting.json's sigmas)."""
    R_nom = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])   # down-looking, image top forward
    theta = np.array([0.9, -0.6, 1.4])
    R = Rotation.from_rotvec(np.radians(theta)).as_matrix() @ R_nom
    got, nominal = boresight_angles_deg(R)
    np.testing.assert_allclose(got, theta, atol=1e-9)
    np.testing.assert_array_equal(nominal, R_nom)
    assert np.array_equal(nominal_mounting(np.eye(3)), np.eye(3))


def test_mounting_page_headline_angles_with_their_sigmas():
    R = Rotation.from_rotvec(np.radians([0.9, -0.6, 1.4])).as_matrix() @ np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.]])
    page = mount_report_html(_mounting("proposed", R), {"traditional": _mounting("traditional", R, 0.0)})
    assert problems(page) == []
    text = " ".join(parse(page).text)
    assert "+0.9000 ± 0.0031, -0.6000 ± 0.0029, +1.4000 ± 0.0102" in text        # θ about body x, y, z ± σ
    assert "-140.20 ± 2.00" in text and "two-step" in text and "'proposed'" in text   # the alias named once
    assert text.count("proposed") == 1 and "traditional" not in text.replace("'traditional'", "")


def _check(rms2d: float, rms3d: float) -> dict:
    axes = {"E": rms2d / 1.4, "N": rms2d / 1.4, "U": rms3d / 2, "2D": rms2d, "3D": rms3d}
    pts = [{"id": f"C{i}", "err_enu": [0.01 * i, -0.02, 0.03], "sigma_pred_enu": [0.02, 0.02, 0.04],
            "ref": [500000.0 + 100 * i, 4000000.0 + 50 * i, 40.0]} for i in range(4)]
    return {"stats": {"n": 4, "avg": axes, "std": axes, "rms": axes},
            "budget": {"sources": {"image measurements": axes, "POS position": axes}, "magnitudes": {},
                       "predicted_rms": axes, "achieved_rms": axes, "mean_flying_height_m": 120.4,
                       "mean_speed_m_s": 8.123},
            "asprs_2023": {"n_checkpoints": 4, "RMSE_x": 0.01, "RMSE_y": 0.012, "RMSE_H": 0.0156, "RMSE_V": 0.03,
                           "product_RMSE_H": 0.017, "product_RMSE_V": 0.031, "warnings": []},
            "points": pts, "warnings": []}


def test_improvement_is_old_minus_new_over_old():
    checks = {"traditional": _check(0.412, 0.5), "proposed": _check(0.08, 0.1)}
    imp = improvement_pct(checks)
    assert imp["proposed"]["2D"] == pytest.approx(100 * (0.412 - 0.08) / 0.412)
    assert imp["proposed"]["3D"] == pytest.approx(80.0)
    page = check_report_html(checks, {"proposed": {"2D": 415.0, "3D": 400.0}})
    assert problems(page) == []
    text = " ".join(parse(page).text)
    assert "Improvement over the two-step method" in text and "80.0" in text and "400" not in text
    assert "(old − new) / old" in text


def test_spp_page_from_its_series_reads_clean(tmp_path):
    """The SPP page (drawn from plain arrays): the signals' lists, sigmas and the residual table by unit."""
    from dgcal.reports.gnss_page import draw_spp_report
    rng = np.random.default_rng(1)
    t = np.arange(60.0)
    series = {"t_fix_s": t, "enu_m": rng.normal(size=(60, 3)) * 0.4, "sigma_enu_m": np.full((60, 3), 0.4),
              "reference_known": True, "t_s": t, "n_sat": np.full(60, 23), "pdop": np.full(60, 1.08),
              "residuals_m": {f"G{k:02d}": (t, rng.normal(size=60) * 0.5) for k in range(1, 9)},
              "sky_azim_deg": rng.uniform(0, 360, 50), "sky_elev_deg": rng.uniform(10, 90, 50)}
    summary = {"rinex_obs": "/data/SEPT078M1.21O", "rinex_nav": "/data/SEPT078M.21P",
               "signals": {"G": ["C1C", "C2W"], "E": ["C1C"]}, "n_epochs": 60, "n_fixed": 60, "mean_n_sat": 23.4,
               "median_pdop": 1.0834, "median_sigma_enu_m": [0.371, 0.401, 0.887], "n_rejected": 0}
    page = draw_spp_report(tmp_path / "gnss_report.html", series, summary).read_text()
    assert problems(page) == []
    text = " ".join(parse(page).text)
    assert "G: C1C, C2W; E: C1C" in text and "0.371, 0.401, 0.887" in text and 'class="lead"' in page


# ------------------------------------------------------------------------------------------------ distortion
def test_distortion_sign_is_positive_outward_in_both_reports():
    """Pincushion (K1 > 0) is drawn positive, barrel (K1 < 0) negative: the camera and the campaign report draw
    the one curve (dgcal.reports.distortion)."""
    from dgcal.calib.camera.models import Fraser7
    from dgcal.reports import campaign, camera, distortion
    for k1, sign in ((2e-2, 1.0), (-2e-2, -1.0)):
        cam = Fraser7((4000, 3000), [3000.0, 2000.0, 1500.0, k1, 0, 0, 0, 0, 0, 0])
        for _r, rad, _ in distortion.distortion_curves(cam).values():
            assert np.all(sign * rad[1:] > 0) and abs(rad[0]) < 1e-6
    assert camera.model_distortion_figure is distortion.distortion_figure
    assert campaign.distortion_figure is distortion.distortion_figure


# ------------------------------------------------------------------------------------------------ every verb
def _chromium_dom(page: Path, tmp: Path) -> str:
    """The page as headless Chromium parsed and rendered it (its DOM), after a screenshot that must not be
    blank."""
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    assert exe, "chromium is required (apt-get install chromium)"
    profile = tmp / f"profile_{page.parent.name}_{page.stem}"
    profile.mkdir(exist_ok=True)
    common = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking",
              "--disable-component-update", "--disable-sync", f"--user-data-dir={profile}"]
    png = tmp / f"{page.parent.name}_{page.stem}.png"
    r = subprocess.run(common + [f"--screenshot={png}", "--window-size=1280,1600", page.resolve().as_uri()],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and png.is_file(), r.stderr[-2000:]
    from PIL import Image
    assert np.asarray(Image.open(png).convert("L"), float).std() > 10, page      # text and tables, not blank
    r = subprocess.run(common + ["--dump-dom", page.resolve().as_uri()], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "<table" in r.stdout, r.stderr[-2000:]
    return r.stdout


def _run(argv: list[str]) -> None:
    from dgcal.cli import main
    assert main(argv) == 0, argv


@pytest.mark.slow
def test_every_verbs_report_renders_clean(shared_data, tmp_path):
    """Every verb's report (camera, triangulate, pos spp/ppk/tc/ukf, mount ×3, check, the campaign, sync, flow,
    georef) from simulated data (the demo's campaign, the low-cost simulators) and the shared RINEX files, read
    as Chromium renders it: no raw key, no e± notation, no Python repr, a unit on every numeric column."""
    from dgcal.campaign import run_campaign
    from dgcal.sim.campaign import simulate_campaign
    sim, out = tmp_path / "sim", tmp_path / "out"
    simulate_campaign(sim / "campaign", seed=3)
    run_campaign(sim / "campaign" / "campaign.toml", out / "campaign")
    _run(["simulate", "lowcost", "--out", str(sim / "lc"), "--duration", "120", "--seed", "1"])
    _run(["pos", "--mode", "ukf", "--imu", str(sim / "lc/imu.csv"), "--gnss", str(sim / "lc/gnss.csv"), "--events",
          str(sim / "lc/events.csv"), "--imu-grade", "adis16405", "--truth", str(sim / "lc/truth_trajectory.csv"),
          "--out", str(out / "ukf"), "--no-progress"])
    _run(["simulate", "logger", "--out", str(sim / "log"), "--duration", "120", "--seed", "1"])
    _run(["sync", "--gnss-log", str(sim / "log/gnss_log.csv"), "--logger", str(sim / "log/logger.csv"), "--images",
          str(sim / "log/images.csv"), "--end-gap", "0.4", "--max-time-error", "0.02", "--out", str(out / "sync")])
    _run(["simulate", "flight", "--no-render", "--out", str(sim / "flight"), "--seed", "0"])
    _run(["georef", "--camera", str(sim / "flight/camera.json"), "--measurements", str(sim / "flight/measurements.csv"),
          "--eop", str(sim / "flight/truth_eop.csv"), "--crs", "EPSG:32651", "--height", "120.0", "--sigma-px", "0.3",
          "--out", str(out / "georef")])
    _run(["simulate", "forward-camera", "--out", str(sim / "fc"), "--duration", "20", "--fps", "2", "--seed", "1"])
    _run(["flow", "--images", str(sim / "fc/frames"), "--gnss", str(sim / "fc/gnss_velocity.csv"), "--camera",
          str(sim / "fc/camera.json"), "--truth", str(sim / "fc/truth_trajectory.csv"), "--ground-height", "20",
          "--out", str(out / "flow"), "--no-progress"])
    obs, nav = str(shared_data / "rinex-sept/SEPT078M1.21O"), str(shared_data / "rinex-sept/SEPT078M.21P")
    ref = ["--reference", "-3962108.673", "3381309.574", "3668678.638"]
    _run(["pos", "--mode", "spp", "--rinex-obs", obs, "--rinex-nav", nav, *ref, "--no-progress", "--out",
          str(out / "spp")])
    _run(["pos", "--mode", "ppk", "--rinex-obs", obs, "--rinex-nav", nav, "--rinex-base",
          str(shared_data / "rinex-3034/3034078M1.21O"), "--base-position", "-3959400.631", "3385704.533",
          "3667523.111", *ref, "--no-progress", "--out", str(out / "ppk")])
    pages = sorted(out.rglob("*.html"))
    names = {p.relative_to(out).as_posix() for p in pages}
    for want in ("campaign/report.html", "campaign/camera/report.html", "campaign/triangulation/report.html",
                 "campaign/pos/report.html", "campaign/check/check.html", "ukf/report.html", "sync/report.html",
                 "georef/georef.html", "flow/report.html", "spp/gnss_report.html", "ppk/gnss_report.html"):
        assert want in names, (want, names)
    assert sum(n.startswith("campaign/mount_") for n in names) == 3
    found = {}
    for p in pages:
        dom = _chromium_dom(p, tmp_path)
        bad = problems(dom)
        if bad:
            found[p.relative_to(out).as_posix()] = bad[:10]
        assert re.search(r"<h1>", dom) and 'class="lead"' in dom, p     # the one skeleton: title, headline first
    assert not found, found
