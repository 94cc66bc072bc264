import os

os.environ.setdefault("JAXDIP_NO_PROGRESS", "1")

import jaxdip  # noqa: E402,F401  (enables float64 before any test builds an array)
