"""Importer for the Shore-hardness GelSight video dataset (Yuan et al. 2017): one press
video per sample, three raw frames (first, midway, brightest), labels from Shore 00.

See docs/data.md, "Importing the Shore-hardness videos".
"""

from __future__ import annotations

import re
import time
from collections import Counter
from pathlib import Path

import cv2
import numpy as np

from tactile_compliance.data.image_ops import resize_frames
from tactile_compliance.data.import_report import (
    ImportReport,
    import_paths,
    store_writing,
    utf8_problem,
)
from tactile_compliance.data.plausibility import MODULUS
from tactile_compliance.data.raw_layout import VIDEO_SUFFIXES
from tactile_compliance.data.store_writer import GraspStoreWriter
from tactile_compliance.physics.shore import shore00_to_modulus_pa
from tactile_compliance.progress import progress_bar

VIDEO_NAME = re.compile(
    r"^(?P<shape>.+)_(?P<hardness>\d+)_(?P<press>\d+)\.(?:"
    + "|".join(suffix[1:] for suffix in VIDEO_SUFFIXES)
    + r")$",
    re.IGNORECASE,
)
MATERIAL = "Silicone"


def read_video_frames(path: str | Path) -> np.ndarray:
    """Decode every frame of a video as uint8 RGB (T, H, W, 3); ValueError if unreadable."""
    capture = cv2.VideoCapture(str(path))
    try:
        if not capture.isOpened():
            raise ValueError(f"{path}: cannot open video")
        promised = int(capture.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        frames = []
        while True:
            ok, frame = capture.read()
            if not ok:
                break
            frames.append(frame[..., ::-1])  # OpenCV decodes BGR; the store is RGB.
    finally:
        capture.release()
    if not frames:
        raise ValueError(f"{path}: no decodable frames")
    # A file cut short decodes fewer frames than its container promises (an estimated
    # count may be one off): not a shorter press (acquisition.sensors does the same).
    if promised > 0 and len(frames) < promised - 1:
        raise ValueError(
            f"{path}: the video ends after {len(frames)} of the {promised} frames its "
            f"container promises: the file is truncated or damaged"
        )
    return np.ascontiguousarray(np.stack(frames))


def video_frame_size(path: str | Path) -> tuple[int, int] | None:
    """(height, width) from a video's header without decoding it; None if unreadable."""
    capture = cv2.VideoCapture(str(path))
    try:
        if not capture.isOpened():
            return None
        height = int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT))
        width = int(capture.get(cv2.CAP_PROP_FRAME_WIDTH))
    finally:
        capture.release()
    return (height, width) if height > 0 and width > 0 else None


def select_press_frames(frames: np.ndarray) -> tuple[int, int, int]:
    """Indices (first, midway, brightest) of a press video, in time order.

    ``frames`` are the decoded frames, (T, H, W, 3) uint8 in RGB order (as
    :func:`read_video_frames` returns them). "Brightest" is the highest mean of OpenCV's
    greyscale, ``0.299 R + 0.587 G + 0.114 B`` rounded per pixel, as the published code
    computes it (``cv2.cvtColor(frame, COLOR_BGR2GRAY)`` on the BGR frames OpenCV decodes,
    at full resolution); the first such frame on a tie. Midway is ``brightest // 2``.
    """
    # COLOR_RGB2GRAY on RGB frames is the published COLOR_BGR2GRAY on the BGR ones, with
    # OpenCV's own fixed-point rounding, so near-ties break the same way.
    grey_level = [
        float(cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_RGB2GRAY).mean())
        for frame in frames
    ]
    brightest = int(np.argmax(grey_level))
    return 0, brightest // 2, brightest


