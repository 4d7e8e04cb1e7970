"""Names a surveyor reads: the label of every summary key the reports show (words with the unit in parentheses),
a humanised label for keys not listed (underscores to spaces, a unit suffix such as _m, _deg, _deg_h turned into
'(m)', '(°)', '(°/h)'), the method names every report uses, and the glossary of the technical terms a page
uses (σ0, redundancy, error/sigma, fix rate, …), added at the end of every page that uses one."""
from __future__ import annotations

import re

# keys whose words need more than humanising; the unit in parentheses sets how values are formatted
LABELS = {
    "slow_scale": "slow error scale, applied (variance factor, unitless)",
    "slow_scale_file": "slow error scale, the file's own (variance factor, unitless)",
    "slow_dof": "satellites beyond four (count)",
    "n_images": "images", "n_oriented": "images oriented", "n_control": "control points used",
    "n_check": "check points", "n_observations": "observations", "n_points": "ground points",
    "n_tie_points": "tie points", "n_rejected": "observations rejected", "n_epochs": "epochs",
    "n_fixed": "epochs with a fix", "n_events": "events", "n_exposures": "exposures", "n_obs": "observations",
    "n_pairs": "frame pairs", "n_failed": "frame pairs that failed", "n": "count",
    "sigma0": "σ0 (a posteriori, unitless)", "redundancy": "redundancy (observations − unknowns)",
    "rms_px": "RMS residual (px)", "converged": "converged", "crs": "map CRS",
    "gyro_bias_deg_h_mean": "gyro bias, mean (°/h)", "accel_bias_mg_mean": "accelerometer bias, mean (mg)",
    "nav_frame_origin_deg_m": "navigation frame origin (lat, lon °, h m)",
    "t_start_gps": "start (GPS time)", "t_end_gps": "end (GPS time)",
    "ddp": "double-differenced phase", "ddc": "double-differenced code", "dop": "Doppler",
    "ddp_float": "double-differenced phase (float, time-differenced)", "pr": "pseudorange",
    "pos": "GNSS position fix", "vel": "GNSS velocity", "keyframes": "keyframes (one per GNSS epoch)",
    "epochs_with_gnss": "epochs with a GNSS update", "epochs_without_gnss_update": "epochs without a GNSS update",
    "median_sigma_m": "median σ N, E, D (m)", "max_sigma_m": "max σ N, E, D (m)",
    "median_sigma_deg": "median σ roll, pitch, heading (°)", "systems": "constellations",
    "events": "events", "rms_3d_m": "3D RMS (m)", "rms_ned_m": "RMS N, E, D (m)", "max_3d_m": "max 3D (m)",
    "median_pdop": "median PDOP", "mean_n_sat": "satellites used, mean (count)", "rms_normalised": "RMS / σ",
    "share_beyond_3sigma": "share beyond 3σ", "share_beyond_99pc": "share beyond χ² 99 %",
    "nis_per_dim": "NIS per dimension", "nis_mean": "NIS per dimension, mean", "max_abs": "max |e|",
    "clock_drift_ppm": "logger clock drift (ppm)", "clock_offset_s": "logger clock offset (s)",
    "clock_residual_rms_s": "clock fit residual, RMS (s)", "clock_residual_max_s": "clock fit residual, max (s)",
    "clock_max_error_s": "clock error, max (s)", "pps_edges": "PPS edges", "pps_edges_expected": "PPS edges expected",
    "pps_edges_spurious": "PPS edges spurious", "gnss_lost_packets": "GNSS packets lost",
    "logger_lost_packets": "logger packets lost", "exposure_sigma_s_median": "exposure σ, median (s)",
    "event_time_bound_s_max": "event time bound, max (s)", "elev_mask_deg": "elevation mask (°)",
    "rinex_obs": "rover observations (RINEX)", "rinex_base": "base observations (RINEX)",
    "rinex_nav": "navigation (RINEX)", "base_ecef_m": "base position (ECEF X, Y, Z m)",
    "median_ecef_m": "median position (ECEF X, Y, Z m)", "pair_every_s": "a pair every (s)",
    "frame_dt_s": "frames apart (s)", "gnss_velocity_sigma_mps": "GNSS velocity noise per axis (m/s)",
    "fix_rate": "fix rate (fixed epochs / all)", "ppk_fix_rate": "PPK fix rate (fixed epochs / all)",
    "run_time_s": "run time (s)", "time_per_epoch_ms": "time per epoch (ms)",
    "image_size": "image size (px)", "model": "model", "opencv_max_error_px": "OpenCV conversion error, max (px)",
    "fixed_parameters": "parameters held fixed", "clock_drift": "logger clock drift (s/s)",
    "covariance_scaled_by": "covariance scaled by (unitless)", "pos_position": "POS position",
    "pos_attitude": "POS attitude", "image_measurements": "image measurements", "lever_arm": "lever arm",
    "delay": "exposure delay", "rho": "correlation ρ (unitless)", "sigma_f_px": "σf (px)",
    "sigma_f_relative": "σf / f (unitless)", "height_above_ground_m": "height above ground (m)",
    "height_sigma_from_f_m": "height σ from σf (m)", "sigma_height_above_ground_m": "σ height above ground (m)",
    "f_height": "focal length and flying height", "datum": "datum", "trusted": "trusted",
    "principal_point": "principal point and horizontal datum",
    "rho_centres": "correlation ρ with the camera centres' shift (unitless)",
    "rho_ground": "correlation ρ with the ground's shift (unitless)",
    "rho_tilt": "correlation ρ with the block's tilt (unitless)",
    "variance_inflation": "variance inflation 1/(1 − ρ²) (unitless)", "sigma_px": "σ (px)",
    "shift_per_sigma_m": "horizontal shift per σ at the flying height (m)", "mostly": "mostly from",
    "check_normalised_rms": "check points' error/σ RMS", "median_sigma": "median σ of the images",
    "initial_orientation": "initial orientation", "orbits": "orbits and clocks", "imu_grade": "IMU error model",
    "withheld_fixes": "withheld fixes",
    "ionosphere_model": "ionosphere model", "ionosphere": "ionosphere", "scatter_enu_m": "scatter E, N, U (m)",
    "rms_3d_vs_reference_m": "3D RMS against the reference (m)", "median_sigma_3d_m": "median σ 3D (m)",
    "median_ecef_fixed_m": "median position of the fixed epochs (ECEF X, Y, Z m)",
    "reference_ecef_m": "reference position (ECEF X, Y, Z m)", "base_spp_ecef_m": "base SPP position (ECEF X, Y, Z m)",
    "median_sigma_enu_fixed_m": "median σ E, N, U of the fixed epochs (m)", "error_fixed": "error, fixed epochs",
    "error_all": "error, all epochs", "mean_enu_m": "mean E, N, U (m)", "forward_fixed": "forward pass: fixed epochs",
    "backward_fixed": "backward pass: fixed epochs",
    "forward_fixed_by_held_integers": "forward pass: epochs fixed by held integers",
    "backward_fixed_by_held_integers": "backward pass: epochs fixed by held integers",
    "n_dropped_tie_observations": "tie observations dropped",
    "dd_rows_dropped": "double differences dropped as outliers",
}

