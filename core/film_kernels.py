"""Compiled film accumulation: one add() call's samples summed per pixel in float64 and folded into the film's
float32 storage at once (core.film defines the storage and the arithmetic; these kernels do the same
operations in the same order, so the images are the bits NumPy's form gives).

Why compiled: NumPy's form makes some thirty array passes over the whole tile per call, whatever the number of
samples in it; at 1 sample per pixel and pass (large frames at low spp) that cost more per sample than the
path itself. Here each call is one pass over its samples and one over the tile's pixels.

The callers pass zeroed scratch arrays, and get them back zeroed (these kernels never allocate: a caller keeps its
scratch from call to call, and fresh zeroed memory would cost a page fault per 4 kB touched on every call).
"""

from __future__ import annotations

import numpy as np

from .jit_cache import jit_inline as _inline
from .jit_cache import jit_no_nrt as _jit


@_jit
def add_colour(pixel, group, radiance, prefix, squares, shift, group_dev, sample_count, dev_sq, group_sum,
               group_samples, pass_sq):
    """Fold samples (pixel (N,) int64 tile-local, group (N,) int64 variance group, radiance (N, 3) float64, or
    float32 read as float64: the same values, without a converted copy) into the film's shift (n, 3), group_dev
    (n, G, 3), sample_count (n,) and, when `squares`, dev_sq (n, 3) (float32, int32): core.film.TileFilm.add then
    _fold. Scratch: group_sum (n, G, 3) float64, group_samples (n, G) int64,
    pass_sq (n, 3) float64 (or (0, 3) without squares), all zero, and zero again on return. Returns -1, or the
    first pixel whose samples do not continue its earlier ones (then nothing is changed)."""
    n, G = group_sum.shape[0], group_sum.shape[1]
    for i in range(pixel.shape[0]):
        p, g = pixel[i], group[i]
        for c in range(3):
            group_sum[p, g, c] += np.float64(radiance[i, c])
        group_samples[p, g] += 1
    for p in range(n):  # every pixel's samples must continue where its earlier ones ended
        count = 0
        for g in range(G):
            count += group_samples[p, g]
        if count == 0:
            continue
        before = np.int64(sample_count[p])
        period = prefix.shape[0] - 1
        q0, r0 = before // period, before % period
        q1, r1 = (before + count) // period, (before + count) % period
        for g in range(G):
            if (q1 - q0) * prefix[period, g] + prefix[r1, g] - prefix[r0, g] != group_samples[p, g]:
                _clear(group_sum, group_samples, pass_sq)
                return p
    if squares:  # squared deviations from the pass's own mean (exactly 0 for a constant pixel)
        for i in range(pixel.shape[0]):
            p = pixel[i]
            count = 0
            for g in range(G):
                count += group_samples[p, g]
            for c in range(3):
                total = group_sum[p, 0, c]
                for g in range(1, G):
                    total += group_sum[p, g, c]
                dev = np.float64(radiance[i, c]) - total / max(count, 1)
                pass_sq[p, c] += dev * dev
    for p in range(n):
        count = 0
        for g in range(G):
            count += group_samples[p, g]
        if count == 0:
            continue
        first = sample_count[p] == 0
        cf = np.float64(count)
        for c in range(3):
            total = group_sum[p, 0, c]
            for g in range(1, G):
                total += group_sum[p, g, c]
            pass_mean = total / cf
            if first:
                shift[p, c] = np.float32(pass_mean)
            k = np.float64(shift[p, c])
            for g in range(G):
                group_dev[p, g, c] = np.float32(np.float64(group_dev[p, g, c])
                                                + (group_sum[p, g, c] - np.float64(group_samples[p, g]) * k))
            if squares:
                d = pass_mean - k
                dev_sq[p, c] = np.float32((np.float64(dev_sq[p, c]) + pass_sq[p, c]) + cf * d * d)
        sample_count[p] += count
    if pixel.shape[0] < group_sum.shape[0]:  # fewer samples than pixels: zero only the rows they wrote
        _clear_rows(pixel, group_sum, group_samples, pass_sq)
    else:
        _clear(group_sum, group_samples, pass_sq)
    return -1


