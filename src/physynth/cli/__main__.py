"""``python -m physynth.cli``: the same as the ``physynth`` command."""

from . import main

main()
