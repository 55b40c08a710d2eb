"""Cameras files: the first glob that fits wins; bad entries name the JSON path."""

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.conftest import shared_data_dir
from toosicubix.errors import FormatError
from toosicubix.formats.cameras import load_cameras

K = [[700.0, 0.0, 600.0], [0.0, 700.0, 180.0], [0.0, 0.0, 1.0]]


def test_first_match_wins(tmp_path):
    path = tmp_path / "cameras.json"
    path.write_text(json.dumps({"cameras": [{"match": "*Camera_5*", "K": K, "distortion": [0.1, 0, 0, 0, 0]},
                                            {"match": "*.png", "K": [[500, 0, 1], [0, 500, 2], [0, 0, 1]]}]}))
    table = load_cameras(path)
    assert table.camera_for("road/Camera_5/a.png") == {"K": K, "distortion": [0.1, 0, 0, 0, 0]}
    assert table.camera_for("b.png")["K"][0][0] == 500
    assert table.camera_for("b.jpg") is None


@pytest.mark.parametrize(("entry", "message"), [
    ({"K": K}, r"\$.cameras\[0\].match: missing"),
    ({"match": "*"}, r"\$.cameras\[0\].K: missing"),
    ({"match": "*", "K": [[1, 0, 0], [0, 1, 0], [0, 0, 2]]}, r"\$.cameras\[0\].K: expected the last row of K"),
    ({"match": "*", "K": K, "distortion": [1, 2]}, r"\$.cameras\[0\].distortion: expected 4, 5, 8, 12 or 14"),
    ({"match": "*", "K": K, "P": K}, r"unknown field 'P'"),
])
def test_bad_entries_name_the_file_and_path(tmp_path, entry, message):
    path = tmp_path / "cameras.json"
    path.write_text(json.dumps({"cameras": [entry]}))
    with pytest.raises(FormatError, match=message) as info:
        load_cameras(path)
    assert str(path) in str(info.value)


def test_reads_the_apollocar3d_cameras_file():
    path = shared_data_dir() / "apollocar3d" / "cameras.json"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    table = load_cameras(path)
    camera = table.camera_for("171206_034625454_Camera_5.jpg")
    assert camera is not None and camera["K"][0][0] > 1000


# --- the forms --cameras takes besides our JSON, and every refusal -------------------------------------------------

#: A KITTI-style P2 = K [I | t]: K of 721.5 px, camera 2 some 6 cm left of camera 0 (t = (0.06, 0, 0) m).
P2 = np.hstack([np.array([[721.5, 0.0, 609.6], [0.0, 721.5, 172.9], [0.0, 0.0, 1.0]]),
                np.array([[721.5 * 0.06], [0.0], [0.0]])])


def _kitti_calib(P: np.ndarray = P2, key: str = "P2") -> str:
    """A calibration file as KITTI's object benchmark writes it (P0..P3, R0_rect, Tr_velo_to_cam, Tr_imu_to_velo)."""
    row = " ".join(f"{v:.12e}" for v in P.ravel())
    eye = " ".join(f"{v:.12e}" for v in np.eye(3).ravel())
    other = " ".join(f"{v:.12e}" for v in np.hstack([np.eye(3), np.zeros((3, 1))]).ravel())
    lines = [f"P0: {other}", f"P1: {other}", f"{key}: {row}", f"P3: {other}", f"R0_rect: {eye}",
             f"Tr_velo_to_cam: {other}", f"Tr_imu_to_velo: {other}"]
    return "\n".join(lines) + "\n"


def _no_pydantic(message: str) -> None:
    assert "Input should" not in message and "pydantic" not in message and "validation error" not in message


def test_a_flat_K_is_three_rows(tmp_path):
    path = tmp_path / "cameras.json"
    path.write_text(json.dumps({"cameras": [{"match": "*", "K": [700, 0, 600, 0, 700, 180, 0, 0, 1]}]}))
    assert load_cameras(path).camera_for("a.png") == {"K": [[700, 0, 600], [0, 700, 180], [0, 0, 1]]}


