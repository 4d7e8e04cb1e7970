"""Camera centres from DJI JPEGs (XMP drone-dji tags, EXIF GPS) built here byte by byte, and the centres CSV."""
import struct

import cv2
import numpy as np
import pyproj
import pytest

from dgcal.fields.errors import InputError
from dgcal.fields.io.centres import read_centres, write_centres
from dgcal.fields.io.dji_images import (DEFAULT_SIGMA_M, dji_centres, jpeg_app1_segments, read_dji_photo,
                                        rtk_class)

XMP = ('<?xpacket begin="\ufeff" id="W5M0MpCehiHzreSzNTczkc9d"?><x:xmpmeta xmlns:x="adobe:ns:meta/">'
       '<rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#"><rdf:Description rdf:about="DJI Meta Data"'
       ' xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/" drone-dji:GpsStatus="RTK"'
       ' drone-dji:AltitudeType="RtkAlt" drone-dji:GpsLatitude="{lat}" drone-dji:{lonkey}="{lon}"'
       ' drone-dji:AbsoluteAltitude="{h}" drone-dji:RelativeAltitude="+150.05"'
       ' drone-dji:GimbalRollDegree="+0.00" drone-dji:GimbalYawDegree="-12.30" drone-dji:GimbalPitchDegree="-90.00"'
       ' drone-dji:FlightRollDegree="+1.20" drone-dji:FlightYawDegree="-11.90" drone-dji:FlightPitchDegree="+3.40"'
       '{rtk}/></rdf:RDF></x:xmpmeta><?xpacket end="w"?>')


def jpeg_with(app1_payloads) -> bytes:
    """A tiny real JPEG (OpenCV) with APP1 segments inserted after SOI, as cameras write them."""
    ok, buf = cv2.imencode(".jpg", np.full((8, 8, 3), 128, np.uint8))
    data = buf.tobytes()
    segs = b"".join(b"\xff\xe1" + struct.pack(">H", len(p) + 2) + p for p in app1_payloads)
    return data[:2] + segs + data[2:]


def xmp_payload(lat=22.77995359, lon=114.10089118, h="+139.231", lonkey="GpsLongitude", rtk=None) -> bytes:
    rtk = ' drone-dji:RtkFlag="50" drone-dji:RtkStdLon="0.01100" drone-dji:RtkStdLat="0.01200"' \
          ' drone-dji:RtkStdHgt="0.02300"' if rtk is None else rtk
    return b"http://ns.adobe.com/xap/1.0/\x00" + XMP.format(lat=lat, lon=lon, h=h, lonkey=lonkey,
                                                            rtk=rtk).encode("utf-8")


def exif_payload(lat, lon, alt) -> bytes:
    """EXIF with a GPS IFD written by Pillow (an independent writer)."""
    from PIL import Image

    def dms(v):
        v = abs(v)
        d = int(v)
        m = int((v - d) * 60)
        return (float(d), float(m), (v - d - m / 60) * 3600)
    ex = Image.Exif()
    ex[0x8825] = {1: "N" if lat >= 0 else "S", 2: dms(lat), 3: "E" if lon >= 0 else "W", 4: dms(lon),
                  5: b"\x00", 6: float(alt)}
    return ex.tobytes()


def test_xmp_centre_sigmas_and_angles(tmp_path):
    p = tmp_path / "DJI_20230712132737_0436.JPG"
    p.write_bytes(jpeg_with([xmp_payload()]))
    ph = read_dji_photo(p)
    assert (ph.lat, ph.lon, ph.h) == (22.77995359, 114.10089118, 139.231)
    assert ph.rtk_flag == 50 and ph.sigma_nev_m == (0.012, 0.011, 0.023)
    assert ph.gimbal_rpy_deg == (0.0, -90.0, -12.3) and ph.flight_rpy_deg == (1.2, 3.4, -11.9)
    eop = dji_centres(tmp_path, "EPSG:32650")
    x, y = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32650", always_xy=True).transform(114.10089118, 22.77995359)
    assert np.allclose(eop.xyz[0], [x, y, 139.231], atol=1e-6)
    assert np.allclose(eop.sigma[0, :3], [0.011, 0.012, 0.023]) and np.isnan(eop.opk).all()


def test_dji_typo_longtitude_and_flag_defaults(tmp_path):
    for k, (flag, cls) in enumerate([(50, "fixed"), (34, "float"), (16, "single"), (0, "none")]):
        (tmp_path / f"IMG_{k}.JPG").write_bytes(jpeg_with([xmp_payload(lonkey="GpsLongtitude",
                                                                       rtk=f' drone-dji:RtkFlag="{flag}"')]))
        assert rtk_class(flag) == cls
    eop = dji_centres(sorted(tmp_path.glob("*.JPG")), "EPSG:32650")
    assert np.allclose(eop.sigma[:, 2], [DEFAULT_SIGMA_M[c][2] for c in ("fixed", "float", "single", "none")])
    assert np.all(np.diff(eop.sigma[:, 0]) > 0)


def test_exif_gps_fallback(tmp_path):
    p = tmp_path / "a.jpg"
    p.write_bytes(jpeg_with([exif_payload(-33.5, -70.25, 812.5)]))
    ph = read_dji_photo(p)
    assert np.allclose([ph.lat, ph.lon, ph.h], [-33.5, -70.25, 812.5], atol=1e-7)
    assert ph.rtk_flag is None
    # EXIF first, XMP second: XMP wins, EXIF only fills what XMP lacks
    p.write_bytes(jpeg_with([exif_payload(1.0, 2.0, 3.0), xmp_payload()]))
    assert read_dji_photo(p).lat == 22.77995359


