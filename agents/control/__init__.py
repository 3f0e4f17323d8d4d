"""Controllers with Stable-Baselines3's ``predict`` signature, and the seeded rollouts that
measure them: constant speeds, zero and random (`controllers`), the searched best constant
(`best_constant`), model-predictive control (`mpc`), the clairvoyant upper reference
(`clairvoyant`), and running seeded episodes of many balls at once (`rollout`). Imports only
`saddle_env` and the top of `agents`."""

from pathlib import Path

from saddle_env.compilation import cache as _cache

# `mpc`'s functions are compiled with numba's on-disk cache and call saddle_env's kernels, so
# this package's cache files must go when a source they import changes, as saddle_env's own
# do (saddle_env/compilation/cache.py). This tree (agents/) is refreshed here, before any of
# its compiled functions is first called, naming saddle_env's tree as one it depends on, and
# the name this package was imported by (`agents` in a clone, `saddle_agents` installed):
# numba's cached code loads its module by the name it was compiled under.
_cache.refresh(Path(__file__).resolve().parents[1], depends_on=[_cache.PACKAGE],
               import_name=__name__.rpartition(".")[0])
