"""python -m saddle_env.workprecision"""

import sys

from . import main

sys.exit(main())
