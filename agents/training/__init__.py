"""Training an agent: the seam behind ``train.py`` (`trainer`), a run's settings and folder
(`runs`), recipes and what they can say (`recipes`, `schedules`, `shaping`, `warm_start`,
`imitation`), the run's closing report (`run_report`), compiling ahead beside a run
(`compile_ahead`), and the back ends (`backends`). Imports `agents.evaluation` and below."""