@pytest.mark.parametrize("K", [
    [700, 0, 600, 0, 700, 180, 0, 0],  # 8 numbers
    [[700, 0, 600], [0, 700, 180]],  # 2 rows
    [[700, 0], [0, 700], [0, 0]],
    [700, 0, 600, 0, 700, 180, 0, 0, "1"],
    [[700, 0, 600], [0, 700, 180], [0, 0, True]],
    "K",
    {"fx": 700},
])
def test_a_malformed_K_names_file_path_and_shape(tmp_path, K):
    path = tmp_path / "cameras.json"
    path.write_text(json.dumps({"cameras": [{"match": "*", "K": K}]}))
    with pytest.raises(FormatError) as info:
        load_cameras(path)
    message = str(info.value)
    assert message.startswith(f"{path}: $.cameras[0].K: expected a 3x3 matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] "
                              "or 9 numbers row by row, got ")
    _no_pydantic(message)


@pytest.mark.parametrize(("text", "message"), [
    ('{"cameras": [{"match": "*", "K": [[NaN, 0, 1], [0, 700, 1], [0, 0, 1]]}]}', r"\$.cameras\[0\].K: expected a 3x3"),
    ('{"cameras": [{"match": "*", "K": [700, 0, 1, 0, 700, 1, 0, 0, 1], "distortion": "none"}]}',
     r"\$.cameras\[0\].distortion: expected 4, 5, 8, 12 or 14 numbers \(OpenCV order"),
    ('{"cameras": [{"match": "*", "K": [700, 0, 1, 0, 700, 1, 0, 0, 1], "distortion": [1e9, 0, 0, 0]}]}',
     r"\$.cameras\[0\].distortion: expected coefficients within \+-1e\+06"),
    ('{"cameras": [{"match": "*", "K": [0.5, 0, 1, 0, 0.5, 1, 0, 0, 1]}]}',
     r"\$.cameras\[0\].K: expected a focal length K\[0\]\[0\] between 1 and 1e\+06 pixels, got 0.5"),
    ('{"toosicubix": 1, "images": []}', r"\$.cameras: missing: expected a cameras JSON file"),
])
def test_json_refusals_name_the_place_and_what_was_expected(tmp_path, text, message):
    path = tmp_path / "cameras.json"
    path.write_text(text)
    with pytest.raises(FormatError, match=message) as info:
        load_cameras(path)
    assert str(info.value).startswith(f"{path}: ")
    _no_pydantic(str(info.value))


def test_a_kitti_calib_file_gives_its_P2_to_every_image(tmp_path):
    path = tmp_path / "000123.txt"
    path.write_text(_kitti_calib())
    table = load_cameras(path)
    camera = table.camera_for("any/image.png")
    np.testing.assert_allclose(camera["P"], P2, rtol=1e-12)  # 13 significant digits written
    assert set(camera) == {"P"}


def test_a_raw_data_calib_file_gives_its_P_rect_02(tmp_path):
    path = tmp_path / "calib_cam_to_cam.txt"
    path.write_text("calib_time: 09-Jan-2012 13:57:47\ncorner_dist: 9.950000e-02\n" + _kitti_calib(key="P_rect_02"))
    np.testing.assert_allclose(load_cameras(path).camera_for("a.png")["P"], P2, rtol=1e-12)


def test_a_folder_of_kitti_calib_files_matches_by_image_stem(tmp_path):
    folder = tmp_path / "calib"
    folder.mkdir()
    other = P2.copy()
    other[0, 0] = other[1, 1] = 700.0
    (folder / "000001.txt").write_text(_kitti_calib())
    (folder / "000002.txt").write_text(_kitti_calib(other))
    table = load_cameras(folder)
    assert table.camera_for("image_2/000001.png")["P"][0][0] == 721.5
    assert table.camera_for("000002.jpg")["P"][0][0] == 700.0
    assert table.camera_for("image_2/000003.png") is None
    assert table.why_none("image_2/000003.png") == f"no KITTI calib file {folder / '000003.txt'}"


