"""Training data for a vocabulary: ORB descriptors of the images of files, folders, TUM RGB-D
folders and MCAP logs."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import InputError
from slamcli.vision.vocabulary.tree import DESCRIPTOR_BYTES, U8, ProgressFn

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
"""Files a folder input is searched for (recursively); a file named directly may also be PNM,
BMP or WebP."""

INPUT_KINDS = "an image, a folder of PNG/JPEG images, a TUM RGB-D folder or an MCAP log"


@dataclass
class TrainingImages:
    """ORB descriptors of the training images, one array per image, and what was left out.

    Attributes:
        descriptors: one (N_i, 32) uint8 array per image used.
        names: the image each array came from (path, or ``log:frame name``).
        unreadable: images that could not be read or decoded, as ``"name: reason"``.
        not_8bit: images left out because they are not 8-bit (depth maps).
    """

    descriptors: list[U8]
    names: list[str]
    unreadable: list[str]
    not_8bit: list[str]

    @property
    def n_descriptors(self) -> int:
        return sum(int(d.shape[0]) for d in self.descriptors)


def _image_files(folder: Path) -> list[Path]:
    return sorted(
        p for p in folder.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()
    )


def _plan_input(path: Path) -> list[Path] | None:
    """The image files of a file or folder input, or None for a log read through a source."""
    from slamcli.formats import sniff

    if not path.exists():
        raise InputError(f"{path}: no such file or folder", hint=f"give {INPUT_KINDS}")
    if path.is_dir():
        if sniff.tum_rgbd(path):
            return None
        files = _image_files(path)
        if not files:
            raise InputError(
                f"{path}: folder holds no {'/'.join(s[1:] for s in IMAGE_SUFFIXES)} images",
                hint=f"give {INPUT_KINDS}",
            )
        return files
    if sniff.mcap(path):
        return None
    return [path]


def _select(index: int, used: int, every: int, max_frames: int | None) -> bool:
    return index % every == 0 and (max_frames is None or used < max_frames)


def extract_training_descriptors(
    inputs: Sequence[str | Path],
    *,
    features: int = 1000,
    every: int = 1,
    max_frames: int | None = None,
    rgb_topic: str | None = None,
    progress: ProgressFn | None = None,
) -> TrainingImages:
    """ORB descriptors of every ``every``-th image of each input, for
    :func:`~slamcli.vision.vocabulary.train_vocabulary`.

    Args:
        inputs: image files, folders of PNG/JPEG images (searched recursively, in sorted path
            order), TUM RGB-D folders (their colour images) or MCAP logs (their image topic).
        features: ORB features per image (``cv2.ORB`` with 8 levels, scale 1.2, on grey).
        every: use every K-th image of each input (the first is always used).
        max_frames: at most this many images from each input.
        rgb_topic: the image topic of MCAP inputs (default: the one image topic they have).
        progress: called as ``progress(done, total)`` per image used; ``total`` is None when an
            input is a log whose length is not known up front.

    Raises:
        InputError: an input is missing, not a kind listed above, or a file named directly is
            not a readable image; a folder's unreadable images are skipped and listed instead.
    """
    from slamcli.backends import import_cv2

    cv2 = import_cv2()
    if features < 1 or every < 1 or (max_frames is not None and max_frames < 1):
        raise ValueError("features, every and max_frames must be positive")
    plans = [(Path(p), _plan_input(Path(p))) for p in inputs]
    total: int | None = 0
    for _, files in plans:
        if files is None or total is None:
            total = None
        else:
            total += len(files[::every][:max_frames])
    orb = cv2.ORB.create(nfeatures=features, nlevels=8, scaleFactor=1.2)
    result = TrainingImages([], [], [], [])

    def use(name: str, gray: U8) -> None:
        _, desc = orb.detectAndCompute(gray, None)
        result.descriptors.append(
            np.zeros((0, DESCRIPTOR_BYTES), np.uint8) if desc is None else desc
        )
        result.names.append(name)
        if progress is not None:
            progress(len(result.names), total)

    for path, files in plans:
        used = 0
        if files is None:
            used = _from_source(
                path, every, max_frames, rgb_topic, cv2, use, result.not_8bit.append
            )
        else:
            named = len(files) == 1 and files[0] == path
            for i, file in enumerate(files):
                if not _select(i, used, every, max_frames):
                    continue
                gray, reason = _read_grey(file, cv2)
                if gray is None:
                    if named:
                        raise InputError(f"{file}: {reason}", hint=f"give {INPUT_KINDS}")
                    if reason == "not 8-bit":
                        result.not_8bit.append(str(file))
                    else:
                        result.unreadable.append(f"{file}: {reason}")
                    continue
                use(str(file), gray)
                used += 1
    return result


def _read_grey(path: Path, cv2: Any) -> tuple[U8 | None, str]:
    from slamcli.formats.images import decode_image, read_image_file

    data, reason = read_image_file(path)
    if data is None:
        return None, reason
    img, reason = decode_image(data)
    if img is None:
        return None, reason
    if img.dtype != np.uint8:
        return None, "not 8-bit"
    gray = _grey(img, cv2, rgb=False)
    return (gray, "") if gray is not None else (None, f"has an unsupported layout {img.shape}")


def _grey(img: NDArray[Any], cv2: Any, *, rgb: bool) -> U8 | None:
    """(H, W) uint8 grey from a grey, RGB/BGR or RGBA/BGRA uint8 image; None for other shapes."""
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 2:
        return np.ascontiguousarray(img)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        codes = {
            (3, True): cv2.COLOR_RGB2GRAY,
            (4, True): cv2.COLOR_RGBA2GRAY,
            (3, False): cv2.COLOR_BGR2GRAY,
            (4, False): cv2.COLOR_BGRA2GRAY,
        }
        return np.asarray(cv2.cvtColor(img, codes[img.shape[2], rgb]), dtype=np.uint8)
    return None


def _from_source(
    path: Path,
    every: int,
    max_frames: int | None,
    rgb_topic: str | None,
    cv2: Any,
    use: Callable[[str, U8], None],
    not_8bit: Callable[[str], None],
) -> int:
    from slamcli.formats import open_source, sniff
    from slamcli.types import ImageFrame

    used = 0
    options = {"rgb_topic": rgb_topic} if rgb_topic and sniff.mcap(path) else {}
    with open_source(path, **options) as source:
        for i, frame in enumerate(source.frames(("image",))):
            if max_frames is not None and used >= max_frames:
                break
            if i % every or not isinstance(frame, ImageFrame):
                continue
            img, name = frame.image, f"{path}:{frame.name or frame.stamp_ns}"
            if img.dtype != np.uint8:
                not_8bit(name)
                continue
            gray = _grey(img, cv2, rgb=True)
            if gray is None:
                continue
            use(name, gray)
            used += 1
    return used
