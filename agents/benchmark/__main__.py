"""``python -m agents.benchmark``: the benchmark's command (`agents.benchmark.run`)."""

from agents.benchmark.run import main

raise SystemExit(main())
