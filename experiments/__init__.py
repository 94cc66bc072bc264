"""The experiments: one module or sub-package per experiment, on top of the library (docs/architecture.md)."""
