"""Every seed range the agents use, declared once, so that evaluation never overlaps
training or model selection.

| range | used by |
|---|---|
| ``s .. s + n_envs − 1`` (s = ``--seed``, 0-99) | a training run's balls (each ball's |
| | generator carries on across its resets) |
| ``SEARCH_SEED ..`` (64 episodes) | the best-constant search, also the warm start's target |
| ``VALIDATION_SEED + s ..`` | model selection during training run s |
| ``TEST_SEED ..`` | the leaderboard's frozen test set, nothing else |
| ``COMPARE_SEED ..`` | the comparison ``train.py`` prints at the end of a run |
| ``IMITATION_SEED + s·k ..`` | run s's imitation warm start (k = its episodes, `agents.training.imitation`) |
| ``DESIGN_SEED ..`` | measurements made to design a task level (the numbers in a level's |
| | ``why_hard``; 200 episodes each) |
"""

SEARCH_SEED = 12_345
VALIDATION_SEED = 1_000_000
TEST_SEED = 2_000_000
COMPARE_SEED = 3_000_000
IMITATION_SEED = 4_000_000
DESIGN_SEED = 500_000

__all__ = ["COMPARE_SEED", "DESIGN_SEED", "IMITATION_SEED", "SEARCH_SEED", "TEST_SEED",
           "VALIDATION_SEED"]
