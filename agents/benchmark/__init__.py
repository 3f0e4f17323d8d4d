"""Measuring: the benchmark over algorithms, levels and seeds (`run`; ``python -m
agents.benchmark``) and its report (`report`), the leaderboard on frozen test episodes
(`leaderboard`), what is left to win (`headroom`), time to target (`time_to_target`), where
training time goes (`profile_training`), RLlib's throughput (`rllib_throughput`) and shipping
the best of a recipe's runs (`ship`). The top layer: imports everything below it."""