def test_geoid_undulation_added(tmp_path):
    p = tmp_path / "a.jpg"
    p.write_bytes(jpeg_with([xmp_payload()]))
    assert read_dji_photo(p, geoid_undulation_m=-3.5).h == pytest.approx(135.731)


@pytest.mark.parametrize("data, field", [
    (b"GIF89a....", "image"),
    (None, "GpsLatitude"),
    ("lat", "drone-dji:GpsLatitude"),
    ("h", "drone-dji:AbsoluteAltitude"),
])
def test_bad_images_name_the_field(tmp_path, data, field):
    p = tmp_path / "x.jpg"
    if data is None:
        p.write_bytes(jpeg_with([]))
    elif data == "lat":
        p.write_bytes(jpeg_with([xmp_payload(lat=95.0)]))
    elif data == "h":
        p.write_bytes(jpeg_with([xmp_payload(h="nan")]))
    else:
        p.write_bytes(data)
    with pytest.raises(InputError) as exc:
        read_dji_photo(p)
    assert "x.jpg" in str(exc.value) and f"field '{field}'" in str(exc.value)


def test_truncated_segment_is_an_input_error():
    data = jpeg_with([xmp_payload()])
    with pytest.raises(InputError, match="runs past the end"):
        jpeg_app1_segments(data[:40])


def test_centres_csv_round_trip_with_blank_angles(tmp_path):
    for k in range(3):
        (tmp_path / f"DJI_{k:04d}.JPG").write_bytes(jpeg_with([xmp_payload(lat=22.78 + k * 1e-4)]))
    eop = dji_centres(tmp_path, "EPSG:32650")
    out = tmp_path / "centres.csv"
    write_centres(out, eop)
    text = out.read_text().splitlines()
    assert text[0] == "image,X,Y,Z,omega,phi,kappa,sX,sY,sZ" and ",,,," in text[1]
    back = read_centres(out)
    assert list(back.image) == list(eop.image) and np.allclose(back.xyz, eop.xyz, atol=1e-4)
    assert np.isnan(back.opk).all() and np.allclose(back.sigma[:, :3], eop.sigma[:, :3], atol=1e-4)
    out.write_text(out.read_text().replace(",0.0110,", ",-0.0110,", 1))
    with pytest.raises(InputError, match=r"centres.csv:2: field 'sx'"):
        read_centres(out)


def test_read_any_centres_folder_jpeg_or_csv(tmp_path):
    from dgcal.fields.io.dji_images import read_any_centres
    d = tmp_path / "imgs"
    d.mkdir()
    (d / "DJI_0001.JPG").write_bytes(jpeg_with([xmp_payload()]))
    a = read_any_centres(d, "EPSG:32650")
    b = read_any_centres(d / "DJI_0001.JPG", "EPSG:32650")
    write_centres(tmp_path / "c.csv", a)
    c = read_any_centres(tmp_path / "c.csv", "EPSG:32650")
    assert list(a.image) == list(b.image) == list(c.image) == ["DJI_0001.JPG"]
    assert np.allclose(a.xyz, c.xyz, atol=1e-4) and np.allclose(a.xyz, b.xyz)
    with pytest.raises(InputError, match="projected CRS"):
        read_any_centres(d, "EPSG:4326")


def test_large_preview_segments_before_the_xmp_are_skipped(tmp_path):
    """DJI stores previews in APP2 segments: metadata after 2 MB of them is still found (headers only are read)."""
    data = jpeg_with([xmp_payload()])
    app2 = b"\xff\xe2" + struct.pack(">H", 65535) + b"\x00" * 65533
    p = tmp_path / "big.jpg"
    p.write_bytes(data[:2] + app2 * 32 + data[2:])
    assert read_dji_photo(p).rtk_flag == 50


def test_gimbal_angles_as_patb():
    from dgcal.fields.frames import R_cam_to_map_from_opk
    from dgcal.fields.io.dji_images import gimbal_opk
    # nadir, image top to north: (0, 0, 0); image top to east: kappa -90 (photo y axis -> east)
    assert np.allclose(gimbal_opk([[0.0, -90.0, 0.0]], 0.0), [[0, 0, 0]], atol=1e-9)
    assert np.allclose(gimbal_opk([[0.0, -90.0, 90.0]], 0.0), [[0, 0, -90]], atol=1e-9)
    # with a convergence of 1.1 deg (grid north 1.1 deg east of true north) a true-north image top has kappa +1.1
    assert np.allclose(gimbal_opk([[0.0, -90.0, 0.0]], 1.1), [[0, 0, 1.1]], atol=1e-9)
    # an oblique view (pitch -60, yaw 30): the optical axis points 30 deg east of north, 60 deg below the horizon
    R = R_cam_to_map_from_opk(*gimbal_opk([[0.0, -60.0, 30.0]], 0.0)[0])
    z = R[:, 2]
    assert np.allclose(z, [np.sin(np.radians(30)) * 0.5, np.cos(np.radians(30)) * 0.5, -np.sin(np.radians(60))])
    assert R[2, 0] == pytest.approx(0.0, abs=1e-12)       # zero roll: the image x axis stays level


def test_centres_with_gimbal_angles(tmp_path):
    (tmp_path / "a.JPG").write_bytes(jpeg_with([xmp_payload()]))
    eop = dji_centres(tmp_path, "EPSG:32650", angles=True)
    assert np.isfinite(eop.opk).all() and abs(eop.opk[0, 0]) < 1e-6
