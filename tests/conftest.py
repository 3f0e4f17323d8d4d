import sys
from pathlib import Path

# Tests import their helpers and the independent reference model as plain modules.
sys.path.insert(0, str(Path(__file__).parent))
