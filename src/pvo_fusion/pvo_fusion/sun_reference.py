"""Where the sun is in the map frame at a given time: s_map(t), the reference of the sun factor.

- :class:`EphemerisSunReference`: NREL SPA ephemeris in the local ENU frame of a GPS origin (the map
  frame when a ``/gps/fix`` exists), re-queried as time advances (thesis §5.5).
- :class:`FixedSunReference`: one direction, for datasets without latitude/longitude.
- :class:`TabulatedSunReference`: directions tabulated over time (e.g. derived from ground truth as the
  stand-in for the ephemeris in the KITTI sun experiment), linearly interpolated.
"""

from __future__ import annotations

import bisect
from pathlib import Path
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pvo_core.ephemeris import GeodeticOrigin, sun_direction_enu

Array = NDArray[np.float64]


class SunReference(Protocol):
    def direction(self, stamp_ns: int) -> Array | None:
        """Unit sun vector in the map frame at ``stamp_ns`` (UNIX ns), or ``None`` when unknown there."""
        ...


class FixedSunReference:
    def __init__(self, direction: ArrayLike) -> None:
        d = np.asarray(direction, dtype=float)
        norm = float(np.linalg.norm(d)) if d.shape == (3,) and np.all(np.isfinite(d)) else 0.0
        if norm < 1e-9:
            raise ValueError(f"sun reference direction {d.tolist()} must be a finite non-zero 3-vector")
        self._direction = d / norm

    def direction(self, stamp_ns: int) -> Array | None:
        return self._direction


class EphemerisSunReference:
    """Sun in ENU at ``origin``; ``time_offset`` (s) is added to stamps first (e.g. -7200 for CEST logged as UTC)."""

    def __init__(self, origin: GeodeticOrigin, time_offset: float = 0.0) -> None:
        self.origin = origin
        self.time_offset = float(time_offset)
        self._cache: dict[int, Array] = {}

    def _at_second(self, second: int) -> Array:
        cached = self._cache.get(second)
        if cached is None:
            if len(self._cache) > 4096:
                self._cache.clear()
            cached = self._cache[second] = sun_direction_enu(self.origin, float(second))
        return cached

    def direction(self, stamp_ns: int) -> Array | None:
        # The sun moves about 0.004 deg/s: interpolating whole-second ephemeris queries is exact to 1e-8 rad.
        t = stamp_ns * 1e-9 + self.time_offset
        second = int(np.floor(t))
        frac = t - second
        d = (1.0 - frac) * self._at_second(second) + frac * self._at_second(second + 1)
        return d / np.linalg.norm(d)


