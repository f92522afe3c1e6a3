"""Tools for testing PhySynth and models written for it (:mod:`~physynth.testing.check_model`)."""

from .check_model import ModelCase, check_model

__all__ = ["ModelCase", "check_model"]
