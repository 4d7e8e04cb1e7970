"""The files of `dgcal triangulate`: EOPs (map CRS), JSON summary, HTML report, adjusted points, residuals and
exports to mapping software, from a dgcal.bundle.inputs.TriangulationRun."""
from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from dgcal.bundle.inputs import TriangulationRun
from dgcal.calib.camera.files import write_camera_json
from dgcal.fields.crs import MapGrid
from dgcal.fields.io.csv_tables import write_table
from dgcal.fields.io.formats import write_eop
from dgcal.reports.bundle import triangulation_honesty, write_bundle_report, write_summary_json
from dgcal.reports.exports.eop import export_all

ROLES = ("eop", "summary", "report", "points", "residuals", "exports", "camera_refined")


def write_triangulation_outputs(out_dir: str | Path, run: TriangulationRun,
                                names: Mapping[str, str]) -> dict[str, Path]:
    """Write the triangulation's files into `out_dir`, named by role in `names` (`ROLES`): eop.csv (PATB, m,
    deg), summary.json (with the check points' honesty record), report.html, points.csv (adjusted points, map
    CRS), residuals.csv (px) and the exports folder (the formats of `run.formats`); returns the paths by role."""
    out = Path(out_dir)
    res = run.result
    paths = {role: out / names[role] for role in ROLES if role in names}
    if run.formats:
        ctrl = {g["id"]: g["xyz"] for g in res.gcp}
        meas = run.inputs.measurements
        obs = [(meas.image[i], meas.id[i], *meas.xy[i]) for i in range(len(meas)) if str(meas.id[i]) in ctrl]
        # the camera of the adjustment: refined in flight when asked, so the exports pair EOPs and camera
        export_all(paths["exports"], res.eop, None if run.crs is None else MapGrid(run.crs), res.camera,
                   run.formats, points_map=ctrl, observations=obs)
    else:
        paths.pop("exports", None)
    if res.bundle.refine and "camera_refined" in paths:
        write_refined_camera(paths["camera_refined"], res)
    else:
        paths.pop("camera_refined", None)
    write_eop(paths["eop"], res.eop)
    honesty = triangulation_honesty(res, run.inputs.points)
    write_summary_json(paths["summary"], res, honesty)
    write_bundle_report(paths["report"], res, honesty=honesty)
    X_map = res.georef.to_map(res.bundle.X_world)
    write_table(paths["points"], ["id", "x", "y", "z", "kind"],
                ([p, *X_map[j], res.point_kind[j]] for j, p in enumerate(res.point_ids)), fmt="%.6f")
    obs_image, obs_point = res.bundle.obs_image, res.bundle.obs_point
    write_table(paths["residuals"], ["image", "id", "rx", "ry"],
                ([res.images[obs_image[k]], res.point_ids[obs_point[k]], *res.bundle.residuals_px[k]]
                 for k in range(len(obs_image))), fmt="%.4f")
    return paths


def write_refined_camera(path: str | Path, res) -> None:
    """camera_refined.json: the camera with the intrinsics refined in flight, their sigmas and correlations
    (the other parameters as given, sigma 0)."""
    b = res.bundle
    cov = b.cov_intrinsics
    sd = np.sqrt(np.clip(np.diag(cov), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(sd, sd)
    sig = np.zeros(len(res.camera.PARAMS))
    idx = [res.camera.PARAMS.index(p) for p in b.refine]
    sig[idx] = sd
    stats = {"source": "dgcal triangulate (intrinsics refined in flight)", "refined": list(b.refine),
             "correlation": {"parameters": list(b.refine), "matrix": corr.tolist()},
             "sigma0": float(b.sigma0), "n_observations": int(len(b.obs_image)),
             "rms_px": float(np.sqrt(np.nanmean(np.sum(b.residuals_px ** 2, 1)))), "n_rejected": 0}
    write_camera_json(path, res.camera, sig, stats)
