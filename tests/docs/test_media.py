"""The README's pictures in docs/media/ (made by docs/media/make_media.py; the commanded flight by
docs/ground_station_gif.py): each is there, small,
of the size and length it was made with, and drawn (not blank). Reads the files only: no flight,
no training, well under a second."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

MEDIA = Path(__file__).resolve().parents[2] / "docs" / "media"

# name: (width, height, fewest frames, most bytes)
EXPECTED = {
    "hover.gif": (480, 360, 120, 1_500_000),  # 5 s at 25 fps
    "circle.gif": (480, 360, 300, 1_500_000),  # two laps, 12.6 s at 25 fps
    "montage.gif": (720, 320, 90, 1_500_000),  # 5 s at 20 fps, three panels
    "curves.png": (720, 250, 1, 200_000),
    "commanded_flight.gif": (720, 340, 120, 1_500_000),  # docs/ground_station_gif.py: ~12 s at 10 fps
}


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_readme_media_are_small_and_drawn(name):
    image = pytest.importorskip("PIL.Image")
    path = MEDIA / name
    assert path.is_file(), f"{path} is missing; regenerate with .venv/bin/python docs/media/make_media.py"
    width, height, fewest, most = EXPECTED[name]
    assert path.stat().st_size <= most, f"{name}: {path.stat().st_size:,} bytes, budget {most:,}"
    with image.open(path) as im:
        assert im.size == (width, height)
        frames = getattr(im, "n_frames", 1)
        assert frames >= fewest
        for k in sorted({0, frames // 2, frames - 1}):
            im.seek(k)
            rgb = np.asarray(im.convert("RGB"), dtype=float)
            assert rgb.std() > 10, f"{name} frame {k} looks blank"
            assert len(np.unique(rgb.reshape(-1, 3), axis=0)) > 8, f"{name} frame {k} has almost no colours"
