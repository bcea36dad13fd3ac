"""Plain-numpy reference implementations for testing the Numba kernels.

Each function here is the most obvious, slow implementation of what a
kernel in ``fastdet.kernels`` computes, written independently of the
kernel's algorithm so that agreement between the two is meaningful.  Keep
them short, loop-based where that is clearest, and free of Numba and of
imports from ``fastdet``.  The HLS conversion's reference is OpenCV itself
(:func:`opencv_hls`), whose output depends on the CPU; the function reads
each pixel's two possible values off OpenCV and places them as its AVX2
code does.
"""

from __future__ import annotations

import numpy as np


def naive_heat(boxes, weights, height, width):
    """Reference for ``fastdet.kernels.heat.accumulate_heat``.

    Adds each box's weight to its (clipped) slice of a float64 map, then
    rounds once to float32.

    Parameters
    ----------
    boxes : numpy.ndarray
        Integer array of shape ``(N, 4)``, rows ``[x1, y1, x2, y2]`` with
        exclusive ``x2``/``y2``; may extend past the map.
    weights : numpy.ndarray
        Array of shape ``(N,)``.
    height, width : int
        Shape of the heat map.

    Returns
    -------
    numpy.ndarray
        float32 array of shape ``(height, width)``.
    """
    heat = np.zeros((height, width), dtype=np.float64)
    for (x1, y1, x2, y2), weight in zip(np.asarray(boxes).tolist(), weights):
        # Clip explicitly: negative slice bounds would wrap around in numpy.
        x1, x2 = np.clip([x1, x2], 0, width)
        y1, y2 = np.clip([y1, y2], 0, height)
        if x2 > x1 and y2 > y1:
            heat[y1:y2, x1:x2] += np.float64(weight)
    return heat.astype(np.float32)


def naive_windows_above(scores, threshold, boxes, scale_index):
    """Boxes, scores and scales of the windows scoring above a Python float
    ``threshold``, as NumPy compares a float32 array with it."""
    hit = np.flatnonzero(scores > threshold)
    return boxes[hit], scores[hit], scale_index[hit]


def naive_component_boxes(labels, count):
    """Reference for ``fastdet.kernels.label.component_boxes``.

    Parameters
    ----------
    labels : numpy.ndarray
        Integer array of shape ``(H, W)``, 0 for background.
    count : int
        Number of labels.

    Returns
    -------
    numpy.ndarray
        int32 array of shape ``(count, 4)``; row ``k`` is
        ``[x1, y1, x2, y2]`` (exclusive ``x2``/``y2``) of label ``k + 1``,
        or all zeros if that label has no pixel.
    """
    boxes = np.zeros((count, 4), dtype=np.int32)
    for k in range(count):
        ys, xs = np.where(labels == k + 1)
        if ys.size:
            boxes[k] = [xs.min(), ys.min(), xs.max() + 1, ys.max() + 1]
    return boxes


def naive_component_max(labels, count, values):
    """Reference for ``fastdet.kernels.label.component_max``.

    Parameters
    ----------
    labels : numpy.ndarray
        Integer array of shape ``(H, W)``, 0 for background.
    count : int
        Number of labels.
    values : numpy.ndarray
        Array with the same shape as ``labels``.

    Returns
    -------
    numpy.ndarray
        float32 array of shape ``(count,)``; ``numpy.max`` of ``values``
        over label ``k + 1``, or ``-inf`` if that label has no pixel.
    """
    maxima = np.full(count, -np.inf, dtype=np.float32)
    for k in range(count):
        selected = values[labels == k + 1]
        if selected.size:
            maxima[k] = selected.max()
    return maxima


