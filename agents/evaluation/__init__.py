"""Evaluating policies: baselines by name and model files by path (`policies`), files from
elsewhere read as data (`model_files`, `literal_kwargs`, `rllib_policy`), and the
``saddle-eval`` command with its tables and intervals (`evaluate`), and what a policy does to
the saddle's speed (`speed_modulation`). Imports `agents.control`."""
