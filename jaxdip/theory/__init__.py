"""The documents' criteria and bounds as functions."""

from jaxdip.theory import mhe

__all__ = ["mhe"]
