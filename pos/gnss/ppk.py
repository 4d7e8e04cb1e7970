"""Carrier-phase PPK of a moving or static rover: double-differenced code and phase, an EKF with the rover's
position and velocity and float ambiguities, LAMBDA with validation, integers held per arc, cycle-slip handling,
forward + backward passes combined (docs/gnss.md, "PPK").

State: rover antenna position and velocity (ECEF m, m/s; `NK` states), beyond `iono_est_km` of baseline the slant
single-difference ionosphere at L1 of every satellite (m), and one between-receiver single-difference ambiguity per
satellite and frequency slot (cycles, from ``amb0``); the double differences are formed per system and slot against
the highest satellite, so a change of reference satellite needs nothing. Measurements (m), per system and slot,
satellite i and reference r::

    DD phase = DD(omc_phase) = -(e_i - e_r).(x - x0) + lam (N_i - N_r) - kappa (I_i - I_r) + noise
    DD code  = DD(omc_code)  = -(e_i - e_r).(x - x0) + kappa (I_i - I_r) + noise

with ``omc`` the zero-difference observed-minus-computed values of ``dgcal.pos.gnss.carrier`` (rover at the
linearisation point ``x0``, base at its known position and its own epoch: any base rate, the age of
differential is reported). Zero-difference noise ``sigma0 * sqrt(1/2 + 1/(2 sin^2 el))`` at each receiver, scaled
by variance factors that the post-fit residuals estimate; the DD covariance is the exact one of the differencing.
Kinematic (default): constant velocity driven by white acceleration (cars, UAVs; the velocity comes from the phase,
Doppler is not needed); static: constant position. Slow phase errors (multipath, antenna, atmosphere) are a random
walk of the ambiguities.

Every epoch: slips (LLI bit 0, a change of bit 1, power failure, gap, geometry-free, Melbourne-Wuebbena of either
receiver) reset the ambiguity of that arc; new ambiguities start at phase minus code; the update is iterated at the
new position; post-fit DD residuals are data-snooped (the worst phase outlier resets its ambiguity, a code outlier
is dropped), and an epoch whose residuals fail their chi-square gets its float covariance inflated. Then the fixed
solution: the float state conditioned on the integers held from earlier fixes (not fed back) plus LAMBDA
(``dgcal.pos.gnss.ambiguity``) on the rest, accepted when the fixed residuals pass; else LAMBDA on the ambiguities
above the AR mask (no half cycle, `min_lock`): full set, else a partial set; **a fix is accepted only if** (1) the
ratio test passes, (2) the ambiguity float-to-fixed distance and (3) the position shift are within their
chi-square quantiles (1 - alpha) with the slow phase errors added, and (4) the DD phase residuals of the fixed
solution pass a chi-square test with no residual beyond ``outlier_w`` sigma; otherwise the epoch is float. An
arc's integer is held once ``hold_after`` validated fixes gave it alike. The backward pass is the same run in
reverse time; ``combine`` merges the two per epoch, float covariances calibrated on the epochs both passes fix.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy.linalg.lapack import dgesdd

from dgcal.fields.constants import C_LIGHT
from dgcal.pos.gnss.ambiguity import AmbiguityFix, fixed_solution, gesv, resolve
from dgcal.pos.gnss.carrier import (CarrierObs, ZeroDiff, first_code, satellite_geometry, slip_flags,
                                   transmission_states, zero_difference)
from dgcal.pos.gnss.chi2_points import chi2_limit
from dgcal.pos.gnss.ppk_design import NK, dd_rows, dd_system
from dgcal.pos.gnss.ppk_merge import combine
from dgcal.pos.gnss.rinex import BroadcastNav

STATUS = ("none", "single", "float", "fixed")


@dataclass
class PpkOptions:
    """Settings of the PPK engine (sigmas are zero-difference values at the zenith)."""

    systems: str = "GECJ"
    n_freq: int = 3
    elev_mask_deg: float = 10.0
    ar_elev_mask_deg: float = 10.0
    dynamics: str = "kinematic"           # kinematic (constant velocity, white acceleration) | static
    solution: str = "combined"            # combined | forward | backward
    code_sigma_m: float = 0.3
    phase_sigma_m: float = 0.003
    ratio_threshold: float = 3.0
    partial: bool = True
    p0: float = 0.999                     # success rate of a partial set
    min_fix_amb: int = 4
    min_lock: int = 0                     # epochs an arc must have been tracked before its ambiguity is fixed
    hold: bool = True                     # hold the integers of validated fixes (not fed back into the float)
    hold_after: int = 3                   # validated fixes that must give an arc's integer alike before it is held
    alpha: float = 1e-3                   # false-alarm probability of the validation tests
    pos_sigma_m: float = 30.0             # prior sigma of the first position (and after a gap)
    vel_sigma_mps: float = 30.0           # kinematic: prior sigma of the first velocity (and after a gap)
    accel_h_mps2: float = 3.0             # kinematic: white horizontal acceleration, m/s^2 per sqrt(Hz) (cars, UAVs)
    accel_v_mps2: float = 1.5             # kinematic: the same, vertical
    amb_sigma_cycles: float = 30.0        # prior sigma of a new ambiguity
    amb_q_cycles2_s: float = 1e-8         # ambiguity random walk beside the one of the phase biases below
    slip_gf_m: float = 0.05
    slip_mw_sigma: float = 4.0
    max_gap_s: float = 30.0               # ambiguity reset after a longer gap
    max_age_s: float = 30.0               # base epochs older/newer than this are not used
    outlier_w: float = 5.0                # post-fit w-test threshold (standardised residual)
    code_corr_s: float = 60.0             # correlation time of code errors (multipath); 0: white
    phase_bias_sigma_m: float = 0.01      # time-correlated SD phase errors (multipath, PCV, differential atmosphere)
    noise_window_s: float = 30.0          # residual-based variance factors of phase and code over ~this time; 0: off
    phase_bias_tau_s: float = 60.0        # their correlation time: the ambiguities' random walk 2 sigma^2 / tau
    iono_ppm: float = 0.5                 # differential ionosphere: slant, mm per km of baseline (1/sin el)
    iono_est_km: float = 10.0             # estimate it beyond this baseline (a slant single difference per satellite,
    #                                       prior iono_ppm): shorter ones fix better without (0: always, inf: never)
    iono_tau_s: float = 600.0             # its correlation time (first-order Gauss-Markov)
    tropo_zenith_m: float = 0.0015        # rover zenith troposphere error left by the model (fixed-position budget)
    humidity: float = 0.7                 # Saastamoinen at both receivers with 70 % humidity (RTKLIB's REL_HUMI): the
    #                                       wet delay's height gradient matters for a UAV 100 m above its base


@dataclass
class PassResult:
    """One filter pass, per rover epoch: status index into ``STATUS``, solution and float (ECEF m, 3x3 m^2)."""

    status: np.ndarray
    p: np.ndarray
    P: np.ndarray
    p_float: np.ndarray
    P_float: np.ndarray
    ratio: np.ndarray
    n_sat: np.ndarray
    n_amb: np.ndarray
    n_fixed_amb: np.ndarray
    chi2: np.ndarray                       # (N, 3): ambiguity, position and residual test statistics / limits
    reason: list
    resid: list = field(default_factory=list)   # per epoch {(sat, slot): DD phase residual m} of the solution


@dataclass
class PpkResult:
    """PPK of every rover epoch: the combined (or chosen) solution plus both passes and diagnostics."""

    t_gps: np.ndarray
    status: np.ndarray
    p: np.ndarray
    P: np.ndarray
    ratio: np.ndarray
    n_sat: np.ndarray
    n_fixed_amb: np.ndarray
    age_s: np.ndarray
    forward: PassResult | None
    backward: PassResult | None
    sats: list[str]
    signals_rover: dict
    signals_base: dict
    slips_rover: int
    slips_base: int
    options: PpkOptions
    info: dict = field(default_factory=dict)
    pair: CarrierPair | None = field(default=None, repr=False)   # the prepared receivers (for the TC smoother)

    @property
    def fix(self) -> np.ndarray:
        """Status names per epoch ('fixed', 'float', 'single', 'none')."""
        return np.array([STATUS[s] for s in self.status])


class CarrierPair:
    """A rover and a base receiver prepared for double differencing (shared by both PPK passes and the TC
    smoother's carrier-phase factors): common satellites and frequency slots, the base epoch of every rover
    epoch (nearest within ``max_age_s``), slip flags of both receivers and the cached zero-difference models
    (``base_zd(j)``, ``rover_zd(k, x0)``; ECEF m)."""

    def __init__(self, rover: CarrierObs, base: CarrierObs, nav: BroadcastNav, base_pos: np.ndarray,
                 opts: PpkOptions):
        self.nav, self.opts = nav, opts
        self.base_pos = np.asarray(base_pos, float)
        F = min(rover.n_slots, base.n_slots, opts.n_freq)
        sats = [s for s in rover.sats if s in base.sats and s[0] in opts.systems]
        self.sats, self.F = sats, F
        ir = [rover.sats.index(s) for s in sats]
        ib = [base.sats.index(s) for s in sats]
        self.t = rover.t_gps
        self.tb = base.t_gps
        fr, fb = rover.freq_hz[ir, :F], base.freq_hz[ib, :F]
        same = np.isfinite(fr) & np.isfinite(fb) & (np.abs(fr - fb) < 1.0)
        self.freq = np.where(same, fr, np.nan)
        self.lam = C_LIGHT / self.freq
        self.Pr, self.Lr = rover.P[:, ir, :F], rover.L[:, ir, :F]
        self.Pb, self.Lb = base.P[:, ib, :F], base.L[:, ib, :F]
        sr = slip_flags(rover, opts.slip_gf_m, opts.slip_mw_sigma, opts.max_gap_s)[:, ir, :F]
        sb = slip_flags(base, opts.slip_gf_m, opts.slip_mw_sigma, opts.max_gap_s)[:, ib, :F]
        self.slips_rover = int(sr[1:].sum())
        self.slips_base = int(sb[1:].sum())
        self.Cr = np.cumsum(sr, axis=0)
        self.Cb = np.cumsum(sb, axis=0)
        # half-cycle ambiguity not yet resolved (LLI bit 1): the phase is used, its ambiguity not fixed
        self.half_r = (rover.lli[:, ir, :F] & 2) > 0
        self.half_b = (base.lli[:, ib, :F] & 2) > 0
        # base epoch for every rover epoch: nearest within max_age
        if len(self.tb):
            j = np.clip(np.searchsorted(self.tb, self.t), 1, max(len(self.tb) - 1, 1))
            j0 = np.clip(j - 1, 0, len(self.tb) - 1)
            j1 = np.clip(j, 0, len(self.tb) - 1)
            pick = np.where(np.abs(self.tb[j1] - self.t) < np.abs(self.tb[j0] - self.t), j1, j0)
            self.jb = pick
            self.age = self.t - self.tb[pick]
            self.jb[np.abs(self.age) > opts.max_age_s] = -1
        else:
            self.jb = np.full(len(self.t), -1)
            self.age = np.full(len(self.t), np.nan)
        self.system = np.array([s[0] for s in sats])
        self.kappa = np.nan_to_num((1575.42e6 / self.freq) ** 2)      # ionosphere of each slot against L1
        # the systems present in the order their groups of double differences are formed, and each satellite's
        present = [s for s in "GECJ" if s in set(self.system.tolist())]
        self.n_sys = len(present)
        self.sys_id = np.array([present.index(s) for s in self.system], dtype=np.int64)
        self.obs_keys = np.empty((len(sats), F), dtype=object)   # (satellite id, slot) of every observation
        for i, sid in enumerate(sats):
            for f in range(F):
                self.obs_keys[i, f] = (sid, f)
        self._geo: dict[int, tuple] = {}
        self._zb: dict[int, ZeroDiff] = {}
        self._zr: dict[int, ZeroDiff] = {}     # the last model of every rover epoch (reused by the TC front end)
        self._tx_rover: tuple | None = None
        self._pr_rover: np.ndarray | None = None     # the first code of every rover epoch and satellite (m)

    def arcs(self) -> np.ndarray:
        """Phase arc number per (rover epoch, satellite, slot): it changes at every slip flag of the rover or of
        the base epoch matched to it (-1 where the rover epoch has no base epoch)."""
        jb = np.maximum(self.jb, 0)
        n_b = int(self.Cb.max()) + 1 if self.Cb.size else 1
        out = self.Cr.astype(np.int64) * n_b + self.Cb[jb]
        out[self.jb < 0] = -1
        return out

    def _rover_states(self) -> tuple:
        """The satellites' states at transmission of every rover epoch, computed at once on first use
        (`dgcal.pos.gnss.carrier.transmission_states`)."""
        if self._tx_rover is None:
            self._pr_rover = first_code(self.Pr)
            self._tx_rover = transmission_states(self.nav, self.sats, self.t, self._pr_rover)
        return self._tx_rover

    def _base_models(self, epochs: np.ndarray) -> ZeroDiff:
        """The zero-difference models of some base epochs at once (leading axis: `epochs`): nothing in them
        depends on the filter, the base stands at its known position."""
        t, P, L = self.tb[epochs], self.Pb[epochs], self.Lb[epochs]
        pr = first_code(P)
        states = transmission_states(self.nav, self.sats, t, pr)
        g = satellite_geometry(self.nav, self.sats, t, pr, self.base_pos, states)
        return zero_difference(self.nav, self.sats, t, P, L, self.freq, self.base_pos, g, self.opts.humidity)

    def base_zd(self, j: int) -> ZeroDiff:
        """Base epoch j modelled at the base position; on first use every base epoch a rover epoch is matched to."""
        if j not in self._zb:
            if not self._zb:
                used = np.unique(self.jb[self.jb >= 0])
                models = self._base_models(used)
                self._zb.update({int(b): models.epoch(q) for q, b in enumerate(used)})
            if j not in self._zb:
                self._zb[j] = self._base_models(np.array([j])).epoch(0)
        return self._zb[j]

    def rover_zd(self, k: int, x0: np.ndarray, reuse_within_m: float | None = None) -> ZeroDiff:
        """Rover epoch k modelled at x0 (ECEF m); with `reuse_within_m` the last model of that epoch is returned
        when it was made within that distance of x0 (its point is ``extra['p_rx']``)."""
        last = self._zr.get(k)
        if reuse_within_m is not None and last is not None and \
                np.linalg.norm(last.extra["p_rx"] - x0) <= reuse_within_m:
            return last
        if k not in self._geo:
            states = tuple(a[k] for a in self._rover_states())
            self._geo[k] = satellite_geometry(self.nav, self.sats, self.t[k], self._pr_rover[k], x0, states)
        zr = zero_difference(self.nav, self.sats, self.t[k], self.Pr[k], self.Lr[k], self.freq, x0,
                             self._geo[k], self.opts.humidity)
        zr.extra["p_rx"] = np.array(x0, float)
        self._zr[k] = zr
        return zr


def _slipped(C: np.ndarray, a: np.ndarray, b, i: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Any slip flag of (satellite i, slot f) in the epochs (min(a,b), max(a,b)], from the cumulative flags C."""
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    return C[hi, i, f] - C[lo, i, f] > 0


@dataclass
class _Rows:
    """The double differences of one epoch, an entry per row: phase (else code), satellite, reference satellite
    and frequency slot (indices into the pair's satellites and slots)."""

    phase: np.ndarray
    sat: np.ndarray
    ref: np.ndarray
    slot: np.ndarray


def estimates_ionosphere(p_rover, base_pos, opts: PpkOptions) -> bool:
    """Whether a pass starting at `p_rover` (ECEF m) estimates the ionosphere: baseline beyond `iono_est_km`."""
    return bool(np.linalg.norm(np.asarray(p_rover, float) - np.asarray(base_pos, float)) > 1e3 * opts.iono_est_km)


class _Pass:
    """One EKF pass over the rover epochs in the given order."""

    def __init__(self, eng: CarrierPair, order: np.ndarray, p_init: np.ndarray):
        self.e, self.order = eng, order
        m, F = len(eng.sats), eng.F
        # states: position, velocity (NK), the slant single-difference ionosphere at L1 per satellite (m, when
        # estimated) from `iono0`, the SD ambiguities (cycles) from `amb0`
        self.iono_est = estimates_ionosphere(p_init, eng.base_pos, eng.opts)
        self.iono0 = NK if self.iono_est else -1
        self.amb0 = NK + (m if self.iono_est else 0)
        self.iono_on = np.zeros(m, dtype=bool)
        self.n = self.amb0 + m * F
        self.x = np.zeros(self.n)
        self.x[:3] = p_init
        self.P = np.zeros((self.n, self.n))
        self.P[:3, :3] = np.eye(3) * eng.opts.pos_sigma_m ** 2
        self.eye = np.eye(self.n)
        self._amb_maps: dict = {}
        self.active = np.zeros((m, F), dtype=bool)
        self.last = np.full((m, F), -1)
        self.last_b = np.full((m, F), -1)
        self.lock = np.zeros((m, F), dtype=int)
        # held integers (fix and hold, not fed back into the float state): per satellite and slot, whether its SD
        # ambiguity minus that of its group's other held satellites is a known integer, K the integer against the
        # group's common origin; a candidate is held once `hold_after` validated fixes gave it alike
        self.known = np.zeros((m, F), dtype=bool)
        self.K = np.zeros((m, F), dtype=np.int64)
        self.K_cand = np.zeros((m, F), dtype=np.int64)
        self.n_conf = np.zeros((m, F), dtype=np.int64)
        self.t_prev = None
        self.t_now = None
        self.have_pos = False
        # variance (cycles^2) of the time-correlated SD phase errors of every state (validation of a fix only)
        self.var_bias = np.zeros(self.n)
        self.var_bias[self.amb0:] = np.nan_to_num((eng.opts.phase_bias_sigma_m / eng.lam.ravel()) ** 2)
        # a Gauss-Markov phase error of variance s^2 and correlation time tau seen through a constant (the
        # ambiguity) is followed by a random walk of 2 s^2 / tau: the float ambiguities stay as uncertain as the
        # slow errors make them (taken as white, they converge to a few millicycles and LAMBDA's ratio collapses
        # on the slow error's 0.05-0.1 cycle offsets)
        tau = eng.opts.phase_bias_tau_s
        self.q_amb = (2.0 * self.var_bias / tau if tau > 0 else np.zeros(self.n)) + eng.opts.amb_q_cycles2_s
        # variance factors (phase, code) of the zenith sigmas from the post-fit residuals: a car's or a UAV's
        # antenna sees more multipath than the options' static figures, and the filter must say so (never below 1)
        self.vf = np.ones(2)
        self.s0_fix = 1.0          # variance factor of the fixed solutions' phase residuals (recent epochs)
        self.s0_epoch = 1.0        # the same of this epoch alone (a burst of multipath shows here first)
        self.t_fix = None

    def idx(self, i, f):
        """State index of the SD ambiguity of satellite(s) i, slot(s) f."""
        return self.amb0 + i * self.e.F + f

    def reset(self, i, f) -> None:
        """Forget the ambiguities of satellites i, slots f (indices or index arrays)."""
        a = self.idx(i, f)
        self.P[a, :] = 0.0
        self.P[:, a] = 0.0
        self.x[a] = 0.0
        self.active[i, f] = False
        self.lock[i, f] = 0
        self.known[i, f] = False
        self.n_conf[i, f] = 0

    # ------------------------------------------------------------------ measurement model
    def _design(self, zr: ZeroDiff, zb: ZeroDiff, valid: np.ndarray, x0: np.ndarray, drop_code: np.ndarray):
        """Double differences y (m, the state-independent part: the model is H x), design H, covariance R, the
        rows and the groups' reference satellites; None without a group (`dgcal.pos.gnss.ppk_design`).

        Groups: per system and slot the valid satellites, when two or more, against the highest one, preferring
        one with an established ambiguity; rows: per group its phase, then its code less `drop_code` (m,F)."""
        e, o = self.e, self.e.opts
        score = zr.elev[:, None] + np.where(self.lock > 0, 10.0, 0.0)
        ph, sat, ref, slot, block, _g_sys, _g_slot, g_ref = dd_rows(valid, e.sys_id, e.n_sys, score, drop_code)
        if len(g_ref) == 0:
            return None
        y, H, R = dd_system(ph, sat, ref, slot, block, zr.los, zr.omc_phase - zb.omc_phase,
                            zr.omc_code - zb.omc_code, e.lam, zr.elev, zb.elev, o.phase_sigma_m * np.sqrt(self.vf[0]),
                            o.code_sigma_m * np.sqrt(self.vf[1]), self._code_factor(), x0, self.n, self.amb0,
                            self.iono0, e.kappa)
        return y, H, R, _Rows(ph, sat, ref, slot), g_ref

    def _code_factor(self) -> np.ndarray:
        """Variance factor (m,F) of code DDs: 1 for a new satellite, (1 + rho)/(1 - rho) once tracked.

        Code errors (multipath) are modelled as first-order Gauss-Markov with correlation time
        ``code_corr_s``: each further epoch of an AR(1) sequence adds ``(1 - rho)/(1 + rho)`` of the
        first epoch's information about a constant (the ambiguity), ``rho = exp(-dt/tau)``.
        """
        o = self.e.opts
        if o.code_corr_s <= 0 or self.t_now is None:
            return np.ones(self.last.shape)
        tracked = (self.last >= 0) & (self.lock > 0)
        rho = np.exp(-np.abs(self.t_now - self.e.t[self.last]) / o.code_corr_s)
        return np.where(tracked, (1.0 + rho) / np.maximum(1.0 - rho, 1e-6), 1.0)

    def _gain(self, P, H, R) -> np.ndarray | None:
        """Kalman gain K = P H' (H P H' + R)^-1; None if singular."""
        HP = H @ P
        try:
            return gesv(HP @ H.T + R, HP).T
        except np.linalg.LinAlgError:
            return None

    def _posterior(self, P, K, H, R) -> np.ndarray:
        """Covariance after the update with gain K (Joseph form, symmetrised)."""
        IKH = self.eye - K @ H
        Pn = IKH @ P @ IKH.T + K @ R @ K.T
        return 0.5 * (Pn + Pn.T)

    # ------------------------------------------------------------------ one epoch
    def _reset_slipped(self, k: int, j: int, valid: np.ndarray) -> None:
        """Reset the ambiguities with a slip flag (rover or base) or a gap since their last update."""
        e = self.e
        i, f = np.nonzero(valid & self.active)
        a, ab = self.last[i, f], self.last_b[i, f]
        bad = ((np.abs(e.t[k] - e.t[a]) > e.opts.max_gap_s) | _slipped(e.Cr, a, k, i, f)
               | ((ab != j) & _slipped(e.Cb, ab, j, i, f)))
        self.reset(i[bad], f[bad])

    def _start_new(self, zr: ZeroDiff, zb: ZeroDiff, valid: np.ndarray) -> None:
        """New ambiguities (cycles) at SD phase minus SD code, with the prior sigma ``amb_sigma_cycles``."""
        i, f = np.nonzero(valid & ~self.active)
        a = self.idx(i, f)
        sd_phase = zr.omc_phase[i, f] - zb.omc_phase[i, f]
        sd_code = zr.omc_code[i, f] - zb.omc_code[i, f]
        self.x[a] = (sd_phase - sd_code) / self.e.lam[i, f]
        self.P[a, :] = 0.0
        self.P[:, a] = 0.0
        self.P[a, a] = self.e.opts.amb_sigma_cycles ** 2
        self.active[i, f] = True
        self.lock[i, f] = 0

    def _predict(self, t: float, dt: float) -> None:
        """Position and velocity to epoch t: constant velocity with white acceleration (kinematic; time runs either
        way, the backward pass predicts into the past), a constant position (static); a fresh start with the prior
        sigmas at the first epoch and after a gap longer than ``max_gap_s``."""
        o = self.e.opts
        if not self.have_pos or dt > o.max_gap_s:
            self.P[:NK, :] = 0.0
            self.P[:, :NK] = 0.0
            self.P[:3, :3] = np.eye(3) * o.pos_sigma_m ** 2
            self.x[3:NK] = 0.0
            if o.dynamics == "kinematic":
                self.P[3:NK, 3:NK] = np.eye(3) * o.vel_sigma_mps ** 2
            return
        if o.dynamics != "kinematic" or dt == 0.0:
            return
        tau = t - self.t_prev                                    # signed: negative in the backward pass
        self.x[:3] += self.x[3:NK] * tau
        Pk = self.P[:NK, :]
        Pk[:3] += tau * Pk[3:NK]                                 # rows: F P
        Pc = self.P[:, :NK]
        Pc[:, :3] += tau * Pc[:, 3:NK]                           # columns: (F P) F'
        # white acceleration of spectral density q in local level axes (horizontal, vertical), into ECEF
        up = self.x[:3] / max(np.linalg.norm(self.x[:3]), 1.0)
        qa = o.accel_h_mps2 ** 2 * (np.eye(3) - np.outer(up, up)) + o.accel_v_mps2 ** 2 * np.outer(up, up)
        self.P[:3, :3] += qa * dt ** 3 / 3.0
        self.P[:3, 3:NK] += qa * dt ** 2 / 2.0
        self.P[3:NK, :3] += qa * dt ** 2 / 2.0
        self.P[3:NK, 3:NK] += qa * dt

    def _predict_iono(self, seen: np.ndarray, elev: np.ndarray, x0: np.ndarray, dt: float) -> None:
        """The ionosphere states to this epoch: first-order Gauss-Markov (``iono_tau_s``) of the steady sigma
        ``iono_ppm`` x baseline / sin el; a satellite seen anew, or again after ``max_gap_s``, starts at zero with it.
        States of satellites not seen are left as they are."""
        o = self.e.opts
        dist = float(np.linalg.norm(x0 - self.e.base_pos))
        sig = o.iono_ppm * 1e-6 * dist / np.sin(np.maximum(elev, np.radians(5.0))) + 1e-4
        a = self.iono0 + np.arange(len(seen))
        gap = (self.t_prev is not None) & (np.abs(self.t_now - self.e.t[np.maximum(self.last.max(axis=1), 0)])
                                           > o.max_gap_s)
        new = seen & (~self.iono_on | gap)
        if new.any():
            i = a[new]
            self.P[i, :] = 0.0
            self.P[:, i] = 0.0
            self.x[i] = 0.0
            self.P[i, i] = sig[new] ** 2
            self.iono_on[new] = True
        old = seen & ~new & self.iono_on
        if old.any() and dt > 0:
            i = a[old]
            phi = np.exp(-dt / o.iono_tau_s)
            self.x[i] *= phi
            self.P[i, :] *= phi
            self.P[:, i] *= phi
            self.P[i, i] += sig[old] ** 2 * (1.0 - phi * phi)

    def step(self, k: int, out: dict) -> None:
        e, o = self.e, self.e.opts
        t = e.t[k]
        j = int(e.jb[k])
        if j < 0:
            return
        dt = 0.0 if self.t_prev is None else abs(t - self.t_prev)
        self.t_now, self.k_now, self.j_now = t, k, j
        self._predict(t, dt)
        act = np.nonzero(self.active.ravel())[0] + self.amb0
        self.P[act, act] += self.q_amb[act] * dt
        x0 = self.x[:3].copy()
        zb = e.base_zd(j)
        zr = e.rover_zd(k, x0)
        valid = (np.isfinite(zr.omc_phase) & np.isfinite(zr.omc_code) & np.isfinite(zb.omc_phase)
                 & np.isfinite(zb.omc_code) & np.isfinite(e.lam)
                 & (zr.elev >= np.radians(o.elev_mask_deg))[:, None])
        if valid.sum() < 2:
            return
        if self.iono0 >= 0:
            self._predict_iono(valid.any(axis=1), zr.elev, x0, dt)
        self._reset_slipped(k, j, valid)
        self._start_new(zr, zb, valid)
        drop_code = np.zeros(valid.shape, bool)
        x_prior, P_prior = self.x.copy(), self.P.copy()
        sol = None
        # the linearisation point and the rover model made there travel together across the snooping rounds (a
        # moving rover's model at the converged point paired with the prior point shifted the solution back)
        lin, zr_it = x0.copy(), zr
        for _snoop in range(6):
            x, P = x_prior, P_prior
            for _it in range(3):
                des = self._design(zr_it, zb, valid, lin, drop_code)
                if des is None:
                    return
                y, H, R, rows, refs = des
                K = self._gain(P_prior, H, R)
                if K is None:
                    return
                x = x_prior + K @ (y - H @ x_prior)
                if np.linalg.norm(x[:3] - lin) < 0.5 or _it == 2:
                    P = self._posterior(P_prior, K, H, R)     # only the last iteration's covariance is kept
                    break
                lin = x[:3].copy()
                zr_it = e.rover_zd(k, lin)
            zr = zr_it
            # post-fit data snooping: w-test of every row against its residual variance diag(R - H P H')
            v = y - H @ x
            q_v = np.diag(R) - np.einsum("ij,ij->i", H @ P, H)
            w = np.abs(v) / np.sqrt(np.maximum(q_v, 1e-12))
            worst = int(np.argmax(w))
            if w[worst] <= o.outlier_w:
                sol = (x, P, y, H, R, rows, refs, lin)
                break
            i, f, ref = int(rows.sat[worst]), int(rows.slot[worst]), int(rows.ref[worst])
            if not rows.phase[worst]:
                drop_code[i, f] = True
                continue
            # many failing rows in the group: the reference slipped
            grp = rows.phase & (rows.slot == f) & (e.system[rows.sat] == e.system[i])
            bad = int(np.sum(w[grp] > o.outlier_w))
            victim = ref if grp.sum() >= 3 and bad >= 0.5 * grp.sum() else i
            a = self.idx(victim, f)
            x_prior[a] = (zr.omc_phase[victim, f] - zb.omc_phase[victim, f]
                          - zr.omc_code[victim, f] + zb.omc_code[victim, f]) / e.lam[victim, f]
            P_prior[a, :] = 0.0
            P_prior[:, a] = 0.0
            P_prior[a, a] = o.amb_sigma_cycles ** 2
            self.lock[victim, f] = 0
            self.known[victim, f] = False
            self.n_conf[victim, f] = 0
            out["resets"] = out.get("resets", 0) + 1
        if sol is None:
            sol = (x, P, y, H, R, rows, refs, lin)
        x, P, y, H, R, rows, refs, lin = sol
        # code rows against their variance before the correlation factor of `_code_factor` (which only stands for
        # the information a correlated error adds to a constant, not for its size)
        v = y - H @ x
        q_fit = np.diag(R) - np.einsum("ij,ij->i", H @ P, H)
        q_v = q_fit.copy()
        code = ~rows.phase
        q_v[code] = np.diag(R)[code] / self._code_factor()[rows.sat[code], rows.slot[code]]
        self._adapt_noise(v, q_v, rows.phase, dt)
        # the epoch's own test: post-fit residuals beyond their chi-square quantile inflate its float covariance
        # to what they say (never a float sigma the epoch's residuals contradict)
        chi2_fit = float(np.sum(v * v / np.maximum(q_fit, 1e-12)))
        dof = max(len(v) - 3, 1)
        inflate = chi2_fit / dof if chi2_fit > _chi2_limit(dof, o.alpha) else 1.0
        self.x, self.P = x, P
        self.have_pos = True
        self.t_prev = t
        self.last[valid] = k
        self.last_b[valid] = j
        self.lock[valid] += 1
        seen = np.zeros(len(e.sats), bool)
        seen[rows.sat] = True
        seen[refs] = True
        n_sat = int(seen.sum())
        out.update(status=2, p_float=x[:3].copy(), P_float=inflate * P[:3, :3], p=x[:3].copy(),
                   P=inflate * P[:3, :3], n_sat=n_sat, n_amb=int(rows.phase.sum()))
        self._resolve(x, P, y, H, R, rows, zr, out)
        if out.get("status") == 3:
            cov = self._fixed_covariance(H, R, rows, zr, out["p"], out["P"])
            if cov is not None:
                out["P"] = cov

    def _adapt_noise(self, v: np.ndarray, q_v: np.ndarray, phase: np.ndarray, dt: float) -> None:
        """Update the variance factors of phase and code (``vf``) from this epoch's post-fit residuals v (m) and their
        variances q_v (m^2): an exponential average over ``noise_window_s`` of factor * mean(v^2 / q_v), at least 1."""
        win = self.e.opts.noise_window_s
        if win <= 0:
            return
        a = min(1.0, max(dt, 1e-3) / win)
        w2 = v * v / np.maximum(q_v, 1e-12)
        for q, rows in enumerate((phase, ~phase)):
            if rows.sum() >= 3:
                self.vf[q] = max(1.0, (1.0 - a) * self.vf[q] + a * self.vf[q] * float(np.mean(w2[rows])))

    def _fixed_covariance(self, H, R, rows: _Rows, zr: ZeroDiff, p: np.ndarray,
                          P_fixed: np.ndarray) -> np.ndarray | None:
        """Covariance (3,3) m^2, ECEF, of a fixed position: the filter's covariance of the fixed solution `P_fixed`
        (the float state conditioned on the fixed integers: ambiguities a partial fix leaves open keep theirs), not
        below the single-epoch weighted least squares of the phase double differences ``(G'WG)^-1``, times the
        variance factor ``s0^2 >= 1`` of the recent and the present fixed residuals (multipath and the slow errors a
        moving antenna sees are not averaged away by the filter's dynamics), plus what the differential atmosphere
        leaves: ``A C A'`` with ``A = (G'WG)^-1 G'W`` and C the atmosphere covariance of the rows (a slant ionosphere
        error per satellite of `iono_ppm` mm per km from the base times 1/sin el, scaled (f_L1/f)^2, and one rover
        zenith troposphere error, 1/sin el), nearly constant over an hour, as
        `dgcal.pos.smoother.carrier.atmosphere_position_covariance` for TC. None if the rows do not fix the position."""
        e, o = self.e, self.e.opts
        ph = np.flatnonzero(rows.phase)
        if len(ph) < 4:
            return None
        G = H[ph, :3]
        W = gesv(R[ph[:, None], ph], np.eye(len(ph)))          # the inverse, as np.linalg.inv computes it
        N = G.T @ W @ G
        sv = dgesdd(N, compute_uv=0)[1]                        # np.linalg.cond's singular values
        if sv[0] / sv[-1] > 1e8:
            return None
        Ninv = gesv(N, np.eye(3))
        # the larger of the two in every direction (generalised eigenvectors of the pair, L L' = (G'WG)^-1)
        Lc = np.linalg.cholesky(Ninv)
        M = np.linalg.solve(Lc, np.linalg.solve(Lc, P_fixed).T)
        lam, V = np.linalg.eigh(0.5 * (M + M.T))
        B = Lc @ V
        cov = max(1.0, self.s0_fix, self.s0_epoch) * (B * np.maximum(lam, 1.0)) @ B.T
        if o.iono_ppm <= 0 and o.tropo_zenith_m <= 0:
            return cov
        A = Ninv @ G.T @ W
        sat, ref, f = rows.sat[ph], rows.ref[ph], rows.slot[ph]
        used = np.zeros(len(e.sats), bool)
        used[sat] = True
        used[ref] = True
        sats, col = np.flatnonzero(used), np.cumsum(used) - 1  # the satellites of the rows, ascending; columns
        mapping = 1.0 / np.sin(np.maximum(zr.elev, np.radians(2.0)))
        kappa = (1575.42e6 / e.freq[sat, f]) ** 2
        r = np.arange(len(ph))
        B = np.zeros((len(ph), len(sats) + 1))
        B[r, col[sat]] -= kappa                                # the phase advances by the ionosphere: -I on phase
        B[r, col[ref]] += kappa
        B[:, -1] = mapping[sat] - mapping[ref]
        dist = float(np.linalg.norm(p - e.base_pos))
        # also where the ionosphere is estimated: a fix off by an ionosphere-like integer combination (N1 and N2 by
        # one each) moves the position by centimetres that its filter covariance does not show
        var = np.append((o.iono_ppm * 1e-6 * dist * mapping[sats]) ** 2, o.tropo_zenith_m ** 2)
        return cov + A @ ((B * var) @ B.T) @ A.T

    def _ambiguity_rows(self, rows: _Rows, zr: ZeroDiff) -> np.ndarray:
        """The phase rows whose DD ambiguity is resolved: both satellites above the AR mask, neither with an
        unresolved half cycle at either receiver."""
        e = self.e
        mask = np.radians(e.opts.ar_elev_mask_deg)
        half = e.half_r[self.k_now] | e.half_b[self.j_now]
        young = self.lock < e.opts.min_lock
        return np.flatnonzero(rows.phase & (zr.elev[rows.ref] >= mask) & (zr.elev[rows.sat] >= mask)
                              & ~half[rows.sat, rows.slot] & ~half[rows.ref, rows.slot]
                              & ~young[rows.sat, rows.slot] & ~young[rows.ref, rows.slot])

    def _ambiguity_map(self, sat: np.ndarray, ref: np.ndarray, slot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(T, Da) for the DD ambiguities (sat - ref, slot): their multi-frequency recombination T
        (`_multifrequency_combinations`) and the map Da (k, n) of the state onto the recombined ambiguities. The
        same set recurs epoch after epoch: kept for the last sets seen."""
        key = (sat.tobytes(), ref.tobytes(), slot.tobytes())
        hit = self._amb_maps.get(key)
        if hit is None:
            D = np.zeros((len(sat), self.n))
            r = np.arange(len(sat))
            D[r, self.idx(sat, slot)] = 1.0
            D[r, self.idx(ref, slot)] = -1.0
            T = _multifrequency_combinations(sat, slot)
            if len(self._amb_maps) >= 64:
                self._amb_maps.clear()
            hit = self._amb_maps[key] = (T, T @ D)
        return hit

    def _resolve(self, x, P, y, H, R, rows: _Rows, zr, out) -> None:
        """The epoch's fixed solution: the integers held from earlier fixes plus LAMBDA on the rest (validated by the
        fixed residuals), else LAMBDA on every ambiguity (validated by ratio, consistency and residuals)."""
        o = self.e.opts
        amb = self._ambiguity_rows(rows, zr)
        out["reason"] = "no ambiguities"
        if len(amb) < o.min_fix_amb:
            return
        sat, ref, slot = rows.sat[amb], rows.ref[amb], rows.slot[amb]
        if o.hold and self.known.any():
            held = self._fix_with_held(x, P, y, H, R, rows, sat, ref, slot, out)
            if held == "fixed":
                return
            if held == "failed":                   # the held integers no longer fit: resolve everything anew
                self.known[:] = False
                self.n_conf[:] = 0
        T, Da = self._ambiguity_map(sat, ref, slot)
        a = Da @ x
        Qa = Da @ P @ Da.T
        fix = resolve(a, Qa, o.ratio_threshold, o.p0, o.min_fix_amb, o.partial)
        out["ratio"] = fix.ratio
        if not fix.fixed:
            out["reason"] = "ratio"
            return
        # the float filter takes phase noise as white: the time-correlated part is added for the test
        xf, Pf, chi2_amb = fixed_solution(x, P, Da, fix, self.var_bias if o.phase_bias_sigma_m > 0 else None)
        lim_amb = _chi2_limit(fix.n_fixed, o.alpha)
        # the position shift of the fix against its covariance under a correct fix: K_p (S + S_bias) K_p', with
        # K_p = P_pa A' S^-1 the map of the ambiguity correction onto the position (S = A P A' of the constraints)
        d = xf[:3] - x[:3]
        A = fix.C @ Da
        AP = A @ P
        S = AP @ A.T
        try:
            Kp = gesv(S, AP[:, :3]).T
            Sd = Kp @ (S + (A * self.var_bias) @ A.T) @ Kp.T if o.phase_bias_sigma_m > 0 else AP[:, :3].T @ Kp.T
            chi2_pos = float(d @ gesv(Sd + 1e-12 * np.eye(3), d))
        except np.linalg.LinAlgError:
            chi2_pos = np.inf
        lim_pos = _chi2_limit(3, o.alpha)
        chi2_res, lim_res, w_max, v, ph = self._fixed_residual_test(xf, y, H, R, rows)
        out["chi2"] = (chi2_amb / lim_amb, chi2_pos / lim_pos, chi2_res / lim_res)
        if not (chi2_amb <= lim_amb and chi2_pos <= lim_pos and chi2_res <= lim_res and w_max <= o.outlier_w):
            out["reason"] = ("ambiguity consistency" if chi2_amb > lim_amb else "position consistency"
                             if chi2_pos > lim_pos else "fixed residuals")
            return
        self._accept(xf, Pf, R, rows, v, ph, fix.n_fixed, sat, ref, slot, out)

    def _fixed_residual_test(self, xf, y, H, R, rows: _Rows):
        """Chi-square (and its limit) and the largest standardised residual of the fixed solution's phase double
        differences against their noise plus the slow phase errors (`_bias_covariance`); the residuals, rows."""
        o = self.e.opts
        ph = np.flatnonzero(rows.phase)
        v = (y - H @ xf)[ph]
        Rp = R[ph[:, None], ph] + self._bias_covariance(rows.sat[ph], rows.ref[ph], rows.slot[ph])
        chi2_res = float(v @ gesv(Rp, v))
        w_max = float(np.max(np.abs(v) / np.sqrt(np.diag(Rp)))) if len(v) else 0.0
        return chi2_res, _chi2_limit(max(len(ph), 1), o.alpha), w_max, v, ph

    def _fix_with_held(self, x, P, y, H, R, rows: _Rows, sat, ref, slot, out) -> str:
        """Fix and hold without feeding back: the float state conditioned on the integers held from earlier fixes
        (`known`), LAMBDA (ratio and consistency tested) on the ambiguities they leave open; "fixed" when the fixed
        residuals pass, "failed" when they do not, "none" when the held integers cannot fix this epoch."""
        o = self.e.opts
        Ck, ck, det = self._held_constraints(sat, ref, slot)
        if len(ck) == 0:
            return "none"
        try:
            xk, Pk, _ = fixed_solution(x, P, Ck, AmbiguityFix(True, np.eye(len(ck)), ck, np.inf, 0.0, 1.0, len(ck),
                                                              "held"))
        except np.linalg.LinAlgError:
            return "none"
        n_fixed = int(det.sum())
        xf, Pf = xk, Pk
        rest = np.flatnonzero(~det)
        if len(rest) == 0:                         # the epoch's own ratio, for the record (held fixes need none)
            _T, Da = self._ambiguity_map(sat, ref, slot)
            out["ratio"] = resolve(Da @ x, Da @ P @ Da.T, o.ratio_threshold, o.p0, o.min_fix_amb, False).ratio
        if len(rest):
            _T, Da = self._ambiguity_map(sat[rest], ref[rest], slot[rest])
            fix = resolve(Da @ xk, Da @ Pk @ Da.T, o.ratio_threshold, o.p0, 1, o.partial)
            out["ratio"] = fix.ratio
            if fix.fixed:
                xn, Pn, chi2_amb = fixed_solution(xk, Pk, Da, fix, self.var_bias if o.phase_bias_sigma_m > 0 else None)
                if chi2_amb <= _chi2_limit(fix.n_fixed, o.alpha):
                    xf, Pf, n_fixed = xn, Pn, n_fixed + fix.n_fixed
        if n_fixed < o.min_fix_amb:
            return "none"
        chi2_res, lim_res, w_max, v, ph = self._fixed_residual_test(xf, y, H, R, rows)
        out["chi2"] = (np.nan, np.nan, chi2_res / lim_res)
        if chi2_res > lim_res or w_max > o.outlier_w:
            out["reason"] = "held integers"
            return "failed"
        self._accept(xf, Pf, R, rows, v, ph, n_fixed, sat, ref, slot, out)
        return "fixed"

    def _held_constraints(self, sat, ref, slot):
        """Constraints ``C x = c`` (rows over the state, integers in cycles) that the held integers put on this
        epoch's ambiguities: per system and slot, every held satellite against one held satellite of the epoch;
        and which ambiguity rows (sat - ref) they determine."""
        e = self.e
        rows_c, vals = [], []
        held = self.known
        det = held[sat, slot] & held[ref, slot]
        members = np.unique(np.concatenate([np.stack([sat, slot], 1), np.stack([ref, slot], 1)]), axis=0)
        keep = held[members[:, 0], members[:, 1]]
        members = members[keep]
        for g in np.unique(np.stack([e.sys_id[members[:, 0]], members[:, 1]], 1), axis=0):
            m = members[(e.sys_id[members[:, 0]] == g[0]) & (members[:, 1] == g[1])]
            pivot = m[0]
            for i, f in m[1:]:
                r = np.zeros(self.n)
                r[self.idx(i, f)] = 1.0
                r[self.idx(pivot[0], f)] = -1.0
                rows_c.append(r)
                vals.append(float(self.K[i, f] - self.K[pivot[0], f]))
        if not rows_c:
            return np.zeros((0, self.n)), np.zeros(0), det
        return np.array(rows_c), np.array(vals), det

    def _accept(self, xf, Pf, R, rows: _Rows, v, ph, n_fixed: int, sat, ref, slot, out) -> None:
        """Write a validated fix into `out`, update the fixed residuals' variance factor and the held integers."""
        o, e = self.e.opts, self.e
        out.update(status=3, p=xf[:3].copy(), P=Pf[:3, :3].copy(), n_fixed_amb=n_fixed, reason="")
        if o.noise_window_s > 0 and len(ph) > 3:
            a = min(1.0, max(abs(self.t_now - self.t_fix), 1e-3) / o.noise_window_s) if self.t_fix is not None else 1.0
            s0 = float(v @ gesv(R[ph[:, None], ph], v)) / (len(ph) - 3)
            self.s0_epoch = s0
            self.s0_fix = (1.0 - a) * self.s0_fix + a * s0 if self.t_fix is not None else max(1.0, s0)
            self.t_fix = self.t_now
        out["resid"] = dict(zip(e.obs_keys[rows.sat[ph], rows.slot[ph]].tolist(), v.tolist()))
        if o.hold:
            self._keep_integers(xf, Pf, sat, ref, slot)

    def _keep_integers(self, xf, Pf, sat, ref, slot) -> None:
        """Hold the integers a validated fix determined: per system and slot, every satellite whose SD ambiguity
        against a pivot (a held satellite of the group, else the reference) is within 0.15 cycle of an integer with
        a sigma under 0.05 cycle; an integer is held once ``hold_after`` validated fixes gave it alike (a fix giving
        another value starts the count again)."""
        e, o = self.e, self.e.opts
        for g_sys, f in {(int(e.sys_id[r]), int(s)) for r, s in zip(ref, slot)}:
            in_g = (e.sys_id[ref] == g_sys) & (slot == f)
            mem = np.unique(np.concatenate([sat[in_g], ref[in_g]]))
            held = mem[self.known[mem, f]]
            group_held = self.known[:, f] & (e.sys_id == g_sys)
            if len(held):
                pivot = int(held[0])
            else:
                self.known[group_held, f] = False              # none of the group's held satellites is here
                pivot = int(ref[in_g][0])
                self.K[pivot, f] = 0
                self.known[pivot, f] = True
                self.n_conf[pivot, f] = o.hold_after
            ip = self.idx(pivot, f)
            for i in mem:
                if i == pivot or self.known[i, f]:
                    continue
                a = self.idx(i, f)
                d = xf[a] - xf[ip]
                var = Pf[a, a] + Pf[ip, ip] - 2.0 * Pf[a, ip]
                n = int(np.round(d))
                if var > 0.05 ** 2 or abs(d - n) > 0.15:
                    continue
                val = int(self.K[pivot, f]) + n
                self.n_conf[i, f] = self.n_conf[i, f] + 1 if self.K_cand[i, f] == val else 1
                self.K_cand[i, f] = val
                if self.n_conf[i, f] >= o.hold_after:
                    self.known[i, f] = True
                    self.K[i, f] = val

    def _bias_covariance(self, sat: np.ndarray, ref: np.ndarray, slot: np.ndarray) -> np.ndarray:
        """Covariance (m^2) of the slow SD phase errors (``phase_bias_sigma_m`` per satellite and slot) in the phase
        double differences sat - ref of one slot each: what a correct fix leaves in its residuals beside the noise."""
        s2 = self.e.opts.phase_bias_sigma_m ** 2
        same = (slot[:, None] == slot[None, :])
        return s2 * same * ((sat[:, None] == sat[None, :]).astype(float) + (ref[:, None] == ref[None, :])
                            - (sat[:, None] == ref[None, :]) - (ref[:, None] == sat[None, :]))

    def run(self) -> PassResult:
        e = self.e
        N = len(e.t)
        status = np.zeros(N, dtype=int)
        p = np.full((N, 3), np.nan)
        Pc = np.full((N, 3, 3), np.nan)
        pf = np.full((N, 3), np.nan)
        Pfl = np.full((N, 3, 3), np.nan)
        ratio = np.full(N, np.nan)
        n_sat = np.zeros(N, dtype=int)
        n_amb = np.zeros(N, dtype=int)
        n_fix = np.zeros(N, dtype=int)
        chi2 = np.full((N, 3), np.nan)
        reason = [""] * N
        resid = [dict() for _ in range(N)]
        for k in self.order:
            out: dict = {}
            self.step(int(k), out)
            if "status" not in out:
                reason[k] = "no double differences"
                continue
            status[k] = out["status"]
            p[k], Pc[k], pf[k], Pfl[k] = out["p"], out["P"], out["p_float"], out["P_float"]
            ratio[k] = out.get("ratio", np.nan)
            n_sat[k], n_amb[k], n_fix[k] = out["n_sat"], out["n_amb"], out.get("n_fixed_amb", 0)
            chi2[k] = out.get("chi2", (np.nan,) * 3)
            reason[k] = out.get("reason", "")
            resid[k] = out.get("resid", {})
        return PassResult(status, p, Pc, pf, Pfl, ratio, n_sat, n_amb, n_fix, chi2, reason, resid)


def _multifrequency_combinations(sat: np.ndarray, slot: np.ndarray) -> np.ndarray:
    """Unimodular integer recombination T of DD ambiguities per satellite: (N_f0 - N_f1, N_f1 - N_f2, ..., N_f0).

    ``sat``, ``slot``: the ambiguities' satellites and slots; rows satellite by satellite in the order they first
    appear. The (extra-)wide-lane differences are far more precise than the single-frequency ambiguities, which
    gives LAMBDA's decorrelation a head start (same integer lattice, far fewer permutations).
    """
    n = len(sat)
    first: dict = {}
    for i in sat.tolist():
        first.setdefault(i, len(first))
    order = np.lexsort((slot, [first[i] for i in sat.tolist()]))   # by satellite (first appearance), then slot
    s = sat[order]
    T = np.zeros((n, n))
    pair = np.flatnonzero(s[:-1] == s[1:])            # row p: slot difference of sorted p, p + 1
    T[pair, order[pair]] = 1.0
    T[pair, order[pair + 1]] = -1.0
    last = np.flatnonzero(np.r_[s[:-1] != s[1:], True])   # a satellite's last row: its first slot
    T[last, order[np.r_[0, last[:-1] + 1]]] = 1.0
    return T


@lru_cache(maxsize=256)
def _chi2_limit(dof: int, alpha: float) -> float:
    """The chi-square quantile 1 - alpha of `dof` degrees of freedom."""
    return float(chi2_limit(dof, alpha))


def ppk(rover: CarrierObs, base: CarrierObs, nav: BroadcastNav, base_pos_ecef, opts: PpkOptions | None = None,
        p_init=None) -> PpkResult:
    """Carrier-phase PPK of the rover against the base at ``base_pos_ecef`` (ECEF m); see the module docstring.

    ``p_init``: approximate rover position (ECEF m) for the first epoch (default: the rover header's).
    Epochs without double differences have status 'none' (the caller may fill them with SPP, 'single').
    """
    opts = opts or PpkOptions()
    eng = CarrierPair(rover, base, nav, base_pos_ecef, opts)
    p0 = np.asarray(p_init if p_init is not None else rover.p_approx_ecef, float)
    if not np.all(np.isfinite(p0)):
        p0 = np.asarray(base_pos_ecef, float)
    N = len(eng.t)
    fw = bw = None
    if opts.solution in ("combined", "forward"):
        fw = _Pass(eng, np.arange(N), p0).run()
    if opts.solution in ("combined", "backward"):
        pe = p0
        if fw is not None and np.any(fw.status >= 2):
            pe = fw.p[np.nonzero(fw.status >= 2)[0][-1]]
        bw = _Pass(eng, np.arange(N)[::-1], pe).run()
    info = {"ionosphere_estimated": estimates_ionosphere(p0, eng.base_pos, opts),
            "baseline_m": float(np.linalg.norm(p0 - eng.base_pos))}
    if fw is not None and bw is not None:
        status, p, P, ratio, n_sat, n_fix, factors = combine(fw, bw, opts.alpha)
        info["float_variance_factors"] = {"forward": factors[0], "backward": factors[1]}
    else:
        r = fw or bw
        status, p, P, ratio, n_sat, n_fix = r.status, r.p, r.P, r.ratio, r.n_sat, r.n_fixed_amb
    return PpkResult(t_gps=eng.t.copy(), status=status, p=p, P=P, ratio=ratio, n_sat=n_sat, n_fixed_amb=n_fix,
                     age_s=np.where(eng.jb >= 0, eng.age, np.nan), forward=fw, backward=bw, sats=eng.sats,
                     signals_rover=dict(rover.signals), signals_base=dict(base.signals),
                     slips_rover=eng.slips_rover, slips_base=eng.slips_base, options=opts, info=info, pair=eng)


PPK_CSV_COLUMNS = ["gps_week", "gps_sow", "x", "y", "z", "fix", "n_sat", "ratio", "sx", "sy", "sz", "sxy", "sxz",
                   "syz", "lat", "lon", "h", "s_e", "s_n", "s_u", "age_s", "n_fixed_amb", "fix_forward",
                   "fix_backward"]


def write_ppk_csv(path, res: PpkResult) -> None:
    """Write gnss.csv of `--mode ppk` (columns ``PPK_CSV_COLUMNS``, ECEF m; see docs/gnss.md), epochs with a solution.

    ``sx,sy,sz`` are 1-sigma (m); ``sxy,sxz,syz`` the cross covariances as RTKLIB writes them,
    ``sign(c) sqrt(|c|)`` (m); ``s_e,s_n,s_u`` local-level sigmas (m).
    """
    from dgcal.fields.crs import R_ecef_to_enu_at, ecef_to_geodetic
    from dgcal.fields.io.csv_tables import write_table
    from dgcal.pos.gnss.observations import split_gps_time
    k = np.nonzero(res.status >= 1)[0]
    week, sow = split_gps_time(res.t_gps[k])
    rows = []
    llh = ecef_to_geodetic(res.p[k]).reshape(-1, 3) if len(k) else np.zeros((0, 3))
    fw = res.forward.status if res.forward is not None else np.zeros(len(res.t_gps), dtype=int)
    bw = res.backward.status if res.backward is not None else np.zeros(len(res.t_gps), dtype=int)
    for j, i in enumerate(k):
        C = res.P[i]
        s = np.sqrt(np.maximum(np.diag(C), 0.0))
        cross = [float(np.sign(c) * np.sqrt(abs(c))) for c in (C[0, 1], C[0, 2], C[1, 2])]
        R_ecef_to_enu = R_ecef_to_enu_at(res.p[i])
        senu = np.sqrt(np.maximum(np.diag(R_ecef_to_enu @ C @ R_ecef_to_enu.T), 0.0))
        rows.append([int(week[j]), float(sow[j]), *res.p[i].tolist(), STATUS[res.status[i]], int(res.n_sat[i]),
                     float(res.ratio[i]) if np.isfinite(res.ratio[i]) else float("nan"), *s.tolist(), *cross,
                     *llh[j].tolist(), *senu.tolist(), float(res.age_s[i]), int(res.n_fixed_amb[i]),
                     STATUS[fw[i]], STATUS[bw[i]]])
    write_table(path, PPK_CSV_COLUMNS, rows, fmt="%.12g")


def ppk_summary(res: PpkResult, reference_ecef: np.ndarray | None = None) -> dict:
    """Numbers for gnss_summary.json of `--mode ppk`: counts per status, fix rate, sigmas, ages, slips, options,
    and with a known position the fixed-epoch 3D RMS and mean/std/RMS error per local axis (m)."""
    from dgcal.fields.crs import R_ecef_to_enu_at
    n = len(res.t_gps)
    st = res.status
    counts = {name: int(np.sum(st == i)) for i, name in enumerate(STATUS)}
    fixed = st == 3
    out = {"mode": "ppk", "n_epochs": n, "counts": counts, "n_fixed": counts["fixed"],
           "fix_rate": float(fixed.mean()) if n else 0.0, "systems": sorted({s[0] for s in res.sats}),
           "signals_rover": {f"{s}{f}": "/".join(v) for (s, f), v in res.signals_rover.items()},
           "signals_base": {f"{s}{f}": "/".join(v) for (s, f), v in res.signals_base.items()},
           "slips_flagged_rover": res.slips_rover, "slips_flagged_base": res.slips_base,
           "median_ratio_fixed": float(np.nanmedian(res.ratio[fixed])) if fixed.any() else None,
           "mean_n_sat": float(np.mean(res.n_sat[st >= 2])) if np.any(st >= 2) else 0.0,
           "age_s": {"median": float(np.nanmedian(np.abs(res.age_s))) if np.isfinite(res.age_s).any() else None,
                     "max": float(np.nanmax(np.abs(res.age_s))) if np.isfinite(res.age_s).any() else None}}
    for name, p in (("forward", res.forward), ("backward", res.backward)):
        if p is not None:
            out[f"{name}_fixed"] = int(np.sum(p.status == 3))
            # fixes made by the held integers alone report no ambiguity test (NaN): LAMBDA was not needed
            out[f"{name}_fixed_by_held_integers"] = int(np.sum((p.status == 3) & np.isnan(p.chi2[:, 0])))
            reasons: dict[str, int] = {}
            for k in np.nonzero(p.status == 2)[0]:
                reasons[p.reason[k] or "float"] = reasons.get(p.reason[k] or "float", 0) + 1
            out[f"{name}_float_reasons"] = reasons
    if fixed.any():
        R_ecef_to_enu = R_ecef_to_enu_at(res.p[fixed][0])
        senu = np.sqrt(np.maximum(np.einsum("ij,njk,lk->nil", R_ecef_to_enu, res.P[fixed], R_ecef_to_enu)
                                  .diagonal(axis1=1, axis2=2), 0))
        out["median_sigma_enu_fixed_m"] = np.median(senu, axis=0).tolist()
        out["median_ecef_fixed_m"] = np.median(res.p[fixed], axis=0).tolist()
    if reference_ecef is not None:
        ref = np.asarray(reference_ecef, float)
        R_ecef_to_enu = R_ecef_to_enu_at(ref)
        out["reference_ecef_m"] = ref.tolist()
        for name, m in (("fixed", fixed), ("all", st >= 1)):
            if not m.any():
                continue
            e = (res.p[m] - ref) @ R_ecef_to_enu.T
            out[f"error_{name}"] = {"n": int(m.sum()), "rms_3d_m": float(np.sqrt(np.mean(np.sum(e ** 2, axis=1)))),
                                    "mean_enu_m": e.mean(axis=0).tolist(), "std_enu_m": e.std(axis=0).tolist(),
                                    "rms_enu_m": np.sqrt(np.mean(e ** 2, axis=0)).tolist()}
    o = res.options
    out["options"] = {k: getattr(o, k) for k in o.__dataclass_fields__}
    out["engine"] = dict(res.info)          # baseline, ionosphere estimated or not, float variance factors
    return out
