"""Copy the Middlebury "Teddy", "Art" and "Tsukuba" pairs into compact array files
``data/middlebury_<name>/<name>.npz`` (the Cones pair has its own script, convert_cones.py).

Usage: python scripts/convert_middlebury.py [/path/to/shared/data]  (the folder holding
``middlebury_teddy``, ``middlebury_art`` and ``middlebury_tsukuba``; see its README).

Each file holds ``left``, ``right`` (H, W) uint8 grey (OpenCV's BGR-to-grey weights, as
``cv2.IMREAD_GRAYSCALE``), ``disparity_raw`` (H, W) uint8 = ``disparity_scale`` x the
ground-truth disparity of the left image exactly as the source stores it (0 = unknown),
``disparity_scale`` (the factor: 4, 3, 16) and ``nonoccluded`` (H, W) bool.

Left and right: Teddy ``im2`` / ``im6``, Art ``view1`` / ``view5``, Tsukuba ``imL2l`` /
``imL2`` (the Tsukuba names look swapped; ``imL2l`` is the left image: with it as left the
truth maps left pixels onto the right image, tested in tests/test_data.py).

Non-occlusion: Teddy and Art come with ``nonocc_derived.png`` (left and right truth agree
within 1 px; derived by whoever collected the copy, not from Middlebury), used as it is.
Tsukuba's copy has no mask and no right truth, so the mask is derived here from the left
truth alone: a left pixel is occluded when a pixel to its right lands on or left of its own
position in the right image (``x2 - d2 <= x - d`` for some ``x2 > x``), i.e. something
nearer hides it from the right camera.
"""

import sys
from pathlib import Path

import cv2
import numpy as np

OUT = Path(__file__).resolve().parents[1] / "data"

PAIRS = {  # name: (folder, left, right, left truth, scale, mask file or None)
    "teddy": ("middlebury_teddy", "im2.png", "im6.png", "disp2.png", 4, "nonocc_derived.png"),
    "art": ("middlebury_art", "view1.png", "view5.png", "disp1.png", 3, "nonocc_derived.png"),
    "tsukuba": ("middlebury_tsukuba", "imL2l.bmp", "imL2.bmp", "groundtruth.bmp", 16, None),
}


def visible_from_right(disparity: np.ndarray) -> np.ndarray:
    """(H, W) bool: left pixels not hidden in the right image by a pixel to their right,
    from the left disparity ``disparity`` (px, NaN unknown: unknown pixels hide nothing)."""
    h, w = disparity.shape
    x = np.arange(w, dtype=float)
    landing = np.where(np.isfinite(disparity), x - disparity, np.inf)   # x - d per pixel
    # smallest landing position among the pixels strictly to the right of each pixel
    right_min = np.minimum.accumulate(landing[:, ::-1], axis=1)[:, ::-1]
    right_min = np.concatenate([right_min[:, 1:], np.full((h, 1), np.inf)], axis=1)
    return np.isfinite(disparity) & (right_min > landing)


def convert(src: Path, name: str) -> Path:
    folder, left_name, right_name, disp_name, scale, mask_name = PAIRS[name]
    d = src / folder
    left = cv2.imread(str(d / left_name), cv2.IMREAD_GRAYSCALE)
    right = cv2.imread(str(d / right_name), cv2.IMREAD_GRAYSCALE)
    raw = cv2.imread(str(d / disp_name), cv2.IMREAD_UNCHANGED)
    if raw.ndim != 2 or raw.dtype != np.uint8:
        raise ValueError(f"{disp_name}: expected an 8-bit single-channel disparity image")
    if mask_name is not None:
        nonoccluded = cv2.imread(str(d / mask_name), cv2.IMREAD_GRAYSCALE) > 0
    else:
        disparity = np.where(raw > 0, raw / scale, np.nan)
        nonoccluded = visible_from_right(disparity)
    out = OUT / folder
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{name}.npz"
    np.savez_compressed(path, left=left, right=right, disparity_raw=raw,
                        disparity_scale=np.int64(scale), nonoccluded=nonoccluded)
    known = raw > 0
    print(f"{name}: {left.shape}, disparity {raw[known].min() / scale:g}-"
          f"{raw.max() / scale:g} px, {known.mean():.1%} known, {nonoccluded.mean():.1%} "
          f"non-occluded, {path.stat().st_size / 1e3:.0f} kB")
    return path


def main(src: str) -> None:
    for name in PAIRS:
        convert(Path(src), name)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "../shared/data")