def naive_cell_histograms(image, ppc, nbins):
    """Reference for ``fastdet.kernels.hog.cell_histograms`` (channels apart).

    Per channel: central-difference gradients ``I[y+1] - I[y-1]`` and
    ``I[x+1] - I[x-1]``, zero on the outermost rows / columns; unsigned
    orientation ``atan2(gy, gx)`` in degrees modulo 180, computed in float64;
    hard binning, bin ``i`` holding angles in ``[i * 180 / nbins,
    (i + 1) * 180 / nbins)`` (an angle that rounds to 180 falls in no bin);
    each cell's histogram is the mean gradient magnitude per bin over its
    pixels, and pixels beyond the last whole cell are ignored.

    Gradients are taken in float32 for float32 images (as the kernels and
    scikit-image do) and in float64 otherwise (exact for integer images).

    Parameters
    ----------
    image : numpy.ndarray
        Array of shape ``(H, W)`` or ``(H, W, C)``.
    ppc : int or tuple of int
        Pixels per cell, ``n`` or ``(ppc_y, ppc_x)``.
    nbins : int
        Number of orientation bins over 0-180 degrees.

    Returns
    -------
    numpy.ndarray
        float64 array of shape ``(H // ppc_y, W // ppc_x, C, nbins)``.
    """
    image = np.asarray(image)
    if image.ndim == 2:
        image = image[:, :, None]
    ppc_y, ppc_x = (ppc, ppc) if np.ndim(ppc) == 0 else ppc
    work = image.astype(np.float32 if image.dtype == np.float32 else np.float64)
    height, width, channels = work.shape
    n_y, n_x = height // ppc_y, width // ppc_x
    out = np.zeros((n_y, n_x, channels, nbins), dtype=np.float64)
    for c in range(channels):
        plane = work[:, :, c]
        gy = np.zeros_like(plane)
        gx = np.zeros_like(plane)
        gy[1:-1, :] = plane[2:, :] - plane[:-2, :]
        gx[:, 1:-1] = plane[:, 2:] - plane[:, :-2]
        gy = gy.astype(np.float64)
        gx = gx.astype(np.float64)
        angle = np.arctan2(gy, gx) * (180.0 / np.pi) % 180.0
        magnitude = np.hypot(gx, gy)
        # Only the pixels of whole cells count.
        angle = angle[:n_y * ppc_y, :n_x * ppc_x]
        magnitude = magnitude[:n_y * ppc_y, :n_x * ppc_x]
        for b in range(nbins):
            inside = (angle >= 180.0 / nbins * b) & (angle < 180.0 / nbins * (b + 1))
            votes = np.where(inside, magnitude, 0.0).reshape(n_y, ppc_y, n_x, ppc_x)
            out[:, :, c, b] = votes.sum(axis=(1, 3)) / (ppc_y * ppc_x)
    return out


def naive_normalize_blocks(cells, cpb, norm, eps=1e-5):
    """Reference for ``fastdet.kernels.blocks.normalize_blocks``.

    Every block of ``cpb_y x cpb_x`` cells, stepped one cell at a time, is
    normalised per channel in float64 by the textbook formula of ``norm``;
    a block's vector is ordered ``(channel, cell_y, cell_x, bin)``.

    Parameters
    ----------
    cells : numpy.ndarray
        Array of shape ``(Hc, Wc, C, nbins)``.
    cpb : int or tuple of int
        Cells per block, ``n`` or ``(cpb_y, cpb_x)``.
    norm : {'L1', 'L1-sqrt', 'L2', 'L2-Hys'}
    eps : float

    Returns
    -------
    numpy.ndarray
        float64 array of shape
        ``(max(Hc - cpb_y + 1, 0), max(Wc - cpb_x + 1, 0), C * cpb_y * cpb_x * nbins)``.
    """
    cpb_y, cpb_x = (cpb, cpb) if np.ndim(cpb) == 0 else cpb
    cells = np.asarray(cells, dtype=np.float64)
    n_y, n_x, channels, nbins = cells.shape
    out = np.zeros((max(n_y - cpb_y + 1, 0), max(n_x - cpb_x + 1, 0),
                    channels * cpb_y * cpb_x * nbins), dtype=np.float64)
    for by in range(out.shape[0]):
        for bx in range(out.shape[1]):
            parts = []
            for c in range(channels):
                v = cells[by:by + cpb_y, bx:bx + cpb_x, c, :].ravel()
                if norm == "L1":
                    v = v / (np.abs(v).sum() + eps)
                elif norm == "L1-sqrt":
                    v = np.sqrt(v / (np.abs(v).sum() + eps))
                elif norm == "L2":
                    v = v / np.sqrt((v ** 2).sum() + eps ** 2)
                elif norm == "L2-Hys":
                    v = v / np.sqrt((v ** 2).sum() + eps ** 2)
                    v = np.minimum(v, 0.2)
                    v = v / np.sqrt((v ** 2).sum() + eps ** 2)
                else:
                    raise ValueError(f"unknown norm {norm!r}")
                parts.append(v)
            out[by, bx] = np.concatenate(parts)
    return out


