"""Denoising a render with Intel Open Image Denoise (OIDN 2, what Cycles uses), through the `pyoidn` package.

The denoiser reads the noisy colour and, when given, Cycles' Denoising Albedo and Denoising Normal passes
(`RenderSettings.denoising_features`; core.integrator.DenoisingFeatures says how they are defined). As Cycles'
"accurate" prefilter does, the albedo and the normal are denoised first, each on its own (an RT filter given only
that auxiliary image), and the colour is then denoised with them marked clean (`clean_aux`), so the noise of the
auxiliary passes does not leak into the image.
The colour is linear HDR radiance (`hdr`); alpha, when present, is passed through unchanged.

This module imports without pyoidn: `denoise()` raises DenoiserUnavailable with the reason and what to install,
and `denoiser_status()` says the same without raising (the add-on's panel and the CLI show it). pyoidn ships
wheels for Linux x86_64, Windows x86_64 and macOS (x86_64, arm64); elsewhere a render is saved undenoised.
"""

from __future__ import annotations

import threading

import numpy as np

QUALITIES = ("high", "balanced", "fast")
INSTALL_HINT = ("install it with `pip install pyoidn` (wheels exist for Linux x86_64, Windows x86_64 and macOS; "
                "there is none for Linux or Windows on ARM)")

_lock = threading.Lock()  # pyoidn keeps one device and filter per process: one call at a time
_prefilter_state: dict = {}  # the CPU device and the albedo / normal prefilters, made on first use


class DenoiserUnavailable(RuntimeError):
    """Open Image Denoise cannot be used here (pyoidn is missing or failed to load)."""


def _load_oidn():
    """The pyoidn module, or DenoiserUnavailable saying why not."""
    try:
        import pyoidn  # noqa: PLC0415 (optional dependency, loaded on first use)
    except Exception as exc:  # ImportError, or a shared library that fails to load (OSError)
        raise DenoiserUnavailable(f"denoising needs Intel Open Image Denoise through the pyoidn package, which "
                                  f"could not be loaded ({type(exc).__name__}: {exc}); {INSTALL_HINT}") from None
    return pyoidn


def denoiser_status() -> str | None:
    """None when denoising is available, else one line saying why not and what to install."""
    try:
        _load_oidn()
    except DenoiserUnavailable as exc:
        return str(exc)
    return None


def _check_image(name: str, image: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray | None:
    if image is None:
        return None
    arr = np.asarray(image)
    if arr.ndim != 3 or arr.shape[:2] != shape or arr.shape[2] < 3:
        raise ValueError(f"denoise: the {name} image has shape {arr.shape}, expected {shape + (3,)}")
    rgb = np.ascontiguousarray(arr[:, :, :3], np.float32)
    if not np.isfinite(rgb).all():
        raise ValueError(f"denoise: the {name} image holds NaN or Inf values")
    return rgb


def _prefilter(oidn, slot: str, image: np.ndarray, quality: str) -> np.ndarray:
    """An auxiliary image (slot "albedo" or "normal") denoised by OIDN's RT filter given only that image, as
    OIDN documents prefiltering (the normal keeps its signs; denoising it as a colour would clamp them)."""
    device = _prefilter_state.get("device")
    if device is None:
        device = _prefilter_state["device"] = oidn.Device(oidn.OIDN_DEVICE_TYPE_CPU)
        device.commit()
    filt = _prefilter_state.get((slot, quality))
    if filt is None:
        filt = _prefilter_state[(slot, quality)] = oidn.Filter(device, "RT")
    h, w, _ = image.shape
    out = np.zeros_like(image)
    filt.set_image(slot, image, oidn.OIDN_FORMAT_FLOAT3, w, h)
    filt.set_image(oidn.OIDN_IMAGE_OUTPUT, out, oidn.OIDN_FORMAT_FLOAT3, w, h)
    filt.set_quality({"high": oidn.OIDN_QUALITY_HIGH, "balanced": oidn.OIDN_QUALITY_BALANCED,
                      "fast": oidn.OIDN_QUALITY_FAST}[quality])
    filt.commit()
    filt.execute()
    error = device.get_error()
    if error:
        raise RuntimeError(f"Open Image Denoise failed prefiltering the {slot} image: {error}")
    return out


def denoise(color: np.ndarray, albedo: np.ndarray | None = None, normal: np.ndarray | None = None, *,
            quality: str = "high", prefilter: bool = True) -> np.ndarray:
    """The denoised image, same shape as `color`.

    color: (h, w, 3 or 4) float32 linear radiance (row order does not matter; alpha is copied through).
    albedo, normal: (h, w, 3) Denoising Albedo and Denoising Normal (camera or world space: OIDN accepts
    either), both or neither (a normal without an albedo is not a combination OIDN takes). quality: "high",
    "balanced" or "fast" (OIDN's filter quality; Cycles' Denoising Quality). prefilter: denoise albedo and
    normal first and pass them as clean (Cycles' "accurate" prefilter); False passes them as they are.
    Raises DenoiserUnavailable when pyoidn is missing, ValueError for bad input.
    """
    if quality not in QUALITIES:
        raise ValueError(f"unknown denoising quality {quality!r}; choose one of {', '.join(QUALITIES)}")
    col = np.asarray(color)
    if col.ndim != 3 or col.shape[2] not in (3, 4):
        raise ValueError(f"denoise: the colour image has shape {col.shape}, expected (h, w, 3) or (h, w, 4)")
    shape = col.shape[:2]
    rgb = _check_image("colour", col, shape)
    alb = _check_image("albedo", albedo, shape)
    nrm = _check_image("normal", normal, shape)
    if nrm is not None and alb is None:
        raise ValueError("denoise: a normal image needs an albedo image as well (OIDN takes albedo, or albedo "
                         "and normal)")
    oidn = _load_oidn()
    # OIDN's ranges: colour >= 0 (HDR), albedo in [0, 1], normal components in [-1, 1].
    rgb = np.maximum(rgb, np.float32(0))
    alb = None if alb is None else np.clip(alb, 0, 1)
    nrm = None if nrm is None else np.clip(nrm, -1, 1)
    with _lock:
        clean = False
        if prefilter and alb is not None:
            alb = _prefilter(oidn, oidn.OIDN_IMAGE_ALBEDO, alb, quality)
            if nrm is not None:
                nrm = _prefilter(oidn, oidn.OIDN_IMAGE_NORMAL, nrm, quality)
            clean = True
        out = oidn.denoise(rgb, alb, nrm, hdr=True, clean_aux=clean, quality=quality)
    out = np.asarray(out, np.float32).reshape(rgb.shape)
    if col.shape[2] == 4:
        out = np.concatenate([out, np.asarray(col[:, :, 3:], np.float32)], axis=2)
    return out
