"""The camera calibration from plate moves, run by the daemon with its own amplifier and camera.

``feeder vision calibrate-moves --daemon`` (the socket's ``calibrate_camera``) measures what
``calibrate-moves`` measures (:mod:`feeder.vision.offset_moves`) without stopping the daemon:
while no move runs, the control loop lends it the amplifiers (its commands wait) and the
camera's poses (the loop goes on reading them), and it stores the calibration, used from the
next move on.  ``stop`` ends the moves within an increment (or the frames being averaged),
every axis grounded, and so does the requesting client's hang-up (:func:`stop_on_hang_up`).
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from feeder.daemon.request_fields import RequestFieldError, finite, integer
from feeder.drivers.sensor import PositionSample, PositionSensor
from feeder.vision.calibration import CameraCalibration
from feeder.vision.offset_moves import SLIP_FRACTION_RANGE, OffsetMoves

if TYPE_CHECKING:
    from feeder.daemon.control_loop import ControlLoop

log = logging.getLogger(__name__)

HANG_UP_POLL_S = 0.2
"""How often the moves check that the client that asked for them is still there."""


@dataclass(frozen=True)
class PlateMoves:
    """What the moves need of the daemon's configuration: the amplifier's output range (V), the
    θ stack's lever arm (m), the camera's image (width, height px), the stacks' static gain
    where it is known (:attr:`~feeder.daemon.config.DaemonConfig.stack_gain_m_per_v`; None:
    each request must give it), and why a calibration would not show the whole travel
    (:meth:`~feeder.daemon.config.CameraConfig.travel_outside`)."""

    v_min_v: float
    v_max_v: float
    lever_arm_m: float
    image_px: tuple[int, int]
    stack_gain_m_per_v: float | None
    travel_outside: Callable[[CameraCalibration], str | None]

    def moves(self, request: dict[str, Any]) -> OffsetMoves:
        """The request's moves (``volts``, ``stack_gain_m_per_v``, ``increment_v``, ``frames``,
        ``slip_fraction``;
        defaults as ``calibrate-moves``'); :class:`RequestFieldError` naming a bad field."""
        defaults = OffsetMoves()
        volts = _within(request, "volts", defaults.volts, max(1.0, self.v_min_v), self.v_max_v)
        gain = finite(request, "stack_gain_m_per_v")
        if gain is None:
            gain = self.stack_gain_m_per_v
        if gain is None:
            raise RequestFieldError(
                "stack_gain_m_per_v is required on hardware without [stack] gain_m_per_v: "
                "the plate's move per volt"
            )
        if not 1e-12 <= gain <= 1e-3:
            raise RequestFieldError(f"stack_gain_m_per_v must be in [1e-12, 1e-3] m/V, got {gain!r}")
        return OffsetMoves(
            volts=volts,
            stack_gain_m_per_v=gain,
            lever_arm_m=self.lever_arm_m,
            increment_v=_within(request, "increment_v", defaults.increment_v, 1e-4, 1.0),
            frames=integer(request, "frames", defaults.frames, 1, 1000),
            slip_fraction=_within(request, "slip_fraction", defaults.slip_fraction, *SLIP_FRACTION_RANGE),
        )


def _within(request: dict[str, Any], key: str, default: float, low: float, high: float) -> float:
    value = finite(request, key)
    if value is None:
        return default
    if not low <= value <= high:
        raise RequestFieldError(f"{key} must be in [{low:g}, {high:g}], got {value!r}")
    return value


class LoopPoses(PositionSensor):
    """The control loop's camera poses as a sensor: each read waits for the next sample the loop
    reads (the loop still takes it)."""

    def __init__(self, loop: ControlLoop) -> None:
        self._loop = loop

    def read(self, timeout_s: float = 1.0) -> PositionSample:
        return self._loop.next_sample(timeout_s)

    def close(self) -> None:
        """The loop's camera stays open."""


@contextlib.contextmanager
def stop_on_hang_up(hung_up: Callable[[], bool], stop: threading.Event) -> Iterator[None]:
    """While inside, set ``stop`` once ``hung_up()`` (checked every :data:`HANG_UP_POLL_S`): a
    client killed outright cannot send ``stop``, and no one would read the result."""
    ended = threading.Event()

    def watch() -> None:
        while not ended.wait(HANG_UP_POLL_S):
            if hung_up():
                log.warning("camera calibration: the client that asked for it has gone; stopping the moves")
                stop.set()
                return

    watcher = threading.Thread(target=watch, name="camera-moves-client", daemon=True)
    watcher.start()
    try:
        yield
    finally:
        ended.set()
        watcher.join()


def summary(report: dict[str, Any]) -> str:
    """One line of a calibration report for the log: the fitted values and whether it was stored."""
    origin = (
        "O not measured (no θ axis)"
        if report["origin_x_px"] is None
        else f"O at ({report['origin_x_px']:.1f}, {report['origin_y_px']:.1f}) px"
    )
    return "{:.5g} µm/px, turned {:.4f} rad{}, {}, back within {:.3f} px; {}".format(
        report["pixel_size_m"] * 1e6,
        report["rotation_rad"],
        ", mirrored" if report["mirrored"] else "",
        origin,
        report["returned_px"],
        "stored, used from the next move on" if report["saved"] else "not stored",
    )
