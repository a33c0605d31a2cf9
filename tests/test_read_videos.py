"""Reading a multi-camera recording from video files the test writes itself."""

import cv2
import numpy as np
import pytest

from lsmta.io import read_videos


def _write(path, frames, fps=30.0):
    h, w = frames[0].shape
    out = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (w, h))
    assert out.isOpened()
    for g in frames:
        out.write(cv2.cvtColor(g, cv2.COLOR_GRAY2BGR))
    out.release()
    return path


def _frames(T, h, w, seed):
    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur(rng.uniform(0, 255, (h, w)), (0, 0), 3)
    return [np.clip(np.roll(base, 2 * t, axis=1), 0, 255).astype(np.uint8) for t in range(T)]


@pytest.fixture
def recording(tmp_path):
    frames = [_frames(12, 48, 64, 1), _frames(12, 48, 60, 2)]   # the second 4 px narrower
    paths = [_write(tmp_path / "cam01.avi", frames[0]), _write(tmp_path / "cam02.avi", frames[1])]
    return paths, frames


def test_frames_are_read_as_needed_and_match_the_files(recording):
    paths, frames = recording
    v = read_videos(paths, frames=slice(2, 9, 3))
    assert v.frames == (2, 5, 8) and v.n_views == 2 and v.fps == pytest.approx(30.0)
    assert v.file_sizes == ((64, 48), (60, 48)) and v.sizes == v.file_sizes
    seen = list(v)
    assert [t for t, _ in seen] == [2, 5, 8]
    for (_, images), t in zip(seen, (2, 5, 8)):
        for k in range(2):
            # MJPG is lossy: a few grey levels
            assert np.abs(images[k].astype(int) - frames[k][t]).mean() < 4
    again = v.read(1)
    assert all(np.array_equal(a, b) for a, b in zip(again, seen[1][1]))
    stacks = v.load(progress=False)
    assert [s.shape for s in stacks] == [(3, 48, 64), (3, 48, 60)]


def test_crop_and_scale(recording):
    paths, _ = recording
    v = read_videos(paths, frames=[0, 4], crop=(4, 8, 44, 40), scale=0.5)
    assert v.sizes == ((20, 16), (20, 16))
    full = read_videos(paths, frames=[4]).read(0)[0]
    got = v.read(1)[0]
    want = cv2.resize(full[8:40, 4:44], (20, 16), interpolation=cv2.INTER_AREA)
    assert np.array_equal(got, want)


def test_clear_errors(recording, tmp_path):
    paths, frames = recording
    with pytest.raises(FileNotFoundError, match=r"paths\[1\]"):
        read_videos([paths[0], tmp_path / "missing.mp4"])
    (tmp_path / "junk.mp4").write_bytes(b"not a video")
    with pytest.raises(ValueError, match=r"paths\[1\]: OpenCV cannot read junk.mp4"):
        read_videos([paths[0], tmp_path / "junk.mp4"])
    short = _write(tmp_path / "short.avi", frames[0][:5])
    with pytest.raises(ValueError, match="cam01.avi: 12, short.avi: 5"):
        read_videos([paths[0], short])
    fast = _write(tmp_path / "fast.avi", frames[0], fps=60.0)
    with pytest.raises(ValueError, match="frame rates"):
        read_videos([paths[0], fast])
    with pytest.raises(ValueError, match="frame 12 is out of range"):
        read_videos(paths, frames=[0, 12])
    with pytest.raises(ValueError, match="stop 20"):
        read_videos(paths, frames=slice(0, 20))
    with pytest.raises(ValueError, match="crop"):
        read_videos(paths, crop=(0, 0, 64, 48))          # the second video is 60 wide
    with pytest.raises(ValueError, match="scale"):
        read_videos(paths, scale=0)
    with pytest.raises(IndexError, match="expected 0 <= i < 1"):
        read_videos(paths, frames=[1]).read(1)
    with pytest.raises(ValueError, match="selects none"):
        read_videos(paths, frames=slice(5, 5))
    with pytest.raises(ValueError, match="whole number of pixels"):
        read_videos(paths, scale=0.3)
