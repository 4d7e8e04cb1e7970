"""The files of `dgcal triangulate`: EOPs (map CRS), JSON summary, HTML report, adjusted points, residuals and
exports to mapping software, from a dgcal.bundle.inputs.TriangulationRun."""
from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from dgcal.bundle.inputs import TriangulationRun
from dgcal.fields.crs import MapGrid
from dgcal.fields.io.csv_tables import write_table
from dgcal.fields.io.formats import write_eop
from dgcal.reports.bundle import write_bundle_report, write_summary_json
from dgcal.reports.exports.eop import export_all

ROLES = ("eop", "summary", "report", "points", "residuals", "exports")


def write_triangulation_outputs(out_dir: str | Path, run: TriangulationRun,
                                names: Mapping[str, str]) -> dict[str, Path]:
    """Write the triangulation's files into `out_dir`, named by role in `names` (`ROLES`): eop.csv (PATB, m,
    deg), summary.json, report.html, points.csv (adjusted points, map CRS), residuals.csv (px) and the
    exports folder (the formats of `run.formats`); returns the paths by role."""
    out = Path(out_dir)
    res = run.result
    paths = {role: out / names[role] for role in ROLES}
    if run.formats:
        ctrl = {g["id"]: g["xyz"] for g in res.gcp}
        meas = run.inputs.measurements
        obs = [(meas.image[i], meas.id[i], *meas.xy[i]) for i in range(len(meas)) if str(meas.id[i]) in ctrl]
        export_all(paths["exports"], res.eop, None if run.crs is None else MapGrid(run.crs), run.inputs.camera,
                   run.formats, points_map=ctrl, observations=obs)
    else:
        del paths["exports"]
    write_eop(paths["eop"], res.eop)
    write_summary_json(paths["summary"], res)
    write_bundle_report(paths["report"], res)
    X_map = res.georef.to_map(res.bundle.X_world)
    write_table(paths["points"], ["id", "x", "y", "z", "kind"],
                ([p, *X_map[j], res.point_kind[j]] for j, p in enumerate(res.point_ids)), fmt="%.6f")
    obs_image, obs_point = res.bundle.obs_image, res.bundle.obs_point
    write_table(paths["residuals"], ["image", "id", "rx", "ry"],
                ([res.images[obs_image[k]], res.point_ids[obs_point[k]], *res.bundle.residuals_px[k]]
                 for k in range(len(obs_image))), fmt="%.4f")
    return paths
