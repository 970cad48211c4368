"""OpenEXR and PNG files: float32 named channels, written atomically.

Atomic (core.atomic_file): every writer writes a temporary file in the destination folder and renames it over
the target only once it is complete, so an existing file is never half-overwritten and a failed write leaves
nothing behind.
"""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

import numpy as np
import OpenEXR

from .atomic_file import OutputError, check_writable, write_atomically, write_bytes_atomically

__all__ = ["OutputError", "check_writable", "data_pass_channels", "image_channels", "linear_to_srgb8", "read_exr",
           "read_header", "read_rgb", "write_exr",
           "write_png"]


def image_channels(
    color: np.ndarray,
    variance: np.ndarray | None = None,
    albedo: np.ndarray | None = None,
    normal: np.ndarray | None = None,
    depth: np.ndarray | None = None,
    *,
    noisy: np.ndarray | None = None,
    denoising_albedo: np.ndarray | None = None,
    denoising_normal: np.ndarray | None = None,
    shadow_catcher: np.ndarray | None = None,
    light_passes: dict[str, np.ndarray] | None = None,
) -> dict[str, np.ndarray]:
    """Monte's channel layout: R G B A, variance.R/G/B, albedo.R/G/B, normal.X/Y/Z, Z (depth); with denoising,
    R G B A hold the denoised image, noisy.R/G/B/A the image before denoising (Blender's Noisy Image pass),
    denoising_albedo.R/G/B and denoising_normal.X/Y/Z the passes the denoiser read (camera space); with a shadow
    catcher, shadow_catcher.R/G/B (Cycles' Shadow Catcher pass, core.film); Cycles' light passes
    (core.light_passes) as <name in snake case>.R/G/B: diffuse_direct.R, ..., emission.R, environment.R.
    Arrays are (H, W, C) with row 0 at the top."""
    channels: dict[str, np.ndarray] = {}
    for i, name in enumerate("RGBA"[: color.shape[2]]):
        channels[name] = color[..., i]
    if noisy is not None:
        for i, name in enumerate("RGBA"[: noisy.shape[2]]):
            channels["noisy." + name] = noisy[..., i]
    for prefix, arr, names in (("variance.", variance, "RGB"), ("albedo.", albedo, "RGB"), ("normal.", normal, "XYZ"),
                               ("denoising_albedo.", denoising_albedo, "RGB"),
                               ("denoising_normal.", denoising_normal, "XYZ"),
                               ("shadow_catcher.", shadow_catcher, "RGB")):
        if arr is not None:
            for i, name in enumerate(names):
                channels[prefix + name] = arr[..., i]
    for name, arr in (light_passes or {}).items():
        prefix = name.lower().replace(" ", "_") + "."
        for i, c in enumerate("RGB"):
            channels[prefix + c] = arr[..., i]
    if depth is not None:
        channels["Z"] = depth
    return channels


def write_exr(path: str | os.PathLike, channels: dict[str, np.ndarray], metadata: dict[str, str] | None = None
              ) -> Path:
    """Write float32 channels (each (H, W), row 0 at the top) to a ZIP-compressed scanline EXR, atomically;
    metadata: extra string attributes of the header (e.g. Cryptomatte's manifests)."""
    if not channels:
        raise ValueError("no channels to write")
    shapes = {np.shape(a) for a in channels.values()}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ValueError(f"all channels must be 2-D with one shape, got {sorted(shapes)}")
    data = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in channels.items()}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    header.update({str(k): str(v) for k, v in (metadata or {}).items()})

    def write(tmp: str) -> None:
        with OpenEXR.File(header, data) as f:
            f.write(tmp)

    return write_atomically(path, write, ".exr")


def data_pass_channels(data_passes: dict[str, np.ndarray], chanids: dict[str, str]) -> dict[str, np.ndarray]:
    """Channels of the data passes ({pass name: (H, W, C)}): "<pass>.<channel>" with each pass's channel letters
    (chanids, e.g. "UVA" for UV; Cryptomatte layers "RGBA": CryptoObject00.R ... as the standard names them)."""
    channels: dict[str, np.ndarray] = {}
    for name, arr in data_passes.items():
        letters = chanids.get(name, "RGBA")
        for i in range(arr.shape[2]):
            channels[f"{name}.{letters[i]}"] = arr[..., i]
    return channels


def read_header(path: str | os.PathLike) -> dict:
    """The header attributes of an EXR's first part."""
    with OpenEXR.File(str(path)) as f:
        return dict(f.header())


def read_exr(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read every channel of an EXR as float32 (H, W) arrays (interleaved groups like 'RGB' split into R, G, B).

    A multi-part file (Blender's multilayer EXR) yields every part's channels; where parts repeat a channel
    name, the later part's channel is named "<part name>.<channel>"."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such EXR file: {path}")
    try:
        f = OpenEXR.File(str(path), separate_channels=True)
    except Exception as exc:  # OpenEXR raises plain exceptions for corrupt files
        raise ValueError(f"{path} is not a readable OpenEXR file: {exc}") from exc
    with f:
        channels: dict[str, np.ndarray] = {}
        for part in f.parts:
            for name, ch in part.channels.items():
                key = name if name not in channels else f"{part.name()}.{name}"
                channels[key] = np.asarray(ch.pixels, dtype=np.float32)
        return channels


def read_rgb(path: str | os.PathLike) -> np.ndarray:
    """An EXR's R, G, B channels as one (H, W, 3) float32 array."""
    ch = read_exr(path)
    try:
        return np.stack([ch["R"], ch["G"], ch["B"]], axis=-1)
    except KeyError as exc:
        raise ValueError(f"{path} has no R, G, B channels (it has {', '.join(sorted(ch))})") from exc


def linear_to_srgb8(rgb: np.ndarray) -> np.ndarray:
    """Linear RGB -> 8-bit sRGB (standard transfer curve, values clipped to [0, 1]), for previews."""
    x = np.clip(np.nan_to_num(rgb, nan=0.0), 0.0, 1.0)
    s = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (s * 255.0 + 0.5).astype(np.uint8)


def write_png(path: str | os.PathLike, rgb: np.ndarray) -> Path:
    """Write a linear (H, W, 3) image, or (H, W, 4) RGBA premultiplied by alpha as Monte renders it, as an sRGB
    8-bit PNG preview (row 0 at the top), atomically. An image whose alpha is below 1 somewhere is written
    with an alpha channel (PNG's alpha is straight: the colour is divided by alpha first); otherwise RGB.
    A minimal PNG encoder (zlib + CRC from the standard library) so core needs no imaging package."""
    colour = rgb[..., :3]
    alpha = rgb[..., 3] if rgb.ndim == 3 and rgb.shape[2] == 4 and np.any(rgb[..., 3] < 1) else None
    if alpha is not None:
        a = np.clip(np.nan_to_num(alpha, nan=0.0), 0.0, 1.0)
        colour = np.where(a[..., None] > 0, colour / np.maximum(a, 1e-12)[..., None], 0.0)
        img = np.concatenate([linear_to_srgb8(colour), (a * 255.0 + 0.5).astype(np.uint8)[..., None]], axis=2)
    else:
        img = linear_to_srgb8(colour)
    h, w, c = img.shape
    raw = np.concatenate([np.zeros((h, 1), np.uint8), img.reshape(h, w * c)], axis=1).tobytes()  # filter 0 rows

    def chunk(kind: bytes, payload: bytes) -> bytes:
        return struct.pack(">I", len(payload)) + kind + payload + struct.pack(">I", zlib.crc32(kind + payload))

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 6 if c == 4 else 2, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b""))

    return write_bytes_atomically(path, png, ".png")
