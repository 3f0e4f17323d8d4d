"""The training back ends behind `agents.training.trainer`, one module each: Stable-Baselines3
(`sb3`), SBX's PPO on JAX (`sbx`) and Ray RLlib (`rllib`). A back end has
``check_dependencies``, ``RESUME_NEEDS_TRUST`` and ``run`` (see `agents.training.trainer`)."""
