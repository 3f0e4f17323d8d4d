"""``python -m agents.benchmark``: the benchmark's command (`agents.benchmark.run`)."""

from .run import main

raise SystemExit(main())
