"""``python -m saddle_env.calibrate``: the ``saddle-fit`` command."""

import sys

from .cli import main

sys.exit(main())
