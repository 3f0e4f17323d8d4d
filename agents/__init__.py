"""Controllers and tools for the SaddleTrap task levels, one job per module (lower first):
`agents.rollout` (running seeded episodes), `agents.controllers` (constant speeds, zero,
random), `agents.best_constant` (the searched best constant, cached), `agents.mpc` (the
model-predictive baseline), `agents.policies` (baselines by name, model files and their
sidecars), `agents.cli_args` (the shared command-line pieces), `agents.evaluation` (the
``saddle-eval`` command) and `agents.training` (behind ``train.py``). `agents.baselines` is a
deprecated re-export of the old names."""
