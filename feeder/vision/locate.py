"""Pose of every part in one image: find the blobs, refuse the doubtful ones, refine by edges.

1. Coarse (OpenCV): the image shrunk 4× (``cv2.resize``, bilinear: 2×2 means),
   a threshold half-way from the support's median (the support is the majority
   of the field) to the pixels far from it (:func:`_threshold`, which also fixes
   the polarity), ``cv2.findContours`` and ``cv2.minAreaRect`` per blob.  A
   threshold's outline is biased by uneven light and blur: it only starts.
2. Refusals: a blob touching the image border (cut), one that fills its
   bounding rectangle neither like a rectangle nor like a disc (overlapped or
   touching parts), one whose size is not the part's (given a template), edges
   that are not straight or not found (ambiguous), an orientation mark that
   cannot be told.  Refused blobs are listed under ``rejected`` with the reason.
3. Fine: subpixel line fits on the four sides (feeder.vision.edges), or a
   circle fit for a disc; the orientation mark (feeder.vision.model) settles
   the angle modulo 2π.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from feeder.vision.edges import CircleFit, RectangleFit, refine_circle, refine_rectangle, sample
from feeder.vision.model import (
    MARK_OFFSET,
    MARK_RADIUS,
    SQUARE_TOLERANCE,
    Detection,
    LocateResult,
    PartTemplate,
    Rejection,
    wrap_angle,
)

RECTANGLE_FILL = 0.88  # a rectangle's blob fills at least this of its minimum-area rectangle
DISC_FILL = (0.70, 0.86)  # a disc's fills π/4 ≈ 0.785 of its bounding square
SIZE_TOLERANCE = 0.12  # coarse size vs the template (relative)
MAX_EDGE_RMS_PX = 0.5  # straight sides scatter far less (≈ 0.1 px at 2 % noise)
MIN_VALID_FRACTION = 0.6  # of the edge profiles that found the edge
MIN_MARK_CONTRAST = 0.25  # mark vs part level, relative to the part/support contrast


def to_gray(image: np.ndarray) -> np.ndarray:
    """A 2-D grey image (colour images are converted by ``cv2.cvtColor``, BGR order)."""
    if image.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        return cv2.cvtColor(image, code)
    if image.ndim != 2:
        raise ValueError(f"expected a 2-D grey or 3-D colour image, got shape {image.shape}")
    return image


MIN_SHRUNK_SIDE_PX = 40
"""The search shrinks the image at most so far that a part's short side keeps this many
pixels: fewer, and pixelation makes a rotated rectangle's blob look like touching parts."""


