"""Tools for testing PhySynth and models written for it: the model conformance check
(:mod:`physynth.testing.check_model`) and the fuzz campaign (:mod:`physynth.testing.fuzz`)."""

from .check_model import ModelCase, check_model

__all__ = ["ModelCase", "check_model"]
