"""`dgcal pos --mode spp`: its options (`SppModeOptions`: the rover's RINEX input and the SPP settings) and its run.

Kept apart from the other modes' options (`dgcal.pos.mode_options`): SPP imports only the GNSS modules, so a call
costs little more than the positioning itself.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from dgcal.pos.gnss.gnss_files import is_ubx_file
from dgcal.pos.gnss.spp import SppOptions, SppRun, spp_files


@dataclass
class RinexInput:
    """A receiver's RINEX observations with the broadcast navigation file(s) and the time span to use."""

    rinex_obs: Path | None = None           # RINEX 2.10/2.11/3.x observations
    rinex_nav: tuple[Path, ...] = ()        # broadcast navigation file(s), merged; SP3 orbits and RINEX clock files
    #                                         among them are precise products (recognised by content)
    t_start: float | None = None            # first epoch, continuous GPS seconds
    t_end: float | None = None              # last epoch, continuous GPS seconds

    def __post_init__(self) -> None:
        # a u-blox UBX log carries its own ephemerides (RXM-SFRBX): without navigation files it is its own
        if self.rinex_obs and not self.rinex_nav and is_ubx_file(self.rinex_obs):
            self.rinex_nav = (Path(self.rinex_obs),)


@dataclass
class SppModeOptions:
    """`dgcal pos --mode spp`: code (and Doppler) single-point positioning of every epoch of `rover`."""

    rover: RinexInput = field(default_factory=RinexInput)
    spp: SppOptions = field(default_factory=SppOptions)
    reference_ecef: tuple[float, float, float] | None = None   # known antenna position (ECEF m) for the summary
    progress: bool = True

    mode = "spp"

    def settings_groups(self, every: bool = False) -> dict:
        """The options objects whose scalar fields `--set` reaches, in the order bare keys are looked up."""
        return {"spp": self.spp}


def run_spp(opts: SppModeOptions) -> SppRun:
    """SPP of every epoch of the rover's RINEX (ECEF m with covariances), its summary, the 3D RMS against
    `reference_ecef` when given."""
    r = opts.rover
    return spp_files(r.rinex_obs, tuple(r.rinex_nav), opts.spp, t_start=r.t_start, t_end=r.t_end,
                     reference_ecef=opts.reference_ecef, progress=opts.progress)