# words inside keys: abbreviations as written, symbols
WORDS = {"rms": "RMS", "gps": "GPS", "gnss": "GNSS", "imu": "IMU", "ecef": "ECEF", "enu": "E, N, U", "ned": "N, E, D",
         "pdop": "PDOP", "nis": "NIS", "eop": "EOP", "eops": "EOPs", "agl": "AGL", "foe": "FOE", "ppk": "PPK",
         "spp": "SPP", "raim": "RAIM", "utc": "UTC", "crs": "CRS", "3d": "3D", "2d": "2D", "tc": "TC", "lc": "LC",
         "ukf": "UKF", "pps": "PPS", "arw": "angle random walk",
         "vrw": "velocity random walk", "dg": "DG", "gcp": "GCP", "asprs": "ASPRS", "rinex": "RINEX",
         "sat": "satellites",
         "sats": "satellites", "lt4": "fewer than 4", "dof": "dof", "std": "std", "avg": "mean", "pc": "%",
         "rmse": "RMSE", "opk": "ω, φ, κ", "rpy": "roll, pitch, yaw", "xyz": "X, Y, Z", "sigma": "σ",
         "obs": "observations",
         "dd": "double-differenced", "ddp": "double-differenced phase", "ddc": "double-differenced code",
         "dop": "Doppler", "pr": "pseudorange", "cv": "cross-validation", "chi2": "χ²", "mps": "m/s"}

