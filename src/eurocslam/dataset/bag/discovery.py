"""Finding a bag's camera, CameraInfo and IMU topics by message type, for bags whose topics are
not EuRoC's (a robot's driver names them: realsense-ros `/camera/infra1/image_rect_raw`,
`/camera/infra2/...`, `/camera/imu` or `/camera/accel/sample` + `/camera/gyro/sample`).

- **Cameras**: two `sensor_msgs/Image` or `CompressedImage` topics whose names differ only in
  `infra1`/`infra2`, `left`/`right` or `cam0`/`cam1` (the first is the left camera); depth
  topics never. Several such pairs: uncompressed before compressed, then raw (`image_raw`)
  before rectified; still several is an error listing them. No named pair but exactly two
  image topics: a pair whose left and right the caller decides (`StereoPair.ordered` False:
  the reader uses the `/tf_static` baseline).
- **CameraInfo**: the `camera_info` topic beside an image topic (`/ns/image_rect_raw` and
  `/ns/image_raw/compressed` both use `/ns/camera_info`).
- **IMU**: one `sensor_msgs/Imu` topic, or one whose name says `accel` and one that says
  `gyro` (separate streams, united by `imu_union`). Several candidates are an error asking for
  `--topic imu=...` (or `accel=`/`gyro=`).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass

from eurocslam.dataset.bag.topics import IMAGE_TYPES
from eurocslam.errors import DatasetError

IMU_TYPE = "sensor_msgs/msg/Imu"
CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"
# (left, right) name parts of a stereo pair, tried in this order
PAIR_TOKENS = (("infra1", "infra2"), ("left", "right"), ("cam0", "cam1"))


def _token(word: str) -> re.Pattern[str]:
    return re.compile(rf"(?<![A-Za-z0-9]){re.escape(word)}(?![A-Za-z0-9])")


@dataclass(frozen=True)
class StereoPair:
    left: str
    right: str
    ordered: bool  # False: left/right still to be decided (by the tf baseline)
    how: str  # what decided the pair, for the notes


def _image_topics(types: Mapping[str, str]) -> list[str]:
    return sorted(
        t for t, ty in types.items() if ty in IMAGE_TYPES and not _token("depth").search(t)
    )


def _rank(pair: StereoPair, types: Mapping[str, str]) -> tuple[int, int]:
    compressed = sum(types[t].endswith("/CompressedImage") for t in (pair.left, pair.right))
    rectified = sum("image_rect" in t for t in (pair.left, pair.right))
    return compressed, rectified


def discover_stereo(
    types: Mapping[str, str], left: str | None = None, right: str | None = None, where: str = ""
) -> StereoPair:
    """The stereo pair among the image topics of a bag (`types`: topic -> message type).
    `left` / `right`: a side the user fixed. Errors name `where` (the bag) and list what it
    has."""
    images = _image_topics(types)
    fixed = left or right
    pairs: list[StereoPair] = []
    for t in images:
        for a, b in PAIR_TOKENS:
            pa = _token(a)
            if pa.search(t):
                other = pa.sub(b, t)
                if other in types and types[other] in IMAGE_TYPES:
                    pairs.append(StereoPair(t, other, True, f"names ({a}/{b})"))
    if fixed:
        pairs = [p for p in pairs if (left is None or p.left == left)]
        pairs = [p for p in pairs if (right is None or p.right == right)]
    if pairs:
        best = min(_rank(p, types) for p in pairs)
        pairs = [p for p in pairs if _rank(p, types) == best]
        if len(pairs) == 1:
            return pairs[0]
        listing = "; ".join(f"{p.left} + {p.right}" for p in pairs)
        raise DatasetError(
            f"{where}: several stereo pairs of image topics ({listing}); pick one with "
            "--topic left=TOPIC --topic right=TOPIC"
        )
    others = [t for t in images if t != fixed]
    if fixed and len(others) == 1:
        if left:
            return StereoPair(left, others[0], True, "the only other image topic")
        return StereoPair(others[0], right or "", True, "the only other image topic")
    if not fixed and len(images) == 2:
        return StereoPair(images[0], images[1], False, "the only two image topics")
    listing = ", ".join(images) or "no image topics"
    raise DatasetError(
        f"{where}: cannot tell which image topics form the stereo pair ({listing}); name them "
        "with --topic left=TOPIC --topic right=TOPIC"
    )


def camera_info_topic(image_topic: str, types: Mapping[str, str]) -> str | None:
    """The `camera_info` topic beside an image topic, if the bag has one."""
    t = image_topic.rstrip("/")
    if t.endswith("/compressed"):
        t = t[: -len("/compressed")]
    ns = t.rsplit("/", 1)[0]
    cand = f"{ns}/camera_info"
    return cand if types.get(cand) == CAMERA_INFO_TYPE else None


@dataclass(frozen=True)
class ImuTopics:
    imu: str | None = None  # one united stream
    accel: str | None = None  # ... or accelerometer and gyroscope apart
    gyro: str | None = None
    how: str = ""


def discover_imu(types: Mapping[str, str], where: str = "") -> ImuTopics:
    """The IMU topic(s) of a bag: one united stream, or an accelerometer and a gyroscope
    stream (by name); none is a stereo-only bag (`ImuTopics()`)."""
    imus = sorted(t for t, ty in types.items() if ty == IMU_TYPE)
    accel = [t for t in imus if "accel" in t.lower()]
    gyro = [t for t in imus if "gyro" in t.lower()]
    united = [t for t in imus if t not in accel and t not in gyro]
    if len(united) == 1:
        return ImuTopics(imu=united[0], how="the only united sensor_msgs/Imu topic")
    if not united and len(accel) == 1 and len(gyro) == 1:
        return ImuTopics(accel=accel[0], gyro=gyro[0], how="accelerometer and gyroscope apart")
    if not imus:
        return ImuTopics()
    raise DatasetError(
        f"{where}: several IMU topics ({', '.join(imus)}); name one with --topic imu=TOPIC, or "
        "separate streams with --topic accel=TOPIC --topic gyro=TOPIC"
    )