def naive_window_sums(feature_map, weights, step, grid):
    """Reference for the window-scoring kernels of ``fastdet.kernels.score``.

    Window ``(iy, ix)`` is the explicit slice
    ``feature_map[iy * step : iy * step + n, ix * step : ix * step + m]``
    (``n, m = weights.shape[:2]``), dotted with ``weights`` in float64.

    Parameters
    ----------
    feature_map : numpy.ndarray
        Array of shape ``(H, W, ...)`` (a HOG block map or a spatial image).
    weights : numpy.ndarray
        Array of shape ``(n, m, ...)``, trailing axes as ``feature_map``'s.
    step : int
        Window step along both axes, in ``feature_map`` elements.
    grid : tuple of int
        ``(ny, nx)`` windows.

    Returns
    -------
    numpy.ndarray
        float64 array of shape ``grid``.
    """
    n, m = weights.shape[:2]
    flat_weights = np.asarray(weights, dtype=np.float64).ravel()
    out = np.zeros(grid, dtype=np.float64)
    for iy in range(grid[0]):
        for ix in range(grid[1]):
            window = feature_map[iy * step:iy * step + n, ix * step:ix * step + m]
            assert window.shape == weights.shape, "window does not fit in the map"
            out[iy, ix] = np.dot(np.asarray(window, dtype=np.float64).ravel(), flat_weights)
    return out


def naive_tile_window_sums(tiles, size, step, grid):
    """Reference for ``fastdet.kernels.score.add_tile_window_sums``.

    Returns the float64 ``np.sum`` of ``tiles[iy * step : + size,
    ix * step : + size]`` for every window of ``grid``.
    """
    out = np.zeros(grid, dtype=np.float64)
    for iy in range(grid[0]):
        for ix in range(grid[1]):
            window = tiles[iy * step:iy * step + size, ix * step:ix * step + size]
            assert window.shape == (size, size), "window does not fit in the tiles"
            out[iy, ix] = np.sum(window, dtype=np.float64)
    return out


def naive_tile_weight_sums(image, lut, tile):
    """Reference for ``fastdet.kernels.colour.tile_weight_sums``.

    Per pixel the weight ``sum_c lut[c, image[y, x, c]]``, summed in float64
    over every whole ``tile x tile`` tile.

    Returns
    -------
    numpy.ndarray
        float64 array of shape ``(H // tile, W // tile)``.
    """
    height, width, channels = image.shape
    pixel = np.zeros((height, width), dtype=np.float64)
    for c in range(channels):
        pixel += np.asarray(lut, dtype=np.float64)[c][image[:, :, c]]
    ty, tx = height // tile, width // tile
    out = np.zeros((ty, tx), dtype=np.float64)
    for y in range(ty):
        for x in range(tx):
            out[y, x] = pixel[y * tile:(y + 1) * tile, x * tile:(x + 1) * tile].sum()
    return out


def naive_bin_order_tile_sums(image, lut, tile):
    """The bin-table paths' tile sums, in their float32 order (both give these bits).

    Per pixel ``(lut[0, v0] + lut[1, v1]) + lut[2, v2]`` in float32; per column
    of a tile row the pixels' weights added row by row from 0; per tile its
    columns added left to right from 0.

    Returns
    -------
    numpy.ndarray
        float32 array of shape ``(H // tile, W // tile)``.
    """
    lut = np.asarray(lut, dtype=np.float32)
    weight = (lut[0][image[:, :, 0]] + lut[1][image[:, :, 1]]) + lut[2][image[:, :, 2]]
    ty, tx = image.shape[0] // tile, image.shape[1] // tile
    out = np.zeros((ty, tx), dtype=np.float32)
    for y in range(ty):
        columns = np.zeros(tx * tile, dtype=np.float32)
        for dy in range(tile):
            columns = columns + weight[y * tile + dy, :tx * tile]
        for x in range(tx):
            total = np.float32(0.0)
            for dx in range(tile):
                total = np.float32(total + columns[x * tile + dx])
            out[y, x] = total
    return out


