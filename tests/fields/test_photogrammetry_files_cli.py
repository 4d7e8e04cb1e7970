"""`dgcal triangulate --measurements markers.xml`: a Metashape markers export (control, check, pinned locations)
gives the EOPs the same measurements give as dgcal CSV; a BINGO export of them reads back to the same pixels."""
import numpy as np
import pytest

from dgcal.calib.camera.files import read_camera
from dgcal.cli import main
from dgcal.fields.io.formats import read_eop, read_measurements, read_points
from dgcal.fields.io.gcp_files import read_any_measurements
from dgcal.sim.flight import simulate_block_flight


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    d = tmp_path_factory.mktemp("sim")
    truth = simulate_block_flight(d, seed=5, render=False, heights=(80.0,), n_strips=(3,), n_images=(7,), n_control=8,
                                  n_check=4, n_tie=250)
    return d, truth


def metashape_xml(points, meas) -> str:
    """A markers export as Metashape writes it: cameras, markers with references (enabled = control), pinned
    locations in Metashape's pixels (origin at the image's corner: dgcal's + 0.5)."""
    images = list(dict.fromkeys(meas.image.tolist()))
    cam_id = {n: k for k, n in enumerate(images)}
    ids = [str(i) for i in points.ids]
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', '<document version="1.5.0">', '  <chunk label="Chunk 1">',
             '    <cameras next_id="%d" next_group_id="0">' % len(images)]
    lines += [f'      <camera id="{k}" sensor_id="0" label="{n}"/>' for n, k in cam_id.items()]
    lines += ["    </cameras>", f'    <markers next_id="{len(ids)}" next_group_id="0">']
    for k, (pid, X, role) in enumerate(zip(ids, points.xyz, points.role)):
        enabled = "true" if role == "control" else "false"
        lines += [f'      <marker id="{k}" label="{pid}">',
                  f'        <reference x="{X[0]:.4f}" y="{X[1]:.4f}" z="{X[2]:.4f}" enabled="{enabled}"/>',
                  "      </marker>"]
    lines += ["    </markers>", '    <frames next_id="1">', '      <frame id="0">', "        <markers>"]
    for k, pid in enumerate(ids):
        rows = np.flatnonzero(meas.id.astype(str) == pid)
        if not len(rows):
            continue
        lines.append(f'          <marker marker_id="{k}">')
        lines += [f'            <location camera_id="{cam_id[meas.image[i]]}" pinned="true"'
                  f' x="{meas.xy[i, 0] + 0.5:.4f}" y="{meas.xy[i, 1] + 0.5:.4f}"/>' for i in rows]
        lines.append("          </marker>")
    lines += ["        </markers>", "      </frame>", "    </frames>", "  </chunk>", "</document>"]
    return "\n".join(lines) + "\n"


def test_metashape_markers_xml_from_the_cli(block, tmp_path):
    d, truth = block
    pts, gm = read_points(d / "gcp.csv"), read_measurements(d / "measurements.csv")
    xml = tmp_path / "markers.xml"
    xml.write_text(metashape_xml(pts, gm))
    args = ["triangulate", "--camera", d / "camera.json", "--crs", truth["crs"], "--sigma-px", 0.3,
            "--gcp-sigma", 0.01, 0.01, 0.02]
    assert main([*map(str, args), "--measurements", str(xml), str(d / "tie_measurements.csv"), "--out",
                 str(tmp_path / "ms")]) == 0
    assert main([*map(str, args), "--gcp", str(d / "gcp.csv"), "--measurements", str(d / "measurements.csv"),
                 str(d / "tie_measurements.csv"), "--out", str(tmp_path / "csv")]) == 0
    a, b = read_eop(tmp_path / "ms" / "eop.csv"), read_eop(tmp_path / "csv" / "eop.csv")
    assert sorted(a.image) == sorted(b.image)
    ib = [list(b.image).index(n) for n in a.image]
    # the same adjustment up to the files' rounding (0.1 mm, 1e-4 px) and the solver's stopping: far below a sigma
    assert np.abs(a.xyz - b.xyz[ib]).max() < 2e-3 and np.abs(a.opk - b.opk[ib]).max() < 3e-4
    assert (np.abs(a.xyz - b.xyz[ib]) / b.sigma[ib, :3]).max() < 0.05
    assert (np.abs(a.opk - b.opk[ib]) / b.sigma[ib, 3:]).max() < 0.05


def test_bingo_export_reads_back_to_the_pixels(block, tmp_path):
    from dgcal.fields.io.bingo import write_bingo
    d, _ = block
    cam = read_camera(d / "camera.json")
    m = read_measurements(d / "tie_measurements.csv")
    size = tuple(int(v) for v in cam.image_size)
    write_bingo(tmp_path / "p_bingo.txt", m, size, 0.0039, camera="sim_8.0_1200x800")
    back, crs, pts = read_any_measurements(tmp_path / "p_bingo.txt", size, 0.0039, sorted(set(m.image)))
    assert crs is None and pts is None and list(back.image) == list(m.image) and list(back.id) == list(m.id)
    assert np.abs(back.xy - m.xy).max() < 1e-3      # 6 decimals of mm = 2.6e-4 px at 3.9 um


def test_bingo_file_from_the_cli(block, tmp_path, capsys):
    """`--measurements p_bingo.txt --pixel-size-mm MM`: the tie points as Pix4D's BINGO export (sensor mm, labels
    without extension, matched to the control file's image names) give the EOPs of the CSV run; without the pixel
    size the run is refused naming the option."""
    from dgcal.fields.io.bingo import write_bingo
    d, truth = block
    cam = read_camera(d / "camera.json")
    size = tuple(int(v) for v in cam.image_size)
    write_bingo(tmp_path / "p_bingo.txt", read_measurements(d / "tie_measurements.csv"), size, 0.0039)
    args = ["triangulate", "--camera", d / "camera.json", "--crs", truth["crs"], "--sigma-px", 0.3, "--gcp",
            d / "gcp.csv", "--gcp-sigma", 0.01, 0.01, 0.02]
    bingo = [*map(str, args), "--measurements", str(d / "measurements.csv"), str(tmp_path / "p_bingo.txt")]
    assert main(bingo + ["--out", str(tmp_path / "nopix")]) == 2
    assert "--pixel-size-mm" in capsys.readouterr().err
    assert not (tmp_path / "nopix").exists()
    assert main(bingo + ["--pixel-size-mm", "0.0039", "--out", str(tmp_path / "bingo")]) == 0
    assert main([*map(str, args), "--measurements", str(d / "measurements.csv"), str(d / "tie_measurements.csv"),
                 "--out", str(tmp_path / "csv")]) == 0
    a, b = read_eop(tmp_path / "bingo" / "eop.csv"), read_eop(tmp_path / "csv" / "eop.csv")
    ib = [list(b.image).index(n) for n in a.image]
    assert sorted(a.image) == sorted(b.image)
    assert (np.abs(a.xyz - b.xyz[ib]) / b.sigma[ib, :3]).max() < 0.05
