"""From measured tracks to the model's parameters.

`tracks` reads and writes the track format (a CSV per release of the ball: ``t, x, y`` and the
optional ``omega``, ``voltage``, ``theta`` columns), the data both a fit and a run on the rig
exchange. See docs/reference/tracks.md.
"""

from saddle_env.calibrate.tracks import (
    COLUMNS,
    Track,
    TrackError,
    read_track,
    read_tracks,
    write_track,
)

__all__ = ["COLUMNS", "Track", "TrackError", "read_track", "read_tracks", "write_track"]
