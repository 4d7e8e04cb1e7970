"""The options of each `dgcal pos` mode, one typed dataclass per mode: SPP, PPK, the GNSS/INS smoother (tc, lc) and
the UKF; inputs (files, time span) and the estimators' own options objects as fields.

A mode's tunable settings are the fields of its estimators' options (`settings_groups`): `dgcal pos --set KEY=VALUE`
sets them by name (`group.key`, or the bare key: the first group listing it), and a key of another mode is an error
naming that mode (`dgcal.settings`). Errors of the library name the options' fields (`rinex_obs`, `base.position_ecef`);
the command line maps them to its flags.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from dgcal.pos.gnss.dd import DDOptions
from dgcal.pos.gnss.ppk import PpkOptions
from dgcal.pos.gnss.spp import SppOptions
from dgcal.pos.gnss.spp_mode import RinexInput, SppModeOptions
from dgcal.pos.base_station import BaseStation
from dgcal.pos.ins.integrity import ImuIntegrityOptions
from dgcal.pos.lowcost.ukf import UkfOptions
from dgcal.pos.readers import FixInput, ImuInput
from dgcal.pos.smoother.batch import SmootherOptions


@dataclass
class OutputSettings:
    """What the GNSS/INS modes write beside the smoothed keyframes: the trajectory rate (Hz), the forward solution
    and its normalised innovations (opt-in: the linearised problem's forward pass; `forward_filter`: an iterated
    Kalman filter instead, slower)."""

    rate_hz: float = 10.0
    forward: bool = False
    forward_filter: bool = False


@dataclass
class UkfRunSettings:
    """`--mode ukf` beside the UKF: the LC smoother for comparison (`compare`, at `compare_rate_hz`) and the seconds
    of convergence left out of the accuracy table (`skip_s`)."""

    compare: bool = True
    compare_rate_hz: float = 10.0
    skip_s: float = 30.0


@dataclass
class PpkModeOptions:
    """`dgcal pos --mode ppk`: carrier-phase PPK of `rover` against `base`; epochs without a solution are SPP."""

    rover: RinexInput = field(default_factory=RinexInput)
    base: BaseStation = field(default_factory=BaseStation)
    ppk: PpkOptions = field(default_factory=PpkOptions)
    spp: SppOptions = field(default_factory=SppOptions)
    reference_ecef: tuple[float, float, float] | None = None
    progress: bool = True

    mode = "ppk"

    def settings_groups(self, every: bool = False) -> dict:
        """The options objects whose scalar fields `--set` reaches, in the order bare keys are looked up."""
        return {"ppk": self.ppk, "spp": self.spp}


# old `--set` names of the GNSS/INS modes -> the field they set
INS_SETTING_ALIASES = {"rate": "output.rate_hz", "forward": "output.forward", "forward_filter": "output.forward_filter",
                       "model_errors": "spp.model_errors", "imu_max_gap_s": "imu_checks.max_gap_s",
                       "dd_code_sigma_m": "dd.code_sigma_m", "dd_code": "dd.use_code", "dd_phase": "dd.use_phase",
                       "compare_rate": "ukf_run.compare_rate_hz"}


@dataclass
class InsModeOptions:
    """`dgcal pos --mode tc|lc`: the GNSS/INS smoother. tc: IMU + the rover's RINEX (with `base`: its carrier phase
    double-differenced against the base); lc: IMU + antenna positions (`fixes`, or SPP of the rover's RINEX).
    Lever arm: IMU origin -> GNSS antenna, body FRD, m."""

    mode: str = "lc"                        # tc | lc
    imu: ImuInput = field(default_factory=ImuInput)
    rover: RinexInput = field(default_factory=RinexInput)
    base: BaseStation = field(default_factory=BaseStation)
    fixes: FixInput = field(default_factory=FixInput)
    events: Path | None = None              # camera events (dgcal CSV, DJI MRK, image,utc CSV, PX4 .ulg)
    events_format: str | None = None        # None: recognised by content
    event_images: Path | None = None        # the image folder a DJI MRK's rows are paired with (or None)
    mrk_names: str = "DJI_{index:04d}.JPG"  # an MRK row's image name, or the pattern its index is found in names by
    mrk_pairing: str = "index"              # MRK rows to images: by the index in the names, or "time" (in order)
    lever_arm_m: tuple[float, float, float] | None = None
    imu_grade: str | None = None            # error-model preset or datasheet TOML (None: adis16488)
    estimate_imu_time_offset: bool = False  # the IMU-GNSS time offset from the data, with its sigma
    smoother: SmootherOptions = field(default_factory=SmootherOptions)
    output: OutputSettings = field(default_factory=OutputSettings)
    imu_checks: ImuIntegrityOptions = field(default_factory=ImuIntegrityOptions)
    spp: SppOptions = field(default_factory=SppOptions)
    dd: DDOptions = field(default_factory=DDOptions)
    # tc with a base: PPK's positions and integers start the double differences; no atmosphere budget on its fixed
    # covariances, which the front end never reads (the smoother budgets the atmosphere itself, from `dd`)
    ppk: PpkOptions = field(default_factory=lambda: PpkOptions(solution="forward", iono_ppm=0.0, tropo_zenith_m=0.0))
    progress: bool = True

    SETTING_ALIASES = INS_SETTING_ALIASES

    def settings_groups(self, every: bool = False) -> dict:
        """The options objects whose scalar fields `--set` reaches, in the order bare keys are looked up: the double
        differences' and PPK's only for tc with a base station (`every`: all that the mode can have)."""
        groups = {"smoother": self.smoother, "output": self.output, "imu_checks": self.imu_checks, "spp": self.spp}
        if self.mode == "tc" and (every or self.base.rinex is not None):
            groups.update(dd=self.dd, ppk=self.ppk)
        return groups


@dataclass
class UkfModeOptions(InsModeOptions):
    """`dgcal pos --mode ukf`: seed 000's UKF on antenna positions (`fixes`, or SPP of the rover's RINEX), the LC
    smoother beside it (`ukf_run`), against a true trajectory (`truth`) when given."""

    mode: str = "ukf"
    ukf: UkfOptions = field(default_factory=UkfOptions)
    ukf_run: UkfRunSettings = field(default_factory=UkfRunSettings)
    truth: Path | None = None               # trajectory CSV or a simulator's truth_trajectory.csv

    def settings_groups(self, every: bool = False) -> dict:
        """The UKF's settings first, then the comparison smoother's and the outputs'."""
        return {"ukf": self.ukf, "ukf_run": self.ukf_run, "smoother": self.smoother, "output": self.output,
                "imu_checks": self.imu_checks, "spp": self.spp}


MODE_OPTIONS = {"spp": SppModeOptions, "ppk": PpkModeOptions, "tc": InsModeOptions, "lc": InsModeOptions,
                "ukf": UkfModeOptions}
PosModeOptions = SppModeOptions | PpkModeOptions | InsModeOptions | UkfModeOptions
