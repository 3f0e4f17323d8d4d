"""The track format: one CSV file per release of the ball, as a camera and its tracker see it.

A header row names the columns; ``t``, ``x`` and ``y`` are required, the rest optional:

========= ====== =================================================================
column    unit   meaning
========= ====== =================================================================
t         s      time of the frame; strictly increasing, any spacing (frames may
                 be missing, the rate may vary)
x, y      m      the ball's centre seen from above, laboratory frame, origin on
                 the saddle's axis; empty or ``nan`` where tracking lost the ball
omega     rad/s  the tachometer's saddle speed (optional)
voltage   V      the motor's voltage (optional)
theta     rad    the saddle's angle from an encoder (optional)
========= ====== =================================================================

Lines starting with ``#`` are comments. A file is data from elsewhere: it is parsed as numbers
only, bounded in size, and every refusal names the file, the line and the rule it broke.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable
from dataclasses import InitVar, dataclass, field
from pathlib import Path

import numpy as np

from saddle_env.jobs.files import write_text_atomically

REQUIRED = ("t", "x", "y")
OPTIONAL = ("omega", "voltage", "theta")
COLUMNS = REQUIRED + OPTIONAL
UNITS = {"t": "s", "x": "m", "y": "m", "omega": "rad/s", "voltage": "V", "theta": "rad"}
MAX_BYTES = 64 * 2**20       # ~ an hour at 1,000 fps: far more than one release of the ball
MAX_ROWS = 2_000_000
MIN_POSITIONS = 3            # fewer tracked frames than this cannot constrain an orbit
MAX_POSITION = 1.0           # [m] a ball on a tabletop saddle is within ~0.1 m of the axis:
                             # beyond this the file is almost surely in pixels or centimetres


class TrackError(ValueError):
    """A track file or array that breaks the format; the message names file, line and rule."""


@dataclass(frozen=True, eq=False)
class Track:
    """One release of the ball: frame times and positions, plus the optional channels.

    ``x`` and ``y`` hold NaN where tracking lost the ball (`tracked` says where it did not);
    an optional channel is None when the file has no such column, and NaN where a reading is
    missing. Arrays are float64 and read-only.

    Parameters
    ----------
    t : numpy.ndarray
        Frame times [s], increasing.
    x, y : numpy.ndarray
        The ball's centre [m], seen from above in the laboratory frame.
    omega : numpy.ndarray, optional
        The tachometer's speed [rad/s].
    voltage : numpy.ndarray, optional
        The motor's voltage [V].
    theta : numpy.ndarray, optional
        The saddle's angle [rad].
    source : str
        Where the track came from, for error messages.
    file_lines : numpy.ndarray, optional
        Each row's line in its file, so that error messages point at lines, not rows.

    Raises
    ------
    TrackError
        If a required column is missing, the arrays' lengths differ, or the values break the
        format (docs/reference/tracks.md).
    """

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    omega: np.ndarray | None = None
    voltage: np.ndarray | None = None
    theta: np.ndarray | None = None
    source: str = field(default="<array>")
    file_lines: InitVar[np.ndarray | None] = None

    def __post_init__(self, file_lines: np.ndarray | None) -> None:
        n = np.shape(self.t)[0] if np.ndim(self.t) == 1 else -1
        for name in COLUMNS:
            value = getattr(self, name)
            if value is None:
                if name in REQUIRED:
                    raise TrackError(f"{self.source}: column {name!r} is required")
                continue
            arr = np.array(value, dtype=float)
            if arr.ndim != 1 or arr.shape[0] != n:
                raise TrackError(f"{self.source}: {name!r} must be a 1-D array as long as 't' "
                                 f"({n} values), got shape {arr.shape}")
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)
        _check(self, file_lines)

    @property
    def tracked(self) -> np.ndarray:
        """True at the frames where the ball's position was measured."""
        return ~(np.isnan(self.x) | np.isnan(self.y))

    @property
    def channels(self) -> tuple[str, ...]:
        """The columns this track has, in the format's order."""
        return tuple(c for c in COLUMNS if getattr(self, c) is not None)

    def __len__(self) -> int:
        return int(self.t.shape[0])