@pytest.mark.parametrize(("text", "line", "message"), [
    ("P0: 1 0 0 0 0 1 0 0 0 0 1 0\n", None, r"a KITTI calib file needs a line 'P2:' with 12 numbers"),
    ("P0: 1 0 0 0 0 1 0 0 0 0 1 0\nP2: 721.5 0 609.6 0 0 721.5 172.9 0 0 0 1\n", 2,
     r"P2: expected 12 numbers \(the 3x4 projection matrix of camera 2, row by row\)"),
    ("P2: 721.5 0 609.6 0 0 721.5 172.9 0 0 0 1 x\n", 1, r"P2: expected 12 numbers"),
    ("P2: 721.5 0 609.6 0 0 721.5 172.9 0 0 0 2 0\n", 1, r"P: expected the last row of K to be \[0, 0, 1\]"),
])
def test_kitti_refusals_name_the_line_and_what_was_expected(tmp_path, text, line, message):
    path = tmp_path / "calib.txt"
    path.write_text(text)
    with pytest.raises(FormatError, match=message) as info:
        load_cameras(path)
    assert info.value.line == line and str(info.value).startswith(f"{path}{'' if line is None else f':{line}'}: ")


def test_a_folder_refuses_a_bad_calib_file_and_names_an_empty_one(tmp_path):
    (tmp_path / "calib").mkdir()
    with pytest.raises(FormatError, match=r"needs <image stem>.txt files; found none \(did you mean .*calib\?\). "
                                          r"--cameras takes a cameras JSON file .* OpenCV or ROS camera YAML"):
        load_cameras(tmp_path)
    (tmp_path / "calib" / "000001.txt").write_text("P2: 1 2 3\n")
    with pytest.raises(FormatError, match=r"000001.txt:1: P2: expected 12 numbers"):
        load_cameras(tmp_path / "calib")


ROS = """image_width: 1242
image_height: 375
camera_name: kitti_02
camera_matrix:
  rows: 3
  cols: 3
  data: [721.5, 0, 609.6, 0, 721.5, 172.9, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.36, 0.15, 0.001, -0.0002, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [721.5, 0, 609.6, 0, 0, 721.5, 172.9, 0, 0, 0, 1, 0]
"""

# As cv::FileStorage writes it: a directive, a tag per matrix, long lists wrapped over lines.
OPENCV = """%YAML:1.0
---
calibration_time: "Thu Nov 26 10:00:00 2026"
image_width: 1242
image_height: 375
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 7.2150000000000000e+02, 0., 6.0960000000000002e+02, 0.,
       7.2150000000000000e+02, 1.7290000000000001e+02, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
   data: [ -3.6e-01, 1.5e-01, 1.e-03, -2.e-04, 0. ]
avg_reprojection_error: 2.1e-01
"""

# As yaml.safe_dump writes a camera_info dictionary: block lists, keys sorted.
ROS_BLOCK = """camera_matrix:
  cols: 3
  data:
  - 721.5
  - 0.0
  - 609.6
  - 0.0
  - 721.5
  - 172.9
  - 0.0
  - 0.0
  - 1.0
  rows: 3
camera_name: kitti_02
distortion_coefficients:
  cols: 5
  data: [-0.36, 0.15, 0.001, -0.0002, 0.0]
  rows: 1
distortion_model: plumb_bob
image_height: 375
image_width: 1242
"""


@pytest.mark.parametrize("text", [ROS, OPENCV, ROS_BLOCK], ids=["ros", "opencv", "ros-block"])
def test_a_camera_yaml_gives_K_and_distortion_to_every_image(tmp_path, text):
    path = tmp_path / "camera.yaml"
    path.write_text(text)
    camera = load_cameras(path).camera_for("frames/000001.png")
    np.testing.assert_allclose(camera["K"], P2[:, :3], rtol=1e-12)
    assert camera["distortion"] == pytest.approx([-0.36, 0.15, 0.001, -0.0002, 0.0], abs=1e-15)


def test_opencv_reads_the_opencv_yaml_as_we_do(tmp_path):
    # The same numbers as cv::FileStorage reads them: the layout is OpenCV's own.
    import cv2

    path = tmp_path / "camera.yaml"
    path.write_text(OPENCV)
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        camera = load_cameras(path).camera_for("a.png")
        np.testing.assert_array_equal(storage.getNode("camera_matrix").mat(), camera["K"])
        np.testing.assert_array_equal(storage.getNode("distortion_coefficients").mat().ravel(), camera["distortion"])
    finally:
        storage.release()