class TabulatedSunReference:
    """Directions at increasing stamps (ns), linearly interpolated; ``None`` further than ``slack_ns`` outside."""

    def __init__(self, stamps_ns: ArrayLike, directions: ArrayLike, slack_ns: int = 1_000_000_000) -> None:
        stamps = np.asarray(stamps_ns, dtype=np.int64)
        dirs = np.asarray(directions, dtype=float)
        if stamps.ndim != 1 or len(stamps) == 0 or dirs.shape != (len(stamps), 3):
            raise ValueError("sun reference table needs N stamps and N x 3 directions")
        if np.any(np.diff(stamps) <= 0):
            raise ValueError("sun reference table stamps must increase strictly")
        norms = np.linalg.norm(dirs, axis=1)
        if not np.all(np.isfinite(dirs)) or np.any(norms < 1e-9):
            raise ValueError("sun reference table holds a zero or non-finite direction")
        self._stamps = stamps.tolist()
        self._directions = dirs / norms[:, None]
        self._slack = int(slack_ns)

    @classmethod
    def from_ground_truth(cls, stamps_ns: ArrayLike, poses: ArrayLike, sun_camera: ArrayLike) -> TabulatedSunReference:
        """The stand-in for the ephemeris where no GPS exists: s_map(t_k) = C_map,k s_k from ground-truth poses
        T_map,cam (N, 4, 4) and camera-frame sun vectors (N, 3) at the same stamps."""
        p = np.asarray(poses, dtype=float)
        s = np.asarray(sun_camera, dtype=float)
        if p.ndim != 3 or p.shape[1:] != (4, 4) or s.shape != (len(p), 3):
            raise ValueError(f"need poses (N, 4, 4) and sun vectors (N, 3), got {p.shape} and {s.shape}")
        return cls(stamps_ns, np.einsum("nij,nj->ni", p[:, :3, :3], s))

    @classmethod
    def from_ephemeris_in_map(
        cls, stamps_ns: ArrayLike, fixes: ArrayLike, map_positions: ArrayLike
    ) -> tuple[TabulatedSunReference, Array]:
        """The ephemeris at the first GPS fix, expressed in a map frame that is not ENU (e.g. a simulator's
        first-camera frame): ``fixes`` (M, 3) latitude, longitude (deg), altitude (m) and the same places in
        the map frame ``map_positions`` (M, 3) give the rotation C_map,enu (Umeyama over the track; it must
        not be a straight line); the table holds C_map,enu s_enu(t) at ``stamps_ns``. Also returns C_map,enu."""
        from pvo_core.ephemeris import geodetic_to_enu
        from pvo_core.metrics import umeyama_alignment

        f = np.asarray(fixes, dtype=float)
        q = np.asarray(map_positions, dtype=float)
        if f.ndim != 2 or f.shape[1] != 3 or q.shape != f.shape or len(f) < 3:
            raise ValueError(f"need >= 3 GPS fixes (M, 3) and map positions (M, 3), got {f.shape} and {q.shape}")
        origin = GeodeticOrigin(float(f[0, 0]), float(f[0, 1]), float(f[0, 2]))
        enu = geodetic_to_enu(origin, f[:, 0], f[:, 1], f[:, 2])
        spread = np.linalg.svd(enu - enu.mean(axis=0), compute_uv=False)
        if spread[1] < 1e-3 * max(spread[0], 1e-9):
            raise ValueError("the GPS track is a straight line: its rotation about the line is unknown")
        rotation, _, _ = umeyama_alignment(enu, q)
        stamps = np.asarray(stamps_ns, dtype=np.int64)
        directions = sun_direction_enu(origin, stamps * 1e-9) @ rotation.T
        return cls(stamps, directions), rotation

    @property
    def stamps(self) -> NDArray[np.int64]:
        return np.asarray(self._stamps, dtype=np.int64)

    @property
    def directions(self) -> Array:
        return self._directions.copy()

    def direction(self, stamp_ns: int) -> Array | None:
        stamps = self._stamps
        i = bisect.bisect_left(stamps, stamp_ns)
        if i < len(stamps) and stamps[i] == stamp_ns:
            return self._directions[i]
        if i == 0:
            return self._directions[0] if stamps[0] - stamp_ns <= self._slack else None
        if i == len(stamps):
            return self._directions[-1] if stamp_ns - stamps[-1] <= self._slack else None
        w = (stamp_ns - stamps[i - 1]) / (stamps[i] - stamps[i - 1])
        d = (1.0 - w) * self._directions[i - 1] + w * self._directions[i]
        return d / np.linalg.norm(d)

    @classmethod
    def read(cls, path: str | Path) -> TabulatedSunReference:
        """From a CSV ``stamp_ns,x,y,z`` (one header line allowed)."""
        path = Path(path)
        if not path.is_file():
            raise ValueError(f"sun reference table {path}: no such file")
        rows = []
        for number, line in enumerate(path.read_text().splitlines(), 1):
            parts = [p.strip() for p in line.split(",")]
            if not line.strip() or (number == 1 and not parts[0].lstrip("-").isdigit()):
                continue
            if len(parts) != 4:
                raise ValueError(f"sun reference table {path}:{number}: expected stamp_ns,x,y,z")
            try:
                rows.append((int(parts[0]), float(parts[1]), float(parts[2]), float(parts[3])))
            except ValueError:
                raise ValueError(f"sun reference table {path}:{number}: not numbers: {line!r}") from None
        if not rows:
            raise ValueError(f"sun reference table {path} is empty")
        table = np.array(rows, dtype=object)
        return cls(np.array(table[:, 0], dtype=np.int64), np.array(table[:, 1:], dtype=float))

    @staticmethod
    def write(path: str | Path, stamps_ns: ArrayLike, directions: ArrayLike) -> None:
        lines = ["stamp_ns,x,y,z"]
        for stamp, d in zip(np.asarray(stamps_ns, dtype=np.int64), np.asarray(directions, dtype=float), strict=True):
            lines.append(f"{int(stamp)},{d[0]:.17g},{d[1]:.17g},{d[2]:.17g}")
        Path(path).write_text("\n".join(lines) + "\n")
