"""Pix4D's BINGO export and Metashape's markers XML: files written as those programs write them, read into px."""
import numpy as np
import pyproj
import pytest

from dgcal.fields.errors import InputError
from dgcal.fields.io.bingo import is_bingo, read_bingo, read_image_map, write_bingo
from dgcal.fields.io.metashape_markers import is_metashape_markers, read_metashape_markers

W, H, PIX_MM = 8192, 5460, 0.0043945     # Zenmuse P1: 8192 x 5460 px, 4.4 um pixels


def truth(seed=3, n_img=3, n_pts=5):
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n_img):
        for j in range(n_pts):
            rows.append((f"DJI_20230712132737_{i + 1:04d}.JPG", str(1000 + j), rng.uniform(0, W - 1),
                         rng.uniform(0, H - 1)))
    return rows


def pix4d_bingo_text(rows, headers=None):
    """The layout of Pix4D's `_bingo.txt`: image name without extension + camera name, id x_mm y_mm, -99;
    mm from the image centre with y up (computed here independently of dgcal)."""
    out, images = [], list(dict.fromkeys(r[0] for r in rows))
    for k, name in enumerate(images):
        out.append(f"{headers[k] if headers else name.rsplit('.', 1)[0]} ZenmuseP1_35.0_8192x5460")
        for img, pid, u, v in rows:
            if img == name:
                out.append(f"{pid} {(u - (W - 1) / 2) * PIX_MM:.6f} {-(v - (H - 1) / 2) * PIX_MM:.6f}")
        out.append("-99")
    return "\n".join(out) + "\n"


def test_bingo_mm_y_up_centre_origin_to_pixels(tmp_path):
    rows = truth()
    p = tmp_path / "project_bingo.txt"
    p.write_text(pix4d_bingo_text(rows))
    assert is_bingo(p)
    names = sorted({r[0] for r in rows})
    m = read_bingo(p, (W, H), PIX_MM, image_names=names)
    assert list(m.image) == [r[0] for r in rows] and list(m.id) == [r[1] for r in rows]
    assert np.abs(m.xy - np.array([r[2:] for r in rows])).max() < 1e-3 / PIX_MM * 1e-3 + 1e-3
    # without names the headers are the labels; a mirrored file reads with y_up=False
    m2 = read_bingo(p, (W, H), PIX_MM, y_up=False)
    assert m2.image[0] == "DJI_20230712132737_0001"
    assert np.allclose(m2.xy[:, 1], (H - 1) - m.xy[:, 1], atol=1e-6)
    write_bingo(tmp_path / "again.txt", m, (W, H), PIX_MM, camera="ZenmuseP1_35.0_8192x5460")
    assert np.allclose(read_bingo(tmp_path / "again.txt", (W, H), PIX_MM, names).xy, m.xy, atol=1e-3)


def test_bingo_numbered_images_and_their_map(tmp_path):
    rows = truth(n_img=2)
    p = tmp_path / "image.dat"
    p.write_text(pix4d_bingo_text(rows, headers=["101", "102"]))
    mp = tmp_path / "images.txt"
    mp.write_text("# number name\n101 DJI_20230712132737_0001.JPG\n102, DJI_20230712132737_0002.JPG\n")
    m = read_bingo(p, (W, H), PIX_MM, image_names=read_image_map(mp))
    assert sorted(set(m.image)) == sorted({r[0] for r in rows})
    with pytest.raises(InputError, match=r"image.dat:\d+: field 'image'.*not in the image map"):
        read_bingo(p, (W, H), PIX_MM, image_names={"101": "a.jpg"})


@pytest.mark.parametrize("edit, line, field", [
    (lambda t: t.replace("-99\n", "", 1), 7, "x_mm"),          # a missing -99: the next header is a bad row
    (lambda t: t.replace("\n1001 ", "\n1001 12.5 ", 1), 3, "x_mm"),
    (lambda t: t.replace("\n1002 ", "\n1002 9999 x", 1), 4, "x_mm"),
    (lambda t: "-99\n" + t, 1, "image"),
    (lambda t: t.replace("\n1003 ", "\n1002 ", 1), 5, "point_id"),
])
def test_bingo_errors_name_line_and_field(tmp_path, edit, line, field):
    p = tmp_path / "b.txt"
    p.write_text(edit(pix4d_bingo_text(truth())))
    with pytest.raises(InputError) as exc:
        read_bingo(p, (W, H), PIX_MM)
    assert f"b.txt:{line}:" in str(exc.value) and f"field '{field}'" in str(exc.value)


def test_bingo_needs_plausible_camera(tmp_path):
    p = tmp_path / "b.txt"
    p.write_text(pix4d_bingo_text(truth()))
    with pytest.raises(InputError, match="pixel_size_mm"):
        read_bingo(p, (W, H), -1.0)
    with pytest.raises(InputError, match="image_size"):
        read_bingo(p, (0, H), PIX_MM)


