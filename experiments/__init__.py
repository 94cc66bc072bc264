"""jaxdip's experiments, one module or sub-package each, each defining ``EXPERIMENT`` (or ``EXPERIMENTS``).

``jaxdip list`` finds them here without a list kept by hand (``jaxdip.runner.discovery``, docs/registry.md);
``fidelity`` holds the fidelity studies, which are not experiments.
"""