# unit suffixes of keys, the longest first (a pair such as _deg_h before _h)
UNIT_SUFFIXES = ((("deg", "rt", "h"), "°/√h"), (("m", "s", "rt", "h"), "m/s/√h"),
                 (("deg", "h"), "°/h"), (("deg", "s"), "°/s"), (("m", "s"), "m/s"), (("mps",), "m/s"),
                 (("deg",), "°"), (("px",), "px"), (("mm",), "mm"), (("cm",), "cm"), (("ms",), "ms"),
                 (("ppm",), "ppm"), (("mg",), "mg"), (("pct",), "%"), (("m",), "m"), (("s",), "s"),
                 (("hz",), "Hz"), (("arcsec",), "″"), (("rad",), "rad"))
STATS = {"mean": "mean", "median": "median", "max": "max", "min": "min", "rms": "RMS", "std": "std"}

_RAW_KEY = re.compile(r"^[A-Za-z][A-Za-z0-9]*(_[A-Za-z0-9]+)+$")


def is_raw_key(text) -> bool:
    """Whether `text` looks like a snake_case summary key rather than words (`n_images`, `sigma0` as listed)."""
    t = str(text)
    return bool(_RAW_KEY.match(t)) or t in LABELS and t.isidentifier() and t.islower()


def split_key(key: str) -> tuple[str, str, str]:
    """A snake_case key's words (humanised), its statistic (mean, max, … or '') and its unit from the suffix."""
    toks = [t for t in str(key).split("_") if t]
    stat = ""
    if len(toks) > 1 and toks[-1].lower() in STATS:
        stat = STATS[toks.pop().lower()]
    unit = ""
    for suffix, u in UNIT_SUFFIXES:
        k = len(suffix)
        if len(toks) > k and tuple(t.lower() for t in toks[-k:]) == suffix:
            unit, toks = u, toks[:-k]
            break
    if len(toks) > 1 and toks[0] == "n":
        toks = toks[1:]
    words = " ".join(WORDS.get(t.lower(), t) for t in toks)
    return words, stat, unit


def label(key) -> str:
    """The words for a summary key: from LABELS, else humanised ('median_sigma_3d_m' → 'median σ 3D (m)')."""
    k = str(key)
    if k in LABELS:
        return LABELS[k]
    if not is_raw_key(k):
        return k
    words, stat, unit = split_key(k)
    text = words + (f", {stat}" if stat else "")
    return f"{text} ({unit})" if unit else text


# method names: the same in every report; the seed paper's names are aliases, mentioned once per page
METHOD_NAMES = {"joint": "joint", "proposed": "joint", "two-step": "two-step", "traditional": "two-step",
                "iso": "integrated", "integrated": "integrated"}
METHOD_NOTE = ("Methods: joint (the seed paper's 'proposed' method: delay, lever arm and boresight estimated "
               "together), two-step (the seed paper's 'traditional' method: per-epoch lever arm and boresight at the "
               "event time, averaged, delay 0) and integrated (image measurements in the adjustment).")


def method_name(name) -> str:
    """The report's name of a mounting method or its alias ('proposed' → 'joint'); other names unchanged."""
    return METHOD_NAMES.get(str(name).strip().lower(), str(name))


