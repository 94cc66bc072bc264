import os

import tempfile

os.environ.setdefault("JAXDIP_NO_PROGRESS", "1")
# the CLI's on-disk compilation cache goes to a throwaway folder, not the user's ~/.cache
os.environ.setdefault("JAXDIP_CACHE_DIR", os.path.join(tempfile.gettempdir(), f"jaxdip-test-xla-{os.getuid()}"))

import jaxdip  # noqa: E402,F401  (enables float64 before any test builds an array)
