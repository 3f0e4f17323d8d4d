"""python -m saddle_env.bench"""

import sys

from . import main

sys.exit(main())
