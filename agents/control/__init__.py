"""Controllers with Stable-Baselines3's ``predict`` signature, and the seeded rollouts that
measure them: constant speeds, zero and random (`controllers`), the searched best constant
(`best_constant`), model-predictive control (`mpc`), the clairvoyant upper reference
(`clairvoyant`), and running seeded episodes of many balls at once (`rollout`). Imports only
`saddle_env` and the top of `agents`."""
