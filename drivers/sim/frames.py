"""Write simulated rig frames and their calibration to a folder (for offline work and demos)."""

from __future__ import annotations

from pathlib import Path

import cv2

from calib_store.model import save_calibration
from drivers.sim.rig import RigConfig, ShaftRenderer


def write_frames(
    output: str | Path, diameters_mm: list[float], count: int = 1, seed: int = 0,
    config: RigConfig | None = None,
) -> list[Path]:
    """Render ``count`` frames of each diameter into ``output`` as PNG, plus
    ``calibration.json``; return the image paths. File names carry the diameter in um."""
    out = Path(output)
    out.mkdir(parents=True, exist_ok=True)
    renderer = ShaftRenderer(config or RigConfig(), seed=seed)
    save_calibration(renderer.calibration, out / "calibration.json")
    paths = []
    frame = 0
    for d in diameters_mm:
        for _ in range(count):
            p = out / f"shaft_{round(d * 1000):06d}um_{frame:04d}.png"
            if not cv2.imwrite(str(p), renderer.render(d, frame)):
                raise OSError(f"could not write {p}")
            paths.append(p)
            frame += 1
    return paths
