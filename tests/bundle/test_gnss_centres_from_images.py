"""`dgcal triangulate --gnss DIR`: camera centres read from DJI images' XMP (a folder of JPEGs) are the datum of a
GCP-free adjustment, as the same centres in a CSV are."""
from __future__ import annotations

import json

import numpy as np
import pyproj
from test_dji_images import jpeg_with, xmp_payload

from dgcal.cli import main
from dgcal.fields.io.formats import EOP, Measurements, write_eop, write_measurements
from dgcal.sim.block import simulate_rtk_block, write_block


def test_gnss_folder_of_dji_jpegs_equals_the_centres_csv(tmp_path):
    sim = simulate_rtk_block(3, n_images=36, n_control=0)
    data = write_block(sim, tmp_path / "data")
    # the images as a DJI drone names and tags them: JPEGs with the RTK centre in their XMP
    jpg = {str(n): f"DJI_{i:04d}.JPG" for i, n in enumerate(sim.centres.image)}
    m = sim.measurements
    write_measurements(data / "meas_jpg.csv", Measurements(np.array([jpg[str(n)] for n in m.image], object), m.id,
                                                           m.xy, m.sigma))
    to_geo = pyproj.Transformer.from_crs(sim.crs, "EPSG:4979", always_xy=True)
    folder = tmp_path / "images"
    folder.mkdir()
    c, s = sim.centres.xyz, sim.centres.sigma
    lon, lat, h = to_geo.transform(c[:, 0], c[:, 1], c[:, 2])
    for i, name in enumerate(sim.centres.image):
        rtk = (f' drone-dji:RtkFlag="50" drone-dji:RtkStdLon="{s[i, 0]:.4f}" drone-dji:RtkStdLat="{s[i, 1]:.4f}"'
               f' drone-dji:RtkStdHgt="{s[i, 2]:.4f}"')
        (folder / jpg[str(name)]).write_bytes(jpeg_with([xmp_payload(f"{lat[i]:.10f}", f"{lon[i]:.10f}",
                                                                     f"{h[i]:+.4f}", rtk=rtk)]))
    write_eop(data / "centres_jpg.csv", EOP(np.array([jpg[str(n)] for n in sim.centres.image], object), c,
                                            sim.centres.opk, sim.centres.sigma))
    common = ["triangulate", "--camera", str(data / "camera.json"), "--gcp", str(data / "gcp.csv"), "--crs", sim.crs,
              "--measurements", str(data / "meas_jpg.csv"), "--image-size", *map(str, sim.camera.image_size)]
    assert main(common + ["--gnss", str(folder), "--out", str(tmp_path / "from_jpgs")]) == 0
    assert main(common + ["--gnss", str(data / "centres_jpg.csv"), "--out", str(tmp_path / "from_csv")]) == 0
    a = json.loads((tmp_path / "from_jpgs" / "summary.json").read_text())
    b = json.loads((tmp_path / "from_csv" / "summary.json").read_text())
    assert a["n_oriented"] == b["n_oriented"] == 36 and a["trusted"]
    assert "36 camera centres" in a["datum"]["text"] and a["datum"]["n_control"] == 0
    for k in ("E", "N", "U"):
        assert abs(a["check_rmse_m"][k] - b["check_rmse_m"][k]) < 2e-3   # the XMP's 1e-10 deg and 0.1 mm rounding
