"""Testing tools shipped with PhySynth: the fuzz campaign (:mod:`physynth.testing.fuzz`)."""