def test_zero_distortion_is_none(tmp_path):
    path = tmp_path / "camera.yaml"
    path.write_text(ROS.replace("[-0.36, 0.15, 0.001, -0.0002, 0]", "[0, 0, 0, 0, 0]"))
    assert set(load_cameras(path).camera_for("a.png")) == {"K"}


@pytest.mark.parametrize(("edit", "line", "message"), [
    (("distortion_model: plumb_bob", "distortion_model: equidistant"), 8,
     r"distortion_model: expected plumb_bob or rational_polynomial \(OpenCV's standard model\), got 'equidistant'"),
    (("  rows: 3\n  cols: 3\n  data: [721.5", "  rows: 1\n  cols: 9\n  data: [721.5"), 4,
     r"camera_matrix: expected rows 3 and cols 3, got 1 and 9"),
    (("data: [721.5, 0, 609.6, 0, 721.5, 172.9, 0, 0, 1]", "data: [721.5, 0, 609.6, 0, 721.5, 172.9, 0, 0]"), 7,
     r"camera_matrix.data: expected 9 numbers \(rows 3 x cols 3\), got 8"),
    (("data: [721.5, 0, 609.6, 0, 721.5, 172.9, 0, 0, 1]", "data: [721.5, 0, 609.6, 0, 721.5, 172.9, 0, 0, 1"), 7,
     r"a list opened with '\[' is never closed"),
    (("data: [721.5, 0, 609.6,", "data: [fx, 0, 609.6,"), 7, r"camera_matrix.data: expected a list of finite numbers"),
    (("  cols: 3\n  data: [721.5", "  data: [721.5"), 4, r"camera_matrix.cols: missing"),
    (("  rows: 3\n  cols: 3\n  data: [721.5", "\trows: 3\n  cols: 3\n  data: [721.5"), 5,
     r"expected spaces for indentation, found a tab"),
    (("data: [721.5, 0, 609.6, 0, 721.5, 172.9, 0, 0, 1]", "data: [721.5, 0, 609.6, 0, 721.5, 172.9, 0, 0, 2]"), 4,
     r"K: expected the last row of K to be \[0, 0, 1\]"),
    (("  rows: 1\n  cols: 5", "  rows: 1\n  cols: 3"), 12, r"distortion_coefficients.data: expected 3 numbers"),
])
def test_yaml_refusals_name_the_line_and_the_layouts(tmp_path, edit, line, message):
    path = tmp_path / "camera.yaml"
    text = ROS if edit[0] in ROS else ROS.replace("data: [721.5, 0, 609.6, 0, 721.5, 172.9, 0, 0, 1]",
                                                  "data: [721.5, 0, 609.6,\n    0, 721.5, 172.9, 0, 0, 1]")
    assert edit[0] in text
    path.write_text(text.replace(edit[0], edit[1]))
    with pytest.raises(FormatError, match=message) as info:
        load_cameras(path)
    assert info.value.line == line and str(info.value).startswith(f"{path}:{line}: ")
    if "K:" not in message:
        assert "(an OpenCV or ROS camera YAML: ROS camera_info: camera_matrix: {rows: 3" in str(info.value)


@pytest.mark.parametrize(("content", "message"), [
    (b"hello\n", r"not a cameras file: expected a cameras JSON file .*, a KITTI calib file \(a line 'P2:' with 12 "
                 r"numbers\), a folder of KITTI calib files \(<image stem>.txt\), or an OpenCV or ROS camera YAML"),
    (b"\x89PNG\r\n\x1a\n" + bytes(100), r"not a cameras file: expected a cameras JSON file"),
    (b"%YAML:1.0\nimage_width: 3\n", r"camera_matrix: missing \(an OpenCV or ROS camera YAML"),
])
def test_a_file_in_no_form_names_every_form(tmp_path, content, message):
    path = tmp_path / "cameras.txt"
    path.write_bytes(content)
    with pytest.raises(FormatError, match=message):
        load_cameras(path)
    with pytest.raises(FormatError, match=r"cannot read: .*; expected a cameras JSON file .* OpenCV or ROS camera"):
        load_cameras(tmp_path / "missing.json")