def import_yuan(
    src_dir: str | Path,
    out_dir: str | Path,
    *,
    image_size: tuple[int, int] | None = None,
    strict: bool = False,
    overwrite: bool = False,
    progress: bool = True,
) -> ImportReport:
    """Import a directory of Shore-hardness press videos into a GraspStore (frame size:
    ``image_size`` (height, width) px, else the videos' most common one).

    One sample per video: its first, midway and brightest frames, raw RGB (``frame_kind:
    raw``), resized to the store's size when another; no force, width or estimates. A
    video whose name does not match, that does not decode, or whose label is implausible
    is skipped and reported (``strict``: the first one stops the import).

    Raises a :class:`~tactile_compliance.data.import_report.DataImportError` subclass when
    the import cannot go on (nothing is written then).
    """
    start = time.perf_counter()
    src, out = import_paths(src_dir, out_dir, overwrite)
    report = ImportReport(source="yuan", source_dir=str(src), store_dir=str(out), strict=strict)
    videos = sorted(p for p in src.rglob("*") if p.suffix.lower() in VIDEO_SUFFIXES and p.is_file())
    report.require_sources(videos, src, f"videos found ({', '.join(VIDEO_SUFFIXES)})")
    objects: set[str] = set()
    imported: set[str] = set()
    # First pass, headers only: the most common frame size (reports nothing).
    sizes = Counter(
        size
        for size in (video_frame_size(v) for v in videos if VIDEO_NAME.match(v.name))
        if size is not None
    )
    if image_size is None and sizes:
        image_size = sizes.most_common(1)[0][0]

    def make_writer() -> GraspStoreWriter:
        assert image_size is not None  # set by the headers or the first readable video
        return GraspStoreWriter(
            out,
            image_size=image_size,
            source="yuan",
            creation_parameters={
                "importer": "yuan",
                "source_dir": str(src.resolve()),
                "frame_kind": "raw",
                "frame_selection": "first, midway, brightest (OpenCV-weighted grey)",
                "label_conversion": "Shore 00 -> E (Larson 2017)",
                "source_image_sizes": {f"{h}x{w}": n for (h, w), n in sizes.most_common()},
            },
            overwrite=overwrite,
        )

    with (
        store_writing(out, report, make_writer) as target,
        progress_bar("Importing videos", total=len(videos), enabled=progress) as advance,
    ):
        for video in videos:
            advance()
            match = VIDEO_NAME.match(video.name)
            problem = utf8_problem(str(video.relative_to(src)))
            if problem:
                report.problem(video, f"invalid name: the path is {problem}")
                continue
            if match is None:
                report.problem(video, "unexpected file name: expected {SHAPE}_{hardness}_{n}.avi")
                continue
            shape, hardness = match["shape"], int(match["hardness"])
            object_id = f"{shape}_{match['hardness']}"  # as spelled in the file name
            objects.add(object_id)
            if not 0 <= hardness <= 100:
                report.problem(video, f"invalid hardness: Shore 00 {hardness} outside [0, 100]")
                continue
            modulus_pa = float(shore00_to_modulus_pa(float(hardness)))
            problem = MODULUS.violation(modulus_pa)
            if problem:
                report.problem(video, f"implausible value: Shore 00 {hardness}: {problem}")
                continue
            try:
                frames = read_video_frames(video)
                chosen = frames[list(select_press_frames(frames))]
                del frames
                if image_size is None:  # no header gave a size: the first video decides
                    image_size = (chosen.shape[1], chosen.shape[2])
                chosen = resize_frames(chosen, image_size)
            except (ValueError, cv2.error, MemoryError) as err:
                report.problem(video, f"unreadable video: {err}")
                continue
            row = {
                "object": object_id,
                "grasp": int(match["press"]),
                "augmentation": 0,
                "finger": "markerless",
                "material": MATERIAL,
                "shape": shape,
                "modulus_pa": modulus_pa,
                "source_path": str(video.relative_to(src)),
            }
            if target.append(chosen, row, video):
                imported.add(object_id)
        report.objects_seen = len(objects)
        report.objects_imported = len(imported)
        target.commit(f"{src}: nothing importable, every video was skipped")
    report.seconds = time.perf_counter() - start
    return report
