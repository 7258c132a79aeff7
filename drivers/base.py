"""The driver interface (DESIGN §4) and the intake counters every driver reports.

A driver yields time-ordered `ImuSample` and `Frame` events (int64 ns stamps), exposes the rig
calibration it knows (or None), the ground truth of a recording when there is one, and a report
of everything it dropped or repaired. Nothing is lost silently: each dropped line, sample or image
is counted in an `IntakeReport`.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Literal

from runtime.errors import ConfigError
from runtime.events import Frame, ImuSample
from runtime.geometry.trajectory import PoseTrajectory

if TYPE_CHECKING:  # calib is imported lazily by the drivers that read calibration
    from calib import Rig

Policy = Literal["drop", "strict"]
"""How a driver treats bad input: "drop" = drop, count and report; "strict" = raise DataError."""

POLICIES: tuple[str, ...] = ("drop", "strict")


def check_policy(policy: str) -> Policy:
    """Validate a policy name; raises ConfigError for anything but "drop" or "strict"."""
    if policy not in POLICIES:
        raise ConfigError(f"unknown intake policy {policy!r}; expected one of {', '.join(POLICIES)}")
    return policy  # type: ignore[return-value]


@dataclass
class StreamCounts:
    """Counters of one input stream (an IMU, a camera, a ground-truth file).

    The identity `lines == parsed + truncated_lines + malformed_lines + dropped_nonfinite
    + dropped_nonmonotonic + dropped_duplicate` holds after reading, and for cameras
    `parsed == emitted + missing_images + repeated_images + unreadable_images + late_images` once every
    event was produced.
    """

    lines: int = 0
    """data rows seen (headers and blank lines excluded)"""
    parsed: int = 0
    """rows kept after validation"""
    truncated_lines: int = 0
    """rows with too few fields (e.g. a cut-off last line)"""
    malformed_lines: int = 0
    """rows with unparseable numbers, extra fields or a non-integer stamp"""
    dropped_nonfinite: int = 0
    """rows holding NaN or Inf"""
    dropped_nonmonotonic: int = 0
    """out-of-order rows whose stamp lies far from every other row's (corrupt stamps)"""
    reordered: int = 0
    """out-of-order rows kept and sorted into time order (part of `parsed`)"""
    dropped_duplicate: int = 0
    """rows repeating an earlier row's stamp (the first row in the file is kept)"""
    missing_images: int = 0
    """frames whose image file does not exist"""
    repeated_images: int = 0
    """frames naming an image file an earlier frame already names (the earlier frame keeps it)"""
    unreadable_images: int = 0
    """frames whose image file exists but does not decode to a grey image of the stream's size"""
    late_images: int = 0
    """frames recorded too long after their place in time to be sorted into it (a bag's reorder window)"""
    converted: int = 0
    """rows or images converted to the expected units or bit depth (accelerometer in g, 12-bit
    images in 16-bit files); the IntakeReport's notes say which conversion"""
    emitted: int = 0
    """events handed to the consumer"""
    gaps: int = 0
    """intervals longer than 1.5x the median period (dropped frames or samples upstream)"""
    missing_estimated: int = 0
    """samples or frames missing inside those gaps, estimated from the median period"""
    median_period_ns: int = 0
    """median interval between consecutive kept stamps"""

    @property
    def dropped(self) -> int:
        """All rows dropped while reading."""
        return (self.truncated_lines + self.malformed_lines + self.dropped_nonfinite
                + self.dropped_nonmonotonic + self.dropped_duplicate)

    def rows_accounted(self) -> bool:
        """True when every data row is either kept or counted as dropped."""
        return self.lines == self.parsed + self.dropped


@dataclass
class IntakeReport:
    """Counters and notes of one driver session, shared by all drivers.

    Attributes:
        driver: the driver's name (e.g. "euroc").
        source: the folder, bag or device it reads.
        policy: the intake policy in force.
        streams: counters per stream name ("imu0", "cam0", "groundtruth", ...).
        notes: human-readable observations (header variations, unequal camera rates, ...).
    """

    driver: str
    source: str
    policy: str = "drop"
    streams: dict[str, StreamCounts] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def stream(self, name: str) -> StreamCounts:
        """The counters of `name`, created on first use."""
        if name not in self.streams:
            self.streams[name] = StreamCounts()
        return self.streams[name]

    def note(self, text: str) -> None:
        """Record an observation once."""
        if text not in self.notes:
            self.notes.append(text)

    def total(self, counter: str) -> int:
        """Sum of one counter over all streams."""
        return int(sum(getattr(s, counter) for s in self.streams.values()))

    def as_dict(self) -> dict:
        """A JSON-ready dict: per-stream counters, totals of the drop counters, and notes."""
        totals = {k: self.total(k) for k in ("truncated_lines", "malformed_lines", "dropped_nonfinite",
                                             "dropped_nonmonotonic", "dropped_duplicate", "reordered",
                                             "converted", "missing_images", "repeated_images",
                                             "unreadable_images", "late_images", "gaps")}
        return {"driver": self.driver, "source": self.source, "policy": self.policy,
                "streams": {k: asdict(v) for k, v in self.streams.items()},
                "totals": totals, "notes": list(self.notes)}

    def summary(self) -> str:
        """A short multi-line text: one line per stream, then the notes."""
        lines = [f"{self.driver} intake from {self.source} (policy {self.policy})"]
        for name, s in self.streams.items():
            parts = [f"{s.parsed}/{s.lines} rows kept", f"{s.emitted} emitted"]
            for key in ("truncated_lines", "malformed_lines", "dropped_nonfinite", "dropped_nonmonotonic",
                        "dropped_duplicate", "reordered", "converted", "missing_images",
                        "repeated_images", "unreadable_images", "late_images", "gaps"):
                value = getattr(s, key)
                if value:
                    parts.append(f"{key.replace('_', ' ')} {value}")
            lines.append(f"  {name}: " + ", ".join(parts))
        lines.extend(f"  note: {n}" for n in self.notes)
        return "\n".join(lines)


class Driver(ABC):
    """A source of time-ordered IMU samples and camera frames (DESIGN §4).

    Use as a context manager so that files or devices are released:
        with EurocDriver(path) as drv:
            for event in drv.events(): ...
    """

    @property
    @abstractmethod
    def rig(self) -> Rig | None:
        """The rig calibration this source knows, or None when it is unknown or withheld."""

    @abstractmethod
    def events(self) -> Iterator[ImuSample | Frame]:
        """Events in non-decreasing t_ns order (at equal stamps the IMU sample comes first)."""

    def groundtruth(self) -> PoseTrajectory | None:
        """Ground-truth poses T_WI (with v, bg, ba when known), or None."""
        return None

    @abstractmethod
    def report(self) -> dict:
        """The intake counters (`IntakeReport.as_dict()`), JSON-ready."""

    def close(self) -> None:
        """Release files, threads or devices (idempotent); subclasses extend it."""
        self._closed = True

    def __enter__(self) -> Driver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
