"""The IMU error model, `ImuErrorModel`: noise densities, bias processes, turn-on biases, scale and misalignment.

One type serves everyone: the presets (`GRADES`, `imu_grade(name)`), the simulator
(`dgcal.sim.imu.simulate_imu` draws one realisation of it) and the smoother and UKF, which carry
`model.smoother_noise()` (the same type with the Gauss-Markov instability folded into the bias random walks).

All fields are SI (rad, m, s), body FRD: white noise as random-walk densities (gyro_arw rad/sqrt(s), accel_vrw
m/s/sqrt(s)); in-run bias instability as a first-order Gauss-Markov process (sigma and correlation
time); bias random walks (rad/s/sqrt(s), m/s^2/sqrt(s)); turn-on bias sigmas (rad/s, m/s^2); scale
factor and misalignment sigmas (fraction, rad). `ImuErrorModel.from_datasheet` takes the usual datasheet
units (deg/sqrt(h), deg/h, m/s/sqrt(h), mg, ppm, deg).
"""
from __future__ import annotations

import tomllib
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from dgcal.fields.constants import G0
from dgcal.fields.errors import InputError
from dgcal.fields.io.validate import toml_numbers_in_range

DEG = np.pi / 180.0


@dataclass(frozen=True)
class ImuErrorModel:
    """An IMU error model in SI units, body FRD (see the module docstring for the meaning of each field)."""

    name: str
    gyro_arw: float
    accel_vrw: float
    gyro_bias_instability: float = 0.0
    gyro_bias_tau_s: float = 1000.0
    accel_bias_instability: float = 0.0
    accel_bias_tau_s: float = 1000.0
    gyro_bias_rw: float = 0.0
    accel_bias_rw: float = 0.0
    gyro_bias_sigma: float = 0.0
    accel_bias_sigma: float = 0.0
    gyro_scale_sigma: float = 0.0
    accel_scale_sigma: float = 0.0
    gyro_misalign_sigma: float = 0.0
    accel_misalign_sigma: float = 0.0
    gyro_range: float = 0.0      # rad/s, measurement range (0: not given)
    accel_range: float = 0.0     # m/s^2 (0: not given)

    @classmethod
    def from_datasheet(cls, name: str, *, gyro_arw_deg_rt_h: float, gyro_bias_instability_deg_h: float,
                       accel_vrw_m_s_rt_h: float, accel_bias_instability_mg: float,
                       gyro_bias_tau_s: float = 1000.0, accel_bias_tau_s: float = 1000.0,
                       gyro_turn_on_deg_s: float = 0.0, accel_turn_on_mg: float = 0.0,
                       gyro_rrw_deg_h_rt_h: float = 0.0, accel_rrw_m_s2_rt_h: float = 0.0,
                       gyro_scale_ppm: float = 0.0, accel_scale_ppm: float = 0.0,
                       gyro_misalign_deg: float = 0.0, accel_misalign_deg: float = 0.0) -> "ImuErrorModel":
        """A model from datasheet units: deg/sqrt(h), deg/h, m/s/sqrt(h), mg, deg/s, ppm, deg."""
        return cls(name=name,
                   gyro_arw=gyro_arw_deg_rt_h * DEG / 60.0,
                   accel_vrw=accel_vrw_m_s_rt_h / 60.0,
                   gyro_bias_instability=gyro_bias_instability_deg_h * DEG / 3600.0,
                   gyro_bias_tau_s=gyro_bias_tau_s,
                   accel_bias_instability=accel_bias_instability_mg * 1e-3 * G0,
                   accel_bias_tau_s=accel_bias_tau_s,
                   gyro_bias_rw=gyro_rrw_deg_h_rt_h * DEG / 3600.0 / 60.0,
                   accel_bias_rw=accel_rrw_m_s2_rt_h / 60.0,
                   gyro_bias_sigma=gyro_turn_on_deg_s * DEG,
                   accel_bias_sigma=accel_turn_on_mg * 1e-3 * G0,
                   gyro_scale_sigma=gyro_scale_ppm * 1e-6, accel_scale_sigma=accel_scale_ppm * 1e-6,
                   gyro_misalign_sigma=gyro_misalign_deg * DEG, accel_misalign_sigma=accel_misalign_deg * DEG)

    def datasheet(self) -> dict:
        """The model in datasheet units (for reports)."""
        return {
            "name": self.name,
            "gyro_arw_deg_rt_h": self.gyro_arw / DEG * 60.0,
            "gyro_bias_instability_deg_h": self.gyro_bias_instability / DEG * 3600.0,
            "gyro_bias_tau_s": self.gyro_bias_tau_s,
            "gyro_turn_on_deg_s": self.gyro_bias_sigma / DEG,
            "accel_vrw_m_s_rt_h": self.accel_vrw * 60.0,
            "accel_bias_instability_mg": self.accel_bias_instability / G0 * 1e3,
            "accel_bias_tau_s": self.accel_bias_tau_s,
            "accel_turn_on_mg": self.accel_bias_sigma / G0 * 1e3,
            "gyro_scale_ppm": self.gyro_scale_sigma * 1e6, "accel_scale_ppm": self.accel_scale_sigma * 1e6,
            "gyro_misalign_deg": self.gyro_misalign_sigma / DEG,
            "accel_misalign_deg": self.accel_misalign_sigma / DEG,
        }

    def as_dict(self) -> dict:
        """All fields (SI) as a JSON-ready dict."""
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "ImuErrorModel":
        """Inverse of `as_dict`."""
        return cls(**d)

    def scaled(self, factor: float) -> "ImuErrorModel":
        """The same model with every stochastic error multiplied by `factor` (e.g. 0 for a perfect IMU)."""
        kw = {k: v * factor for k, v in asdict(self).items() if k != "name" and not k.endswith("_tau_s")}
        return replace(self, name=f"{self.name}x{factor:g}", **kw)

    def smoother_noise(self) -> "ImuErrorModel":
        """The model as the smoother and the UKF carry it (SI, body FRD): no Gauss-Markov state.

        A first-order Gauss-Markov bias instability b with correlation time T (at least 1 s) becomes a random
        walk of density b*sqrt(2/T), which matches its variance growth over one correlation time, added in
        quadrature to the bias random walk; the turn-on sigmas (the prior on the first bias) are at least the
        instability; small floors keep the bias covariances positive (the gyro's turn-on floor, 1e-9 rad/s, is
        below a navigation grade's 0.005 deg/h: it would otherwise set the heading a static record gyrocompasses
        to). White noise, scale factor and misalignment sigmas are unchanged (the smoother carries the last two as
        turn noise). Idempotent.
        """
        tau_g = max(float(self.gyro_bias_tau_s), 1.0)
        tau_a = max(float(self.accel_bias_tau_s), 1.0)
        gbi, abi = float(self.gyro_bias_instability), float(self.accel_bias_instability)
        grw, arw_b = float(self.gyro_bias_rw), float(self.accel_bias_rw)
        gyro_bias_rw = np.hypot(grw, gbi * np.sqrt(2.0 / tau_g)) if gbi else grw
        accel_bias_rw = np.hypot(arw_b, abi * np.sqrt(2.0 / tau_a)) if abi else arw_b
        return replace(self, gyro_arw=float(self.gyro_arw), accel_vrw=float(self.accel_vrw),
                       gyro_bias_instability=0.0, accel_bias_instability=0.0,
                       gyro_bias_rw=max(float(gyro_bias_rw), 1e-9), accel_bias_rw=max(float(accel_bias_rw), 1e-8),
                       gyro_bias_sigma=max(float(self.gyro_bias_sigma), gbi, 1e-9),
                       accel_bias_sigma=max(float(self.accel_bias_sigma), abi, 1e-6),
                       gyro_scale_sigma=float(self.gyro_scale_sigma),
                       gyro_misalign_sigma=float(self.gyro_misalign_sigma),
                       accel_scale_sigma=float(self.accel_scale_sigma),
                       accel_misalign_sigma=float(self.accel_misalign_sigma))

    @property
    def has_gauss_markov_bias(self) -> bool:
        """True if the model has an in-run bias instability (the smoother needs `smoother_noise()` first)."""
        return bool(self.gyro_bias_instability or self.accel_bias_instability)


