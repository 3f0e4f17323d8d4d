"""Running an exported policy without torch: numpy and onnxruntime only (the ``[deploy]``
extra). ``saddle-export MODEL --out DIR`` writes the folder (docs/how-to/export.md);

```
from saddle_env.deploy import Controller
controller = Controller.from_dir("DIR")
action = controller.act(observation)
```

onnxruntime and onnx are imported when a folder is loaded, not with this package, so
``import saddle_env`` works without them; a missing one is a one-line `ImportError` naming
the extra. A folder is read as data: `saddle_env.deploy.folder` checks it first.
"""

from .controller import Controller
from .folder import PolicyFolderError, PolicySpec, read_spec

__all__ = ["Controller", "PolicyFolderError", "PolicySpec", "read_spec"]
