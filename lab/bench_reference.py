"""A folder of converged reference images for the benchmarks, keyed by what they depend on.

A reference is the mean of K independent Cycles renders (seeds) at N samples each, stored as
`<scene>-<W>x<H>-<key>.exr` (R, G, B) with a JSON sidecar holding the parameters and the reference's own
mean squared error (estimated from the seeds' spread, see bench_math.reference_from_seeds). The key is a
hash of every parameter that changes the image (scene and its version, resolution, bounces, filter,
samples, seeds, renderer version), so a reference is reused exactly when it still applies.

The seed's Cornell box at 256x256 with the default settings starts from the bundled render
(lab/data/cornell_cycles_4096spp.exr: Cycles 5.0.1, 4 seeds x 1024 spp, own RMSE about 0.007). No bpy here:
rendering a missing reference is the add-on's job (lab/bench_cycles.py).
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core import exr
from .bench_math import write_json

# What the bundled reference was rendered with (the seed's Cornell box, core.builtin_scenes.cornell_box, in Cycles).
BUNDLED_PARAMS = {"scene": "cornell", "resolution": [256, 256], "max_bounces": 16,
                  "filter_type": "blackman-harris", "filter_width": 1.5, "spp_per_seed": 1024, "seeds": 4}
BUNDLED_OWN_RMSE = 0.007


@dataclass
class Reference:
    """A converged image (H, W, 3) float32, its own mean squared error, and where it came from."""

    image: np.ndarray
    own_mse: float
    params: dict
    path: Path | None = None
    source: str = "cache"  # "cache", "bundled", "rendered" or "file"


def reference_key(params: dict) -> str:
    """A short stable hash of the parameters (order-independent)."""
    text = json.dumps(params, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def file_digest(path: str | os.PathLike) -> str:
    """SHA-256 of a file's bytes (part of the key for a user's .blend)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()[:16]


def bundled_matches(params: dict) -> bool:
    """True when params ask for what the bundled Cornell reference is (renderer version aside)."""
    return all(params.get(k) == v for k, v in BUNDLED_PARAMS.items())


class ReferenceCache:
    """Reference images under one folder (created if missing)."""

    def __init__(self, folder: str | os.PathLike) -> None:
        self.folder = Path(folder).expanduser()
        if self.folder.exists() and not self.folder.is_dir():
            raise ValueError(f"reference folder {self.folder} is a file, not a folder")
        self.folder.mkdir(parents=True, exist_ok=True)

    def path_for(self, params: dict) -> Path:
        w, h = params["resolution"]
        safe = "".join(c if c.isalnum() or c in "-_" else "_" for c in str(params["scene"]))
        return self.folder / f"{safe}-{w}x{h}-{reference_key(params)}.exr"

    def load(self, params: dict) -> Reference | None:
        """The cached reference for params, or (for the bundled configuration) the bundled one, stored into
        the cache on first use; None when there is none yet."""
        path = self.path_for(params)
        meta_path = path.with_suffix(".json")
        if path.is_file() and meta_path.is_file():
            meta = json.loads(meta_path.read_text())
            image = exr.read_rgb(path)
            if list(image.shape[:2]) != [params["resolution"][1], params["resolution"][0]]:
                raise ValueError(f"cached reference {path} is {image.shape[1]}x{image.shape[0]}, expected "
                                 f"{params['resolution'][0]}x{params['resolution'][1]}; delete it to re-render")
            return Reference(image, float(meta["own_mse"]), meta["params"], path, "cache")
        if bundled_matches(params):
            from .bench import bundled_reference

            ref = Reference(bundled_reference(), BUNDLED_OWN_RMSE**2, dict(params), None, "bundled")
            ref.path = self.store(ref.image, ref.own_mse, params, note="bundled lab/data/cornell_cycles_4096spp.exr")
            return ref
        return None

    def store(self, image: np.ndarray, own_mse: float, params: dict, note: str = "") -> Path:
        """Write the reference EXR and its JSON sidecar (each atomically; the sidecar last, so a reference is
        only found complete)."""
        path = self.path_for(params)
        rgb = np.asarray(image[..., :3], np.float32)
        exr.write_exr(path, {"R": rgb[..., 0], "G": rgb[..., 1], "B": rgb[..., 2]})
        write_json(path.with_suffix(".json"), {"params": params, "own_mse": own_mse,
                                               "own_rmse": float(np.sqrt(own_mse)), "note": note})
        return path


def read_reference_file(path: str | os.PathLike) -> Reference:
    """A reference EXR named by the user; its own noise comes from a JSON sidecar (own_mse) when there is
    one, else it is taken as exact (own_mse 0, so RMSE includes the reference's noise)."""
    path = Path(path)
    image = exr.read_rgb(path)
    meta_path = path.with_suffix(".json")
    own = 0.0
    params: dict = {}
    if meta_path.is_file():
        meta = json.loads(meta_path.read_text())
        own, params = float(meta.get("own_mse", 0.0)), meta.get("params", {})
    return Reference(image, own, params, path, "file")