@_jit
def _clear(group_sum, group_samples, pass_sq):
    for p in range(group_sum.shape[0]):
        for g in range(group_sum.shape[1]):
            group_samples[p, g] = 0
            for c in range(3):
                group_sum[p, g, c] = 0.0
    for p in range(pass_sq.shape[0]):
        for c in range(3):
            pass_sq[p, c] = 0.0


@_jit
def _clear_rows(pixel, group_sum, group_samples, pass_sq):
    """Zero the scratch rows of the pixels in `pixel` (the only rows add_colour writes): for calls with fewer
    samples than the tile has pixels (adaptive sampling's passes over the pixels still noisy), where clearing
    the whole (n, G, 3) scratch (~0.2 MB for a 64x64 tile with 2 groups) would be most of the call. With a sample per pixel or
    more _clear's plain pass over the scratch is as fast (a per-row clear inside the fold measured 1.3x slower)."""
    for i in range(pixel.shape[0]):
        p = pixel[i]
        for g in range(group_sum.shape[1]):
            group_samples[p, g] = 0
            for c in range(3):
                group_sum[p, g, c] = 0.0
        if p < pass_sq.shape[0]:
            for c in range(3):
                pass_sq[p, c] = 0.0


@_jit
def add_sums3(pixel, values, out, scratch):
    """out (n, 3) float32 += per-pixel float64 sums of values (N, 3) float64, rounded once (scratch (n, 3)
    float64, zero, and zero again on return)."""
    for i in range(pixel.shape[0]):
        p = pixel[i]
        for c in range(3):
            scratch[p, c] += values[i, c]
    for p in range(out.shape[0]):
        for c in range(3):
            out[p, c] = np.float32(np.float64(out[p, c]) + scratch[p, c])
            scratch[p, c] = 0.0


@_jit
def add_sums1(pixel, values, finite_only, out, counts, scratch, scratch_counts):
    """out (n,) float32 += per-pixel float64 sums of values (N,) float64 (only the finite ones when
    finite_only), rounded once; counts (n,) int32 += how many were summed (scratch (n,) float64 and
    scratch_counts (n,) int64, zero, and zero again on return)."""
    for i in range(pixel.shape[0]):
        v = values[i]
        if finite_only and not np.isfinite(v):
            continue
        p = pixel[i]
        scratch[p] += v
        scratch_counts[p] += 1
    for p in range(out.shape[0]):
        out[p] = np.float32(np.float64(out[p]) + scratch[p])
        counts[p] += scratch_counts[p]
        scratch[p] = 0.0
        scratch_counts[p] = 0


@_jit
def colour_images(shift, group_dev, sample_count, prefix, squares, dev_sq, alpha, transparent_sum, y0, x0, width,
                  color, variance):
    """A tile's colour images from its film (core.film.TileFilm.mean, alpha_image and _variance_of_mean: the same
    float64 operations in the same order, so the same float32 bits), written into color (H, W, 4) and variance
    (H, W, 3) float32 at rows y0.., columns x0.. (the tile `width` pixels wide, pixel p at row p // width):
    NumPy's form made some forty float64 passes over (n, G, 3) temporaries per tile, a per-pixel cost that no
    sample count amortises. alpha: whether transparent_sum (n,) float32 is read (1 elsewhere)."""
    n, G = group_dev.shape[0], group_dev.shape[1]
    period = prefix.shape[0] - 1
    for p in range(n):
        y, x = y0 + p // width, x0 + p % width
        count = np.int64(sample_count[p])
        n_real = np.float64(count)
        n_mean = np.float64(max(count, 1))
        full, rest = count // period, count % period
        filled = 0
        for g in range(G):
            if full * prefix[period, g] + prefix[rest, g] > 0:
                filled += 1
        for c in range(3):
            total = np.float64(group_dev[p, 0, c])
            for g in range(1, G):
                total += np.float64(group_dev[p, g, c])
            color[y, x, c] = np.float32(np.float64(shift[p, c]) + total / n_mean)
            var = 0.0
            if squares and count > 1:
                var = (np.float64(dev_sq[p, c]) - total * total / n_real) / (n_real - 1.0) / n_real
            if G > 1 and filled >= 2:
                grouped = 0.0
                mean_dev = total / max(n_real, 1.0)
                for g in range(G):
                    ng = np.float64(full * prefix[period, g] + prefix[rest, g])
                    dev = 0.0
                    if ng > 0:
                        dev = np.float64(group_dev[p, g, c]) / max(ng, 1.0) - mean_dev
                    grouped += ng * dev * dev
                var = grouped / ((np.float64(filled) - 1.0) * n_real)
            if var < 0.0:  # (NaN stays NaN, as np.maximum keeps it)
                var = 0.0
            variance[y, x, c] = np.float32(var)
        if alpha:
            color[y, x, 3] = np.float32(1.0 - np.float64(transparent_sum[p]) / n_mean)
        else:
            color[y, x, 3] = np.float32(1.0)


