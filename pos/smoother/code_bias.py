"""Time-correlated pseudorange errors as states of the TC smoother: one Gauss-Markov bias per satellite.

A pseudorange's error is receiver noise (white at the epoch rate) plus what the broadcast orbit, clock,
ionosphere and troposphere models leave, which changes over tens of minutes. Weighted as white noise, the second
part is averaged over every epoch the IMU bridges and the trajectory's sigmas shrink by the square root of the
epoch count while its error does not (a real u-blox walk: 21 m errors with 0.3-0.6 m sigmas). Here each
satellite's slow error is a first-order Gauss-Markov state b (m) with the front end's budget as its standard
deviation (`GnssEpoch.sigma_pr_bias_m`, elevation dependent) and correlation time `tau_s`:

    b_k = sigma_k u_k,   u_{k+1} = phi u_k + w_k,   phi = exp(-dt/tau),   var(w) = 1 - phi^2,   u_first ~ N(0, 1)

The state is a scalar key `CB(slot, k)` in metres holding the correction d = -b that gtsam's
`DifferentialPseudorangeFactorArm` subtracts from its predicted range (white noise only on the pseudorange); the
Gauss-Markov factors are linear (JacobianFactors on two keys). A satellite's bias lives from
its first to its last pseudorange (through short gaps, where only the process ties it); after a gap longer than
two correlation times a new, independent arc starts. Arcs share `n_slots` slots (a slot serves one arc at a time),
so every keyframe block has the same layout for the covariance recursion (`dgcal.pos.smoother.covariance`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np


_SLOT_STRIDE = 10_000_000   # keyframe indices below this per slot


def CB(slot: int, k: int) -> int:
    """Key of the pseudorange correction (m, minus the bias) held by a code-bias slot at keyframe k."""
    return gtsam.symbol("q", slot * _SLOT_STRIDE + k)


@dataclass
class CodeBiasArcs:
    """The code-bias arcs of a flight: satellite, system, slot, first and last keyframe and the bias sigma (m) at
    every keyframe of the arc; `at[k]` maps a satellite to its (arc, slot) at keyframe k."""

    sat: list = field(default_factory=list)
    system: list = field(default_factory=list)
    slot: list = field(default_factory=list)
    k0: list = field(default_factory=list)
    k1: list = field(default_factory=list)
    sigma: list = field(default_factory=list)
    n_slots: int = 0
    tau_s: float = 1800.0
    at: list = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.sat)

    def key(self, sat: str, k: int) -> int | None:
        """The CB key of a satellite at keyframe k, or None if it has no bias state there."""
        hit = self.at[k].get(sat) if k < len(self.at) else None
        return None if hit is None else CB(hit[1], k)

    def previous(self, key: int, k: int) -> int | None:
        """The key of the same arc at keyframe k-1 as `key` (a CB key at k), or None at an arc's start."""
        slot = gtsam.Symbol(key).index() // _SLOT_STRIDE
        for a, j in self.at[k].values():
            if j == slot:
                return CB(slot, k - 1) if self.k0[a] < k else None
        return None

    def where(self) -> dict:
        """key -> (keyframe, slot) of every bias key."""
        out = {}
        for a in range(len(self.sat)):
            for k in range(self.k0[a], self.k1[a] + 1):
                out[CB(self.slot[a], k)] = (k, self.slot[a])
        return out

    def active(self, K: int) -> np.ndarray:
        """(K, n_slots) bool: which slot holds an arc at each keyframe."""
        act = np.zeros((K, self.n_slots), bool)
        for a in range(len(self.sat)):
            act[self.k0[a]:self.k1[a] + 1, self.slot[a]] = True
        return act


