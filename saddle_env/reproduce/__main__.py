"""``python -m saddle_env.reproduce``."""

import sys

from .cli import main

sys.exit(main())