# Datasheet-class numbers. ADIS16488A: gyro in-run bias 5.1 deg/h, ARW 0.26 deg/sqrt(h); accel in-run
# bias 0.07 mg, VRW 0.029 m/s/sqrt(h) (rounded up a little for margin). ADIS16405 (the seed 000 unit):
# 25.2 deg/h, 2.0 deg/sqrt(h), 0.2 mg, 0.2 m/s/sqrt(h). Turn-on biases are the residuals after the
# factory calibration a user would see (smaller than the datasheet's worst-case repeatability).
GRADES: dict[str, ImuErrorModel] = {
    "navigation": ImuErrorModel.from_datasheet(
        "navigation", gyro_arw_deg_rt_h=0.002, gyro_bias_instability_deg_h=0.003, accel_vrw_m_s_rt_h=0.0006,
        accel_bias_instability_mg=0.01, gyro_bias_tau_s=3600.0, accel_bias_tau_s=3600.0,
        gyro_turn_on_deg_s=0.005 / 3600.0, accel_turn_on_mg=0.025, gyro_scale_ppm=5.0, accel_scale_ppm=100.0,
        gyro_misalign_deg=0.001, accel_misalign_deg=0.001),
    "adis16488": ImuErrorModel.from_datasheet(
        "adis16488", gyro_arw_deg_rt_h=0.3, gyro_bias_instability_deg_h=6.0, accel_vrw_m_s_rt_h=0.029,
        accel_bias_instability_mg=0.1, gyro_bias_tau_s=1000.0, accel_bias_tau_s=1000.0,
        gyro_turn_on_deg_s=0.01, accel_turn_on_mg=2.0, gyro_scale_ppm=500.0, accel_scale_ppm=500.0,
        gyro_misalign_deg=0.02, accel_misalign_deg=0.02),
    "adis16405": ImuErrorModel.from_datasheet(
        "adis16405", gyro_arw_deg_rt_h=2.0, gyro_bias_instability_deg_h=25.2, accel_vrw_m_s_rt_h=0.2,
        accel_bias_instability_mg=0.2, gyro_bias_tau_s=500.0, accel_bias_tau_s=500.0,
        gyro_turn_on_deg_s=0.05, accel_turn_on_mg=5.0, gyro_scale_ppm=2000.0, accel_scale_ppm=2000.0,
        gyro_misalign_deg=0.05, accel_misalign_deg=0.05),
    "consumer": ImuErrorModel.from_datasheet(
        "consumer", gyro_arw_deg_rt_h=0.6, gyro_bias_instability_deg_h=30.0, accel_vrw_m_s_rt_h=0.09,
        accel_bias_instability_mg=0.5, gyro_bias_tau_s=100.0, accel_bias_tau_s=100.0,
        gyro_turn_on_deg_s=0.2, accel_turn_on_mg=20.0, gyro_scale_ppm=3000.0, accel_scale_ppm=3000.0,
        gyro_misalign_deg=0.2, accel_misalign_deg=0.2),
}


