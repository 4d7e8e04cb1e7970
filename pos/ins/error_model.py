"""IMU error models by grade: noise densities, bias processes, turn-on biases, scale and misalignment.

All fields are SI (rad, m, s): white noise as random-walk densities (gyro_arw rad/sqrt(s), accel_vrw
m/s/sqrt(s)); in-run bias instability as a first-order Gauss-Markov process (sigma and correlation
time); bias random walks (rad/s/sqrt(s), m/s^2/sqrt(s)); turn-on bias sigmas (rad/s, m/s^2); scale
factor and misalignment sigmas (fraction, rad). `ImuGrade.from_datasheet` takes the usual datasheet
units (deg/sqrt(h), deg/h, m/s/sqrt(h), mg, ppm, deg). The smoother reads these through
`dgcal.pos.smoother.preintegration.imu_noise_from_grade`.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

G0 = 9.80665
DEG = np.pi / 180.0


@dataclass(frozen=True)
class ImuGrade:
    """An IMU error model in SI units (see module docstring for the meaning of each field)."""

    name: str
    gyro_arw: float
    accel_vrw: float
    gyro_bias_instability: float
    gyro_bias_tau_s: float
    accel_bias_instability: float
    accel_bias_tau_s: float
    gyro_bias_rw: float = 0.0
    accel_bias_rw: float = 0.0
    gyro_bias_sigma: float = 0.0
    accel_bias_sigma: float = 0.0
    gyro_scale_sigma: float = 0.0
    accel_scale_sigma: float = 0.0
    gyro_misalign_sigma: float = 0.0
    accel_misalign_sigma: float = 0.0

    @classmethod
    def from_datasheet(cls, name: str, *, gyro_arw_deg_rt_h: float, gyro_bias_instability_deg_h: float,
                       accel_vrw_m_s_rt_h: float, accel_bias_instability_mg: float,
                       gyro_bias_tau_s: float = 1000.0, accel_bias_tau_s: float = 1000.0,
                       gyro_turn_on_deg_s: float = 0.0, accel_turn_on_mg: float = 0.0,
                       gyro_rrw_deg_h_rt_h: float = 0.0, accel_rrw_m_s2_rt_h: float = 0.0,
                       gyro_scale_ppm: float = 0.0, accel_scale_ppm: float = 0.0,
                       gyro_misalign_deg: float = 0.0, accel_misalign_deg: float = 0.0) -> "ImuGrade":
        """A grade from datasheet units: deg/sqrt(h), deg/h, m/s/sqrt(h), mg, deg/s, ppm, deg."""
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
        """The grade in datasheet units (for reports)."""
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
    def from_dict(cls, d: dict) -> "ImuGrade":
        """Inverse of `as_dict`."""
        return cls(**d)

    def scaled(self, factor: float) -> "ImuGrade":
        """The same grade with every stochastic error multiplied by `factor` (e.g. 0 for a perfect IMU)."""
        kw = {k: v * factor for k, v in asdict(self).items() if k != "name" and not k.endswith("_tau_s")}
        return replace(self, name=f"{self.name}x{factor:g}", **kw)


# Datasheet-class numbers. ADIS16488A: gyro in-run bias 5.1 deg/h, ARW 0.26 deg/sqrt(h); accel in-run
# bias 0.07 mg, VRW 0.029 m/s/sqrt(h) (rounded up a little for margin). ADIS16405 (the seed 000 unit):
# 25.2 deg/h, 2.0 deg/sqrt(h), 0.2 mg, 0.2 m/s/sqrt(h). Turn-on biases are the residuals after the
# factory calibration a user would see (smaller than the datasheet's worst-case repeatability).
GRADES: dict[str, ImuGrade] = {
    "navigation": ImuGrade.from_datasheet(
        "navigation", gyro_arw_deg_rt_h=0.002, gyro_bias_instability_deg_h=0.003, accel_vrw_m_s_rt_h=0.0006,
        accel_bias_instability_mg=0.01, gyro_bias_tau_s=3600.0, accel_bias_tau_s=3600.0,
        gyro_turn_on_deg_s=0.005 / 3600.0, accel_turn_on_mg=0.025, gyro_scale_ppm=5.0, accel_scale_ppm=100.0,
        gyro_misalign_deg=0.001, accel_misalign_deg=0.001),
    "adis16488": ImuGrade.from_datasheet(
        "adis16488", gyro_arw_deg_rt_h=0.3, gyro_bias_instability_deg_h=6.0, accel_vrw_m_s_rt_h=0.029,
        accel_bias_instability_mg=0.1, gyro_bias_tau_s=1000.0, accel_bias_tau_s=1000.0,
        gyro_turn_on_deg_s=0.01, accel_turn_on_mg=2.0, gyro_scale_ppm=500.0, accel_scale_ppm=500.0,
        gyro_misalign_deg=0.02, accel_misalign_deg=0.02),
    "adis16405": ImuGrade.from_datasheet(
        "adis16405", gyro_arw_deg_rt_h=2.0, gyro_bias_instability_deg_h=25.2, accel_vrw_m_s_rt_h=0.2,
        accel_bias_instability_mg=0.2, gyro_bias_tau_s=500.0, accel_bias_tau_s=500.0,
        gyro_turn_on_deg_s=0.05, accel_turn_on_mg=5.0, gyro_scale_ppm=2000.0, accel_scale_ppm=2000.0,
        gyro_misalign_deg=0.05, accel_misalign_deg=0.05),
    "consumer": ImuGrade.from_datasheet(
        "consumer", gyro_arw_deg_rt_h=0.6, gyro_bias_instability_deg_h=30.0, accel_vrw_m_s_rt_h=0.09,
        accel_bias_instability_mg=0.5, gyro_bias_tau_s=100.0, accel_bias_tau_s=100.0,
        gyro_turn_on_deg_s=0.2, accel_turn_on_mg=20.0, gyro_scale_ppm=3000.0, accel_scale_ppm=3000.0,
        gyro_misalign_deg=0.2, accel_misalign_deg=0.2),
}


def imu_grade(grade: str | ImuGrade | dict) -> ImuGrade:
    """A grade by preset name ('navigation', 'adis16488', 'adis16405', 'consumer'), dict or instance."""
    if isinstance(grade, ImuGrade):
        return grade
    if isinstance(grade, dict):
        return ImuGrade.from_dict(grade)
    key = str(grade).lower().replace("-", "").replace("_", "")
    aliases = {"tactical": "adis16488", "mems": "consumer", "nav": "navigation"}
    key = aliases.get(key, key)
    if key not in GRADES:
        raise ValueError(f"unknown IMU grade {grade!r} (one of {', '.join(GRADES)})")
    return GRADES[key]