def _check(track: Track, lines: np.ndarray | None = None) -> None:
    """The rules every track keeps, whether read from a file or built from arrays. ``lines``
    maps row i to its line in the file, so an error points at what the user can open."""

    def where(i: int) -> str:
        return f"line {int(lines[i])}" if lines is not None else f"row {i}"

    src, t = track.source, track.t
    if len(t) > MAX_ROWS:
        raise TrackError(f"{src}: {len(t)} rows; a track holds at most {MAX_ROWS:,}")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise TrackError(f"{src}, {where(bad[0])}: 't' must be a finite time [s], "
                         f"got {float(t[bad[0]])}")
    steps = np.diff(t)
    bad = np.flatnonzero(steps <= 0)
    if bad.size:
        i = bad[0] + 1
        raise TrackError(f"{src}, {where(i)}: 't' = {float(t[i])!r} s does not come after the previous "
                         f"row's {float(t[i - 1])!r} s; times must be strictly increasing (sort the "
                         f"file, and drop repeated frames)")
    for name in COLUMNS[1:]:
        v = getattr(track, name)
        if v is None:
            continue
        bad = np.flatnonzero(np.isinf(v))
        if bad.size:
            raise TrackError(f"{src}, {where(bad[0])}: {name!r} is infinite; write a number "
                             f"[{UNITS[name]}], or leave the cell empty for a missing value")
    lost_x, lost_y = np.isnan(track.x), np.isnan(track.y)
    bad = np.flatnonzero(lost_x != lost_y)
    if bad.size:
        raise TrackError(f"{src}, {where(bad[0])}: only one of 'x' and 'y' is given; a lost frame "
                         f"leaves both empty")
    seen = ~lost_x
    if seen.sum() < MIN_POSITIONS:
        raise TrackError(f"{src}: {int(seen.sum())} frames with a position; a track needs at "
                         f"least {MIN_POSITIONS}")
    for name in ("x", "y"):
        v = getattr(track, name)
        far = np.flatnonzero(seen & (np.abs(np.nan_to_num(v)) > MAX_POSITION))
        if far.size:
            raise TrackError(f"{src}, {where(far[0])}: {name!r} = {float(v[far[0]])!r}; positions are in "
                             f"metres from the saddle's axis and must lie within ±{MAX_POSITION} m "
                             f"(pixels or centimetres? convert them first)")


def _parse_number(text: str, src: str, line: int, name: str) -> float:
    text = text.strip()
    if text == "" or text.lower() in ("nan", "na"):
        return math.nan
    try:
        return float(text)
    except ValueError:
        raise TrackError(f"{src}, line {line}: {name!r} = {text!r} is not a number") from None


def read_track(path: str | Path) -> Track:
    """Read one track file (the format: docs/reference/tracks.md).

    Parameters
    ----------
    path : str or Path
        The CSV file.

    Returns
    -------
    Track
        The track, checked.

    Raises
    ------
    TrackError
        Naming the file and line, for a missing or unknown column, a row of the wrong width, a
        cell that is not a number, times that do not increase, an infinite value, a half-lost
        frame, positions that are not in metres, or a file beyond the size limits.
    """
    path = Path(path)
    src = str(path)
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise TrackError(f"{src}: cannot read the track file ({exc.strerror})") from None
    if size > MAX_BYTES:
        raise TrackError(f"{src}: {size:,} bytes; a track file holds at most {MAX_BYTES:,}")
    try:
        text = path.read_text(encoding="utf-8-sig")   # a spreadsheet's BOM is not a column name
    except UnicodeDecodeError as exc:
        raise TrackError(f"{src}: not UTF-8 text (byte {exc.start}); a track is a CSV file") \
            from None
    return parse_track(text, src)


