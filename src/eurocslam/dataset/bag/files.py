"""Bag files on disk: which paths are bags, opening them with `rosbags` (errors become one-line
`DatasetError`s naming the bag), and the `sensor.yaml` files attached to an MCAP."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from eurocslam.errors import CalibrationError, DatasetError

BAG_SUFFIXES = (".bag", ".db3", ".mcap")


def is_bag_path(path: Path | str) -> bool:
    """A ROS 1 bag, a `.db3` or `.mcap` file, or a ROS 2 bag folder (has `metadata.yaml`)."""
    p = Path(path)
    if p.is_dir():
        return (p / "metadata.yaml").is_file()
    if p.name == "metadata.yaml":  # a ROS 2 bag folder given by its metadata file
        return p.is_file()
    return p.suffix.lower() in BAG_SUFFIXES


def bag_kind(path: Path) -> str:
    if path.is_dir():
        return "ROS 2 bag folder"
    return {".bag": "ROS 1 bag", ".db3": "ROS 2 .db3", ".mcap": "MCAP"}[path.suffix.lower()]


def _typestore_for(path: Path) -> Any:
    from rosbags.typesys import Stores, get_typestore

    # only used when the bag carries no message definitions (old ROS 2 .db3 files)
    ros1 = path.suffix.lower() == ".bag"
    return get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)


@contextmanager
def open_reader(path: Path) -> Iterator[Any]:
    """An open `rosbags.highlevel.AnyReader`; its errors become `DatasetError` naming the bag."""
    from rosbags.highlevel import AnyReader, AnyReaderError

    try:
        reader = AnyReader([path], default_typestore=_typestore_for(path))
        reader.open()
    except (AnyReaderError, FileNotFoundError, OSError) as e:
        raise DatasetError(f"{path}: cannot read as a {bag_kind(path)}: {e}") from None
    except Exception as e:  # rosbags raises assorted errors on corrupt files
        raise DatasetError(
            f"{path}: cannot read as a {bag_kind(path)}: {type(e).__name__}: {e}"
        ) from None
    try:
        yield reader
    finally:
        reader.close()


def _mcap_files(path: Path) -> list[Path]:
    if path.is_dir():
        return sorted(path.glob("*.mcap"))
    return [path] if path.suffix.lower() == ".mcap" else []


def mcap_sensor_yaml_texts(path: Path) -> dict[str, str]:
    """`sensor.yaml` texts attached to an MCAP (or the MCAPs of a ROS 2 bag folder), keyed by
    sensor name (`cam0`, `cam1`, `imu0`, ...): the parent folder in the attachment's name, as in
    `mav0/cam0/sensor.yaml` or `cam0/sensor.yaml`, or a name like `cam0.yaml`."""
    from mcap.reader import make_reader

    out: dict[str, str] = {}
    for f in _mcap_files(path):
        try:
            with f.open("rb") as fh:
                for att in make_reader(fh).iter_attachments():
                    parts = [p for p in att.name.replace("\\", "/").split("/") if p]
                    if not parts:
                        continue
                    if parts[-1] == "sensor.yaml" and len(parts) >= 2:
                        sensor = parts[-2]
                    elif parts[-1].endswith((".yaml", ".yml")):
                        sensor = parts[-1].rsplit(".", 1)[0].removesuffix("_sensor")
                    else:
                        continue
                    try:
                        out[sensor] = bytes(att.data).decode("utf-8")
                    except UnicodeDecodeError:
                        raise CalibrationError(
                            f"{f}: attachment '{att.name}' is not UTF-8 text"
                        ) from None
        except CalibrationError:
            raise
        except Exception as e:  # mcap raises its own error types on damaged summaries
            raise DatasetError(
                f"{f}: cannot read MCAP attachments: {type(e).__name__}: {e}"
            ) from None
    return out
