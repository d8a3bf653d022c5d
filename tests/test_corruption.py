"""Corruption cases (GUIDE section 7) on a clean copy of real EuRoC data.

Each case damages a copy of `V1_01_easy_micro` (40 real stereo pairs, real IMU and ground truth
cropped around them) in one way, then checks both halves:
  * the doctor reports it with the expected severity, naming the file (and line), never crashes,
    and its exit code follows the severity;
  * the reader either refuses with a `DatasetError` naming the file (and line/key), or copes and
    counts the problem in `skips`, never a traceback and never silent garbage.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest

from asl_helpers import (
    clean_v101_copy,
    data_rows,
    image_names,
    materialise,
    read_lines,
    write_lines,
)
from eurocslam.dataset.asl import AslSequence
from eurocslam.dataset.doctor.asl_checks import diagnose
from eurocslam.dataset.doctor.report import ERROR, INFO, WARNING, DoctorReport
from eurocslam.errors import DatasetError

N_FRAMES = 40


@pytest.fixture(scope="module")
def pristine(v101_micro: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("pristine") / "V1_01_clean"
    clean_v101_copy(v101_micro, root, max_frames=N_FRAMES)
    return root


@pytest.fixture
def seq(pristine: Path, tmp_path: Path) -> Path:
    dst = tmp_path / "V1_01_clean"
    shutil.copytree(pristine, dst, symlinks=True)
    return dst


def test_clean_copy_is_clean(pristine: Path) -> None:
    report = diagnose(pristine, sample=4)
    assert report.findings == (), report.format_text()
    assert report.exit_code == 0
    assert report.stereo_pairs == N_FRAMES
    s = AslSequence(pristine)
    assert s.skips.total == 0
    assert len(s.entries) == N_FRAMES


# ---- the cases ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Case:
    mutate: Callable[[Path], int | None]  # damages mav0; returns a frame time to read, if any
    severity: str  # expected doctor finding
    text: str  # ... whose message contains this
    file: str  # ... about this file (suffix of its path)
    reader: str  # "raises:<substring>", "skip:<kind substring>" or "ok"
    line: int | None = None  # expected 1-based line of the finding
    full: bool = False  # decode every image in the doctor


def _imu(m: Path) -> Path:
    return m / "imu0" / "data.csv"


def _gt(m: Path) -> Path:
    return m / "state_groundtruth_estimate0" / "data.csv"


def _edit(path: Path, fn: Callable[[list[str]], list[str]]) -> None:
    write_lines(path, fn(read_lines(path)))


def _swap(lines: list[str], i: int) -> list[str]:
    lines[i], lines[i + 1] = lines[i + 1], lines[i]
    return lines


def _t(m: Path, k: int = 10) -> int:
    return int(data_rows(m / "cam0" / "data.csv")[k].split(",")[0])


def _img(m: Path, k: int = 10, cam: str = "cam0") -> Path:
    return materialise(m / cam / "data" / image_names(m, cam)[k])


def _orig(m: Path, k: int = 10, cam: str = "cam0") -> np.ndarray:
    img = cv2.imread(str(m / cam / "data" / image_names(m, cam)[k]), cv2.IMREAD_UNCHANGED)
    assert img is not None
    return img


def _set_yaml(m: Path, cam: str, old: str, new: str) -> None:
    p = m / cam / "sensor.yaml"
    text = p.read_text()
    assert old in text
    p.write_text(text.replace(old, new))


def m_imu_unordered(m: Path) -> None:
    _edit(_imu(m), lambda ls: _swap(ls, 10))


def m_imu_duplicate(m: Path) -> None:
    _edit(_imu(m), lambda ls: [*ls[:11], ls[10], *ls[11:]])


def m_cam_duplicate(m: Path) -> None:
    _edit(m / "cam0" / "data.csv", lambda ls: [*ls[:6], ls[5], *ls[6:]])


def m_cam_unordered(m: Path) -> None:
    _edit(m / "cam0" / "data.csv", lambda ls: _swap(ls, 5))


def m_imu_truncated(m: Path) -> None:
    p = _imu(m)
    raw = p.read_bytes().rstrip(b"\n")
    p.write_bytes(raw[: len(raw) - 60])  # an interrupted copy: the last row cut short


def m_imu_broken_row(m: Path) -> None:
    _edit(_imu(m), lambda ls: [*ls[:99], ",".join(ls[99].split(",")[:3]), *ls[100:]])


def m_blank_lines(m: Path) -> None:
    _edit(_imu(m), lambda ls: [*ls[:50], "", "   ", *ls[50:], ""])
    _edit(m / "cam0" / "data.csv", lambda ls: [ls[0], "", *ls[1:]])


def m_crlf(m: Path) -> None:
    for p in m.glob("*/data.csv"):
        write_lines(p, read_lines(p), eol="\r\n")
    for p in m.glob("*/sensor.yaml"):
        p.write_bytes(p.read_text().replace("\n", "\r\n").encode())


def m_bom(m: Path) -> None:
    for p in (_imu(m), m / "cam0" / "data.csv", m / "cam0" / "sensor.yaml"):
        p.write_bytes(b"\xef\xbb\xbf" + p.read_bytes())


def m_yaml_directive(m: Path) -> None:
    _set_yaml(m, "cam0", "%YAML:1.0\n", "%YAML 1.1\n---\n")


def m_missing_yaml(m: Path) -> None:
    (m / "cam1" / "sensor.yaml").unlink()


def m_png_garbage(m: Path) -> int:
    _img(m).write_bytes(np.random.default_rng(1).integers(0, 256, 5000, np.uint8).tobytes())
    return _t(m)


def m_png_zero(m: Path) -> int:
    _img(m).write_bytes(b"")
    return _t(m)


def m_png_truncated(m: Path) -> int:
    p = _img(m)
    p.write_bytes(p.read_bytes()[:20000])
    return _t(m)


def m_png_bit_flip(m: Path) -> int:
    p = _img(m)
    data = bytearray(p.read_bytes())
    data[len(data) // 2] ^= 0x10  # inside the image data: only the chunk CRC tells
    p.write_bytes(bytes(data))
    return _t(m)


def m_png_16bit(m: Path) -> int:
    img = _orig(m)
    cv2.imwrite(str(_img(m)), img.astype(np.uint16) * 257)
    return _t(m)


def m_png_colour(m: Path) -> int:
    img = _orig(m)
    cv2.imwrite(str(_img(m)), cv2.cvtColor(img, cv2.COLOR_GRAY2BGR))
    return _t(m)


def m_png_wrong_size(m: Path) -> int:
    img = _orig(m)
    cv2.imwrite(str(_img(m)), cv2.resize(img, (376, 240)))
    return _t(m)


def m_png_blank(m: Path) -> int:
    cv2.imwrite(str(_img(m)), np.zeros((480, 752), np.uint8))
    return _t(m)


def m_count_mismatch(m: Path) -> None:
    _edit(m / "cam0" / "data.csv", lambda ls: ls[:-3])


def m_imu_gap(m: Path) -> None:
    _edit(_imu(m), lambda ls: [*ls[:200], *ls[220:]])


def m_imu_empty(m: Path) -> None:
    _imu(m).write_bytes(b"")


def m_cam_empty(m: Path) -> None:
    _edit(m / "cam0" / "data.csv", lambda ls: ls[:1])


def m_gt_empty(m: Path) -> None:
    _gt(m).write_bytes(b"")


def m_no_mav0(m: Path) -> None:
    shutil.rmtree(m)


def m_cam_seconds(m: Path) -> None:
    def conv(ls: list[str]) -> list[str]:
        out = [ls[0]]
        for ln in ls[1:]:
            t, name = ln.split(",")
            out.append(f"{int(t) / 1e9:.6f},{name}")
        return out

    _edit(m / "cam0" / "data.csv", conv)


def m_gt_microseconds(m: Path) -> None:
    def conv(ls: list[str]) -> list[str]:
        return [ls[0]] + [f"{int(ln.split(',')[0]) // 1000},{ln.split(',', 1)[1]}" for ln in ls[1:]]

    _edit(_gt(m), conv)


def m_non_numeric(m: Path) -> None:
    _edit(_imu(m), lambda ls: [*ls[:30], ls[30].rsplit(",", 1)[0] + ",abc", *ls[31:]])


def m_nan(m: Path) -> None:
    _edit(_imu(m), lambda ls: [*ls[:30], ls[30].rsplit(",", 1)[0] + ",nan", *ls[31:]])


def _gt_quat(scale: float) -> Callable[[Path], None]:
    def mutate(m: Path) -> None:
        def fn(ls: list[str]) -> list[str]:
            f = ls[7].split(",")
            f[4:8] = [repr(float(v) * scale) for v in f[4:8]]
            ls[7] = ",".join(f)
            return ls

        _edit(_gt(m), fn)

    return mutate


def m_reflection(m: Path) -> None:
    _set_yaml(m, "cam0", "data: [0.0148655429818,", "data: [-0.0148655429818,")
    _set_yaml(m, "cam0", "0.999557249008,", "-0.999557249008,")
    _set_yaml(m, "cam0", "-0.0257744366974,", "0.0257744366974,")


def m_negative_focal(m: Path) -> None:
    _set_yaml(m, "cam0", "intrinsics: [458.654,", "intrinsics: [-458.654,")


def m_missing_key(m: Path) -> None:
    _set_yaml(m, "cam1", "intrinsics:", "intrinsix:")


def m_listed_missing(m: Path) -> int:
    (m / "cam0" / "data" / image_names(m, "cam0")[10]).unlink()
    return _t(m)


def m_unlisted(m: Path) -> None:
    src = m / "cam0" / "data" / image_names(m, "cam0")[0]
    (m / "cam0" / "data" / "1403715299999999999.png").write_bytes(src.read_bytes())


def m_data_folder_missing(m: Path) -> None:
    shutil.rmtree(m / "cam1" / "data")


def m_accel_in_g(m: Path) -> None:
    def fn(ls: list[str]) -> list[str]:
        out = [ls[0]]
        for ln in ls[1:]:
            f = ln.split(",")
            f[4:7] = [repr(float(v) / 9.81) for v in f[4:7]]
            out.append(",".join(f))
        return out

    _edit(_imu(m), fn)


def m_swapped_cameras(m: Path) -> None:
    a, b = m / "cam0" / "sensor.yaml", m / "cam1" / "sensor.yaml"
    ta, tb = a.read_bytes(), b.read_bytes()
    a.write_bytes(tb)
    b.write_bytes(ta)


def m_binary_csv(m: Path) -> None:
    _imu(m).write_bytes(b"#timestamp\n" + bytes(range(128, 256)) * 10)


def m_bad_header(m: Path) -> None:
    _edit(_imu(m), lambda ls: ["#timestamp [ns],w_x,w_y,w_z,a_x", *ls[1:]])


def m_imu_no_overlap(m: Path) -> None:
    def fn(ls: list[str]) -> list[str]:
        return [ls[0]] + [
            f"{int(ln.split(',')[0]) + 100 * 10**9},{ln.split(',', 1)[1]}" for ln in ls[1:]
        ]

    _edit(_imu(m), fn)


def m_cam_integer_seconds(m: Path) -> None:
    def conv(ls: list[str]) -> list[str]:
        return [ls[0]] + [f"{int(ln.split(',')[0]) // 10**9},{ln.split(',')[1]}" for ln in ls[1:]]

    _edit(m / "cam0" / "data.csv", conv)


def m_imu_integer_seconds(m: Path) -> None:
    def conv(ls: list[str]) -> list[str]:
        return [ls[0]] + [
            f"{int(ln.split(',')[0]) // 10**9},{ln.split(',', 1)[1]}" for ln in ls[1:]
        ]

    _edit(_imu(m), conv)


def m_cam1_offset(m: Path) -> None:
    def conv(ls: list[str]) -> list[str]:
        return [ls[0]] + [f"{int(ln.split(',')[0]) + 1000},{ln.split(',')[1]}" for ln in ls[1:]]

    _edit(m / "cam1" / "data.csv", conv)


def m_rate_mismatch(m: Path) -> None:
    _set_yaml(m, "cam0", "rate_hz: 20", "rate_hz: 40")


CASES: dict[str, Case] = {
    "imu unordered": Case(m_imu_unordered, WARNING, "go backwards", "imu0/data.csv",
                          "skip:out-of-order", line=12),
    "imu duplicate": Case(m_imu_duplicate, WARNING, "duplicate timestamp", "imu0/data.csv",
                          "skip:duplicate IMU timestamp", line=12),
    "cam duplicate": Case(m_cam_duplicate, WARNING, "duplicate timestamp", "cam0/data.csv",
                          "skip:duplicate cam0 timestamp", line=7),
    "cam unordered": Case(m_cam_unordered, WARNING, "go backwards", "cam0/data.csv",
                          "skip:out-of-order"),
    "imu truncated last row": Case(m_imu_truncated, WARNING, "truncated last row", "imu0/data.csv",
                                   "skip:truncated last row"),
    "imu broken row": Case(m_imu_broken_row, ERROR, "without 7 columns", "imu0/data.csv",
                           "raises:data.csv:100: expected 7 columns", line=100),
    "blank lines": Case(m_blank_lines, INFO, "blank line", "imu0/data.csv", "ok"),
    "crlf": Case(m_crlf, "", "", "", "ok"),
    "bom": Case(m_bom, INFO, "byte-order mark", "imu0/data.csv", "ok"),
    "yaml directive variant": Case(m_yaml_directive, "", "", "", "ok"),
    "missing sensor.yaml": Case(m_missing_yaml, ERROR, "file missing", "cam1/sensor.yaml",
                                "raises:cam1/sensor.yaml: file not found"),
    "png garbage": Case(m_png_garbage, WARNING, "not a PNG", "cam0/data", "skip:unreadable image"),
    "png zero bytes": Case(m_png_zero, WARNING, "empty file", "cam0/data", "skip:unreadable image"),
    "png truncated": Case(m_png_truncated, WARNING, "truncated PNG", "cam0/data",
                          "skip:unreadable image"),
    "png bit flip": Case(m_png_bit_flip, WARNING, "CRC error in 'IDAT' chunk", "cam0/data",
                         "skip:unreadable image", full=True),
    "png 16-bit": Case(m_png_16bit, WARNING, "16-bit", "cam0/data", "skip:converted (16-bit"),
    "png colour": Case(m_png_colour, WARNING, "RGB", "cam0/data", "skip:converted (colour"),
    "png wrong size": Case(m_png_wrong_size, ERROR, "376x240", "cam0/data",
                           "skip:size differs from calibration"),
    "png blank": Case(m_png_blank, WARNING, "blank image", "cam0/data", "ok", full=True),
    "cam0/cam1 count mismatch": Case(m_count_mismatch, WARNING, "in cam1 only", "cam1/data.csv",
                                     "skip:frame in cam1 only"),
    "imu gap": Case(m_imu_gap, WARNING, "largest 105.0 ms", "imu0/data.csv", "skip:imu0 gap",
                    line=201),
    "imu empty": Case(m_imu_empty, ERROR, "empty file", "imu0/data.csv", "raises:no IMU rows"),
    "cam0 csv no rows": Case(m_cam_empty, ERROR, "no data rows", "cam0/data.csv",
                             "raises:cam0/data.csv: no image rows"),
    "ground truth empty": Case(m_gt_empty, WARNING, "empty file", "state_groundtruth_estimate0/"
                               "data.csv", "skip:empty ground-truth"),
    "no mav0": Case(m_no_mav0, ERROR, "not an EuRoC ASL sequence", "", "raises:not an EuRoC"),
    "cam timestamps in seconds": Case(m_cam_seconds, ERROR, "look like seconds", "cam0/data.csv",
                                      "raises:looks like seconds", line=2),
    "gt timestamps in microseconds": Case(m_gt_microseconds, ERROR, "integer nanoseconds",
                                          "state_groundtruth_estimate0/data.csv",
                                          "raises:seconds vs nanoseconds"),
    "non-numeric value": Case(m_non_numeric, ERROR, "non-numeric", "imu0/data.csv",
                              "raises:imu0/data.csv:31", line=31),
    "nan value": Case(m_nan, ERROR, "non-finite", "imu0/data.csv", "raises:imu0/data.csv:31",
                      line=31),
    "quaternion not unit": Case(_gt_quat(1.1), WARNING, "not unit length",
                                "state_groundtruth_estimate0/data.csv", "ok", line=8),
    "quaternion zero": Case(_gt_quat(0.0), ERROR, "zero quaternion",
                            "state_groundtruth_estimate0/data.csv", "raises::8: zero quaternion",
                            line=8),
    "T_BS reflection": Case(m_reflection, ERROR, "determinant", "cam0/sensor.yaml",
                            "raises:key 'T_BS'"),
    "negative focal length": Case(m_negative_focal, ERROR, "focal lengths must be positive",
                                  "cam0/sensor.yaml", "raises:key 'intrinsics'"),
    "missing key": Case(m_missing_key, ERROR, "missing key 'intrinsics'", "cam1/sensor.yaml",
                        "raises:missing key 'intrinsics'"),
    "image listed but missing": Case(m_listed_missing, WARNING, "listed image(s) missing",
                                     "cam0/data.csv", "skip:cam0 image listed but missing",
                                     line=12),
    "image not listed": Case(m_unlisted, WARNING, "not listed", "cam0/data", "ok"),
    "image folder missing": Case(m_data_folder_missing, ERROR, "image folder missing", "cam1/data",
                                 "raises:image folder not found"),
    "accelerometer in g": Case(m_accel_in_g, WARNING, "in g instead of m/s^2", "imu0/data.csv",
                               "ok"),
    "cameras swapped": Case(m_swapped_cameras, WARNING, "left of cam0", "cam1/sensor.yaml", "ok"),
    "binary csv": Case(m_binary_csv, ERROR, "not a text file", "imu0/data.csv",
                       "raises:not a text file"),
    "header column count": Case(m_bad_header, ERROR, "header has 5 columns", "imu0/data.csv",
                                "ok", line=1),
    "imu does not overlap": Case(m_imu_no_overlap, ERROR, "does not overlap", "imu0/data.csv",
                                 "ok"),
    "cam timestamps in integer seconds": Case(m_cam_integer_seconds, ERROR, "(timestamps in "
                                              "seconds?)", "cam0/data.csv",
                                              "raises:seconds vs nanoseconds"),
    # the reader and the doctor blame the same file: the one the other streams disagree with
    "imu timestamps in integer seconds": Case(m_imu_integer_seconds, ERROR, "(timestamps in "
                                              "seconds?)", "imu0/data.csv",
                                              "raises:imu0/data.csv: timestamps are ~1e9 but"),
    "cam1 clock offset": Case(m_cam1_offset, ERROR, "share no timestamp", "cam1/data.csv",
                              "raises:share no timestamp"),
    "rate mismatch": Case(m_rate_mismatch, WARNING, "differs from sensor.yaml rate_hz",
                          "cam0/data.csv", "ok"),
}  # fmt: skip


def _check_doctor(report: DoctorReport, case: Case) -> None:
    text = report.format_text()
    assert not report.by_check("internal"), text
    if not case.severity:  # tolerated silently
        assert report.exit_code == 0, text
        return
    hits = [
        f
        for f in report.findings
        if f.severity == case.severity
        and case.text in f.message
        and (f.file or "").endswith(case.file)
        and (case.line is None or f.line == case.line)
    ]
    assert hits, f"expected {case.severity} '{case.text}' on {case.file}:{case.line}\n{text}"
    assert report.exit_code == {ERROR: 2, WARNING: 1, INFO: 0}[case.severity], text
    # every finding is one line naming where it is
    for f in report.findings:
        assert "\n" not in f.text()


@pytest.mark.parametrize("name", list(CASES))
def test_corruption(seq: Path, name: str) -> None:
    case = CASES[name]
    t_read = case.mutate(seq / "mav0")
    report = diagnose(seq, sample=2, full=case.full)
    _check_doctor(report, case)
    if case.reader.startswith("raises:"):
        with pytest.raises(DatasetError) as ei:
            AslSequence(seq)
        msg = str(ei.value)
        assert case.reader[len("raises:") :] in msg
        assert "\n" not in msg
        # the doctor says what the pipeline will do
        assert report.by_check("reader") or name == "no mav0"
        return
    s = AslSequence(seq)
    if t_read is not None:
        frames = list(s.frames(include_incomplete=True, t_start_ns=t_read, t_end_ns=t_read))
        assert len(frames) == 1
        left = frames[0].left
        assert left is None or (left.dtype == np.uint8 and left.shape == (480, 752))
    if case.reader.startswith("skip:"):
        kind = case.reader[len("skip:") :]
        assert any(kind in k for k in s.skips.counts), s.skips.lines()
    else:
        assert case.reader == "ok"
    assert not report.by_check("reader"), report.format_text()


# ---- what the reader returns after coping ----------------------------------------------------


def test_unordered_and_duplicate_imu_are_sorted_and_deduplicated(seq: Path) -> None:
    m_imu_unordered(seq / "mav0")
    m_imu_duplicate(seq / "mav0")
    s = AslSequence(seq)
    assert np.all(np.diff(s.imu.t_ns) > 0)
    assert len(s.imu) == len(data_rows(seq / "mav0" / "imu0" / "data.csv")) - 1


def test_converted_images_equal_the_original(seq: Path) -> None:
    m = seq / "mav0"
    original = _orig(m)
    for mutate in (m_png_16bit, m_png_colour):
        t = mutate(m)
        (frame,) = AslSequence(seq).frames(t_start_ns=t, t_end_ns=t)
        assert frame.left is not None
        np.testing.assert_array_equal(frame.left, original)


def test_unreadable_image_drops_only_that_frame(seq: Path) -> None:
    m_png_truncated(seq / "mav0")
    s = AslSequence(seq)
    frames = list(s.frames(t_end_ns=_t(seq / "mav0", 12)))
    assert len(frames) == 12  # 13 frames up to index 12, the damaged one (10) skipped
    assert s.skips.counts == {"unreadable image": 1}
    assert "truncated PNG" in s.skips.examples["unreadable image"][0]


def test_count_mismatch_pairs_on_timestamp(seq: Path) -> None:
    m_count_mismatch(seq / "mav0")
    s = AslSequence(seq)
    assert len(s.complete_entries) == N_FRAMES - 3
    assert s.skips.counts["frame in cam1 only"] == 3
    for e in s.complete_entries:
        assert e.left is not None and e.right is not None
        assert e.left.name == e.right.name  # EuRoC names images by their timestamp


def test_quaternion_normalised_by_reader(seq: Path) -> None:
    _gt_quat(1.1)(seq / "mav0")
    gt = AslSequence(seq).groundtruth
    assert gt is not None
    np.testing.assert_allclose(np.linalg.norm(gt.q_wxyz, axis=1), 1.0, atol=1e-12)


def test_doctor_never_raises_on_unreadable_paths(tmp_path: Path) -> None:
    for p in (tmp_path / "nope", tmp_path):
        r = diagnose(p)
        assert r.exit_code == 2
        assert r.findings[0].severity == ERROR
    f = tmp_path / "file.txt"
    f.write_text("x")
    assert diagnose(f).exit_code == 2


# ---- random damage: neither the doctor nor the reader may crash ---------------------------------


def _random_damage(m: Path, rng: np.random.Generator) -> str:
    files = sorted(
        p for p in m.rglob("*") if p.is_file() and (p.suffix != ".png" or rng.random() < 0.05)
    )
    target = files[int(rng.integers(len(files)))]
    if target.is_symlink():
        materialise(target)
    data = bytearray(target.read_bytes())
    how = int(rng.integers(4))
    if how == 0 and data:  # truncate anywhere
        del data[int(rng.integers(len(data))) :]
    elif how == 1 and data:  # overwrite a few bytes with anything
        for _ in range(int(rng.integers(1, 6))):
            data[int(rng.integers(len(data)))] = int(rng.integers(256))
    elif how == 2 and data:  # drop a slice
        a = int(rng.integers(len(data)))
        del data[a : a + int(rng.integers(1, 200))]
    else:  # remove the file
        target.unlink()
        return f"removed {target}"
    target.write_bytes(bytes(data))
    return f"damage {how} on {target}"


@pytest.mark.parametrize("seed", range(16))
def test_random_damage_never_crashes(seq: Path, seed: int) -> None:
    rng = np.random.default_rng(seed)
    what = [_random_damage(seq / "mav0", rng) for _ in range(2)]
    report = diagnose(seq, sample=2)
    assert not report.by_check("internal"), (what, report.format_text())
    try:
        s = AslSequence(seq)
    except DatasetError as e:
        assert "\n" not in str(e)
        assert report.exit_code == 2, (what, str(e), report.format_text())
        return
    for t in {int(w.rsplit("/", 1)[1][:-4]) for w in what if w.endswith(".png")}:
        for f in s.frames(include_incomplete=True, t_start_ns=t, t_end_ns=t):
            for img in (f.left, f.right):
                assert img is None or (img.dtype == np.uint8 and img.shape == (480, 752))