def test_the_shared_kitti_calib_folder():
    folder = shared_data_dir() / "kitti" / "calib"
    if not folder.is_dir():
        pytest.skip(f"{folder} not found")
    table = load_cameras(folder)
    stem = min(table.by_stem)
    P = np.array(table.camera_for(f"image_2/{stem}.png")["P"])
    offset = np.linalg.solve(P[:, :3], P[:, 3])  # camera 2 sits some 6 cm from camera 0
    assert 0.03 < np.linalg.norm(offset) < 0.1


# --- hostile values (issue 34) ---------------------------------------------------------------------------------

@pytest.mark.parametrize("K", [[[10**400, 0, 600], [0, 700, 180], [0, 0, 1]], [10**400] * 9,
                               [[700, 0, 600], [0, 700, 180], [0, 0, "1"]]])
def test_a_huge_or_odd_K_entry_is_named(tmp_path, K):
    path = tmp_path / "cameras.json"
    path.write_text(json.dumps({"cameras": [{"match": "*", "K": K}]}))
    with pytest.raises(FormatError, match=r"cameras.json: \$.cameras\[0\].K: expected a 3x3 matrix"):
        load_cameras(path)


@pytest.mark.parametrize("value", ["4_01.2", "nan", "\u0664\u0660\u0661"])
def test_kitti_and_yaml_numbers_are_read_strictly(tmp_path, value):
    calib = tmp_path / "calib.txt"
    calib.write_text(f"P2: {value} 0 600 0 0 700 180 0 0 0 1 0\n")
    with pytest.raises(FormatError, match=r"calib.txt:1: P2: expected 12 numbers"):
        load_cameras(calib)
    yaml = tmp_path / "camera.yaml"
    yaml.write_text(f"camera_matrix:\n  rows: 3\n  cols: 3\n  data: [{value}, 0, 600, 0, 700, 180, 0, 0, 1]\n")
    with pytest.raises(FormatError, match=r"camera_matrix.data: expected a list of finite numbers"):
        load_cameras(yaml)


def test_intrinsics_of_a_K_or_a_P_camera():
    from toosicubix.formats.cameras import intrinsics

    K = [[700.0, 0.0, 600.0], [0.0, 700.0, 180.0], [0.0, 0.0, 1.0]]
    np.testing.assert_array_equal(intrinsics({"K": K}), K)
    np.testing.assert_array_equal(intrinsics({"P": [[*K[0], 44.9], [*K[1], 0.2], [*K[2], 0.003]]}), K)


CAMERA_FILES = {
    "cameras.json": json.dumps({"cameras": [{"match": "*", "K": [[700, 0, 600], [0, 700, 180], [0, 0, 1]],
                                             "distortion": [0.1, 0.01, 0, 0]}]}),
    "calib.txt": "P0: 700 0 600 0 0 700 180 0 0 0 1 0\nP2: 700 0 600 44.9 0 700 180 0.2 0 0 1 0.003\n",
    "camera.yaml": "%YAML:1.0\ncamera_matrix: !!opencv-matrix\n  rows: 3\n  cols: 3\n  dt: d\n  data: [700, 0, 600, 0, "
                   "700, 180, 0, 0, 1]\ndistortion_coefficients: !!opencv-matrix\n  rows: 1\n  cols: 5\n  dt: d\n"
                   "  data: [0.1, 0.01, 0, 0, 0]\n",
}


@settings(max_examples=150, deadline=None, database=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(name=st.sampled_from(sorted(CAMERA_FILES)), at=st.integers(0, 400), cut=st.integers(0, 12),
       noise=st.one_of(st.binary(max_size=6), st.sampled_from([b"9" * 5000, b"4_01.2", b"nan", b"\xc2\xb2", b"1e999",
                                                               b"[", b"{", b"-", b"\t"])))
def test_any_camera_file_reads_as_a_camera_or_a_format_error(tmp_path, name, at, cut, noise):
    from toosicubix.annotations.schema import CameraModel
    from toosicubix.formats.cameras import intrinsics

    data = CAMERA_FILES[name].encode()
    path = tmp_path / name
    path.write_bytes(data[:at] + noise + data[at + cut:])
    try:
        table = load_cameras(path)
    except FormatError as exc:
        assert str(exc).startswith(str(path))
        return
    camera = table.camera_for("a.png")
    CameraModel.model_validate(camera)  # what the annotation file takes
    assert np.isfinite(intrinsics(camera)).all()
