"""What the eye looks for and what it reports, in the image convention (DESIGN §10).

Image convention: origin at the centre of the top-left pixel, x to the right,
y down (pixels); an angle is measured from +x towards +y.  A part's angle is the
direction of its first dimension (L of ``LxWxT``), reported modulo its symmetry:
π/2 for a square, π for a rectangle, 2π with an orientation mark.

The orientation mark is a disc of radius ``MARK_RADIUS`` × min(L, W) centred on
the part's +L half-axis at ``MARK_OFFSET`` × L from the centre (for a disc part:
at half its radius).  The renderer (firmware_sim.camera_render) draws it from
these same constants.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

MARK_OFFSET = 0.25
MARK_RADIUS = 0.1
SQUARE_TOLERANCE = 0.03  # |L - W| / max(L, W) below this is a square


@dataclass(frozen=True)
class PartTemplate:
    """The part the eye looks for, in pixels.

    length_px, width_px: footprint L × W (a disc: its diameter twice).
    disc: a round part (no sides; its angle comes from the mark only).
    mark: the part carries the orientation mark, so the angle is known modulo 2π.
    """

    length_px: float
    width_px: float
    disc: bool = False
    mark: bool = False

    @property
    def square(self) -> bool:
        return abs(self.length_px - self.width_px) <= SQUARE_TOLERANCE * max(self.length_px, self.width_px)

    @property
    def symmetry_rad(self) -> float:
        """The angle period of the part's look: 2π with a mark, π/2 square, π rectangle, 0 plain disc."""
        if self.mark:
            return 2 * math.pi
        if self.disc:
            return 0.0
        return math.pi / 2 if self.square else math.pi


@dataclass(frozen=True)
class Detection:
    """One part located in one image (pixels, radians; see the module's convention).

    score: 0..1, the fraction of edge profiles that found the edge times a
        penalty on the RMS residual of the edge fits (1 = every profile, residual ≪ 0.2 px).
    length_px, width_px: the measured footprint (distance between the fitted sides).
    edge_rms_px: RMS distance of the subpixel edge points from their fitted lines.
    symmetry_rad: the period ``angle_rad`` is reported in (0: a plain disc, angle meaningless).
    disc: a round part (length_px = width_px = its diameter).
    """

    x_px: float
    y_px: float
    angle_rad: float
    score: float
    length_px: float
    width_px: float
    edge_rms_px: float
    symmetry_rad: float
    disc: bool = False


@dataclass(frozen=True)
class Rejection:
    """A blob that is not reported as a part: where (pixels) and why."""

    x_px: float
    y_px: float
    reason: str


@dataclass(frozen=True)
class LocateResult:
    """Every part found in one image, and the blobs refused (cut by the border, overlapped, ambiguous)."""

    width: int
    height: int
    parts: tuple[Detection, ...]
    rejected: tuple[Rejection, ...]
    polarity: str  # "bright" (parts brighter than the support) or "dark"


def wrap_angle(angle_rad: float, period_rad: float) -> float:
    """``angle_rad`` reduced to [0, period) (period 0: returned as 0)."""
    if period_rad <= 0:
        return 0.0
    wrapped = math.fmod(angle_rad, period_rad)
    if wrapped < 0:
        wrapped += period_rad
    return 0.0 if wrapped >= period_rad else wrapped


def angle_difference(a_rad: float, b_rad: float, period_rad: float) -> float:
    """Signed a − b in [−period/2, period/2)."""
    return wrap_angle(a_rad - b_rad + period_rad / 2, period_rad) - period_rad / 2
