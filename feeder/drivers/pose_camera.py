"""A camera that locates: every part's pose (x, y, ψ) in the plate frame, from the frames of a camera.

:class:`CameraPoseSensor` reads a :class:`~feeder.drivers.video_camera.FrameSource`
(``open_camera("http://127.0.0.1:PORT/video.mjpg")``, a USB or GenICam camera, a
recording) on its own thread, locates the parts (:func:`feeder.vision.locate.locate`),
converts pixels to the plate frame (:class:`~feeder.vision.calibration.CameraCalibration`)
and keeps the newest :class:`~feeder.drivers.sensor.PositionSample`; the caller's
:meth:`~CameraPoseSensor.read` only waits for it, so locating never costs the
caller's thread (a control loop's tick) any time.  A live camera's newest sample
replaces one not yet read; a recording's waits until it was read, so that, as its
frames, none of its samples is lost however slow the reader.

Per frame:

- *Tracking* (the usual case): each part is searched in a region of interest
  around where it was last seen, its side ``2 × (reach + roi_margin_px)`` (reach:
  half the part's diagonal), so a 2048 × 2048 frame costs a few small locates,
  not a whole-frame search.
- *Acquiring* (the first frame, and any frame in which a tracked part is not
  found in its region, e.g. it moved further than the margin): the whole frame
  is searched and the parts matched to the ones tracked (nearest centres, one
  to one: ``scipy.optimize.linear_sum_assignment``; extra blobs are ignored).

Parts get ids 1, 2, ... by their x in the plate frame when first acquired
(``parts`` of them: the sensor waits until it sees that many), and keep them.
A sample's ``time_s`` is the host's ``time.monotonic()`` when the frame arrived.
ψ is unwrapped from frame to frame (a part's look repeats every
``template.symmetry_rad``; the sensor follows the turn continuously, so a square
turned by 60° reads 60°, not −30°).  A frame in which not every part is found
gives no sample (``sequence`` then has a gap).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import linear_sum_assignment

from feeder.drivers.frame_source import Frame, FrameSource
from feeder.drivers.sensor import PositionSample, PositionSensor, SensorLost
from feeder.vision.calibration import CameraCalibration
from feeder.vision.locate import locate, to_gray
from feeder.vision.model import Detection, PartTemplate, angle_difference

log = logging.getLogger(__name__)

FRAME_TIMEOUT_S = 1.0
"""The locating thread's wait for a frame before it checks for close again."""


def part_template(
    length_m: float, width_m: float, calibration: CameraCalibration, disc: bool = False, mark: bool = False
) -> PartTemplate:
    """The template of a part of footprint ``length_m`` × ``width_m`` under ``calibration``."""
    return PartTemplate(length_m / calibration.pixel_size_m, width_m / calibration.pixel_size_m, disc, mark)


@dataclass(frozen=True)
class LocatedFrame:
    """A frame and what was found in it (for displays).

    image: the frame as the camera delivered it; sample: the poses (plate frame,
    by part id); detections: the same parts in the image (px), by part id;
    full_frame: the whole frame was searched (acquiring) rather than regions;
    locate_s: wall time the locating took.
    """

    image: np.ndarray
    sample: PositionSample
    detections: tuple[Detection, ...]
    full_frame: bool
    locate_s: float