# the technical terms a page may use: (pattern found in the page's text, term, explanation)
GLOSSARY = (
    (r"σ0|sigma0", "σ0 (a posteriori)",
     "The square root of the weighted sum of squared residuals over the redundancy: 1 when the residuals are as "
     "large as the observation sigmas assumed; the reported sigmas are scaled by it."),
    (r"\bredundancy\b", "redundancy", "Observations minus unknowns: how many checks the adjustment has."),
    (r"error/sigma|error / sigma|\|error\|/sigma|RMS / σ", "error/sigma",
     "An error divided by the sigma the run claimed for it; honest sigmas give an RMS near 1."),
    (r"\bfix rate\b|fixed / float", "fix rate, fixed / float",
     "Fixed: the carrier-phase ambiguities resolved to integers (centimetre level); float: estimated as real "
     "numbers (decimetres); the fix rate is the share of fixed epochs."),
    (r"median ratio|ambiguity test", "ratio (ambiguity test)",
     "The second-best integer solution's residuals over the best's: above the threshold (usually 3) the fix is "
     "accepted."),
    (r"PDOP", "PDOP", "Position dilution of precision: how the satellite geometry scales range errors into "
                      "position errors."),
    (r"\bNIS\b", "NIS", "Normalised innovation squared: an innovation squared over its predicted covariance, per "
                        "dimension 1 when the filter's sigmas are right."),
    (r"double-differenced|double differences", "double-differenced (DD)",
     "Rover minus base, satellite minus reference satellite: receiver and satellite clocks cancel."),
    (r"\bRAIM\b", "RAIM", "Receiver autonomous integrity monitoring: a satellite whose residual fails the test is "
                          "left out."),
    (r"ASPRS", "ASPRS 2023", "The ASPRS Positional Accuracy Standards for Digital Geospatial Data, edition 2 "
                             "(2023): RMSE horizontal (H) and vertical (V) on check points."),
    (r"\bEOPs?\b", "EOP", "Exterior orientation parameters of an image: projection centre X, Y, Z and the angles "
                          "ω, φ, κ."),
    (r"boresight", "boresight", "The rotation between the camera and the IMU body axes (R_cam_to_body)."),
    (r"lever arm", "lever arm", "The vector from the IMU origin to the camera's perspective centre, body axes (x "
                                "forward, y right, z down)."),
    (r"exposure delay|\bdelay\b", "exposure delay", "Exposure time minus the event time the logger recorded (s)."),
    (r"χ²/dof|chi2/dof", "χ²/dof", "Chi-square per degree of freedom: 1 when the values scatter as their sigmas "
                                   "say."),
    (r"\bkeyframes?\b", "keyframe", "An epoch of the smoother's state (one per GNSS epoch); the IMU bridges "
                                    "between them."),
    (r"improvement", "improvement", "(old − new) / old × 100 %: the share of the old method's RMS error the new "
                                    "method removes."),
    (r"\bFOE\b", "FOE", "Focus of expansion: the image point the optic flow radiates from (the direction of travel)."),
    (r"\bAGL\b|height above ground", "AGL", "Height above ground level."),
    (r"GPST", "GPST", "GPS time: continuous, ahead of UTC by the leap seconds (18 s since 2017)."),
)


_KEY_IN_TEXT = re.compile(r"(?<![\w./\\-])[a-z][a-z0-9]*(?:_[a-z0-9]+)+(?![\w.(/\\-])")


def humanise_text(text: str) -> str:
    """`text` (a library's warning, say) with the snake_case keys in it as words ('lever_x' → 'lever x'); file
    names and paths are left alone."""
    return _KEY_IN_TEXT.sub(lambda m: label(m.group(0)), str(text))


def glossary_for(text: str) -> list[tuple[str, str]]:
    """The glossary entries (term, explanation) whose term occurs in `text`, in the glossary's order."""
    return [(term, what) for pattern, term, what in GLOSSARY if re.search(pattern, text)]
