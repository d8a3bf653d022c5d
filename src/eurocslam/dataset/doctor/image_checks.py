"""The doctor's image checks: every listed image's PNG header (IHDR: size, bit depth, colour
type) and its last 12 bytes (the IEND chunk: truncation) are read; only an evenly spaced sample
is fully decoded (`full` decodes all of them)."""

from __future__ import annotations

import os
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from eurocslam.dataset.calib import CameraCalib
from eurocslam.dataset.doctor.csv_scan import MAX_EXAMPLES, ScannedCsv
from eurocslam.dataset.doctor.report import ERROR, WARNING, Findings
from eurocslam.dataset.images import PNG_SIGNATURE, decode_image


@dataclass
class ImageState:
    """What the image checks are asked to do, and what they found (per camera)."""

    full: bool
    sample: int
    progress: Callable[[int, str], Any] | None
    headers_read: int = 0
    decoded: int = 0
    usable: dict[str, set[str]] = field(default_factory=dict)  # file names per camera


@dataclass(frozen=True)
class PngHeader:
    """What the first 33 and last 12 bytes of a PNG say. `problem` is None for a sound file."""

    width: int = 0
    height: int = 0
    bit_depth: int = 0
    colour_type: int = 0
    problem: str | None = None

    def format_kinds(self) -> list[str]:
        """How the image differs from 8-bit mono ("16-bit", "RGB", ...; the reader converts
        it), empty for 8-bit mono."""
        kinds = [f"{self.bit_depth}-bit"] if self.bit_depth != 8 else []
        if self.colour_type != 0:
            kinds.append(COLOUR_TYPES.get(self.colour_type, "colour"))
        return kinds


COLOUR_TYPES = {0: "grey", 2: "RGB", 3: "palette", 4: "grey+alpha", 6: "RGBA"}


def is_format_kind(kind: str) -> bool:
    """A kind from `PngHeader.format_kinds` (not a size or an unreadable file)."""
    return kind.endswith("-bit") or kind in COLOUR_TYPES.values() or kind == "colour"


def format_message(kind: str, names: list[str]) -> str:
    ex = ", ".join(names[:MAX_EXAMPLES])
    return f"{len(names)} image(s) are {kind}, not 8-bit mono: {ex}; the reader converts them"


def read_png_header(path: Path) -> PngHeader:
    """Size, bit depth and colour type from the IHDR chunk; truncation from the IEND chunk."""
    try:
        with open(path, "rb") as f:
            head = f.read(33)
            if not head:
                return PngHeader(problem="empty file")
            if not head.startswith(PNG_SIGNATURE):
                return PngHeader(problem="not a PNG file (bad signature)")
            if len(head) < 33 or head[12:16] != b"IHDR":
                return PngHeader(problem="corrupt PNG (no IHDR chunk)")
            f.seek(-12, os.SEEK_END)
            tail = f.read(12)
    except OSError as e:
        return PngHeader(problem=f"cannot read: {e.strerror or e}")
    width, height, depth, ctype = struct.unpack(">IIBB", head[16:26])
    problem = None if b"IEND" in tail else "truncated PNG (no IEND chunk at the end)"
    return PngHeader(width, height, depth, ctype, problem)