class CameraPoseSensor(PositionSensor):
    """Poses of ``parts`` parts from ``source`` (see the module doc); owns and closes ``source``.

    roi_margin_px: how far (px) a part may move between two frames and still be
        found in its region; default: its reach (half its diagonal).
    parts: how many parts are on the plate; None: as many as the first frame with
        any shows.
    polarity: ``bright``/``dark``/``auto`` (parts vs support; auto is decided on the
        whole frame at acquisition, then kept for the regions).
    """

    def __init__(
        self,
        source: FrameSource,
        calibration: CameraCalibration,
        template: PartTemplate,
        parts: int | None = None,
        roi_margin_px: float | None = None,
        polarity: str = "auto",
    ) -> None:
        self.source = source
        self.calibration = calibration
        self.template = template
        self.parts = parts
        self.reach_px = 0.5 * (
            template.length_px if template.disc else math.hypot(template.length_px, template.width_px)
        )
        self.roi_margin_px = self.reach_px if roi_margin_px is None else roi_margin_px
        self.polarity = polarity
        self._last: list[Detection] = []  # each part's latest detection, by id − 1
        self._psi: dict[int, float] = {}  # unwrapped plate angle per part id
        self._cond = threading.Condition()
        self._latest: LocatedFrame | None = None
        self._returned = -1
        self._error = ""
        self._closed = threading.Event()
        self.full_frame_searches = 0
        self.region_searches = 0
        self._thread = threading.Thread(target=self._run, name="pose-camera", daemon=True)
        self._thread.start()

    # -- the caller's side -------------------------------------------------------

    def read(self, timeout_s: float = 1.0) -> PositionSample:
        """The newest sample not yet returned; :class:`SensorLost` if none within ``timeout_s``."""
        with self._cond:
            fresh = self._cond.wait_for(
                lambda: self._closed.is_set() or self._unread(),
                timeout_s,
            )
            if self._closed.is_set():
                raise SensorLost(f"{self.source.name}: the pose sensor is closed")
            if not fresh or self._latest is None:
                why = self._error or "no frame with every part located"
                raise SensorLost(f"{self.source.name}: no poses within {timeout_s:g} s ({why})")
            self._returned = self._latest.sample.sequence
            self._cond.notify_all()  # a recording's next sample waits for this one to be read
            return self._latest.sample

    def latest_image(self) -> LocatedFrame | None:
        """The newest frame in which every part was located (None before the first)."""
        with self._cond:
            return self._latest

    def close(self) -> None:
        self._closed.set()
        with self._cond:
            self._cond.notify_all()
        self.source.close()
        self._thread.join(timeout=5.0)

    # -- the locating thread -------------------------------------------------------

    def _run(self) -> None:
        while not self._closed.is_set():
            try:
                frame = self.source.read(FRAME_TIMEOUT_S)
            except SensorLost as exc:
                self._set_error(str(exc))
                continue
            started = time.perf_counter()
            located = self._locate(frame)
            if located is None:
                continue
            detections, full = located
            sample = self._sample(frame, detections)
            result = LocatedFrame(frame.image, sample, detections, full, time.perf_counter() - started)
            with self._cond:
                if not self.source.live:
                    self._cond.wait_for(lambda: self._closed.is_set() or not self._unread())
                self._latest = result
                self._error = ""
                self._cond.notify_all()

    def _unread(self) -> bool:
        """A sample is waiting to be read (call with the condition held)."""
        return self._latest is not None and self._latest.sample.sequence > self._returned

    def _set_error(self, reason: str) -> None:
        with self._cond:
            self._error = reason
        log.debug("pose camera %s: %s", self.source.name, reason)

    def _locate(self, frame: Frame) -> tuple[tuple[Detection, ...], bool] | None:
        """The parts by id (regions, else the whole frame), and whether the whole frame was searched."""
        if self._last:
            found = [d for last in self._last if (d := self._in_region(frame.image, last)) is not None]
            if len(found) == len(self._last) and _moved_alike(self._last, found):
                self.region_searches += 1
                self._last = found
                return tuple(self._last), False
        self.full_frame_searches += 1
        result = locate(frame.image, self.template, self.polarity)
        self.polarity = result.polarity  # the regions keep the whole frame's polarity
        parts = result.parts
        if not self._last:
            if not parts or (self.parts is not None and len(parts) != self.parts):
                self._set_error(f"acquiring: {len(parts)} parts seen, {self.parts or 'some'} expected")
                return None
            self.parts = len(parts)
            self._last = sorted(parts, key=lambda d: self.calibration.to_plate(d.x_px, d.y_px)[0])
            return tuple(self._last), True
        if len(parts) < len(self._last):
            self._set_error(f"{len(parts)} of {len(self._last)} parts seen in the whole frame")
            return None
        old = np.array([[d.x_px, d.y_px] for d in self._last])
        new = np.array([[d.x_px, d.y_px] for d in parts])
        if len(parts) == len(self._last):
            # the plate carries every part alike: match the arrangements, not the places (a burst
            # that moves the parts further than they lie apart swapped their ids in 1-D ties)
            old, new = old - old.mean(axis=0), new - new.mean(axis=0)
        rows, cols = linear_sum_assignment(np.linalg.norm(old[:, None, :] - new[None, :, :], axis=2))
        self._last = [parts[c] for _, c in sorted(zip(rows, cols, strict=True))]
        return tuple(self._last), True

    def _in_region(self, image: np.ndarray, last: Detection) -> Detection | None:
        """The part nearest ``last`` in a region around it, in image pixels (None: not found)."""
        h, w = image.shape[:2]
        half = self.reach_px + self.roi_margin_px
        x0, x1 = max(0, int(last.x_px - half)), min(w, math.ceil(last.x_px + half) + 1)
        y0, y1 = max(0, int(last.y_px - half)), min(h, math.ceil(last.y_px + half) + 1)
        if x1 - x0 < 16 or y1 - y0 < 16:
            return None
        found = locate(to_gray(image[y0:y1, x0:x1]), self.template, self.polarity).parts
        if not found:
            return None
        best = min(found, key=lambda d: math.hypot(d.x_px + x0 - last.x_px, d.y_px + y0 - last.y_px))
        return replace(best, x_px=best.x_px + x0, y_px=best.y_px + y0)

    def _sample(self, frame: Frame, detections: tuple[Detection, ...]) -> PositionSample:
        poses = []
        for part_id, detection in enumerate(detections, start=1):
            x_m, y_m = self.calibration.to_plate(detection.x_px, detection.y_px)
            psi = self.calibration.angle_to_plate(detection.angle_rad)
            period = detection.symmetry_rad
            previous = self._psi.get(part_id)
            if previous is not None and period > 0:
                psi = previous + angle_difference(psi, previous, period)
            self._psi[part_id] = psi
            poses.append((x_m, y_m, psi))
        return PositionSample(frame.time_s, poses[0][0], frame.sequence, tuple(poses))


def _moved_alike(last: list[Detection], found: list[Detection]) -> bool:
    """Every part moved alike since the last frame, within half the least distance between two
    of them (px): else a region may hold its neighbour (a burst moved the parts further than
    they lie apart) and the whole frame must decide which is which."""
    if len(last) < 2:
        return True
    moves = np.array([[f.x_px - p.x_px, f.y_px - p.y_px] for p, f in zip(last, found, strict=True)])
    places = np.array([[p.x_px, p.y_px] for p in last])
    apart = min(float(np.linalg.norm(a - b)) for i, a in enumerate(places) for b in places[i + 1 :])
    spread = max(float(np.linalg.norm(a - b)) for i, a in enumerate(moves) for b in moves[i + 1 :])
    return spread < 0.5 * apart
