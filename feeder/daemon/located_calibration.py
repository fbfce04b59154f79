"""The camera calibration the daemon locates parts with: the stored one over the configured one.

``feeder vision calibrate --save-state`` stores a measured calibration (pixel size, the image's
turn and mirroring, O in the image) in the daemon's state; the configuration gives the camera's
scale with O at the image centre.  A stored field overrides the configured one.  The daemon
may run while a calibration is measured and stored: :meth:`LocatedCalibration.saved` tells it
to open its camera again with the new one before the next move.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from feeder.daemon.store import Store
from feeder.vision.calibration import CameraCalibration

STORED = "the stored camera calibration"
"""How errors name a stored calibration's fields (``the stored camera calibration.mirrored``)."""


class LocatedCalibration:
    """Which calibration the sensor locates with (``calibration``: None for the configured one)
    and the stored record it came from.

    configured: the links' configured calibration (None: the daemon reads no camera).
    """

    def __init__(self, configured: Callable[[], CameraCalibration | None], store: Store) -> None:
        self._configured = configured
        self._store = store
        self.record, self.calibration = self.read()

    def read(self) -> tuple[dict[str, Any] | None, CameraCalibration | None]:
        """The stored record and the calibration it makes of the configured one (None: nothing
        stored, or no camera); :class:`~feeder.errors.InputError` naming a bad stored field."""
        configured = self._configured()
        record = self._store.camera_calibration()
        if configured is None or record is None:
            return record, None
        return record, configured.updated(record, STORED)

    def use(self, record: dict[str, Any] | None, calibration: CameraCalibration | None) -> None:
        """The sensor now locates with ``calibration`` (what :meth:`read` gave)."""
        self.record, self.calibration = record, calibration

    def saved(self) -> bool:
        """A calibration was stored since the one in use was read (a camera is read)."""
        if self._configured() is None:
            return False
        record = self._store.camera_calibration()
        return record is not None and (self.record is None or record["updated_s"] != self.record["updated_s"])

    def status(self) -> dict[str, Any] | None:
        """The calibration in use (None: no camera); ``source``: ``stored`` or ``configuration``."""
        if self.calibration is not None:
            return {**(self.record or {}), **self.calibration.to_dict(), "source": "stored"}
        configured = self._configured()
        return None if configured is None else {**configured.to_dict(), "source": "configuration"}