def _shrink_factor(gray: np.ndarray, template: PartTemplate | None) -> int:
    side = min(gray.shape)
    f = 4 if side >= 512 else 2 if side >= 128 else 1
    if template is not None:
        f = min(f, max(1, int(min(template.length_px, template.width_px) // MIN_SHRUNK_SIDE_PX)))
    return f


def _as_uint8(small: np.ndarray) -> np.ndarray:
    if small.dtype == np.uint8:
        return small
    values = small.astype(np.float32)
    low, high = float(values.min()), float(values.max())
    return np.clip((values - low) * (255.0 / max(high - low, 1e-12)) + 0.5, 0, 255).astype(np.uint8)


def locate(image: np.ndarray, template: PartTemplate | None = None, polarity: str = "auto") -> LocateResult:
    """Every part in ``image`` (grey or BGR; uint8, uint16 or float).

    template: the part looked for (sizes in px, disc, mark); None takes any
        rectangle or disc, the longer side as the first dimension, no mark.
    polarity: "bright" (parts brighter than the support), "dark" or "auto".
    """
    gray = to_gray(image)
    h, w = gray.shape
    f = _shrink_factor(gray, template)
    shrunk = cv2.resize(gray, (w // f, h // f), interpolation=cv2.INTER_LINEAR) if f > 1 else gray
    small = _as_uint8(shrunk)
    if polarity not in ("auto", "bright", "dark"):
        raise ValueError(f"polarity must be auto, bright or dark, got {polarity!r}")
    threshold, polarity = _threshold(small, polarity)
    kind = cv2.THRESH_BINARY if polarity == "bright" else cv2.THRESH_BINARY_INV
    _, mask = cv2.threshold(small, threshold, 255, kind)
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    contrast = abs(cv2.mean(shrunk, mask)[0] - cv2.mean(shrunk, cv2.bitwise_not(mask))[0])
    sy, sx = h / small.shape[0], w / small.shape[1]
    noise_area = max(16.0, 1e-4 * small.size)  # a blob smaller is noise or dust: never listed
    min_area = 0.25 * _template_area(template) / (sx * sy) if template else noise_area
    parts: list[Detection] = []
    rejected: list[Rejection] = []
    for contour in contours:
        area = cv2.contourArea(contour)
        if area < min_area:
            if template is not None and area >= noise_area:  # a wrong pixel size shows here
                (cx, cy), _, _ = cv2.minAreaRect(contour)
                rejected.append(Rejection((cx + 0.5) * sx - 0.5, (cy + 0.5) * sy - 0.5,
                                          f"too small for the part: {area * sx * sy:.0f} px², "
                                          f"the part {_template_area(template):.0f} px²"))  # fmt: skip
            continue
        result = _one_blob(gray, contour, area, (sx, sy), contrast, template)
        if isinstance(result, Detection):
            parts.append(result)
        else:
            rejected.append(result)
    parts.sort(key=lambda p: (p.y_px, p.x_px))
    return LocateResult(w, h, tuple(parts), tuple(rejected), polarity)


OUTLIER_SPREADS = 8.0
"""A pixel this many robust spreads (1.4826 × MAD) from the support's median is a part's."""


def _threshold(small: np.ndarray, polarity: str) -> tuple[float, str]:
    """The level between the support and the parts, and the parts' polarity (``auto``: the side
    with more pixels far from the support's median).  Half-way from the support's median to the
    median of those far pixels: Otsu's threshold assumes two classes of some size, and an 80 µm
    part at 2.7 µm/px (0.02 % of a 2048² field) left it in the support's vignetting.  From the
    256-level histogram (~1 ms a 1024² frame; ``np.median`` of the pixels took ~30 ms)."""
    counts = np.bincount(small.ravel(), minlength=256).astype(np.int64)
    levels = np.arange(counts.size, dtype=np.float64)
    support = _median(levels, counts)
    deviations = np.abs(levels - support)
    order = np.argsort(deviations, kind="stable")
    spread = max(1.0, 1.4826 * _median(deviations[order], counts[order]))
    bright, dark = levels > support + OUTLIER_SPREADS * spread, levels < support - OUTLIER_SPREADS * spread
    if polarity == "auto":
        polarity = "bright" if counts[bright].sum() >= counts[dark].sum() else "dark"
    far = bright if polarity == "bright" else dark
    if not counts[far].any():  # no part: a threshold nothing passes
        return (255.0 if polarity == "bright" else 0.0), polarity
    return (support + _median(levels[far], counts[far])) / 2, polarity


def _median(values: np.ndarray, counts: np.ndarray) -> float:
    """The median of ``values`` (ascending) each taken ``counts`` times, as ``np.median`` of them
    all gives it (the mean of the two middle ones for an even number)."""
    ranks = np.cumsum(counts)
    total = int(ranks[-1])
    low, high = np.searchsorted(ranks, [(total - 1) // 2, total // 2], side="right")
    return float(values[low] + values[high]) / 2


def _template_area(template: PartTemplate) -> float:
    if template.disc:
        return math.pi / 4 * template.length_px**2
    return template.length_px * template.width_px


def _one_blob(
    gray: np.ndarray,
    contour: np.ndarray,
    area: float,
    scale: tuple[float, float],
    contrast: float,
    template: PartTemplate | None,
) -> Detection | Rejection:
    """Classify, check and refine one blob of the shrunk mask (``contrast``: parts vs support)."""
    sx, sy = scale
    h, w = gray.shape
    (cx, cy), (rw, rh), angle_deg = cv2.minAreaRect(contour)
    x, y = (cx + 0.5) * sx - 0.5, (cy + 0.5) * sy - 0.5
    bx, by, bw, bh = cv2.boundingRect(contour)
    if bx <= 0 or by <= 0 or bx + bw >= gray.shape[1] / sx - 0.5 or by + bh >= gray.shape[0] / sy - 0.5:
        return Rejection(x, y, "cut by the image border")
    fill = area / max(rw * rh, 1e-9)
    rw, rh = (rw + 1) * sx, (rh + 1) * sy  # the contour runs through the boundary pixels' centres
    round_blob = abs(rw - rh) <= 0.1 * max(rw, rh) and DISC_FILL[0] <= fill <= DISC_FILL[1]
    if fill < RECTANGLE_FILL and not round_blob:
        return Rejection(
            x,
            y,
            f"overlapped or touching parts: the blob fills {fill:.2f} of its bounding "
            "rectangle (a rectangle 1, a disc 0.79)",
        )
    if template is not None:
        problem = _size_problem(template, round_blob, rw, rh, area * sx * sy)
        if problem:
            return Rejection(x, y, problem)
    disc = template.disc if template is not None else round_blob
    expected_reach = math.hypot(rw, rh) / 2 + 25
    x0, x1 = max(0, int(x - expected_reach)), min(w, int(x + expected_reach) + 1)
    y0, y1 = max(0, int(y - expected_reach)), min(h, int(y + expected_reach) + 1)
    roi = gray[y0:y1, x0:x1].astype(np.float32)
    if disc:
        return _disc(roi, (x0, y0), x - x0, y - y0, (rw + rh) / 4, contrast, template)
    return _rectangle(roi, (x0, y0), x - x0, y - y0, math.radians(angle_deg), rw, rh, contrast, template)


def _size_problem(template: PartTemplate, round_blob: bool, rw: float, rh: float, area: float) -> str:
    expected = _template_area(template)
    if area > 1.6 * expected:
        return f"overlapped or touching parts: area of {area / expected:.1f} parts"
    if template.disc != round_blob:
        return "not the part's shape (" + ("round" if round_blob else "not round") + ")"
    measured = sorted((rw, rh))
    wanted = sorted((template.length_px, template.width_px))
    for got, want in zip(measured, wanted, strict=True):
        if abs(got - want) > max(SIZE_TOLERANCE * want, 8.0):
            return (
                f"size {measured[1]:.0f}×{measured[0]:.0f} px does not match the part "
                f"{wanted[1]:.0f}×{wanted[0]:.0f} px"
            )
    return ""


def _score(fit: RectangleFit | CircleFit) -> float:
    return fit.valid_fraction / (1.0 + (fit.edge_rms_px / 0.2) ** 2)


def _edge_problem(fit: RectangleFit | CircleFit | None) -> str:
    if fit is None:
        return "ambiguous: too few edge points on a side"
    if fit.valid_fraction < MIN_VALID_FRACTION:
        return f"ambiguous: only {fit.valid_fraction:.0%} of the edge profiles found the edge"
    if fit.edge_rms_px > MAX_EDGE_RMS_PX:
        return f"ambiguous: edges not straight (RMS {fit.edge_rms_px:.2f} px), touching or overlapped"
    return ""


def _rectangle(
    roi: np.ndarray,
    origin: tuple[int, int],
    x: float,
    y: float,
    angle: float,
    rw: float,
    rh: float,
    contrast: float,
    template: PartTemplate | None,
) -> Detection | Rejection:
    fit = refine_rectangle(roi, x, y, angle, rw, rh, min_contrast=0.3 * contrast)
    ox, oy = origin
    problem = _edge_problem(fit)
    if problem or fit is None:
        return Rejection(x + ox, y + oy, problem)
    angle, length, width = fit.angle_rad, fit.length_px, fit.width_px
    first, second = (
        (template.length_px, template.width_px) if template else (max(length, width), min(length, width))
    )
    if abs(length - second) + abs(width - first) < abs(length - first) + abs(width - second):
        angle, length, width = angle + math.pi / 2, width, length
    square = abs(length - width) <= SQUARE_TOLERANCE * max(length, width)
    if template is not None:
        square = template.square
    period = math.pi / 2 if square else math.pi
    if template is not None and template.mark:
        step = period
        turns = round(2 * math.pi / step)
        centres = [
            (
                fit.x_px + MARK_OFFSET * length * math.cos(angle + k * step),
                fit.y_px + MARK_OFFSET * length * math.sin(angle + k * step),
            )
            for k in range(turns)
        ]
        k = _mark_choice(roi, centres, MARK_RADIUS * min(length, width), fit.inner_level, fit.outer_level)
        if k is None:
            return Rejection(fit.x_px + ox, fit.y_px + oy, "ambiguous: the orientation mark cannot be told")
        angle, period = angle + k * step, 2 * math.pi
    return Detection(
        fit.x_px + ox,
        fit.y_px + oy,
        wrap_angle(angle, period),
        _score(fit),
        length,
        width,
        fit.edge_rms_px,
        period,
    )


def _mark_choice(
    roi: np.ndarray,
    centres: list[tuple[float, float]],
    radius: float,
    part_level: float,
    support_level: float,
) -> int | None:
    """Which candidate position holds the mark (the largest departure from the part's level)."""
    r = np.linspace(0, 0.6 * radius, 4)[:, None]
    t = np.linspace(0, 2 * math.pi, 12, endpoint=False)[None, :]
    dx, dy = (r * np.cos(t)).ravel(), (r * np.sin(t)).ravel()
    departures = np.array(
        [abs(float(np.mean(sample(roi, cx + dx, cy + dy))) - part_level) for cx, cy in centres]
    )
    order = np.argsort(departures)[::-1]
    contrast = abs(part_level - support_level)
    best, second = departures[order[0]], departures[order[1]] if len(order) > 1 else 0.0
    if best < MIN_MARK_CONTRAST * contrast or second > 0.5 * best:
        return None
    return int(order[0])


def _disc(
    roi: np.ndarray,
    origin: tuple[int, int],
    x: float,
    y: float,
    radius: float,
    contrast: float,
    template: PartTemplate | None,
) -> Detection | Rejection:
    fit = refine_circle(roi, x, y, radius, min_contrast=0.3 * contrast)
    ox, oy = origin
    problem = _edge_problem(fit)
    if problem or fit is None:
        return Rejection(x + ox, y + oy, problem)
    angle, period = 0.0, 0.0
    if template is not None and template.mark:
        ring = np.linspace(0, 2 * math.pi, 720, endpoint=False)
        values = sample(
            roi, fit.x_px + fit.radius_px / 2 * np.cos(ring), fit.y_px + fit.radius_px / 2 * np.sin(ring)
        )
        departure = np.abs(values - fit.inner_level)
        if departure.max() < MIN_MARK_CONTRAST * abs(fit.inner_level - fit.outer_level):
            return Rejection(fit.x_px + ox, fit.y_px + oy, "ambiguous: the orientation mark cannot be told")
        weight = np.clip(departure - 0.5 * departure.max(), 0, None)
        angle = math.atan2(float(np.sum(weight * np.sin(ring))), float(np.sum(weight * np.cos(ring))))
        period = 2 * math.pi
    diameter = 2 * fit.radius_px
    return Detection(
        fit.x_px + ox,
        fit.y_px + oy,
        wrap_angle(angle, period),
        _score(fit),
        diameter,
        diameter,
        fit.edge_rms_px,
        period,
        disc=True,
    )