@_inline
def _unit_normal_pixel(nx, ny, nz, y, x, normal_out):
    """The float64 normal (nx, ny, nz) made unit and stored as float32 at row y, column x of normal_out (0 where
    its length is not > 0): the normal AOV's last step, for a film's sums and for a one-sample tile alike."""
    length = np.sqrt(nx * nx + ny * ny + nz * nz)
    if length > 0:
        scale = max(length, 1e-30)
        normal_out[y, x, 0] = np.float32(nx / scale)
        normal_out[y, x, 1] = np.float32(ny / scale)
        normal_out[y, x, 2] = np.float32(nz / scale)
    else:
        normal_out[y, x, 0] = np.float32(0.0)
        normal_out[y, x, 1] = np.float32(0.0)
        normal_out[y, x, 2] = np.float32(0.0)


@_inline
def _fold_aov_pixel(samples, albedo0, albedo1, albedo2, normal0, normal1, normal2, depth_sum, hits, y, x, albedo_out,
                    normal_out, depth_out):
    """One pixel's AOV sums (float64: albedo, normal, depth; `hits` finite depths, `samples` its sample count)
    made its AOV images at row y, column x: the albedo mean, the unit mean normal (0 where the pixel saw no
    surface) and the mean depth (1e10 where nothing was hit). aov_images and finish_frame_aovs both fold here
    (core.film.TileFilm.aov_images' float64 operations in its order), so the film's and the frame's sums give the
    same bits. Reads every sum before it writes, so the outputs may be the arrays the sums were read from."""
    n = np.float64(max(np.int64(samples), 1))
    nx = normal0 / n
    ny = normal1 / n
    nz = normal2 / n
    albedo_out[y, x, 0] = np.float32(albedo0 / n)
    albedo_out[y, x, 1] = np.float32(albedo1 / n)
    albedo_out[y, x, 2] = np.float32(albedo2 / n)
    _unit_normal_pixel(nx, ny, nz, y, x, normal_out)
    if hits > 0:
        depth_out[y, x] = np.float32(depth_sum / np.float64(max(hits, 1)))
    else:
        depth_out[y, x] = np.float32(1e10)


@_jit
def aov_images(albedo, normal, depth_sum, depth_count, sample_count, y0, x0, width, albedo_out, normal_out,
               depth_out):
    """A tile's AOV images from its film (core.film.TileFilm.aov_images, the same float64 operations in the same
    order): albedo and normal (H, W, 3), depth (H, W) float32 written at rows y0.., columns x0.. (see
    colour_images). The normal is unit where the pixel saw a surface (0 elsewhere); depth 1e10 where nothing was
    hit."""
    for p in range(albedo.shape[0]):
        _fold_aov_pixel(sample_count[p], np.float64(albedo[p, 0]), np.float64(albedo[p, 1]), np.float64(albedo[p, 2]),
                        np.float64(normal[p, 0]), np.float64(normal[p, 1]), np.float64(normal[p, 2]),
                        np.float64(depth_sum[p]), depth_count[p], y0 + p // width, x0 + p % width, albedo_out,
                        normal_out, depth_out)