def naive_heat_features(heat, origin, boxes, threshold, frame_size, levels=(1 / 3, 2 / 3)):
    """The box refinement's features (fastdet.detector.refine.heat_features)
    with NumPy array operations, box by box."""
    n_features = 1 + 4 * len(levels) + 4 + 2
    out = np.zeros((len(boxes), n_features))
    out[:, 0] = 1.0
    frame_width, frame_height = frame_size
    geometry = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    out[:, -2] = np.log(np.maximum(geometry[:, 3] - geometry[:, 1], 1) / frame_height)
    out[:, -1] = np.abs((geometry[:, 0] + geometry[:, 2]) / 2 - frame_width / 2) / frame_height
    flip = geometry[:, 0] + geometry[:, 2] < frame_width
    ox, oy = origin
    for row, (x1, y1, x2, y2) in enumerate(np.asarray(boxes, dtype=np.int64).reshape(-1, 4)):
        width, height = max(x2 - x1, 1), max(y2 - y1, 1)
        cx, cy = (x1 + x2) / 2, (y1 + y2) / 2
        a1, b1 = max(x1 - ox, 0), max(y1 - oy, 0)
        a2, b2 = min(x2 - ox, heat.shape[1]), min(y2 - oy, heat.shape[0])
        mass = np.zeros((0, 0))
        if a2 > a1 and b2 > b1:
            mass = np.maximum(heat[b1:b2, a1:a2].astype(np.float64) - threshold, 0.0)
        total = mass.sum()
        if total <= 0:
            out[row, 1:-2] = [-0.5, -0.5, 0.5, 0.5] * len(levels) + [0, 0, 0.29, 0.29]
            continue
        xs = (np.arange(a1, a2) + ox + 0.5 - cx) / width
        ys = (np.arange(b1, b2) + oy + 0.5 - cy) / height
        columns, rows = mass.sum(axis=0), mass.sum(axis=1)
        peak = mass.max()
        col = 1
        for level in levels:
            above = mass >= level * peak
            cols_in = np.flatnonzero(above.any(axis=0))
            rows_in = np.flatnonzero(above.any(axis=1))
            left, right = xs[cols_in[0]] - 0.5 / width, xs[cols_in[-1]] + 0.5 / width
            if flip[row]:
                left, right = -right, -left
            out[row, col:col + 4] = (left, ys[rows_in[0]] - 0.5 / height, right,
                                     ys[rows_in[-1]] + 0.5 / height)
            col += 4
        mx = columns @ xs / total
        my = rows @ ys / total
        out[row, col:col + 4] = (-mx if flip[row] else mx, my,
                                 np.sqrt(columns @ (xs - mx) ** 2 / total),
                                 np.sqrt(rows @ (ys - my) ** 2 / total))
    return out


def naive_refine_boxes(boxes, features, weights, frame_width):
    """The refinement's edge placement (fastdet.detector.refine.refine_boxes) with NumPy."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    offsets = features @ np.asarray(weights, dtype=np.float64).T
    flip = boxes[:, 0] + boxes[:, 2] < frame_width
    offsets[flip] = np.stack([-offsets[flip, 2], offsets[flip, 1], -offsets[flip, 0],
                              offsets[flip, 3]], axis=1)
    width = boxes[:, 2] - boxes[:, 0]
    height = boxes[:, 3] - boxes[:, 1]
    cx = (boxes[:, 0] + boxes[:, 2]) / 2
    cy = (boxes[:, 1] + boxes[:, 3]) / 2
    out = np.stack([cx + offsets[:, 0] * width, cy + offsets[:, 1] * height,
                    cx + offsets[:, 2] * width, cy + offsets[:, 3] * height], axis=1)
    return np.concatenate([np.minimum(out[:, :2], out[:, 2:]), np.maximum(out[:, :2], out[:, 2:])],
                          axis=1)


def naive_integer_chain(steps, seed):
    """The clock probe's chain (fastdet.kernels.clock.integer_chain) in Python integers."""
    x = seed % 2**64
    for _ in range(steps):
        x = ((x ^ (x >> 7)) + 1) % 2**64
    return x