def imu_grade(grade: str | ImuErrorModel | dict) -> ImuErrorModel:
    """An error model by preset name ('navigation', 'adis16488', 'adis16405', 'consumer'), dict, instance, or the
    path of a datasheet TOML file (`read_imu_datasheet`)."""
    if isinstance(grade, ImuErrorModel):
        return grade
    if isinstance(grade, dict):
        return ImuErrorModel.from_dict(grade)
    if isinstance(grade, Path) or str(grade).lower().endswith(".toml"):
        return read_imu_datasheet(grade)
    key = str(grade).lower().replace("-", "").replace("_", "")
    aliases = {"tactical": "adis16488", "mems": "consumer", "nav": "navigation"}
    key = aliases.get(key, key)
    if key not in GRADES:
        raise ValueError(f"unknown IMU grade {grade!r} (one of {', '.join(GRADES)})")
    return GRADES[key]


# --------------------------------------------------------------------------------------------- datasheet TOML
# accepted keys of a datasheet TOML: name -> factor to the SI field (None: handled separately)
_RT_H = 60.0                     # 1/sqrt(s) per 1/sqrt(h)
_GYRO_KEYS = {
    "arw_deg_rt_h": ("gyro_arw", DEG / _RT_H), "noise_density_deg_s_rt_hz": ("gyro_arw", DEG),
    "noise_density_mdps_rt_hz": ("gyro_arw", DEG * 1e-3),
    "bias_instability_deg_h": ("gyro_bias_instability", DEG / 3600.0),
    "bias_instability_deg_s": ("gyro_bias_instability", DEG),
    "bias_tau_s": ("gyro_bias_tau_s", 1.0),
    "turn_on_deg_s": ("gyro_bias_sigma", DEG), "turn_on_deg_h": ("gyro_bias_sigma", DEG / 3600.0),
    "rrw_deg_h_rt_h": ("gyro_bias_rw", DEG / 3600.0 / _RT_H),
    "rrw_deg_s2_rt_hz": ("gyro_bias_rw", DEG),
    "scale_ppm": ("gyro_scale_sigma", 1e-6), "scale_percent": ("gyro_scale_sigma", 1e-2),
    "misalign_deg": ("gyro_misalign_sigma", DEG), "misalign_percent": ("gyro_misalign_sigma", 1e-2),
    "range_deg_s": ("gyro_range", DEG),
}
_ACCEL_KEYS = {
    "vrw_m_s_rt_h": ("accel_vrw", 1.0 / _RT_H), "noise_density_ug_rt_hz": ("accel_vrw", 1e-6 * G0),
    "noise_density_m_s2_rt_hz": ("accel_vrw", 1.0),
    "bias_instability_mg": ("accel_bias_instability", 1e-3 * G0),
    "bias_instability_ug": ("accel_bias_instability", 1e-6 * G0),
    "bias_tau_s": ("accel_bias_tau_s", 1.0),
    "turn_on_mg": ("accel_bias_sigma", 1e-3 * G0), "turn_on_ug": ("accel_bias_sigma", 1e-6 * G0),
    "rrw_m_s2_rt_h": ("accel_bias_rw", 1.0 / _RT_H), "rrw_ug_rt_hz": ("accel_bias_rw", 1e-6 * G0),
    "scale_ppm": ("accel_scale_sigma", 1e-6), "scale_percent": ("accel_scale_sigma", 1e-2),
    "misalign_deg": ("accel_misalign_sigma", DEG), "misalign_percent": ("accel_misalign_sigma", 1e-2),
    "range_g": ("accel_range", G0), "range_m_s2": ("accel_range", 1.0),
}