def code_bias_arcs(t_key: np.ndarray, epochs_at_key: list, tau_s: float, skip: set | None = None,
                   min_sigma_m: float = 1e-3) -> CodeBiasArcs:
    """Arcs of the satellites whose pseudoranges carry a bias budget (`sigma_pr_bias_m` > `min_sigma_m`), at the
    keyframes of `epochs_at_key` (keyframes in `skip` have no pseudorange factors, e.g. double differences)."""
    skip = skip or set()
    seen: dict = {}
    for k, ep in enumerate(epochs_at_key):
        if ep is None or k in skip or ep.sigma_pr_bias_m is None:
            continue
        ok = np.isfinite(ep.pr_corr_m) & (np.asarray(ep.sigma_pr_bias_m) > min_sigma_m)
        for i in np.flatnonzero(ok):
            seen.setdefault(ep.sat[i], []).append((k, float(ep.sigma_pr_bias_m[i]), str(ep.system[i])))
    arcs = CodeBiasArcs(tau_s=float(tau_s), at=[{} for _ in range(len(t_key))])
    pieces = []
    for sat, rows in seen.items():
        ks = np.array([r[0] for r in rows])
        sg = np.array([r[1] for r in rows])
        cut = np.flatnonzero(np.diff(t_key[ks]) > 2.0 * tau_s) + 1
        for part_k, part_s in zip(np.split(ks, cut), np.split(sg, cut)):
            pieces.append((int(part_k[0]), int(part_k[-1]), sat, rows[0][2], part_k, part_s))
    pieces.sort(key=lambda p: (p[0], p[2]))
    free_after: list = []   # per slot: the last keyframe of its current arc
    for k0, k1, sat, system, ks, sg in pieces:
        slot = next((j for j, last in enumerate(free_after) if last < k0), len(free_after))
        if slot == len(free_after):
            free_after.append(k1)
        else:
            free_after[slot] = k1
        a = len(arcs.sat)
        arcs.sat.append(sat)
        arcs.system.append(system)
        arcs.slot.append(slot)
        arcs.k0.append(k0)
        arcs.k1.append(k1)
        arcs.sigma.append(np.interp(np.arange(k0, k1 + 1), ks, sg))
        for k in range(k0, k1 + 1):
            arcs.at[k][sat] = (a, slot)
    arcs.n_slots = len(free_after)
    return arcs


def insert_initial(arcs: CodeBiasArcs, values) -> None:
    """Initial values of the bias keys: zero."""
    for a in range(len(arcs)):
        for k in range(arcs.k0[a], arcs.k1[a] + 1):
            values.insert(CB(arcs.slot[a], k), 0.0)


def _linear(keys: list, coeffs: list, sigma: float, lin_values):
    """The linear factor sum(coeffs * x) ~ N(0, sigma^2) about `lin_values` (error exactly A x, as
    `dgcal.pos.smoother.factors.clock_factors` builds it)."""
    x0 = sum(c * lin_values.atDouble(key) for key, c in zip(keys, coeffs))
    args = []
    for key, c in zip(keys, coeffs):
        args += [key, np.array([[float(c)]])]
    jf = gtsam.JacobianFactor(*args, np.array([-x0]), gtsam.noiseModel.Isotropic.Sigma(1, float(sigma)))
    return gtsam.LinearContainerFactor(jf, lin_values)


def bias_process_factors(arcs: CodeBiasArcs, t_key: np.ndarray, lin_values) -> list[tuple[int, object]]:
    """(keyframe, factor) of every arc's prior u ~ N(0, 1) at its first keyframe and its Gauss-Markov steps
    u_{k+1} - phi u_k ~ N(0, 1 - phi^2), u = d / sigma (see the module docstring)."""
    out = []
    for a in range(len(arcs)):
        j, sig = arcs.slot[a], arcs.sigma[a]
        k0 = arcs.k0[a]
        out.append((k0, _linear([CB(j, k0)], [1.0 / sig[0]], 1.0, lin_values)))
        for k in range(k0, arcs.k1[a]):
            phi = float(np.exp(-(t_key[k + 1] - t_key[k]) / arcs.tau_s))
            out.append((k + 1, _linear([CB(j, k + 1), CB(j, k)], [1.0 / sig[k + 1 - k0], -phi / sig[k - k0]],
                                       float(np.sqrt(max(1.0 - phi * phi, 1e-12))), lin_values)))
    return out


def bias_estimates(arcs: CodeBiasArcs, values) -> dict:
    """Estimated bias (m, measured minus modelled range) of every satellite at its arcs' keyframes:
    sat -> (keyframes, bias)."""
    out: dict = {}
    for a in range(len(arcs)):
        ks = np.arange(arcs.k0[a], arcs.k1[a] + 1)
        b = -np.array([values.atDouble(CB(arcs.slot[a], k)) for k in ks])
        prev = out.get(arcs.sat[a])
        out[arcs.sat[a]] = (ks, b) if prev is None else (np.r_[prev[0], ks], np.r_[prev[1], b])
    return out
