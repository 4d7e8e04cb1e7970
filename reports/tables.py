"""Tables more than one report shows, built the same way everywhere: a camera's parameters with their units and
sigmas, and the GNSS/INS residual statistics per factor with each factor's unit."""
from __future__ import annotations

from dgcal.reports.glossary import label
from dgcal.reports.units import fmt_number, value_sigma, with_unit

PX_PARAMETERS = {"f", "fx", "fy", "cx", "cy", "b1", "b2"}   # in pixels; the others are unitless coefficients

# the unit of each GNSS/INS factor's residuals (dgcal.pos summaries' `residuals` and `innovations` keys)
RESIDUAL_UNITS = {"pr": "m", "ddp": "m", "ddp_float": "m", "ddc": "m", "dop": "m/s", "pos": "m", "vel": "m/s"}


def parameter_unit(name: str) -> str:
    """The unit of a camera parameter: 'px' for focal lengths, principal point and affinity, '' for coefficients."""
    return "px" if str(name).lower() in PX_PARAMETERS else ""


def parameter_rows(names, values, sigmas, t_values=None) -> list[list[str]]:
    """Rows 'parameter, unit, value, sigma[, t]' with the value's decimals following its sigma (None: held fixed)."""
    rows = []
    for i, (k, v, s) in enumerate(zip(names, values, sigmas)):
        u = parameter_unit(k)
        a, b = value_sigma(float(v), None if s is None else float(s), u)
        row = [k, u or "unitless", a, b]
        if t_values is not None:
            t = t_values[i]
            row.append("–" if t is None else f"{t:.1f}")
        rows.append(row)
    return rows


RESIDUAL_HEADER = ["factor", "n", "RMS (unit per row)", "RMS / σ", "max |e| (unit per row)", "share beyond 3σ (%)"]


def residual_rows(stats: dict) -> list[list[str]]:
    """One row per factor of a residual or innovation summary (n, rms, rms_normalised, max_abs, share_beyond_3sigma):
    the factor's words, its RMS and max with their unit, the RMS over sigma, the share beyond 3 sigma in percent."""
    rows = []
    for k, v in stats.items():
        u = RESIDUAL_UNITS.get(k, "")
        share = v.get("share_beyond_3sigma")
        rows.append([label(k), v.get("n"), with_unit(v.get("rms"), u), fmt_number(v.get("rms_normalised"), "",
                                                                                  decimals=2),
                     with_unit(v.get("max_abs"), u), "–" if share is None else fmt_number(100 * share, "%")])
    return rows


def flat_pairs(summary: dict, skip=()) -> list[tuple[str, object]]:
    """(name, value) rows of a summary's keys not in `skip` whose values a table can show: numbers, texts, lists of
    numbers, and one level of a mapping of those (as 'key: sub-key'); a mapping's 'text' is the key's own row.
    Deeper structures (lists of records) are left to the JSON file. Names stay raw keys: the page's builder turns
    them into words with units (dgcal.reports.glossary)."""
    out = []
    for k, v in summary.items():
        if k in skip or v is None:
            continue
        if isinstance(v, dict):
            if isinstance(v.get("text"), str):
                out.append((k, v["text"]))
            out += [(f"{label(k)}: {label(sk)}", sv) for sk, sv in v.items() if sk != "text" and _flat(sv)]
        elif _flat(v):
            out.append((k, v))
    return out


def _flat(v) -> bool:
    if isinstance(v, (list, tuple)):
        return len(v) <= 12 and all(isinstance(x, (int, float, str)) and not isinstance(x, bool) for x in v)
    return isinstance(v, (int, float, str, bool))


def add_residual_table(rep, stats: dict) -> None:
    """The residual statistics of a GNSS/INS run as one table in `rep` (nothing when there are none)."""
    if stats:
        rep.table(RESIDUAL_HEADER, residual_rows(stats))