@_jit
def add_aovs_to_frame(pixel, albedo_in, normal_in, depth_in, y0, x0, width, albedo, normal, depth, hits, sums3,
                      sums1, scratch_counts):
    """A local render's first-hit AOVs summed straight into the frame's albedo, normal (H, W, 3) and depth (H, W)
    float32 images and the depth hits into its sample-count image (H, W) int32 (borrowed until the tile is final:
    finish_frame_aovs), for the tile whose pixel p lies at row y0 + p // width, column x0 + p % width: the
    operations and order of add_sums3 (albedo, normal) and add_sums1 (finite depths) on a film's sums, so the same
    bits. Scratch: sums3 (n, 6) float64, sums1 (n,) float64, scratch_counts (n,) int64 for the tile's n pixels,
    zero, and zero again on return."""
    for i in range(pixel.shape[0]):
        p = pixel[i]
        for c in range(3):
            sums3[p, c] += albedo_in[i, c]
        for c in range(3):
            sums3[p, 3 + c] += normal_in[i, c]
        d = depth_in[i]
        if np.isfinite(d):
            sums1[p] += d
            scratch_counts[p] += 1
    for p in range(sums1.shape[0]):
        y, x = y0 + p // width, x0 + p % width
        for c in range(3):
            albedo[y, x, c] = np.float32(np.float64(albedo[y, x, c]) + sums3[p, c])
            normal[y, x, c] = np.float32(np.float64(normal[y, x, c]) + sums3[p, 3 + c])
            sums3[p, c] = 0.0
            sums3[p, 3 + c] = 0.0
        depth[y, x] = np.float32(np.float64(depth[y, x]) + sums1[p])
        hits[y, x] += scratch_counts[p]
        sums1[p] = 0.0
        scratch_counts[p] = 0


@_jit
def finish_frame_aovs(sample_count, y0, x0, width, albedo, normal, depth, hits):
    """A final tile's AOV sums in the frame's images (add_aovs_to_frame) made its AOV images in place: the
    operations of aov_images, so the same bits as a film's AOV sums give. sample_count (n,) int32: the tile's
    samples per pixel (its film's). Leaves the tile's hits at 0 (the caller writes the sample counts there)."""
    for p in range(sample_count.shape[0]):
        y, x = y0 + p // width, x0 + p % width
        _fold_aov_pixel(sample_count[p], np.float64(albedo[y, x, 0]), np.float64(albedo[y, x, 1]),
                        np.float64(albedo[y, x, 2]), np.float64(normal[y, x, 0]), np.float64(normal[y, x, 1]),
                        np.float64(normal[y, x, 2]), np.float64(depth[y, x]), hits[y, x], y, x, albedo, normal, depth)
        hits[y, x] = 0


@_jit
def one_sample_images(radiance, albedo_in, normal_in, depth_in, aovs, y0, x0, width, color, albedo, normal, depth,
                      counts):
    """A tile that takes exactly one sample per pixel (pixel p's in row p of radiance (n, 3), albedo_in,
    normal_in (n, 3) and depth_in (n,), float32) written into the frame's images at rows y0.., columns x0.. (the
    tile `width` pixels wide) without a film: the bits add_colour, colour_images, add_aovs_to_frame and
    finish_frame_aovs give at one sample (core.render.FrameImages.put_one_sample says why), in one pass over the
    tile instead of NumPy's dozen. colour: `sample + 0.0` in float32 (-0.0 becomes 0.0), alpha 1 (the variance,
    0, is left to the frame's zeroed image); with aovs: the albedo `value + 0.0`, the normal made unit in float64
    as _fold_aov_pixel does (0 where its length is not > 0), the depth `value + 0.0` where finite, else 1e10;
    the sample count 1. Without aovs the AOV arrays are not read (any of the right types)."""
    zero = np.float32(0.0)
    for p in range(radiance.shape[0]):
        y, x = y0 + p // width, x0 + p % width
        for c in range(3):
            color[y, x, c] = radiance[p, c] + zero
        color[y, x, 3] = np.float32(1.0)
        counts[y, x] = 1
        if aovs:
            for c in range(3):
                albedo[y, x, c] = albedo_in[p, c] + zero
            _unit_normal_pixel(np.float64(normal_in[p, 0] + zero), np.float64(normal_in[p, 1] + zero),
                               np.float64(normal_in[p, 2] + zero), y, x, normal)
            d = depth_in[p]
            if np.isfinite(d):
                depth[y, x] = d + zero
            else:
                depth[y, x] = np.float32(1e10)