def check_images(
    found: Findings,
    state: ImageState,
    cam: str,
    mav0: Path,
    c: ScannedCsv | None,
    calib: CameraCalib | None,
    calib_where: tuple[str, str] | None = None,
) -> None:
    """Images listed but missing, present but not listed, every PNG header (size against the
    calibration, bit depth, colour, truncation), then a decoded sample (`decode_sample`).
    `calib_where`: the file and key the calibration's resolution comes from (default: the
    camera's sensor.yaml, `resolution`)."""
    folder = mav0 / cam / "data"
    csv_path = mav0 / cam / "data.csv"
    if c is None or c.names is None or not folder.is_dir():
        return
    present = set(os.listdir(folder))
    listed = set(c.names)
    missing = [(int(li), nm) for li, nm in zip(c.lines, c.names, strict=True) if nm not in present]
    if missing:
        ex = ", ".join(f"{nm} (line {li})" for li, nm in missing[:MAX_EXAMPLES])
        found.add(
            WARNING,
            "images",
            f"{len(missing)} of {len(c.names)} listed image(s) missing: {ex}; the reader "
            "skips those frames",
            csv_path,
            missing[0][0],
        )
    unlisted = sorted(
        n for n in present if n not in listed and n.lower().endswith((".png", ".jpg", ".pgm"))
    )
    if unlisted:
        found.add(
            WARNING,
            "images",
            f"{len(unlisted)} image file(s) not listed in data.csv (ignored by the reader): "
            + ", ".join(unlisted[:MAX_EXAMPLES]),
            folder,
        )
    probs: dict[str, list[str]] = {}
    sizes: dict[tuple[int, int], int] = {}
    usable: list[str] = []
    seen: set[str] = set()
    for name in c.names:
        if name not in present or name in seen:
            continue
        seen.add(name)
        h = read_png_header(folder / name)
        state.headers_read += 1
        if h.problem is not None:
            probs.setdefault(h.problem, []).append(name)
            continue
        sizes[(h.width, h.height)] = sizes.get((h.width, h.height), 0) + 1
        if calib is not None and (h.width, h.height) != calib.resolution:
            probs.setdefault(f"size {h.width}x{h.height}", []).append(name)
            continue
        for kind in h.format_kinds():
            probs.setdefault(kind, []).append(name)
        usable.append(name)
    for kind, names in probs.items():
        ex = ", ".join(names[:MAX_EXAMPLES])
        if kind.startswith("size "):
            assert calib is not None
            src, key = calib_where or (f"{cam}/sensor.yaml", "resolution")
            found.add(
                ERROR,
                "images",
                f"{len(names)} image(s) are {kind[5:]} but {Path(src).name} {key} is "
                f"{calib.width}x{calib.height}: {ex}; the reader skips them",
                folder,
                key=key,
            )
        elif is_format_kind(kind):
            found.add(WARNING, "images", format_message(kind, names), folder)
        else:
            found.add(
                WARNING,
                "images",
                f"{len(names)} unreadable image(s), {kind}: {ex}; the reader skips them",
                folder,
            )
    if c.names and not usable:
        found.add(ERROR, "images", f"no usable image among {len(c.names)} listed", folder)
    state.usable[cam] = set(usable)
    decode_sample(found, state, cam, folder, usable)


def decode_sample(
    found: Findings, state: ImageState, cam: str, folder: Path, usable: list[str]
) -> None:
    """Decode `state.sample` evenly spaced usable images (all with `state.full`), CRCs checked:
    unreadable ones leave `state.usable`, blank ones are a warning."""
    if not usable:
        return
    if state.full or len(usable) <= state.sample:
        picks = usable
    elif state.sample <= 0:
        return
    else:
        idx = np.unique(np.linspace(0, len(usable) - 1, state.sample).round().astype(int))
        picks = [usable[i] for i in idx]
    unreadable: list[str] = []
    blank: list[str] = []
    for name in picks:
        if state.progress is not None:
            state.progress(1, cam)
        dec = decode_image(folder / name, check_crc=True)
        state.decoded += 1
        if dec.image is None:
            unreadable.append(f"{name} ({dec.problem})")
        elif int(dec.image.min()) == int(dec.image.max()):
            blank.append(f"{name} (every pixel {int(dec.image.min())})")
    what = "all" if len(picks) == len(usable) else f"a sample of {len(picks)}"
    if unreadable:
        found.add(
            WARNING,
            "images",
            f"{len(unreadable)} image(s) of {what} decoded are unreadable: "
            + ", ".join(unreadable[:MAX_EXAMPLES])
            + "; the reader skips them",
            folder,
        )
        state.usable[cam] -= {u.split(" ")[0] for u in unreadable}
    if blank:
        found.add(
            WARNING,
            "images",
            f"{len(blank)} blank image(s) among {what} decoded: " + ", ".join(blank[:MAX_EXAMPLES]),
            folder,
        )
