"""Importer for the Shore-hardness GelSight video dataset (Yuan et al. 2017).

One ``.avi`` per press, named ``{SHAPE}_{hardness:02d}_{n}.avi`` (e.g. ``BASIC_34_2.avi``).
Three frames are kept per video: the first frame, the frame with the highest mean grey
level (the deepest press) and the frame midway between them. Labels come from the
Shore 00 hardness through Larson's conversion; there is no force, width or estimate.
Frames are stored as raw camera images (``frame_kind: raw`` in the store header), in RGB.
"""

from __future__ import annotations

import re
import time
from pathlib import Path

import cv2
import numpy as np

from tactile_compliance.data.image_ops import resize_frames
from tactile_compliance.data.import_report import DataImportError, ImportReport, import_paths
from tactile_compliance.data.store import GraspStoreWriter
from tactile_compliance.physics.shore import shore00_to_modulus_pa
from tactile_compliance.progress import progress_bar

VIDEO_NAME = re.compile(r"^(?P<shape>.+)_(?P<hardness>\d+)_(?P<press>\d+)\.avi$", re.IGNORECASE)
MATERIAL = "Silicone"


def read_video_frames(path: str | Path) -> np.ndarray:
    """Decode every frame of a video as uint8 RGB (T, H, W, 3); ValueError if unreadable."""
    capture = cv2.VideoCapture(str(path))
    try:
        if not capture.isOpened():
            raise ValueError(f"{path}: cannot open video")
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
    return np.ascontiguousarray(np.stack(frames))


def select_press_frames(frames: np.ndarray) -> tuple[int, int, int]:
    """Indices (first, midway, brightest) of a press video (T, H, W, 3), in time order."""
    grey_level = frames.reshape(len(frames), -1).mean(axis=1)
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
    """Import a directory of Shore-hardness press videos into a GraspStore.

    ``image_size`` is (height, width) in pixels; by default the first video's size is used
    and other videos are resized to it.
    """
    start = time.perf_counter()
    src, out = import_paths(src_dir, out_dir, overwrite)
    report = ImportReport(source="yuan", source_dir=str(src), store_dir=str(out), strict=strict)
    videos = sorted(p for p in src.rglob("*") if p.suffix.lower() == ".avi" and p.is_file())
    if not videos:
        raise DataImportError(f"{src}: no .avi videos found")
    objects: set[str] = set()
    imported: set[str] = set()
    writer: GraspStoreWriter | None = None
    try:
        with progress_bar("Importing videos", total=len(videos), enabled=progress) as advance:
            for video in videos:
                advance()
                match = VIDEO_NAME.match(video.name)
                if match is None:
                    report.problem(
                        video, "unexpected file name: expected {SHAPE}_{hardness}_{n}.avi"
                    )
                    continue
                shape, hardness = match["shape"], int(match["hardness"])
                object_id = f"{shape}_{match['hardness']}"  # as spelled in the file name
                objects.add(object_id)
                if not 0 <= hardness <= 100:
                    report.problem(video, f"invalid hardness: Shore 00 {hardness} outside [0, 100]")
                    continue
                try:
                    frames = read_video_frames(video)
                except ValueError as err:
                    report.problem(video, f"unreadable video: {err}")
                    continue
                chosen = frames[list(select_press_frames(frames))]
                if image_size is None:
                    image_size = (chosen.shape[1], chosen.shape[2])
                if writer is None:
                    writer = GraspStoreWriter(
                        out,
                        image_size=image_size,
                        source="yuan",
                        creation_parameters={
                            "importer": "yuan",
                            "source_dir": str(src.resolve()),
                            "frame_kind": "raw",
                            "frame_selection": "first, midway, brightest",
                            "label_conversion": "Shore 00 -> E (Larson 2017)",
                        },
                        overwrite=overwrite,
                    )
                writer.append(
                    resize_frames(chosen, image_size),
                    {
                        "object": object_id,
                        "grasp": int(match["press"]),
                        "augmentation": 0,
                        "finger": "markerless",
                        "material": MATERIAL,
                        "shape": shape,
                        "modulus_pa": float(shore00_to_modulus_pa(float(hardness))),
                        "source_path": str(video.relative_to(src)),
                    },
                )
                imported.add(object_id)
                report.samples_imported += 1
        if writer is None:
            raise DataImportError(f"{src}: nothing importable\n{report.format()}")
        writer.commit()
    except BaseException:
        if writer is not None:
            writer.abort()
        raise
    report.objects_seen = len(objects)
    report.objects_imported = len(imported)
    report.seconds = time.perf_counter() - start
    return report
