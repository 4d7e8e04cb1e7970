"""GNSS observation types shared by the front end (SPP), the simulator and the TC smoother.

Conventions (see docs/gnss.md):

* Time: ``t_gps`` is continuous GPS time in seconds, ``week * 604800 + sow``, of the receiver
  epoch as stamped by the receiver clock (the receiver clock error is part of the estimated
  clock bias, as usual for code positioning).
* Satellite states are evaluated at the signal transmission time
  ``t_tx = t_gps - pr_m / c - sat_clk_s`` and then rotated about the Earth's axis by the signal
  travel time (Sagnac), i.e. they are expressed in the ECEF frame *at reception time*. The
  geometric range is therefore simply ``rho = |sat_pos_ecef - p_rx_ecef|`` with no further
  Earth-rotation term.
* ``sat_clk_s`` is the satellite clock offset in seconds for the signal used, including the
  relativistic (eccentricity) term and the group delay of that signal (GPS/QZSS ``TGD``,
  Galileo ``BGD``, BeiDou ``TGD1``).
* ``iono_m`` and ``tropo_m`` are the modelled slant delays (Klobuchar, Saastamoinen) at the
  approximate receiver position ``p_approx_ecef`` of the epoch, in metres (positive = delay).

The *corrected pseudorange* is::

    pr_corr_m = pr_m + c * sat_clk_s - iono_m - tropo_m
              = |sat_pos_ecef - p_rx_ecef| + c * dt_rx[system] + noise(sigma_pr_m)

where ``c * dt_rx[CLOCK_GROUP[system]]`` is the receiver clock bias in metres of the
constellation (one per clock group: 'G' (GPS and QZSS), 'E', 'C', 'R'), and the *corrected range rate* is::

    rr_corr_mps = range_rate_mps + c * sat_clk_drift
                = e . (sat_vel_ecef - v_rx_ecef) + c * ddt_rx + noise(sigma_rr_mps)

with ``e = (sat_pos_ecef - p_rx_ecef) / rho`` the unit line of sight from receiver to satellite
and ``c * ddt_rx`` the receiver clock drift in m/s (common to all systems). ``sat_vel_ecef`` is
the time derivative of ``sat_pos_ecef`` with respect to reception time (it contains the
light-time and Earth-rotation rate terms), so the formula above needs no further correction.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dgcal.fields.constants import C_LIGHT, SECONDS_PER_WEEK
SYSTEMS = ("G", "E", "C", "J")  # GPS, Galileo, BeiDou, QZSS: every mode's default
ALL_SYSTEMS = SYSTEMS + ("R",)  # and GLONASS, which SPP alone uses (when asked for)
# Receiver clock parameter of each system: QZSS L1 C/A is interoperable with GPS and shares its
# receiver clock bias (as in RTKLIB); Galileo, BeiDou and GLONASS have their own (inter-system bias; GLONASS's
# inter-frequency code biases between its FDMA channels are left in the code noise, as in RTKLIB).
CLOCK_GROUP = {"G": "G", "J": "G", "E": "E", "C": "C", "R": "R"}


def split_gps_time(t_gps):
    """Continuous GPS seconds -> (week, seconds of week)."""
    t = np.asarray(t_gps, dtype=float)
    week = np.floor(t / SECONDS_PER_WEEK).astype(int)
    return week, t - week * SECONDS_PER_WEEK


@dataclass
class GnssEpoch:
    """All satellites of one receiver epoch; per-satellite arrays have length ``n``.

    Raw measurements: ``pr_m`` (code pseudorange, m), ``doppler_hz`` (Hz, NaN if absent),
    ``range_rate_mps = -wavelength_m * doppler_hz`` (m/s), ``cn0_dbhz``.
    Front-end products (broadcast ephemeris and models, see the module docstring):
    ``sat_pos_ecef`` (n,3) m, ``sat_vel_ecef`` (n,3) m/s, ``sat_clk_s`` s, ``sat_clk_drift`` s/s,
    ``iono_m``, ``tropo_m`` m, ``elev_deg``, ``azim_deg``, ``sigma_pr_m``, ``sigma_rr_mps``;
    ``sigma_pr_bias_m``: the part of ``sigma_pr_m`` that is a slowly varying error of the satellite (the broadcast
    orbit, clock and atmosphere models' budget; 0 where the models are exact): ``sigma_pr_m`` is its root sum of
    squares with the receiver noise. SPP uses the total per epoch; the smoother carries the bias as a state.
    ``pr2_m``/``wavelength2_m``: a second code of the satellite (raw epochs, None if the file has none); the
    front end forms the ionosphere-free combination from it (``pr_m`` then holds it and ``iono_m`` is 0).
    """

    t_gps: float
    sat: list[str]
    system: np.ndarray
    pr_m: np.ndarray
    doppler_hz: np.ndarray
    range_rate_mps: np.ndarray
    wavelength_m: np.ndarray
    cn0_dbhz: np.ndarray
    sat_pos_ecef: np.ndarray
    sat_vel_ecef: np.ndarray
    sat_clk_s: np.ndarray
    sat_clk_drift: np.ndarray
    iono_m: np.ndarray
    tropo_m: np.ndarray
    elev_deg: np.ndarray
    azim_deg: np.ndarray
    sigma_pr_m: np.ndarray
    sigma_rr_mps: np.ndarray
    p_approx_ecef: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    sigma_pr_bias_m: np.ndarray | None = None
    pr2_m: np.ndarray | None = None          # second-frequency code (m, NaN where absent), raw epochs only
    wavelength2_m: np.ndarray | None = None  # its wavelength (m)

    @property
    def n(self) -> int:
        """Number of satellites in the epoch."""
        return len(self.sat)

    @property
    def pr_corr_m(self) -> np.ndarray:
        """Corrected pseudorange (m): ``rho + c*dt_rx[CLOCK_GROUP[system]] + noise``."""
        return self.pr_m + C_LIGHT * self.sat_clk_s - self.iono_m - self.tropo_m

    @property
    def rr_corr_mps(self) -> np.ndarray:
        """Corrected range rate (m/s): ``e.(v_sat - v_rx) + c*ddt_rx + noise``; NaN without Doppler."""
        return self.range_rate_mps + C_LIGHT * self.sat_clk_drift

    @property
    def sigma_pr_noise_m(self) -> np.ndarray:
        """Sigma (m) of the pseudorange's white receiver noise: ``sigma_pr_m`` without the satellite bias part."""
        if self.sigma_pr_bias_m is None:
            return self.sigma_pr_m
        return np.sqrt(np.clip(self.sigma_pr_m ** 2 - self.sigma_pr_bias_m ** 2, 0.0, None))

    @property
    def clock_group(self) -> np.ndarray:
        """Receiver clock parameter ('G', 'E', 'C', 'R') of each satellite, see ``CLOCK_GROUP``."""
        return np.array([CLOCK_GROUP[s] for s in self.system])

    @property
    def has_doppler(self) -> np.ndarray:
        """Boolean mask of satellites with a Doppler measurement."""
        return np.isfinite(self.range_rate_mps)

    def subset(self, mask) -> "GnssEpoch":
        """A copy holding only the satellites selected by a boolean mask or index array."""
        idx = np.arange(self.n)[mask]
        kw = {}
        for name, val in self.__dict__.items():
            if name == "sat":
                kw[name] = [self.sat[i] for i in idx]
            elif name in ("t_gps", "p_approx_ecef") or val is None:
                kw[name] = val
            else:
                kw[name] = np.asarray(val)[idx]
        return GnssEpoch(**kw)


@dataclass
class GnssObservations:
    """A receiver's epochs in time order plus header information.

    ``p_approx_ecef``: approximate antenna position (m, ECEF), from the RINEX header or SPP.
    ``signals``: the observation code used per system, e.g. ``{'G': 'C1C', 'E': 'C1C'}``.
    ``source``: the file (or 'simulation') the data came from, for error messages and reports.
    ``truth``: for simulated data only, the true receiver states per epoch (see ``dgcal.sim.gnss``).
    """

    epochs: list[GnssEpoch]
    receiver: str = ""
    p_approx_ecef: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    signals: dict[str, str] = field(default_factory=dict)
    source: str = ""
    truth: dict | None = None
    signals2: dict[str, str] = field(default_factory=dict)  # second code per system (ionosphere-free pairs)

    def __len__(self) -> int:
        return len(self.epochs)

    def __iter__(self):
        return iter(self.epochs)

    def __getitem__(self, i: int) -> GnssEpoch:
        return self.epochs[i]

    @property
    def t_gps(self) -> np.ndarray:
        """Epoch times, continuous GPS seconds."""
        return np.array([e.t_gps for e in self.epochs], dtype=float)

    @property
    def systems(self) -> list[str]:
        """Constellations present, in the order of ``ALL_SYSTEMS``."""
        have = set()
        for e in self.epochs:
            have.update(np.unique(e.system).tolist())
        return [s for s in ALL_SYSTEMS if s in have]
