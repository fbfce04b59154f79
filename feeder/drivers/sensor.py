"""Position sensor interface (camera, interferometer, ...)."""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from types import TracebackType

from feeder.errors import FeederError


class SensorLost(FeederError, RuntimeError):
    """No sample within the timeout, or the sensor's link closed."""


class CameraError(FeederError, RuntimeError):
    """A camera cannot be opened as asked (bad spec, missing optional package)."""


@dataclass(frozen=True)
class PositionSample:
    """One measurement.

    time_s: the sensor's timestamp of the exposure (its own clock, seconds).
    position_m: part position along the feed axis, metres.
    sequence: frame number, increasing by one per frame (gaps = dropped frames).
    poses: every part's pose (x_m, y_m, psi_rad) in the plate frame, in the order of
        the parts' ids, when the sensor sees poses (a camera); ``position_m`` is then the
        first part's x.  Empty for a sensor that reads one axis.
    """

    time_s: float
    position_m: float
    sequence: int
    poses: tuple[tuple[float, float, float], ...] = ()


class PositionSensor(ABC):
    """Reads the part's position."""

    @abstractmethod
    def read(self, timeout_s: float = 1.0) -> PositionSample:
        """The newest sample not yet returned; raises :class:`SensorLost`."""

    @abstractmethod
    def close(self) -> None:
        """Release the link."""

    def __enter__(self) -> PositionSensor:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