def parse_track(text: str, source: str = "<text>") -> Track:
    """`read_track` on the text of a file."""
    # newline=None: \r\n and a lone \r end a line too, as when read_track reads a file
    rows = csv.reader(io.StringIO(text, newline=None))
    try:
        return _parse_rows(rows, source)
    except csv.Error as exc:
        raise TrackError(f"{source}, line {rows.line_num}: not a CSV row ({exc})") from None


def _parse_rows(rows: Iterable[list[str]], source: str) -> Track:
    header: list[str] | None = None
    values: list[list[float]] = []
    lines: list[int] = []
    for line_no, row in enumerate(rows, start=1):
        if not row or not "".join(row).strip() or row[0].lstrip().startswith("#"):
            continue
        if header is None:
            header = [c.strip().lower() for c in row]
            unknown = [c for c in header if c not in COLUMNS]
            if unknown:
                raise TrackError(f"{source}, line {line_no}: unknown column(s) {unknown}; the "
                                 f"columns are {list(REQUIRED)} and optionally {list(OPTIONAL)}")
            missing = [c for c in REQUIRED if c not in header]
            if missing:
                raise TrackError(f"{source}, line {line_no}: the header lacks {missing}; the "
                                 f"columns are {list(REQUIRED)} and optionally {list(OPTIONAL)}")
            twice = sorted({c for c in header if header.count(c) > 1})
            if twice:
                raise TrackError(f"{source}, line {line_no}: column(s) {twice} appear twice")
            continue
        if len(row) != len(header):
            raise TrackError(f"{source}, line {line_no}: {len(row)} cells, the header has "
                             f"{len(header)}")
        if len(values) >= MAX_ROWS:
            raise TrackError(f"{source}: more than {MAX_ROWS:,} rows; a track holds at most that")
        values.append([_parse_number(c, source, line_no, n) for c, n in zip(row, header)])
        lines.append(line_no)
    if header is None:
        raise TrackError(f"{source}: no header row; the first line names the columns, e.g. "
                         f"'t,x,y'")
    data = np.array(values, dtype=float).reshape(len(values), len(header))
    cols = {name: data[:, header.index(name)] for name in header}
    return Track(**cols, source=source, file_lines=np.array(lines, dtype=int))


def read_tracks(paths: str | Path | Iterable[str | Path]) -> list[Track]:
    """Tracks from files, or from every ``*.csv`` in a run folder (sorted by name).

    Parameters
    ----------
    paths : str, Path or iterable of them
        Track files, or a folder of them.

    Returns
    -------
    list of Track
        The tracks, in the order given (a folder's by file name).

    Raises
    ------
    TrackError
        If there are no track files, or one of them breaks the format (`read_track`).
    """
    if isinstance(paths, (str, Path)):
        p = Path(paths)
        if p.is_dir():
            files = sorted(p.glob("*.csv"))
            if not files:
                raise TrackError(f"{p}: a run folder with no *.csv track files")
            return [read_track(f) for f in files]
        return [read_track(p)]
    out = [t for p in paths for t in read_tracks(p)]
    if not out:
        raise TrackError("no track files given")
    return out


def format_track(track: Track, comments: Iterable[str] = ()) -> str:
    """The file text of a track: `repr`-exact numbers, so a written track reads back equal."""
    names = track.channels
    out = io.StringIO()
    for c in comments:
        for line in str(c).splitlines():
            out.write(f"# {line}\n")
    out.write(",".join(names) + "\n")
    cols = [getattr(track, n) for n in names]
    for i in range(len(track)):
        out.write(",".join("" if math.isnan(c[i]) else repr(float(c[i])) for c in cols) + "\n")
    return out.getvalue()


def write_track(path: str | Path, track: Track, comments: Iterable[str] = ()) -> Path:
    """Write a track file whole or not at all (a stop mid-write leaves no half file).

    Parameters
    ----------
    path : str or Path
        The CSV file to write.
    track : Track
        The track.
    comments : iterable of str
        Comment lines to put at the top of the file.

    Returns
    -------
    Path
        The file written.
    """
    return write_text_atomically(path, format_track(track, comments))
