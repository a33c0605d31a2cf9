"""Copy the Middlebury "Cones" pair into the compact array file data/middlebury_cones/cones.npz.

Usage: python scripts/convert_cones.py /path/to/middlebury_cones  (folder with left.png,
right.png, disp_left.tif and occlusion.png). Writes ``left``, ``right`` (H, W) uint8,
``disparity4`` (H, W) uint8 = 4 x the ground-truth disparity of the left image (it is
quantised to 0.25 px, so this is exact; 0 = unknown) and ``nonoccluded`` (H, W) bool.
"""

import sys
from pathlib import Path

import cv2
import numpy as np
from skimage.io import imread

OUT = Path(__file__).resolve().parents[1] / "data" / "middlebury_cones"


def main(src: str) -> None:
    src = Path(src)
    left = cv2.imread(str(src / "left.png"), cv2.IMREAD_GRAYSCALE)
    right = cv2.imread(str(src / "right.png"), cv2.IMREAD_GRAYSCALE)
    disparity = imread(src / "disp_left.tif").astype(np.float64)
    occlusion = cv2.imread(str(src / "occlusion.png"), cv2.IMREAD_GRAYSCALE)
    d4 = 4 * disparity
    if not (np.allclose(d4, np.rint(d4)) and d4.max() <= 255):
        raise ValueError("disp_left.tif: expected disparities quantised to 0.25 px, below 64")
    OUT.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(OUT / "cones.npz", left=left, right=right,
                        disparity4=np.rint(d4).astype(np.uint8), nonoccluded=occlusion > 0)
    print(f"cones: {left.shape}, disparity {disparity.min():g}-{disparity.max():g} px, "
          f"{(occlusion > 0).mean():.1%} non-occluded")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "../shared/data/middlebury_cones")
