"""Convert the AnimFace Maya ASCII captures to the compact arrays in data/animface/.

Usage: python scripts/convert_animface.py /path/to/animface  (folder with JawMoCap.ma and
CheeksMoCap.ma). Writes data/animface/<name>.npz with ``labels`` (M,) str, ``points``
(T, M, 3) float32 in mm and ``times`` (T,) in the file's time unit.
"""

import sys
from pathlib import Path

import numpy as np

from lsmta.io import read_maya_curves

OUT = Path(__file__).resolve().parents[1] / "data" / "animface"


def main(src: str) -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    for name in ("JawMoCap", "CheeksMoCap"):
        labels, points, times = read_maya_curves(Path(src) / f"{name}.ma")
        np.savez_compressed(OUT / f"{name}.npz", labels=np.array(labels),
                            points=points.astype(np.float32), times=times)
        print(f"{name}: {points.shape[0]} frames, {points.shape[1]} markers")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "../shared/data/animface")