def imu_model_from_datasheet_dict(d: dict, source: str = "datasheet") -> ImuErrorModel:
    """An ImuErrorModel from a datasheet dict: `name`, optional `base` (a preset whose values are kept where the
    datasheet is silent), `[gyro]` and `[accel]` tables with unit-suffixed keys (ARW deg/sqrt(h) or noise density
    deg/s/sqrt(Hz), bias instability deg/h, VRW m/s/sqrt(h) or ug/sqrt(Hz), mg, ppm, %, range deg/s and g)."""
    allowed = {"name", "base", "gyro", "accel", "model", "manufacturer", "notes"}
    bad = [k for k in d if k not in allowed]
    if bad:
        raise InputError(f"unknown key {bad[0]!r} (one of {', '.join(sorted(allowed))})", source, field=bad[0])
    base = d.get("base")
    if base is not None:
        try:
            start = asdict(imu_grade(str(base)))
        except ValueError as exc:
            raise InputError(str(exc), source, field="base") from None
    else:
        start = asdict(ImuErrorModel("datasheet", 0.0, 0.0))
    start["name"] = str(d.get("name", Path(source).stem if source else "datasheet"))
    seen: dict[str, str] = {}
    for sect, keys in (("gyro", _GYRO_KEYS), ("accel", _ACCEL_KEYS)):
        tab = d.get(sect, {})
        if not isinstance(tab, dict):
            raise InputError("must be a table", source, field=sect)
        for k, v in tab.items():
            if k not in keys:
                raise InputError(f"unknown key (one of {', '.join(keys)})", source, field=f"{sect}.{k}")
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v < 0:
                raise InputError(f"must be a number >= 0, not {v!r}", source, field=f"{sect}.{k}")
            name, factor = keys[k]
            if name in seen:
                raise InputError(f"{name} given twice ({seen[name]} and {k})", source, field=f"{sect}.{k}")
            seen[name] = k
            start[name] = float(v) * factor
    for req in ("gyro_arw", "accel_vrw"):
        if start[req] <= 0:
            raise InputError("the datasheet needs the white noise (gyro arw_deg_rt_h or noise_density_deg_s_rt_hz, "
                             "accel vrw_m_s_rt_h or noise_density_ug_rt_hz) or a base preset", source,
                             field="gyro" if req == "gyro_arw" else "accel")
    for tau in ("gyro_bias_tau_s", "accel_bias_tau_s"):
        if start[tau] <= 0:
            raise InputError("must be > 0", source, field=tau.replace("_bias_tau_s", ".bias_tau_s"))
    return ImuErrorModel(**start)


def read_imu_datasheet(path: str | Path) -> ImuErrorModel:
    """`--imu-grade FILE.toml`: an IMU error model from its datasheet figures (see
    `imu_model_from_datasheet_dict`)."""
    path = Path(path)
    if not path.is_file():
        raise InputError("file not found", path)
    try:
        text = path.read_text(encoding="utf-8")
        d = tomllib.loads(text)
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read: {exc}", path) from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"not valid TOML: {str(exc).split(' (at line')[0]}", path, getattr(exc, "lineno", None)) \
            from None
    return imu_model_from_datasheet_dict(toml_numbers_in_range(d, path, text), str(path))