def naive_snap_box_sides(frame, boxes, fraction, limits):
    """Box sides snapped to the strongest vertical edges (fastdet.kernels.refine.snap_box_sides),
    with scipy's Sobel filter of the channel-sum intensity and NumPy's argmax."""
    from scipy import ndimage

    intensity = frame.astype(np.int64).sum(axis=2)
    # Sobel along x, smoothing along y: [1, 2, 1] rows times [-1, 0, 1] columns.
    strength = np.abs(ndimage.sobel(intensity, axis=1))
    height, width = intensity.shape
    lx0, ly0, lx1, ly1 = limits
    first_column, stop_column = max(lx0, 0) + 1, min(lx1, width) - 1
    first_limit, stop_limit = max(ly0, 0) + 1, min(ly1, height) - 1
    out = np.array(boxes, dtype=np.int64).reshape(-1, 4).copy()
    for row in out:
        x1, y1, x2, y2 = (int(v) for v in row)
        w, h = x2 - x1, y2 - y1
        ya, yb = max(y1 + h // 4, first_limit), min(y2 - h // 4, stop_limit)
        if w < 2 or ya >= yb:
            continue
        reach = max(int(fraction * w), 1)
        sides = []
        for centre, past in ((x1, 0), (x2, 1)):
            columns = np.arange(max(centre - reach, first_column),
                                min(centre + reach, stop_column - 1) + 1)
            sums = strength[ya:yb, columns].sum(axis=0)
            if not len(columns) or sums.max() == 0:
                sides.append(centre)      # no edge within reach: the side stays
            else:
                sides.append(int(columns[np.argmax(sums)]) + past)
        if sides[0] < sides[1]:
            row[0], row[2] = sides
    return out


def naive_fma_float32(a, b, c):
    """``a * b + c`` of float32 arrays rounded once to float32 (to nearest, ties to even).

    Exact rationals, one element at a time; infinities and NaN as IEEE 754
    defines them.  A reference for the kernels' fused multiply-add, which no
    NumPy function computes.
    """
    a, b, c = (np.asarray(v, dtype=np.float32) for v in (a, b, c))
    out = np.empty(np.broadcast(a, b, c).shape, dtype=np.float32)
    with np.errstate(invalid="ignore", over="ignore"):
        for index, values in enumerate(zip(*(np.broadcast_to(v, out.shape).ravel()
                                             for v in (a, b, c)))):
            out.flat[index] = _naive_fma_one(*values)
    return out


def _naive_fma_one(x, y, z):
    from fractions import Fraction

    if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z)):
        # The product of finite floats is finite in float64, so float64 is exact here.
        return np.float32(np.float64(x) * np.float64(y) + np.float64(z))
    exact = Fraction(float(x)) * Fraction(float(y)) + Fraction(float(z))
    if exact == 0:
        # The sign of an exact zero sum follows IEEE 754's rules, which float64 applies.
        return np.float32(np.float64(x) * np.float64(y) + np.float64(z))
    # Past the largest float32 by half a step or more, rounding gives infinity.
    if abs(exact) >= Fraction(float(np.finfo(np.float32).max)) + Fraction(2) ** 103:
        return np.float32(np.inf if exact > 0 else -np.inf)
    near = np.float32(float(exact))  # within one float32 step of the answer
    candidates = [v for v in (np.nextafter(near, np.float32(-np.inf)), near,
                              np.nextafter(near, np.float32(np.inf))) if np.isfinite(v)]

    def distance(v):
        return abs(Fraction(float(v)) - exact)

    best = min(distance(v) for v in candidates)
    ties = [v for v in candidates if distance(v) == best]
    if len(ties) > 1:
        ties = [v for v in ties if int(np.float32(v).view(np.uint32)) % 2 == 0]
    return ties[0]


def opencv_hls(image, lanes=8):
    """``cv2.cvtColor(image, cv2.COLOR_BGR2HLS)`` as OpenCV converts it where its
    SIMD code takes runs of ``lanes`` pixels (8: its AVX2 code), on any CPU.

    Reference for ``fastdet.kernels.convert.bgr_to_hls``.  OpenCV converts
    each row in chunks of 256 pixels, whole runs of ``lanes`` with its SIMD
    code and the rest with scalar code that rounds otherwise; which runs it
    takes depends on the CPU it runs on (16 with AVX-512).  Each pixel's two
    values are read off OpenCV itself: the SIMD one from a row padded to
    whole runs of 16 (SIMD on every build), the scalar one from a row of one
    pixel; then each pixel takes the one of its place.
    """
    import cv2

    image = np.ascontiguousarray(image)
    height, width = image.shape[:2]
    padded = np.zeros((height, -(-width // 16) * 16, 3), np.uint8)
    padded[:, :width] = image
    simd = cv2.cvtColor(padded, cv2.COLOR_BGR2HLS)[:, :width]
    scalar = cv2.cvtColor(image.reshape(-1, 1, 3), cv2.COLOR_BGR2HLS).reshape(image.shape)
    x = np.arange(width)
    start = x // 256 * 256
    takes_simd = x - start < np.minimum(256, width - start) // lanes * lanes
    return np.where(takes_simd[None, :, None], simd, scalar)


#: A BGR colour OpenCV's SIMD and scalar HLS code convert apart.
OPENCV_RULES_APART = (190, 116, 116)


def opencv_simd_lanes():
    """Pixels per SIMD run of this OpenCV's BGR to HLS code on this CPU (4, 8
    or 16), or None: counted on one 63-pixel row of a colour its two codes
    convert apart (runs of 4, 8 or 16 leave 60, 56 or 48 SIMD pixels)."""
    import cv2

    def row(width):
        pixels = np.empty((1, width, 3), np.uint8)
        pixels[:] = OPENCV_RULES_APART
        return cv2.cvtColor(pixels, cv2.COLOR_BGR2HLS)[0]

    simd_value, scalar_value = row(16)[0], row(1)[0]
    assert (simd_value != scalar_value).any(), "the probe colour no longer tells the codes apart"
    probe = row(63)
    for lanes in (4, 8, 16):
        count = 63 - 63 % lanes
        if (probe[:count] == simd_value).all() and (probe[count:] == scalar_value).all():
            return lanes
    return None
