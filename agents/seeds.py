"""Every seed range the agents use, declared once, so that evaluation never overlaps
training or model selection.

| range | used by |
|---|---|
| ``s .. s + n_envs − 1`` (s = ``--seed``, 0-99) | a training run's balls (each ball's |
| | generator carries on across its resets) |
| ``SEARCH_SEED ..`` (64 episodes) | the best-constant grid search, also the warm start's |
| | target and ``mpc``'s reference speed |
| ``SEARCH_SEED + 64 ..`` (512) | best-const's paired comparison of the grid's best speeds |
| ``VALIDATION_SEED ..`` | the validation curve of every training run (the same episodes |
| | for every seed) and the reference lines drawn beside it |
| ``RESELECT_SEED + s·8n ..`` | run s's 4n fresh episodes, on which its best snapshots are |
| | re-evaluated before one is shipped, then 4n report episodes, on |
| | which the shipped one's recorded score is measured (n = its |
| | validation episodes, `agents.training.selection`) |
| ``TEST_SEED ..`` | the leaderboard's frozen test set, nothing else |
| ``COMPARE_SEED ..`` | the comparison ``train.py`` prints at the end of a run |
| ``IMITATION_SEED + s·k ..`` | run s's imitation warm start (k = its episodes, `agents.training.imitation`) |
| ``DESIGN_SEED ..`` | measurements made to design a task level (the numbers in a level's |
| | ``why_hard``; 200 episodes each) |
"""

SEARCH_SEED = 12_345
VALIDATION_SEED = 1_000_000
RESELECT_SEED = 1_500_000
MAX_EVAL_EPISODES = 250_000     # so that the two ranges above never meet
TEST_SEED = 2_000_000
COMPARE_SEED = 3_000_000
IMITATION_SEED = 4_000_000
DESIGN_SEED = 500_000

__all__ = ["COMPARE_SEED", "DESIGN_SEED", "IMITATION_SEED", "MAX_EVAL_EPISODES", "RESELECT_SEED",
           "SEARCH_SEED", "TEST_SEED", "VALIDATION_SEED"]