# ---------------------------------------------------------------------------------------------
METASHAPE = """<?xml version="1.0" encoding="UTF-8"?>
<document version="1.5.0">
  <chunk label="Chunk 1" enabled="true">
    <sensors next_id="1">
      <sensor id="0" label="ZenmuseP1 (35mm)" type="frame">
        <resolution width="8192" height="5460"/>
      </sensor>
    </sensors>
    <cameras next_id="3" next_group_id="0">
      <camera id="0" sensor_id="0" label="DJI_0001"/>
      <camera id="1" sensor_id="0" label="DJI_0002"/>
      <camera id="2" sensor_id="0" label="DJI_0003"/>
    </cameras>
    <markers next_id="3" next_group_id="0">
      <marker id="0" label="GCP1">
        <reference x="500100.123" y="2519800.456" z="101.5" sx="0.01" sy="0.01" sz="0.02" enabled="true"/>
      </marker>
      <marker id="1" label="CP1">
        <reference x="500300.5" y="2519900.25" z="99.75" enabled="false"/>
      </marker>
      <marker id="2" label="tie 1"/>
    </markers>
    <frames next_id="1">
      <frame id="0">
        <markers>
          <marker marker_id="0">
            <location camera_id="0" pinned="true" x="4278" y="2187.5"/>
            <location camera_id="1" pinned="true" x="4100.25" y="1200.75"/>
            <location camera_id="2" pinned="false" x="3900.1" y="300.2"/>
          </marker>
          <marker marker_id="1">
            <location camera_id="1" pinned="true" x="10.5" y="20.5"/>
          </marker>
          <marker marker_id="2">
            <location camera_id="2" pinned="true" x="0.5" y="0.5"/>
          </marker>
        </markers>
      </frame>
    </frames>
    <reference>@WKT@</reference>
  </chunk>
</document>
""".replace("@WKT@", pyproj.CRS("EPSG:32650").to_wkt("WKT1_GDAL"))


def test_metashape_markers_points_roles_and_pixels(tmp_path):
    p = tmp_path / "markers.xml"
    p.write_text(METASHAPE)
    assert is_metashape_markers(p) and not is_bingo(p)
    pts, m, crs = read_metashape_markers(p, image_names=["DJI_0001.JPG", "DJI_0002.JPG", "DJI_0003.JPG"])
    assert list(pts.ids) == ["GCP1", "CP1"] and list(pts.role) == ["control", "check"]
    assert np.allclose(pts.xyz[0], [500100.123, 2519800.456, 101.5]) and np.allclose(pts.sigma[0], [.01, .01, .02])
    assert np.isnan(pts.sigma[1]).all()
    assert list(m.image) == ["DJI_0001.JPG", "DJI_0002.JPG", "DJI_0002.JPG", "DJI_0003.JPG"]
    assert list(m.id) == ["GCP1", "GCP1", "CP1", "tie 1"]
    # Metashape's pixel origin is the image's corner: the top-left pixel's centre (0.5, 0.5) is dgcal's (0, 0)
    assert np.allclose(m.xy, [[4277.5, 2187.0], [4099.75, 1200.25], [10.0, 20.0], [0.0, 0.0]])
    assert list(m.lines) == [27, 28, 32, 35]
    assert pyproj.CRS(crs).to_epsg() == 32650
    _, m_all, _ = read_metashape_markers(p, include_unpinned=True)
    assert len(m_all) == 5 and m_all.image[0] == "DJI_0001"


@pytest.mark.parametrize("old, new, line, field", [
    ('z="101.5"', 'z="nan"', 16, "z"),
    ('x="4100.25"', 'x="4100,25"', 28, "x"),
    ('camera_id="1" pinned="true" x="10.5"', 'camera_id="7" pinned="true" x="10.5"', 32, "camera_id"),
    ('<marker marker_id="1">', '<marker marker_id="9">', 31, "marker_id"),
    ('sx="0.01"', 'sx="-0.01"', 16, "sx"),
    ('enabled="false"', 'enabled="maybe"', 19, "enabled"),
    ('</frames>', '<frames>', 41, None),
])
def test_metashape_errors_name_line_and_field(tmp_path, old, new, line, field):
    p = tmp_path / "markers.xml"
    p.write_text(METASHAPE.replace(old, new, 1))
    with pytest.raises(InputError) as exc:
        read_metashape_markers(p)
    assert f"markers.xml:{line}:" in str(exc.value)
    if field:
        assert f"field '{field}'" in str(exc.value)


def test_pix4d_article_example_with_blank_lines(tmp_path):
    """The example of Pix4D's article 203590305 (images separated by blank lines, no -99) reads by content."""
    from dgcal.fields.io.gcp_files import read_any_measurements
    p = tmp_path / "project_bingo.txt"
    p.write_text("P1060498 H_8.07_6.0525\n1006 -1.90643 1.83493\n1020 2.00132 -0.797681\n\n"
                 "P1060499 H_8.07_6.0525\n\n1006 -2.42102 1.87814\n1020 2.15263 -0.33399\n")
    assert is_bingo(p)
    m, _, _ = read_any_measurements(p, (4000, 3000), 0.0015, ["P1060498.JPG", "P1060499.JPG"])
    assert list(m.image) == ["P1060498.JPG"] * 2 + ["P1060499.JPG"] * 2 and list(m.id) == ["1006", "1020"] * 2
    assert np.allclose(m.xy[0], [1999.5 - 1.90643 / 0.0015, 1499.5 - 1.83493 / 0.0015])


def test_metashape_geographic_markers_converted_to_the_map_crs(tmp_path):
    lon, lat = 117.00321, 22.78012
    geo = METASHAPE.replace('x="500100.123" y="2519800.456"', f'x="{lon}" y="{lat}"').split("<reference>PROJCS")[0]
    geo += '<reference>GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563]],' \
           'PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433],AUTHORITY["EPSG","4326"]]</reference>\n' \
           '  </chunk>\n</document>\n'
    p = tmp_path / "geo.xml"
    p.write_text(geo)
    pts, _, crs = read_metashape_markers(p, to_crs="EPSG:32650")
    x, y = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32650", always_xy=True).transform(lon, lat)
    assert crs == "EPSG:32650" and np.allclose(pts.xyz[0], [x, y, 101.5], atol=1e-6)
    assert np.allclose(pts.sigma[0], [0.01, 0.01, 0.02])
