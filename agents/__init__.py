"""Controllers for SaddleTrap-v0: baselines (`agents.baselines`), evaluation
(`agents.evaluation`, the ``saddle-eval`` command) and training (`agents.training`)."""
