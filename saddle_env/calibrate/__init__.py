"""From measured tracks to the model's parameters.

`tracks` reads and writes the track format (a CSV per release of the ball: ``t, x, y`` and the
optional ``omega``, ``voltage``, ``theta`` columns), the data both a fit and a run on the rig
exchange. See docs/reference/tracks.md.

`fit.fit_tracks` fits the model's unknowns to tracks (least squares with multiple shooting on
`model`, the forward model over the project's batched predictor); `synthetic.synthetic_tracks`
makes tracks of a simulated rig with known parameters; `cli` is ``saddle-fit``
(docs/how-to/calibrate.md); `plot` draws measured against fitted orbits. Those modules import
scipy and (the plot) matplotlib, so they are not imported here.
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
