"""Recorded tracks from a file: the Argoverse 2 scenario format, or the documented CSV format.

CSV (``docs/coverage.md``, "Track files"): a header line and one row per sample,

    track_id,t,x,y,heading,speed

``t`` in seconds (any clock, increasing within a track), ``x, y`` in metres in one metric world
frame, ``heading`` in radians from +x counter-clockwise (wrapped or not), ``speed`` in m/s (>= 0).
Rows may come in any order. Each track is resampled to 10 Hz (``av2.SAMPLE_DT_S``) by linear
interpolation (heading unwrapped first) and cut where two samples lie more than ``MAX_GAP_S``
apart; pieces shorter than ``av2.MIN_TRACK_S`` are dropped. A ``.parquet`` file is read as an
Argoverse 2 scenario (``av2.load_tracks``).
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from experiments.av2 import MIN_TRACK_S, SAMPLE_DT_S, Track, load_tracks

COLUMNS = ("track_id", "t", "x", "y", "heading", "speed")
#: Samples further apart than this split a track.
MAX_GAP_S = 0.5


def load(path: Path, min_s: float = MIN_TRACK_S) -> list[Track]:
    """The tracks in ``path`` (``.csv``: the documented format; ``.parquet``: Argoverse 2)."""
    path = Path(path)
    if path.suffix == ".parquet":
        return load_tracks(path, min_s=min_s)
    if path.suffix == ".csv":
        return load_csv(path, min_s=min_s)
    raise ValueError(f"{path}: unknown track format (use .csv as documented, or .parquet)")


def load_csv(path: Path, min_s: float = MIN_TRACK_S) -> list[Track]:
    """Tracks of a CSV file in the documented format, resampled to 10 Hz, sorted by id."""
    rows: dict[str, list[tuple[float, ...]]] = {}
    with Path(path).open(newline="") as f:
        reader = csv.DictReader(f)
        missing = set(COLUMNS) - set(reader.fieldnames or ())
        if missing:
            raise ValueError(f"{path}: missing columns {sorted(missing)} (need {COLUMNS})")
        for line, row in enumerate(reader, start=2):
            try:
                values = tuple(float(row[c]) for c in COLUMNS[1:])
            except ValueError as exc:
                raise ValueError(f"{path}:{line}: {exc}") from None
            if not all(math.isfinite(v) for v in values) or values[4] < 0:
                raise ValueError(f"{path}:{line}: values must be finite and speed >= 0")
            rows.setdefault(row["track_id"], []).append(values)
    tracks = []
    for tid in sorted(rows):
        samples = np.array(sorted(rows[tid]))
        tracks += _resampled(tid, samples, min_s)
    return tracks


def _resampled(track_id: str, samples: np.ndarray, min_s: float) -> list[Track]:
    """One track's samples [n, 5] (t, x, y, heading, speed) at 10 Hz, one Track per gap-free
    piece at least ``min_s`` long."""
    t = samples[:, 0]
    if np.any(np.diff(t) <= 0):
        raise ValueError(f"track {track_id!r}: timestamps must increase")
    cuts = np.flatnonzero(np.diff(t) > MAX_GAP_S) + 1
    out = []
    for k, piece in enumerate(np.split(samples, cuts)):
        if len(piece) < 2 or piece[-1, 0] - piece[0, 0] < min_s - 1e-9:
            continue
        grid = piece[0, 0] + SAMPLE_DT_S * np.arange(
            math.floor((piece[-1, 0] - piece[0, 0]) / SAMPLE_DT_S + 1e-9) + 1
        )
        heading = np.unwrap(piece[:, 3])
        name = track_id if len(cuts) == 0 else f"{track_id}#{k}"
        out.append(
            Track(
                track_id=name,
                t=grid,
                x=np.interp(grid, piece[:, 0], piece[:, 1]),
                y=np.interp(grid, piece[:, 0], piece[:, 2]),
                heading=np.interp(grid, piece[:, 0], heading),
                speed=np.interp(grid, piece[:, 0], piece[:, 4]),
            )
        )
    return out


def write_csv(path: Path, tracks: list[Track]) -> Path:
    """Write ``tracks`` in the documented CSV format."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with Path(path).open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(COLUMNS)
        for tr in tracks:
            for i in range(len(tr.t)):
                writer.writerow(
                    [
                        tr.track_id,
                        *(f"{v[i]:.6f}" for v in (tr.t, tr.x, tr.y, tr.heading, tr.speed)),
                    ]
                )
    return path
